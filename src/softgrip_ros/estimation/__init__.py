"""softgrip_ros.estimation."""

"""softgrip_ros.model."""

"""softgrip_ros.canbus."""

"""softgrip_ros.control."""

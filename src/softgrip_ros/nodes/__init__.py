"""softgrip_ros.nodes."""

"""softgrip_ros: a ROS 2 Jazzy driver suite for a two-finger pneumatic soft gripper.

The physics (``model``), estimation (``estimation``), control (``control``) and
CAN (``canbus``) cores are plain Python and numpy, importable without ROS.
``nodes`` holds the thin rclpy adapters.
"""
__version__ = "0.1.0"

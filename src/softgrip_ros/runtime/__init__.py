"""Process and thread machinery the nodes run the models in (no ROS): the L2 solver's child
process and the thread that feeds it. The models themselves live in softgrip_ros.model."""

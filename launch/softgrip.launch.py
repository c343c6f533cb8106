"""Bring up one softgrip gripper: ros2 launch softgrip_ros softgrip.launch.py [name:=value ...]

Arguments (``ros2 launch softgrip_ros softgrip.launch.py --show-args`` lists them):

- ``namespace``: every node and topic under it (two grippers: /g1 and /g2);
- ``prefix``: put before the gripper's joint and frame names, as the URDF macro's ``prefix``;
- ``can_interface``, ``can_channel``: the python-can bus (``virtual`` is in-process only);
- ``params_file``: the parameters (default: the installed config/softgrip.yaml);
- ``use_sim``: a simulated device answers on the bus instead of hardware;
- ``standalone``: the four node executables instead of the composed ``controller``;
- ``publish_robot_description``: robot_state_publisher with urdf/softgrip.urdf.xacro, when it
  is installed (TF for RViz and MoveIt from joint_states).

The composed ``controller`` starts its own simulated device on a ``virtual`` bus; with another
interface, ``use_sim`` starts ``sim_device`` beside it. The standalone nodes are separate
processes, so they need a bus that crosses processes (``softgrip_ipc``, or SocketCAN).
"""
import os

from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, LogInfo, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

PACKAGE = "softgrip_ros"
NODES = ("pressure_controller", "estimator", "kinematics", "grasp_manager")
ARGUMENTS = {  # name: (default, description)
    "namespace": ("", "namespace of every node and topic, e.g. /g1"),
    "prefix": ("", "prefix of the gripper's joint and frame names, as the URDF's, e.g. g1_"),
    "can_interface": ("virtual", "python-can interface: virtual (in-process), softgrip_ipc, "
                      "socketcan, pcan, ..."),
    "can_channel": ("softgrip", "python-can channel, e.g. can0"),
    "params_file": ("", "a ROS 2 params file (empty: the installed config/softgrip.yaml)"),
    "use_sim": ("true", "start the simulated device on the bus (true|false)"),
    "standalone": ("false", "the separate node executables instead of controller (true|false)"),
    "publish_robot_description": ("true", "robot_state_publisher with the gripper's URDF, "
                                  "when it is installed (true|false)"),
}


def _flag(context, name: str) -> bool:
    value = LaunchConfiguration(name).perform(context).strip().lower()
    if value not in ("true", "false"):
        raise ValueError(f"launch argument {name} must be true or false, got {value!r}")
    return value == "true"


def _bringup(context, *args, **kwargs):
    namespace = LaunchConfiguration("namespace").perform(context)
    prefix = LaunchConfiguration("prefix").perform(context)
    interface = LaunchConfiguration("can_interface").perform(context)
    channel = LaunchConfiguration("can_channel").perform(context)
    share = get_package_share_directory(PACKAGE)
    params_file = (LaunchConfiguration("params_file").perform(context) or
                   os.path.join(share, "config", "softgrip.yaml"))
    use_sim, standalone = _flag(context, "use_sim"), _flag(context, "standalone")
    if interface == "virtual" and standalone:
        raise ValueError("can_interface virtual is in-process only: standalone nodes need a bus "
                         "that crosses processes (can_interface:=softgrip_ipc, or socketcan)")
    if interface == "virtual" and not use_sim:
        raise ValueError("can_interface virtual with use_sim false: nothing would answer on the "
                         "bus (give the hardware's interface, e.g. can_interface:=socketcan)")
    overrides = {"prefix": prefix, "can.interface": interface, "can.channel": channel}
    parameters = [params_file, overrides]
    actions = []
    if standalone:
        actions += [Node(package=PACKAGE, executable=name, namespace=namespace,
                         parameters=parameters, output="screen") for name in NODES]
    else:
        # with a virtual bus, controller starts the simulated device itself
        actions.append(Node(package=PACKAGE, executable="controller", namespace=namespace,
                            parameters=parameters, output="screen"))
    if use_sim and (standalone or interface != "virtual"):
        actions.append(Node(package=PACKAGE, executable="sim_device", namespace=namespace,
                            parameters=parameters, output="screen"))
    if _flag(context, "publish_robot_description"):
        actions += _robot_state_publisher(share, namespace, prefix)
    return actions


def _robot_state_publisher(share: str, namespace: str, prefix: str) -> list:
    try:
        get_package_share_directory("robot_state_publisher")
    except PackageNotFoundError:
        return [LogInfo(msg="robot_state_publisher is not installed: no robot_description or "
                            "TF (joint_states is still published)")]
    import xacro
    description = xacro.process_file(os.path.join(share, "urdf", "softgrip.urdf.xacro"),
                                     mappings={"prefix": prefix}).toxml()
    return [Node(package="robot_state_publisher", executable="robot_state_publisher",
                 namespace=namespace, parameters=[{"robot_description": description}],
                 output="screen")]


def generate_launch_description():
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=description)
         for name, (default, description) in ARGUMENTS.items()]
        + [OpaqueFunction(function=_bringup)])

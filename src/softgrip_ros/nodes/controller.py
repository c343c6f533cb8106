"""controller: the whole suite in one process, the main entry point.

The pressure controller, estimator, kinematics and grasp manager on one MultiThreadedExecutor;
with ``can.interface`` virtual (the default) also the simulated device, on the controller's
virtual channel. Parameters come from config/softgrip.yaml in the package share unless a
``--params-file`` is given; ``--ros-args -r __ns:=/softgrip`` puts everything in a namespace.
SIGINT or SIGTERM: the grasp manager stops, the pressure controller vents, exit 0.

The nodes are the parts of the runtime core (softgrip_ros.runtime.core), wired once by its
``wire``: the busy links between them are direct calls over typed ports, not DDS (each reading
batch, status report, estimate, NIS evidence, scene and pressure command). rclpy has no
intra-process transport, and each message the executor takes costs a few hundred microseconds of
Python: at 700 readings, 200 estimates and 50 statuses a second, that saturated a core
(docs/benchmarks.md, bench_e2e). The grasp manager owns the pressure here: pressure/command is
published for other subscribers but not subscribed (a command from elsewhere would be overridden
by its next refresh anyway). The other topics are still published for every subscriber; grasp
commands still go through DDS.
"""
from __future__ import annotations

import sys

from rclpy.executors import MultiThreadedExecutor
from rclpy.parameter import Parameter

from softgrip_ros.config_paths import config_file
from softgrip_ros.nodes.common import close_all, run_node
from softgrip_ros.nodes.estimator import EstimatorNode
from softgrip_ros.nodes.grasp_manager import GraspManagerNode
from softgrip_ros.nodes.kinematics import KinematicsNode
from softgrip_ros.nodes.pressure_controller import PressureControllerNode
from softgrip_ros.nodes.sim_device import SimDeviceNode
from softgrip_ros.runtime.core import wire


def with_default_params(args: list) -> list:
    """``args`` with ``--params-file <share>/config/softgrip.yaml`` first, unless one is given:
    a params file given after ``-p`` would override it, so the default goes before the user's."""
    if "--params-file" in args:
        return args
    return [
        *args[:1], "--ros-args", "--params-file",
        str(config_file("softgrip.yaml")), "--", *args[1:]
    ]


def make_nodes(context=None, overrides: dict | None = None) -> list:
    """The composed suite, in start order (closed in reverse: grasp manager first, device last).
    ``overrides``: {node name: [Parameter]} on top of the params file (tests)."""
    overrides = overrides or {}
    nodes = []
    try:
        controller = PressureControllerNode(
            in_process=True, context=context,
            parameter_overrides=overrides.get("pressure_controller", []))
        nodes.append(controller)
        interface, channel = controller.values["can.interface"], controller.values["can.channel"]
        if interface == "virtual":
            nodes.insert(
                0,
                SimDeviceNode(
                    context=context, parameter_overrides=[
                        Parameter("can.interface", value=interface),
                        Parameter("can.channel", value=channel)
                    ]))
        # each kept as soon as it is made: its threads run from then on
        estimator = EstimatorNode(in_process=True, context=context,
                                  parameter_overrides=overrides.get("estimator", []))
        nodes.append(estimator)
        kinematics = KinematicsNode(in_process=True, context=context,
                                    parameter_overrides=overrides.get("kinematics", []))
        nodes.append(kinematics)
        grasp_manager = GraspManagerNode(in_process=True, context=context,
                                         parameter_overrides=overrides.get("grasp_manager", []))
        nodes.append(grasp_manager)
        wire(controller, estimator, kinematics, grasp_manager)
    except BaseException:  # a Ctrl-C too: their threads must not run into the interpreter's exit
        close_all(nodes)
        raise
    return nodes


def main(args=None) -> int:
    args = with_default_params(list(sys.argv if args is None else args))
    return run_node(make_nodes, args,
                    executor_factory=lambda: MultiThreadedExecutor(num_threads=2))

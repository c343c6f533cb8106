"""kinematics: tip poses from the pressure estimate.

In: pressure/estimate. Out: tip_pose/left and tip_pose/right (PoseWithCovarianceStamped, in
``prefix`` + ``frame_id``: x from the left finger to the right, z towards the tips; the
orientation turns +z to the tip's tangent about y), after each estimate (at most
``publish_rate_hz``). Their covariance is the pressure variance pushed through the model's tip
derivative, J var J' with J = d(x, z, tip angle)/dp. joint_states (JointState) from the same
estimate with the same stamp: every movable joint of urdf/softgrip_macro.xacro, so that
robot_state_publisher puts the URDF's tips where tip_pose says, and ``tip_spacing`` (D2).
finger_markers (MarkerArray line strips of both backbones) only while someone subscribes.
/diagnostics: the model in use, its error bound and whether the pressure lies in its validated
range.

``fidelity``: l0, l1, l2, or auto: the cheapest model whose error bound for the scene meets
``tolerance_m`` (softgrip_ros.model.fidelity). The scene comes from the grasp manager on
``grasp_scene`` (or by direct calls in the composed controller): free bending, or an object
clamped or pinched. L2 solves (milliseconds) run in a child process, handed over by a worker
thread, only when the pressure moved by more than ``resolve_pressure_pa`` and at most once per
``min_solve_interval``; the poses and joints use the latest solve meanwhile.
"""
from __future__ import annotations

import math
import threading

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseWithCovarianceStamped
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import Header
from visualization_msgs.msg import MarkerArray

from softgrip_interfaces.msg import GraspScene
from softgrip_ros.health import Health, Report
from softgrip_ros.model.fidelity import FREE, ROD_CONTINUATION_STEPS, Scene, SceneModel
from softgrip_ros.checks import future_stamp_reason
from softgrip_ros.nodes import messages
from softgrip_ros.nodes.common import (NodeTimers, closed_if_cut_short, listened, publish,
                                       run_node, stamp_msg, stamp_seconds)
from softgrip_ros.nodes.parameters import check_all, declare
from softgrip_ros.nodes.specs import KINEMATICS_SPECS as SPECS
from softgrip_ros.runtime.core import Estimate
from softgrip_ros.runtime.rod_solver import LatestSolveThread, RodSolverProcess


class KinematicsNode(Node):
    """The kinematics part of the runtime core (runtime.core): inputs :meth:`take_estimate` and
    :meth:`take_scene`. in_process: composed, they come from the estimator and the grasp manager
    by direct call (runtime.core.wire) instead of through pressure/estimate and grasp_scene."""

    def __init__(self, in_process: bool = False, **kwargs):
        super().__init__("kinematics", **kwargs)
        # the in-process path calls in from the controller's CAN thread
        self._lock = threading.Lock()
        self.closed = False
        specs = {s.name: s for s in SPECS}
        self.values = declare(self, SPECS)
        self.add_on_set_parameters_callback(lambda params: check_all(
            specs, params, lambda _: "kinematics parameters apply at start-up: restart the node"))
        # L2 runs in a process of its own (spawned at the first scene that needs it): in this one
        # it would starve the controller's threads of the GIL
        self.rod_solver = (RodSolverProcess(
            self.values["gripper_model"], self.values["l2_nice_increment"], ROD_CONTINUATION_STEPS)
                           if self.values["fidelity"] in ("l2", "auto") else None)
        self.solver = self.periodic = None
        with closed_if_cut_short(self):
            self._build(in_process)

    def _build(self, in_process: bool) -> None:
        """Everything after the L2 solver's creation, up to the timers' start."""
        self.model = SceneModel(self.values["fidelity"], self.values["tolerance_m"],
                                self.values["gripper_model"],
                                resolve_pressure_pa=self.values["resolve_pressure_pa"],
                                min_solve_interval_s=self.values["min_solve_interval"],
                                rod_solver=self.rod_solver)
        self.scene = FREE
        logger = self.get_logger()
        self.solver = LatestSolveThread(
            self.model, name="kinematics-l2", on_error=lambda pressure, error: logger.error(
                f"L2 solve at {pressure:.0f} Pa failed: {error!r}"))
        self.period_s = 1.0 / self.values["publish_rate_hz"]
        self.last_publish_s = -math.inf
        self.last = None  # (variance, Evaluation)
        self.left_pub = self.create_publisher(PoseWithCovarianceStamped, "tip_pose/left", 10)
        self.right_pub = self.create_publisher(PoseWithCovarianceStamped, "tip_pose/right", 10)
        self.joints_pub = self.create_publisher(JointState, "joint_states", 10)
        self.frame_id = self.values["prefix"] + self.values["frame_id"]
        self.marker_pub = self.create_publisher(MarkerArray, "finger_markers", 1)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        if not in_process:
            self.create_subscription(FluidPressure, "pressure/estimate", self._on_estimate_message,
                                     10)
            latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
            self.create_subscription(GraspScene, "grasp_scene", self._on_scene_message, latched)
        self.periodic = NodeTimers(self, in_process)
        self.periodic.every(1.0 / self.values["marker_rate_hz"], self._publish_markers)
        self.periodic.every(1.0, self._publish_diagnostics)
        self.periodic.start()

    def close(self) -> None:
        """Nothing to vent: the kinematics only listens. Later in-process estimates are ignored.
        Also what a construction cut short had started."""
        if self.periodic is not None:
            self.periodic.stop()
        with self._lock:
            self.closed = True
        if self.solver is not None:
            self.solver.stop()
        if self.rod_solver is not None:  # first: it ends a running solve the thread waits on
            self.rod_solver.close()
        if self.solver is not None:
            self.solver.close()

    def take_scene(self, scene: Scene) -> None:
        """What the fingers meet from now on (the grasp manager's call)."""
        with self._lock:
            self.scene = scene

    def _on_scene_message(self, msg) -> None:
        try:
            scene = messages.scene_from_message(msg)
        except ValueError as error:
            self.get_logger().error(f"grasp_scene refused, kept {self.scene.describe()}: {error}")
            return
        self.take_scene(scene)

    def _on_estimate_message(self, msg: FluidPressure) -> None:
        stamp_s = stamp_seconds(msg.header.stamp)
        refused = future_stamp_reason(stamp_s,
                                      self.get_clock().now().nanoseconds * 1e-9,
                                      self.values["stamp_tolerance"])
        if refused:  # it would hold every later pose back until its stamp
            self.get_logger().warn(f"pressure/estimate {refused}", throttle_duration_sec=5.0)
            return
        self.take_estimate(Estimate(stamp_s, messages.gauge_pa(msg), msg.variance))

    def take_estimate(self, estimate: Estimate) -> None:
        """Publish both tip poses for the estimate, unless one went out less than a period
        ago."""
        stamp_s, gauge_pa, variance_pa2 = estimate
        with self._lock:
            if (self.closed or stamp_s - self.last_publish_s < 0.9 * self.period_s or
                    not math.isfinite(gauge_pa)):
                return
            evaluation = self.model.evaluate(gauge_pa, self.scene, solve=False)
            if self.model.needs_solve(evaluation.pressure_pa, self.scene, stamp_s):
                self.solver.request(evaluation.pressure_pa, self.scene, stamp_s)
            self.last = (variance_pa2, evaluation)
            self.last_publish_s = stamp_s
        header = Header(stamp=stamp_msg(stamp_s), frame_id=self.frame_id)
        if listened(self, self.joints_pub):
            publish(self, self.joints_pub, messages.joint_state(evaluation.joints(),
                                                                self.values["prefix"], header))
        for sign, publisher in ((1.0, self.left_pub), (-1.0, self.right_pub)):
            if listened(self, publisher):
                publish(
                    self, publisher,
                    messages.tip_pose(evaluation.tip, evaluation.tip_slope, variance_pa2, sign,
                                      header))

    def _publish_markers(self) -> None:
        if self.last is None or not listened(self, self.marker_pub):
            return  # model no more than a scene needs
        header = Header(stamp=self.get_clock().now().to_msg(), frame_id=self.frame_id)
        publish(self, self.marker_pub, messages.finger_markers(self.last[1].backbone(), header))

    def _publish_diagnostics(self) -> None:
        report = (Report(Health.WARN, "no pressure estimate yet", {})
                  if self.last is None else self.last[1].report(self.model.solves))
        publish(
            self, self.diagnostics_pub,
            messages.diagnostics(report, "softgrip: kinematics", "model",
                                 self.get_clock().now().to_msg()))


def main(args=None) -> int:
    return run_node(KinematicsNode, args)

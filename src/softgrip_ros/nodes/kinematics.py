"""kinematics: tip poses from the pressure estimate.

In: pressure/estimate. Out: tip_pose/left and tip_pose/right (PoseWithCovarianceStamped, in
``frame_id``: x from the left finger to the right, z towards the tips; the orientation turns +z
to the tip's tangent about y), after each estimate (at most ``publish_rate_hz``). Their
covariance is the pressure variance pushed through the model's tip derivative,
J var J' with J = d(x, z, tip angle)/dp. finger_markers (MarkerArray line strips of both
backbones) only while someone subscribes. /diagnostics: the model in use, its error bound and
whether the pressure lies in its validated range.

``fidelity``: l0, l1, l2, or auto: the cheapest model whose error bound for the scene meets
``tolerance_m`` (softgrip_ros.model.fidelity). The scene comes from the grasp manager on
``grasp_scene`` (or by direct calls in the composed controller): free bending, or an object
clamped or pinched. L2 solves (milliseconds) run in a child process, handed over by a worker
thread, only when the pressure moved
by more than ``resolve_pressure_pa`` and at most once per ``min_solve_interval``; the poses use the
latest solve meanwhile.
"""
from __future__ import annotations

import math
import threading

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, PoseWithCovarianceStamped
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from sensor_msgs.msg import FluidPressure
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from softgrip_interfaces.msg import GraspScene
from softgrip_ros.model.fidelity import CHOICES, FREE, ROD_CONTINUATION_STEPS, Scene, SceneModel
from softgrip_ros.runtime.rod_solver import SOLVER_PROCESS_NICE_INCREMENT, LatestSolveThread, RodSolverProcess
from softgrip_ros.model.rod import Circle, Sheet
from softgrip_ros.nodes.common import (P_ATM_PA, NodeTimers, future_stamp_reason, listened, publish, run_node, stamp_msg,
                                       stamp_seconds)
from softgrip_ros.nodes.parameters import ParamSpec, check_all, declare

SPECS = [
    ParamSpec("publish_rate_hz", 200.0, "largest tip_pose rate (one per estimate up to this)", "Hz", 1.0, 2000.0),
    ParamSpec("marker_rate_hz", 10.0, "finger_markers rate while subscribed", "Hz", 0.5, 60.0),
    ParamSpec("fidelity", "auto", "model: l0, l1, l2, or auto (the cheapest whose error bound meets tolerance_m)",
              choices=CHOICES),
    ParamSpec("tolerance_m", 1e-3, "tip-position error auto must stay within (bounds: config/model_error_bounds.yaml)",
              "m", 1e-6, 0.1),
    ParamSpec("resolve_pressure_pa", 200.0, "an L2 solve runs again once the pressure moved by more than this", "Pa",
              0.0, 5000.0),
    ParamSpec("min_solve_interval", 0.1, "... and at most once per this (its CPU would starve the pressure loop)", "s",
              0.0, 10.0),
    ParamSpec("l2_nice_increment", SOLVER_PROCESS_NICE_INCREMENT, "added to the nice value of the L2 solver's child process, "
              "so that its solves yield the CPU to the pressure loop, the CAN reception and the estimator", "", 0, 19),
    ParamSpec("cavity_type", "type_II", "finger type of config/gripper_geometry.yaml", choices=("type_I", "type_II", "type_III")),
    ParamSpec("frame_id", "softgrip_base", "frame of the tip poses and markers"),
    ParamSpec("stamp_tolerance", 0.5, "an estimate stamped further ahead of this node's clock than this is ignored",
              "s", 0.0, 60.0),
]


class KinematicsNode(Node):
    """in_process: the estimates come by direct calls to :meth:`on_estimate` from the composed
    controller's estimator, instead of through pressure/estimate (see nodes.controller)."""

    def __init__(self, in_process: bool = False, **kwargs):
        super().__init__("kinematics", **kwargs)
        self._lock = threading.Lock()      # the in-process path calls in from the controller's CAN thread
        self.closed = False
        specs = {s.name: s for s in SPECS}
        self.values = declare(self, SPECS)
        self.add_on_set_parameters_callback(
            lambda params: check_all(specs, params, lambda _: "kinematics parameters apply at start-up: restart the node"))
        # L2 runs in a process of its own: in this one it would starve the controller's threads of the GIL
        self.rod_solver = (RodSolverProcess(self.values["cavity_type"], self.values["l2_nice_increment"],
                                            ROD_CONTINUATION_STEPS)
                           if self.values["fidelity"] in ("l2", "auto") else None)
        self.model = SceneModel(self.values["fidelity"], self.values["tolerance_m"], self.values["cavity_type"],
                                resolve_pressure_pa=self.values["resolve_pressure_pa"],
                                min_solve_interval_s=self.values["min_solve_interval"], rod_solver=self.rod_solver)
        self.scene = FREE
        logger = self.get_logger()
        self.solver = LatestSolveThread(self.model, name="kinematics-l2", on_error=lambda pressure, error: logger.error(
            f"L2 solve at {pressure:.0f} Pa failed: {error!r}"))
        self.period_s = 1.0 / self.values["publish_rate_hz"]
        self.last_publish_s = -math.inf
        self.last = None                     # (variance, Evaluation)
        self.left_pub = self.create_publisher(PoseWithCovarianceStamped, "tip_pose/left", 10)
        self.right_pub = self.create_publisher(PoseWithCovarianceStamped, "tip_pose/right", 10)
        self.marker_pub = self.create_publisher(MarkerArray, "finger_markers", 1)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        if not in_process:
            self.create_subscription(FluidPressure, "pressure/estimate", self._on_estimate_message, 10)
            latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
            self.create_subscription(GraspScene, "grasp_scene", self._on_scene_message, latched)
        self.periodic = NodeTimers(self, in_process)
        self.periodic.every(1.0 / self.values["marker_rate_hz"], self._publish_markers)
        self.periodic.every(1.0, self._publish_diagnostics)
        self.periodic.start()

    def close(self) -> None:
        """Nothing to vent: the kinematics only listens. Later in-process estimates are ignored."""
        self.periodic.stop()
        with self._lock:
            self.closed = True
        self.solver.close()
        if self.rod_solver is not None:
            self.rod_solver.close()

    def on_scene(self, scene: Scene) -> None:
        """What the fingers meet from now on (the grasp manager's call)."""
        with self._lock:
            self.scene = scene

    def _on_scene_message(self, msg) -> None:
        try:
            scene = scene_from_message(msg)
        except ValueError as error:
            self.get_logger().error(f"grasp_scene refused, kept {self.scene.describe()}: {error}")
            return
        self.on_scene(scene)

    def _on_estimate_message(self, msg: FluidPressure) -> None:
        stamp_s = stamp_seconds(msg.header.stamp)
        refused = future_stamp_reason(stamp_s, self.get_clock().now().nanoseconds * 1e-9, self.values["stamp_tolerance"])
        if refused:    # it would hold every later pose back until its stamp
            self.get_logger().warn(f"pressure/estimate {refused}", throttle_duration_sec=5.0)
            return
        self.on_estimate(stamp_s, msg.fluid_pressure - P_ATM_PA, msg.variance)

    def on_estimate(self, stamp_s: float, gauge_pa: float, variance_pa2: float) -> None:
        """Publish both tip poses for the estimate at ``stamp_s``, unless one went out less than a period ago."""
        with self._lock:
            if self.closed or stamp_s - self.last_publish_s < 0.9 * self.period_s or not math.isfinite(gauge_pa):
                return
            evaluation = self.model.evaluate(gauge_pa, self.scene, solve=False)
            if self.model.needs_solve(evaluation.pressure_pa, self.scene, stamp_s):
                self.solver.request(evaluation.pressure_pa, self.scene, stamp_s)
            self.last = (variance_pa2, evaluation)
            self.last_publish_s = stamp_s
        (x_left, z, angle_left), slope = evaluation.tip, evaluation.tip_slope    # slope: d(x, z, angle)/dp
        header = Header(stamp=stamp_msg(stamp_s), frame_id=self.values["frame_id"])
        for sign, publisher in ((1.0, self.left_pub), (-1.0, self.right_pub)):
            if not listened(self, publisher):
                continue
            x, angle = x_left * sign, angle_left * sign
            jacobian = (sign * slope[0], 0.0, slope[1], 0.0, sign * slope[2], 0.0)     # over x y z rx ry rz
            message = PoseWithCovarianceStamped(header=header)
            message.pose.pose.position.x, message.pose.pose.position.z = x, z
            message.pose.pose.orientation.y, message.pose.pose.orientation.w = math.sin(0.5 * angle), math.cos(0.5 * angle)
            message.pose.covariance = [a * b * variance_pa2 for a in jacobian for b in jacobian]
            publish(self, publisher, message)

    def _publish_markers(self) -> None:
        if self.last is None or not listened(self, self.marker_pub):
            return                                          # model no more than a scene needs
        backbone = self.last[1].backbone()
        header = Header(stamp=self.get_clock().now().to_msg(), frame_id=self.values["frame_id"])
        markers = MarkerArray()
        for marker_id, sign in enumerate((1.0, -1.0)):
            marker = Marker(header=header, ns="softgrip_fingers", id=marker_id, type=Marker.LINE_STRIP, action=Marker.ADD)
            marker.scale.x = 0.004
            marker.pose.orientation.w = 1.0
            marker.color = ColorRGBA(r=0.9, g=0.5, b=0.1, a=1.0)
            marker.points = [Point(x=sign * x, y=0.0, z=z) for x, z in backbone]
            markers.markers.append(marker)
        publish(self, self.marker_pub, markers)

    def _publish_diagnostics(self) -> None:
        status = DiagnosticStatus(name="softgrip: kinematics", hardware_id="model")
        if self.last is None:
            status.level, status.message = DiagnosticStatus.WARN, "no pressure estimate yet"
        else:
            e = self.last[1]
            good = e.in_validated_range and e.meets_tolerance
            status.level = DiagnosticStatus.OK if good else DiagnosticStatus.WARN
            status.message = (f"{e.model} at {e.pressure_pa:.0f} Pa, {e.message}"
                              + ("" if e.in_validated_range else "; outside the validated range")
                              + ("" if e.meets_tolerance else f"; error bound {1e3 * e.bound_m:.2f} mm exceeds the tolerance"))
            status.values = [KeyValue(key="model_fidelity", value=e.model),
                             KeyValue(key="scene_class", value=e.scene_class),
                             KeyValue(key="error_bound_m", value=f"{e.bound_m:.3g}"),
                             KeyValue(key="pressure_in_validated_range", value=str(bool(e.in_validated_range))),
                             KeyValue(key="contact_force_n", value=f"{e.contact_force_n:.3f}"),
                             KeyValue(key="l2_solves", value=str(self.model.solves))]
        publish(self, self.diagnostics_pub, DiagnosticArray(header=Header(stamp=self.get_clock().now().to_msg()), status=[status]))


def scene_message(scene: Scene) -> GraspScene:
    message = GraspScene(kind=GraspScene.FREE, opening_gauge_pressure_pa=float(scene.opening_gauge_pa))
    if isinstance(scene.obstacle, Circle):
        message.kind, message.object_diameter_m = GraspScene.CYLINDER, 2.0 * scene.obstacle.radius_m
        message.object_center_z_m = scene.obstacle.center_z_m
    elif isinstance(scene.obstacle, Sheet):
        message.kind, message.object_diameter_m = GraspScene.SHEET, scene.obstacle.thickness_m
    return message


def scene_from_message(message) -> Scene:
    """The Scene of a GraspScene; ValueError (with the reason) for an unknown kind or a bad number."""
    opening = float(message.opening_gauge_pressure_pa)
    if not math.isfinite(opening):
        raise ValueError(f"opening_gauge_pressure_pa must be finite, got {opening}")
    if message.kind == GraspScene.FREE:
        return FREE
    if message.kind == GraspScene.CYLINDER:
        return Scene(Circle(0.0, float(message.object_center_z_m), 0.5 * float(message.object_diameter_m)), opening)
    if message.kind == GraspScene.SHEET:
        return Scene(Sheet(float(message.object_diameter_m)), opening)
    raise ValueError(f"unknown scene kind {message.kind}")


def main(args=None) -> int:
    return run_node(KinematicsNode, args)

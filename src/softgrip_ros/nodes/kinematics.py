"""kinematics: tip poses from the pressure estimate.

In: pressure/estimate. Out: tip_pose/left and tip_pose/right (PoseWithCovarianceStamped, in
``frame_id``: x from the left finger to the right, z towards the tips; the orientation turns +z
to the tip's tangent about y), after each estimate (at most ``publish_rate_hz``). Their
covariance is the pressure variance pushed through the model's tip derivative,
J var J' with J = d(x, z, tip angle)/dp. finger_markers (MarkerArray line strips of both
backbones) only while someone subscribes. /diagnostics: the model in use and whether the
pressure lies in its validated range.

``fidelity``: l0, l1, or auto (softgrip_ros.model.calibration.FidelityChoice).
"""
from __future__ import annotations

import math
import threading

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, PoseWithCovarianceStamped
from rclpy.node import Node
from sensor_msgs.msg import FluidPressure
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from softgrip_ros.model.calibration import FidelityChoice
from softgrip_ros.nodes.common import P_ATM_PA, publish, run_node, stamp_msg, stamp_seconds
from softgrip_ros.nodes.parameters import ParamSpec, check_all, declare

SPECS = [
    ParamSpec("publish_rate_hz", 200.0, "largest tip_pose rate (one per estimate up to this)", "Hz", 1.0, 2000.0),
    ParamSpec("marker_rate_hz", 10.0, "finger_markers rate while subscribed", "Hz", 0.5, 60.0),
    ParamSpec("fidelity", "l0", "bending law: l0, l1, or auto (l0 in the validated range, else l1)", choices=FidelityChoice.CHOICES),
    ParamSpec("cavity_type", "type_II", "finger type of config/gripper_geometry.yaml", choices=("type_I", "type_II", "type_III")),
    ParamSpec("frame_id", "softgrip_base", "frame of the tip poses and markers"),
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
        self.fidelity = FidelityChoice(self.values["fidelity"], self.values["cavity_type"])
        self.period_s = 1.0 / self.values["publish_rate_hz"]
        self.last_publish_s = -math.inf
        self.last = None                     # (pressure, variance, model name, pose)
        self.left_pub = self.create_publisher(PoseWithCovarianceStamped, "tip_pose/left", 10)
        self.right_pub = self.create_publisher(PoseWithCovarianceStamped, "tip_pose/right", 10)
        self.marker_pub = self.create_publisher(MarkerArray, "finger_markers", 1)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        if not in_process:
            self.create_subscription(FluidPressure, "pressure/estimate", lambda msg: self.on_estimate(
                stamp_seconds(msg.header.stamp), msg.fluid_pressure - P_ATM_PA, msg.variance), 10)
        self.create_timer(1.0 / self.values["marker_rate_hz"], self._publish_markers)
        self.create_timer(1.0, self._publish_diagnostics)

    def close(self) -> None:
        """Nothing to vent: the kinematics only listens. Later in-process estimates are ignored."""
        with self._lock:
            self.closed = True

    def on_estimate(self, stamp_s: float, gauge_pa: float, variance_pa2: float) -> None:
        """Publish both tip poses for the estimate at ``stamp_s``, unless one went out less than a period ago."""
        with self._lock:
            if self.closed or stamp_s - self.last_publish_s < 0.9 * self.period_s or not math.isfinite(gauge_pa):
                return
            model = self.fidelity.model_for(gauge_pa)
            pressure = min(max(gauge_pa, model.MODEL_MIN_PRESSURE_PA), model.max_pressure_pa)
            pose = model.pose(pressure)
            slope = model.tip_slope_at(pressure)           # d(x, z, angle)/dp of the left tip
            self.last = (pressure, variance_pa2, model, pose)
            self.last_publish_s = stamp_s
        header = Header(stamp=stamp_msg(stamp_s), frame_id=self.values["frame_id"])
        for sign, publisher in ((1.0, self.left_pub), (-1.0, self.right_pub)):
            x, z, angle = pose.left_tip_x_m * sign, pose.left_tip_z_m, pose.left_tip_angle_rad * sign
            jacobian = (sign * slope[0], 0.0, slope[1], 0.0, sign * slope[2], 0.0)     # over x y z rx ry rz
            message = PoseWithCovarianceStamped(header=header)
            message.pose.pose.position.x, message.pose.pose.position.z = x, z
            message.pose.pose.orientation.y, message.pose.pose.orientation.w = math.sin(0.5 * angle), math.cos(0.5 * angle)
            message.pose.covariance = [a * b * variance_pa2 for a in jacobian for b in jacobian]
            publish(self, publisher, message)

    def _publish_markers(self) -> None:
        if self.last is None or self.marker_pub.get_subscription_count() == 0:
            return                                          # model no more than a scene needs
        pressure, _, model, _ = self.last
        backbone = model.backbone(pressure)
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
            pressure, variance, model, pose = self.last
            status.level = DiagnosticStatus.OK if pose.in_validated_range else DiagnosticStatus.WARN
            status.message = f"{model.model} at {pressure:.0f} Pa" + ("" if pose.in_validated_range else ": outside the validated range")
            status.values = [KeyValue(key="model_fidelity", value=model.model),
                             KeyValue(key="pressure_in_validated_range", value=str(bool(pose.in_validated_range))),
                             KeyValue(key="tip_spacing_m", value=f"{pose.tip_spacing_m:.5f}")]
        publish(self, self.diagnostics_pub, DiagnosticArray(header=Header(stamp=self.get_clock().now().to_msg()), status=[status]))


def main(args=None) -> int:
    return run_node(KinematicsNode, args)

"""Conversions between the cores' values and ROS messages, each in one place: the nodes publish
and read messages only through these. Pressures in messages are absolute where the type says
so (sensor_msgs/FluidPressure) and gauge everywhere else."""
from __future__ import annotations

import math

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, Pose, PoseStamped, PoseWithCovarianceStamped, Quaternion
from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from softgrip_interfaces.msg import (ControllerStatus, GraspCommand, GraspScene, GraspTruth,
                                     GripperState, PressureCommand, SimContacts)
from softgrip_ros.control.grasp_fsm import GraspRequest, GraspState
from softgrip_ros.control.pressure import Source
from softgrip_ros.control.reports import outputs_changed_at
from softgrip_ros.health import Health, Report
from softgrip_ros.model.fidelity import FREE, Scene
from softgrip_ros.model.pneumatics import P_ATM_PA
from softgrip_ros.model.rod import Circle, Sheet
from softgrip_ros.nodes.common import stamp_msg, stamp_seconds
from softgrip_ros.runtime.core import ControllerReport, PressureOrder

_SOURCES = {
    Source.SUPPLY: PressureCommand.SUPPLY, Source.VACUUM: PressureCommand.VACUUM,
    Source.VENT: PressureCommand.VENT, Source.HOLD: PressureCommand.HOLD
}

_LEVELS = {
    Health.OK: DiagnosticStatus.OK, Health.WARN: DiagnosticStatus.WARN,
    Health.ERROR: DiagnosticStatus.ERROR
}  # the field is a byte, not an int


def diagnostics(report: Report, name: str, hardware_id: str, stamp) -> DiagnosticArray:
    """One DiagnosticStatus (its level the report's health) in a DiagnosticArray."""
    status = DiagnosticStatus(
        name=name, hardware_id=hardware_id, level=_LEVELS[report.health], message=report.message,
        values=[KeyValue(key=k, value=str(v)) for k, v in report.values.items()])
    return DiagnosticArray(header=Header(stamp=stamp), status=[status])


def controller_status(output, link, header: Header, note: str, now: float,
                      outputs_changed_s: float) -> ControllerStatus:
    """The ControllerStatus of a control ``output`` (a ControlOutput) and the ``link``'s counts;
    ``note``: what the last command's handling said, after the output's own message. ``now``:
    the instant of the link's clock that ``header``'s stamp is; ``outputs_changed_s``: when the
    output's valves or regulator command changed, on that clock (see
    ControllerLink.status_outputs)."""
    return ControllerStatus(
        header=header, mode=int(output.mode), setpoint_gauge_pressure_pa=output.setpoint_gauge_pa,
        measured_gauge_pressure_pa=link.controller.measured(now),
        estimated_gauge_pressure_pa=link.controller.estimate_gauge_pa(now),
        regulator_actual_gauge_pressure_pa=link.regulator_actual_gauge_pa,
        regulator_report_age_s=now - link.regulator_report_time,
        regulator_command_gauge_pressure_pa=output.regulator_setpoint_gauge_pa,
        regulator_enabled=output.regulator_enabled, valve_states=[int(v) for v in output.valves],
        output_change_age_s=now - outputs_changed_s,
        frames_rx=link.frames_rx, frames_tx=link.frames_tx, frames_bad=link.frames_bad,
        last_sensor_frame_age_s=link.last_sensor_age_s(), fault_flags=int(output.fault_flags),
        message="; ".join(m for m in (output.message, note) if m))


def fluid_pressure(gauge_pa: float, variance_pa2: float, stamp_s: float,
                   frame_id: str) -> FluidPressure:
    return FluidPressure(header=Header(stamp=stamp_msg(stamp_s), frame_id=frame_id),
                         fluid_pressure=gauge_pa + P_ATM_PA, variance=variance_pa2)


def gauge_pa(msg: FluidPressure) -> float:
    return msg.fluid_pressure - P_ATM_PA


def pressure_command(target_gauge_pa: float, source: Source, header: Header) -> PressureCommand:
    return PressureCommand(header=header, target_gauge_pressure_pa=target_gauge_pa,
                           max_rate_pa_per_s=math.nan, source=_SOURCES[source])


def pressure_order(msg: PressureCommand) -> PressureOrder:
    """A PressureCommand as the runtime core's value; ValueError for an unknown source is left to
    the controller, which refuses it with its reason (so the source passes as it came)."""
    try:
        source = Source(msg.source)
    except ValueError:
        source = msg.source
    return PressureOrder(msg.target_gauge_pressure_pa, source, msg.max_rate_pa_per_s,
                         stamp_seconds(msg.header.stamp))


def controller_report(msg: ControllerStatus) -> ControllerReport | None:
    """A ControllerStatus as the runtime core's value (None for one without valve states)."""
    if not msg.valve_states:
        return None
    stamp_s = stamp_seconds(msg.header.stamp)
    return ControllerReport(stamp_s, outputs_changed_at(stamp_s, msg.output_change_age_s),
                            msg.fault_flags, msg.measured_gauge_pressure_pa,
                            msg.regulator_command_gauge_pressure_pa, msg.regulator_enabled,
                            msg.valve_states[0], msg.message)


def grasp_request(msg: GraspCommand) -> GraspRequest:
    """A GraspCommand's request; a friction coefficient of 0 (unset) means the default."""
    friction = math.nan if msg.friction_coefficient == 0.0 else msg.friction_coefficient
    return GraspRequest(mode=msg.mode, object_diameter_m=msg.object_diameter_m,
                        object_mass_kg=msg.object_mass_kg,
                        target_tip_spacing_m=msg.target_tip_spacing_m,
                        friction_coefficient=friction, open_pressure_pa=msg.open_pressure_pa,
                        clamp_pressure_pa=msg.clamp_pressure_pa, command_id=msg.command_id)


def gripper_state(state: GraspState, header: Header) -> GripperState:
    s = state
    return GripperState(header=header, phase=int(s.phase), mode=int(s.mode),
                        command_id=s.command_id, command_rejected=s.command_rejected,
                        target_gauge_pressure_pa=s.target_gauge_pa,
                        estimated_gauge_pressure_pa=s.estimated_gauge_pa,
                        estimated_gauge_pressure_std_pa=s.estimated_std_pa,
                        included_angle_rad=s.included_angle_rad, tip_spacing_m=s.tip_spacing_m,
                        root_spacing_m=s.root_spacing_m, clamp_force_n=s.clamp_force_n,
                        model_fidelity=s.model_fidelity,
                        pressure_in_validated_range=s.in_validated_range, message=s.message,
                        object_status=int(s.object_status), object_size_m=s.object_size_m)


def scene_message(scene: Scene) -> GraspScene:
    message = GraspScene(kind=GraspScene.FREE,
                         opening_gauge_pressure_pa=float(scene.opening_gauge_pa))
    if isinstance(scene.obstacle, Circle):
        message.kind = GraspScene.CYLINDER
        message.object_diameter_m = 2.0 * scene.obstacle.radius_m
        message.object_center_z_m = scene.obstacle.center_z_m
    elif isinstance(scene.obstacle, Sheet):
        message.kind, message.object_diameter_m = GraspScene.SHEET, scene.obstacle.thickness_m
    return message


def scene_from_message(message: GraspScene) -> Scene:
    """The Scene of a GraspScene; ValueError (with the reason) for an unknown kind or a bad
    number."""
    opening = float(message.opening_gauge_pressure_pa)
    if not math.isfinite(opening):
        raise ValueError(f"opening_gauge_pressure_pa must be finite, got {opening}")
    if message.kind == GraspScene.FREE:
        return FREE
    if message.kind == GraspScene.CYLINDER:
        radius_m = 0.5 * float(message.object_diameter_m)
        return Scene(Circle(0.0, float(message.object_center_z_m), radius_m), opening)
    if message.kind == GraspScene.SHEET:
        return Scene(Sheet(float(message.object_diameter_m)), opening)
    raise ValueError(f"unknown scene kind {message.kind}")


def tip_pose(tip, tip_slope, variance_pa2: float, sign: float,
             header: Header) -> PoseWithCovarianceStamped:
    """The pose of the left finger's tip (``sign`` 1) or the right's (-1), mirrored in x, from the
    model's ``tip`` (x, z, tip angle) and ``tip_slope`` d(x, z, angle)/dp. Its covariance is the
    pressure variance pushed through that derivative, J var J'."""
    (x_left, z, angle_left), slope = tip, tip_slope
    x, angle = x_left * sign, angle_left * sign
    jacobian = (sign * slope[0], 0.0, slope[1], 0.0, sign * slope[2], 0.0)  # over x y z rx ry rz
    message = PoseWithCovarianceStamped(header=header)
    message.pose.pose.position.x, message.pose.pose.position.z = x, z
    orientation = message.pose.pose.orientation
    orientation.y, orientation.w = math.sin(0.5 * angle), math.cos(0.5 * angle)  # about +y
    message.pose.covariance = [a * b * variance_pa2 for a in jacobian for b in jacobian]
    return message


def finger_markers(backbone, header: Header) -> MarkerArray:
    """Line strips of both fingers' backbones (``backbone``: the left's (x, z) points)."""
    markers = MarkerArray()
    for marker_id, sign in enumerate((1.0, -1.0)):
        marker = Marker(header=header, ns="softgrip_fingers", id=marker_id, type=Marker.LINE_STRIP,
                        action=Marker.ADD)
        marker.scale.x = 0.004
        marker.pose.orientation.w = 1.0
        marker.color = ColorRGBA(r=0.9, g=0.5, b=0.1, a=1.0)
        marker.points = [Point(x=sign * x, y=0.0, z=z) for x, z in backbone]
        markers.markers.append(marker)
    return markers


SIDES = ("left", "right")
TIP_SPACING_JOINT = "tip_spacing"
# the estimator's NIS evidence (EstimatorConsistency) for a pressure controller run apart
CONSISTENCY_TOPIC = "estimator/consistency"


def joint_names(prefix: str) -> list:
    """The movable joints of urdf/softgrip_macro.xacro, in joint_states order: per finger and
    segment i (1 = root), ``<side>_seg<i>_in`` (turn), ``_chord`` (prismatic), ``_out`` (turn);
    then ``tip_spacing``, the D2 the gripper actions command."""
    return [f"{prefix}{side}_seg{i}_{part}" for side in SIDES
            for i in range(1, 6) for part in ("in", "chord", "out")] + [prefix + TIP_SPACING_JOINT]


def joint_state(joints, prefix: str, header: Header) -> JointState:
    """JointState of the model's shape: ``joints`` = (five (turn, chord, turn), D2) of the left
    finger (:attr:`Evaluation.joints`); the right finger's joints turn the other way about y
    in the URDF, so they carry the same values."""
    segments, tip_spacing_m = joints
    one_finger = [float(v) for segment in segments for v in segment]
    # D2 at tip contact is 0 up to rounding; the URDF's tip_spacing stops at 0
    return JointState(header=header, name=joint_names(prefix),
                      position=one_finger + one_finger + [max(0.0, float(tip_spacing_m))])


def world_truth(truth, header: Header) -> tuple:
    """(sim/object_pose PoseStamped, sim/contacts SimContacts, sim/grasp_truth GraspTruth) of a
    :class:`~softgrip_ros.model.world.world.WorldTruth`."""
    from softgrip_ros.model.world.world import GraspTruthState
    x, y, z = truth.object_position_m
    w, qx, qy, qz = truth.object_quaternion_wxyz
    pose = PoseStamped(header=header, pose=Pose(position=Point(x=x, y=y, z=z),
                                                orientation=Quaternion(w=w, x=qx, y=qy, z=qz)))
    contacts = SimContacts(header=header, left_normal_force_n=float(truth.normal_force_n[0]),
                           right_normal_force_n=float(truth.normal_force_n[1]),
                           left_touching=bool(truth.touching[0]),
                           right_touching=bool(truth.touching[1]),
                           object_on_floor=bool(truth.on_floor))
    state = truth.state
    held = (GraspTruthState.IN_HAND, GraspTruthState.LIFTED, GraspTruthState.SLIPPING)
    grasp = GraspTruth(header=header, state=int(state), object_in_hand=state in held,
                       lifted=state == GraspTruthState.LIFTED or (
                           state == GraspTruthState.SLIPPING and not truth.on_floor),
                       slipping=state == GraspTruthState.SLIPPING,
                       dropped=state == GraspTruthState.DROPPED,
                       slip_distance_m=float(truth.slip_distance_m), arm_move=truth.arm_move,
                       world_time_s=float(truth.time_s), world_cpu_s=float(truth.cpu_s),
                       scene=truth.scene,
                       base_position_m=[float(v) for v in truth.base_position_m],
                       left_hinge_angles_rad=list(truth.hinge_angles_rad[0]),
                       right_hinge_angles_rad=list(truth.hinge_angles_rad[1]),
                       gauge_pressure_pa=float(truth.gauge_pressure_pa))
    return pose, contacts, grasp

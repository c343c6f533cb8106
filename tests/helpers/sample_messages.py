"""Sample softgrip_interfaces messages with distinctive values (NaN included), and deep equality.

Shared by the publisher subprocess and the test that receives its messages, so
both sides agree on what "all fields intact" means.
"""
import math

from softgrip_interfaces.action import Grasp
from softgrip_interfaces.msg import (ControllerStatus, GraspCommand, GraspScene, GripperState,
                                     PressureCommand)
from std_msgs.msg import Header
from builtin_interfaces.msg import Time


def _header(frame: str) -> Header:
    return Header(stamp=Time(sec=1_700_000_123, nanosec=456_789), frame_id=frame)


def grasp_command() -> GraspCommand:
    return GraspCommand(header=_header("softgrip_base"), mode=GraspCommand.ENVELOP_CLAMP,
                        object_diameter_m=0.04, object_mass_kg=0.2, target_tip_spacing_m=math.nan,
                        friction_coefficient=0.55, open_pressure_pa=math.nan,
                        clamp_pressure_pa=-12_345.5, command_id="grasp-42 \u00e9")


def gripper_state() -> GripperState:
    return GripperState(header=_header("softgrip_base"), phase=GripperState.ENVELOPED,
                        mode=GraspCommand.ENVELOP_CLAMP, command_id="grasp-42",
                        command_rejected=False, target_gauge_pressure_pa=31_500.25,
                        estimated_gauge_pressure_pa=31_480.0,
                        estimated_gauge_pressure_std_pa=120.5, included_angle_rad=1.2,
                        tip_spacing_m=0.0455, root_spacing_m=math.nan, clamp_force_n=-0.0,
                        model_fidelity=GripperState.FIDELITY_L1, pressure_in_validated_range=True,
                        message="enveloped; waiting for the arm")


def pressure_command() -> PressureCommand:
    return PressureCommand(header=_header("x"), target_gauge_pressure_pa=-45_000.0,
                           max_rate_pa_per_s=math.nan, source=PressureCommand.VACUUM)


def controller_status() -> ControllerStatus:
    return ControllerStatus(
        header=_header("can0"), mode=ControllerStatus.MODE_FAULT,
        setpoint_gauge_pressure_pa=50_000.0, measured_gauge_pressure_pa=math.nan,
        estimated_gauge_pressure_pa=49_800.5, regulator_actual_gauge_pressure_pa=50_010.0,
        valve_states=[ControllerStatus.VALVE_VENT, ControllerStatus.VALVE_SUPPLY],
        frames_rx=2**40 + 3, frames_tx=17, frames_bad=5, last_sensor_frame_age_s=math.inf,
        fault_flags=ControllerStatus.FAULT_OVERPRESSURE | ControllerStatus.FAULT_SENSOR_TIMEOUT,
        message="overpressure: vented")


def grasp_goal() -> Grasp.Goal:
    return Grasp.Goal(command=grasp_command())


def grasp_result() -> Grasp.Result:
    return Grasp.Result(object_held=True, final_phase=GripperState.HOLDING,
                        final_gauge_pressure_pa=-20_000.0, clamp_force_n=3.25, message="held")


def grasp_feedback() -> Grasp.Feedback:
    return Grasp.Feedback(state=gripper_state())


def grasp_scene() -> GraspScene:
    return GraspScene(header=_header("softgrip_base"), kind=GraspScene.CYLINDER,
                      object_diameter_m=0.04, object_center_z_m=0.0981,
                      opening_gauge_pressure_pa=17e3)


# topic name -> (message type, factory)
SAMPLES = {
    "roundtrip/grasp_command": (GraspCommand, grasp_command),
    "roundtrip/gripper_state": (GripperState, gripper_state),
    "roundtrip/pressure_command": (PressureCommand, pressure_command),
    "roundtrip/controller_status": (ControllerStatus, controller_status),
    "roundtrip/grasp_scene": (GraspScene, grasp_scene),
    "roundtrip/grasp_goal": (Grasp.Goal, grasp_goal),
    "roundtrip/grasp_result": (Grasp.Result, grasp_result),
    "roundtrip/grasp_feedback": (Grasp.Feedback, grasp_feedback),
}


def differences(expected, received, path="msg") -> list[str]:
    """Field-by-field differences between two ROS messages; NaN equals NaN, -0.0 keeps its sign."""
    if hasattr(expected, "get_fields_and_field_types"):
        diffs = []
        for field in expected.get_fields_and_field_types():
            diffs += differences(getattr(expected, field), getattr(received, field),
                                 f"{path}.{field}")
        return diffs
    if isinstance(expected, float):
        same = (math.isnan(expected) and
                math.isnan(received)) or (expected == received and
                                          math.copysign(1, expected) == math.copysign(1, received))
        return [] if same else [f"{path}: sent {expected!r}, received {received!r}"]
    if isinstance(expected, (list, tuple)) or hasattr(expected, "tolist"):
        expected, received = list(expected), list(received)
        if len(expected) != len(received):
            return [f"{path}: sent {len(expected)} items, received {len(received)}"]
        return [
            d for i, (e, r) in enumerate(zip(expected, received))
            for d in differences(e, r, f"{path}[{i}]")
        ]
    return [] if expected == received else [f"{path}: sent {expected!r}, received {received!r}"]

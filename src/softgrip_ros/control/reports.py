"""The health of the pressure controller and of the grasp state machine, as /diagnostics shows
it (the estimator's is :meth:`PressureEstimator.report`). The nodes publish these unchanged."""
from __future__ import annotations

import dataclasses
import math

from softgrip_ros.control.grasp_fsm import GraspState, Phase
from softgrip_ros.estimation.grasp_sensing import ObjectStatus
from softgrip_ros.control.faults import ERROR_FAULTS, Fault, fault_names
from softgrip_ros.control.pressure import ControlOutput, PressureMode
from softgrip_ros.health import Health, Report


def outputs_changed_at(stamp_s: float, output_change_age_s: float) -> float:
    """When a ControllerStatus's outputs (its regulator command and valves) went out: its stamp
    less its ``output_change_age_s`` (the stamp itself when that is unknown). A status is
    published after the step and its sends, later still when its thread waits on a loaded host:
    a process model switched at the stamp runs on the old inputs meanwhile."""
    if math.isfinite(output_change_age_s) and output_change_age_s >= 0.0:
        return stamp_s - output_change_age_s
    return stamp_s


def severity(output: ControlOutput) -> Health:
    """How bad an output is: a safety fault or a blind controller is an error; a recoverable
    fault (clamped setpoint, command timeout, regulator report, a refused command, rejected
    frames) is a warning. Holding and venting as asked are normal operation."""
    if output.fault_flags & ERROR_FAULTS or output.mode == PressureMode.FAULT:
        return Health.ERROR
    if output.fault_flags:
        return Health.WARN
    return Health.OK


@dataclasses.dataclass(frozen=True)
class LinkStats:
    """What the CAN link and the control loop have counted (one snapshot, so that each count
    and its last error agree)."""

    frames_rx: int
    frames_tx: int
    frames_bad: int
    rejected: dict  # frames refused by the E2E checks, by reason
    last_sensor_age_s: float
    silent_sensors: tuple  # configured sensors with no fresh reading
    listener_errors: int = 0  # in-process consumers of the readings that raised
    last_listener_error: str = ""
    status_errors: int = 0  # consumers of the status that raised
    last_status_error: str = ""
    receive_errors: int = 0  # bus reads that failed
    last_receive_error: str = ""
    # the control loop held up past the valves' lifetime with a source valve open (the device
    # closed it until the next frame): a host that starves the loop
    valve_lapses: int = 0


def pressure_controller_report(output: ControlOutput | None, stats: LinkStats | None) -> Report:
    """The pressure controller's health: its output's severity and faults, sensors gone silent,
    frames the E2E checks refused, and a consumer or bus read that failed (each caught so that
    control goes on, each a warning that must still be seen)."""
    if output is None or stats is None:
        return Report(Health.WARN, "not active", {})
    faults = output.fault_flags
    report = Report(
        severity(output), output.message or
        ("ok" if not faults else f"faults: {fault_names(faults)}"), {
            "mode": output.mode.name, "fault_flags": int(faults), "frames_rx": stats.frames_rx,
            "frames_tx": stats.frames_tx, "frames_bad": stats.frames_bad, "rejected": dict(
                stats.rejected), "last_sensor_age_s": f"{stats.last_sensor_age_s:.4f}",
            "sensor_listener_errors": stats.listener_errors,
            "status_publish_errors": stats.status_errors, "receive_errors": stats.receive_errors,
            "valve_lapses": stats.valve_lapses
        })
    if stats.silent_sensors and not faults & Fault.SENSOR_TIMEOUT:  # the others carry on
        report = report.with_note(Health.WARN,
                                  f"sensors silent: {', '.join(stats.silent_sensors)}")
    if faults & Fault.FRAMES_REJECTED:
        rejected = ", ".join(f"{k} {v}" for k, v in stats.rejected.items() if v)
        report = report.with_note(report.health,
                                  f"frames rejected by the E2E checks (so far: {rejected})")
    errors = [
        error for count, error in ((stats.listener_errors, stats.last_listener_error),
                                   (stats.status_errors, stats.last_status_error)) if count
    ]
    if errors:
        report = report.with_note(Health.WARN, f"consumer error: {errors[-1]}")
    if stats.receive_errors:
        report = report.with_note(Health.WARN, f"bus read error: {stats.last_receive_error}")
    return report


def grasp_report(state: GraspState) -> Report:
    """The grasp state machine's health: an error in FAULT, else OK with the state's message."""
    health = Health.ERROR if state.phase == Phase.FAULT else Health.OK
    return Report(
        health, state.message, {
            "phase": state.phase.name, "command_id": state.command_id,
            "model_fidelity": state.model_fidelity
        })


def sensing_report(state: GraspState) -> Report:
    """The air's verdict on the object (the grasp-sensing diagnostics entry): OK, a warning when
    the object was lost or the fingers closed on nothing; the evidence as its message."""
    health = (Health.WARN if state.object_status in (ObjectStatus.LOST, ObjectStatus.NO_OBJECT)
              else Health.OK)
    return Report(
        health, f"{state.object_status.name}: {state.object_evidence}", {
            "object_status": state.object_status.name,
            "object_size_mm": (f"{state.object_size_m * 1e3:.1f}"
                               if math.isfinite(state.object_size_m) else "n/a"),
        })

"""The pressure controller's faults (ControllerStatus.fault_flags) and the sets each part acts
on: the one place they are defined (no ROS)."""
from __future__ import annotations

import enum


class Fault(enum.IntFlag):
    """ControllerStatus.fault_flags."""

    NONE = 0
    OVERPRESSURE = 1  # a pressure limit (over or under) would be crossed: safe state
    SENSOR_TIMEOUT = 2  # no valid sensor reading: valves held closed
    COMMAND_TIMEOUT = 4
    BUS_SILENT = 8
    # the regulator reports a fault or does not follow its model: safe state
    REGULATOR = 16
    SETPOINT_CLAMPED = 32
    BUS_ERROR = 64
    SENSOR_DISAGREE = 128  # two sensors disagree: safe state
    SENSOR_STUCK = 256  # a sensor frozen while the pressure moves: safe state
    SENSOR_IMPLAUSIBLE = 512  # a jump or a reading no plant can make: safe state
    SENSOR_NOISE = 1024  # a sensor far noisier than rated: safe state
    # the chamber does not respond to the valves as the plant predicts: safe state
    RESPONSE = 2048
    # the estimator finds a sensor inconsistent with the model: safe state
    SENSOR_INCONSISTENT = 4096
    COMMAND_REJECTED = 8192  # the last command was refused (e.g. stamped in the future)
    FRAMES_REJECTED = 16384  # frames failed the E2E checks recently (corrupt, stale or replayed)


# Faults whose evidence puts the controller in its safe state until cleared
SAFETY_FAULTS = (Fault.OVERPRESSURE | Fault.REGULATOR | Fault.SENSOR_DISAGREE | Fault.SENSOR_STUCK
                 | Fault.SENSOR_IMPLAUSIBLE | Fault.SENSOR_NOISE | Fault.RESPONSE
                 | Fault.SENSOR_INCONSISTENT)
# the safety faults, and those that leave the controller blind: no regulation meanwhile
ERROR_FAULTS = SAFETY_FAULTS | Fault.SENSOR_TIMEOUT | Fault.BUS_SILENT
# what stops a grasp
HALTING_FAULTS = ERROR_FAULTS | Fault.REGULATOR | Fault.BUS_ERROR
# the controller holds, and resumes by itself
TRANSIENT_FAULTS = Fault.SENSOR_TIMEOUT | Fault.BUS_SILENT


def fault_names(flags: int) -> str:
    """'sensor disagree, response' for the flags set ('' for none)."""
    return ", ".join(f.name.lower().replace("_", " ") for f in Fault if f and f in Fault(flags))


def fault_text(fault_flags: int) -> str:
    """The controller faults that stop a grasp, named ('' when none)."""
    return fault_names(Fault(fault_flags) & HALTING_FAULTS)

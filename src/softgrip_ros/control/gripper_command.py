"""control_msgs' gripper actions on the grasp state machine (no ROS), for a soft gripper with no
finger encoder: every position and effort here is a model estimate, from the pressure estimate
through the bending model (D2) and the clamp force law (the force); nothing measures them.

- ``position`` is the tip spacing D2, in m.
- **Opening** (``position`` above the present modelled D2): OPEN with positive pressure, aimed
  at the pressure whose modelled D2 is ``position`` (the inverse model). Done at ENVELOPED,
  once the pressure has settled and the modelled D2 has come within ``goal_tolerance_m`` below
  ``position``; ``reached_goal`` when it is within the tolerance either way. (A grasp's OPEN
  aims ``pressure_tolerance_pa`` higher, so that D2 clears an object; a gripper goal is judged
  by its tolerance instead.)
- **Closing** (below, or inside the rest opening, which needs vacuum): clamp with the pressure
  at which ``max_effort`` (N, per finger; 0 = the configured default) comes out of the clamp
  force law for an object ``position`` wide. Done at HOLDING. ``effort`` is the modelled clamp
  force. With object sensing (:mod:`softgrip_ros.control.object_sensing`) the goal waits for
  the air's verdict on the closing: fingers stopped on an object are ``stalled``, at the size
  they felt (``reached_goal`` when that is within tolerance of ``position``); fingers that
  closed on nothing are not, at the modelled D2. When the air cannot tell (or without sensing)
  the model decides: ``reached_goal`` when the modelled D2 is within tolerance of
  ``position``, else ``stalled`` (the model assumes an object ``position`` wide, so while
  holding it reports D2 at that size).
- A goal that cannot be done is refused at once, with the reason: a NaN or negative position,
  one beyond the widest opening, a negative effort, or one the pressure limits cannot give.
"""
from __future__ import annotations

import dataclasses
import math

from softgrip_ros.control.grasp_fsm import (HOLDING_STATUSES, GoalOutcome, GraspMode,
                                            GraspRequest, GraspStateMachine, Phase, Rejection)
from softgrip_ros.estimation.grasp_sensing import ObjectStatus


@dataclasses.dataclass(frozen=True)
class GripperGoal:
    position_m: float
    effort_n: float  # per finger; for a closing goal only
    closing: bool
    task: int  # the state machine's task it started


@dataclasses.dataclass(frozen=True)
class GripperProgress:
    """Where a goal stands (``outcome``: FAILED in FAULT, SUPERSEDED once another command took
    over); the rest as control_msgs reports it."""

    outcome: GoalOutcome
    position_m: float
    effort_n: float
    stalled: bool
    reached_goal: bool
    message: str


def start_gripper_goal(fsm: GraspStateMachine, position_m: float, max_effort_n: float,
                       default_effort_n: float, goal_tolerance_m: float, now: float,
                       command_id: str = "",
                       controller_fault: str = "") -> GripperGoal | Rejection:
    """Start a goal on ``fsm``: its GripperGoal, or why it is refused (nothing moves then; the
    state's message says why, as for a rejected GraspCommand)."""
    problem = ""
    high = fsm.kinematics.tip_spacing_range_m()[1]
    if not (math.isfinite(position_m) and position_m >= 0.0):
        problem = f"position must be a finite tip spacing >= 0 m, got {position_m}"
    elif not (math.isfinite(max_effort_n) and max_effort_n >= 0.0):
        problem = f"max_effort must be a finite force >= 0 N (0: the default), got {max_effort_n}"
    elif position_m > high:
        problem = (f"position {position_m * 1e3:.1f} mm is wider than the gripper opens "
                   f"({high * 1e3:.1f} mm)")
    if problem:
        return fsm.refuse(command_id, problem)
    present = fsm.state.tip_spacing_m
    if not math.isfinite(present):  # no estimate yet: the fingers at rest
        present = fsm.kinematics.pose(0.0).tip_spacing_m
    effort = max_effort_n if max_effort_n > 0.0 else default_effort_n
    aim_pa = fsm.kinematics.pressure_for_tip_spacing(position_m)
    # a D2 inside the rest opening needs vacuum: that is a closing goal, whichever way it moves
    closing = position_m < present or aim_pa <= 0.0
    if closing:
        reason = fsm.close_on(position_m, effort, now, command_id, controller_fault)
    else:
        reason = fsm.command(GraspRequest(
            GraspMode.OPEN, target_tip_spacing_m=max(position_m - goal_tolerance_m, 0.0),
            open_pressure_pa=aim_pa, command_id=command_id), now, controller_fault)
    return reason or GripperGoal(position_m, effort, closing, fsm.task)


def gripper_progress(fsm: GraspStateMachine, goal: GripperGoal,
                     goal_tolerance_m: float) -> GripperProgress:
    s = fsm.state
    position = s.tip_spacing_m if math.isfinite(s.tip_spacing_m) else 0.0
    reached = abs(position - goal.position_m) <= goal_tolerance_m
    outcome = GoalOutcome.RUNNING
    if fsm.task != goal.task:
        outcome = GoalOutcome.SUPERSEDED
    elif s.phase == Phase.FAULT:
        outcome = GoalOutcome.FAILED
    elif s.phase == (Phase.HOLDING if goal.closing else Phase.ENVELOPED):
        outcome = GoalOutcome.RUNNING if fsm.sensing_pending() else GoalOutcome.SUCCEEDED
    succeeded = outcome == GoalOutcome.SUCCEEDED
    stalled = bool(succeeded and goal.closing and not reached)
    if succeeded and goal.closing and fsm.sensing_enabled:
        if s.object_status in HOLDING_STATUSES:
            if math.isfinite(s.object_size_m):
                position = s.object_size_m
            stalled = True
            reached = abs(position - goal.position_m) <= goal_tolerance_m
        elif s.object_status == ObjectStatus.NO_OBJECT:
            stalled = False
    return GripperProgress(outcome, position, s.clamp_force_n, stalled, reached, s.message)


def present_progress(fsm: GraspStateMachine) -> GripperProgress:
    """The gripper as it is, for a goal refused before it began (nothing reached)."""
    s = fsm.state
    position = s.tip_spacing_m if math.isfinite(s.tip_spacing_m) else 0.0
    return GripperProgress(GoalOutcome.FAILED, position, s.clamp_force_n, False, False,
                           s.message)

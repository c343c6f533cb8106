"""control_msgs' gripper semantics on the grasp state machine, closed around the pressure
controller and the plant (tests/helpers/grasp_loop), without ROS."""
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from softgrip_ros.control.grasp_fsm import (GoalOutcome, GraspConfig, GraspMode, GraspRequest,
                                            Phase, Rejection)
from softgrip_ros.control.gripper_command import gripper_progress, start_gripper_goal
from softgrip_ros.control.pressure import Source
from softgrip_ros.model.calibration import build_kinematics
from softgrip_ros.model.force_law import ObjectKind
from tests.helpers.grasp_loop import GraspLoop

pytestmark = pytest.mark.cpu  # computation only: scripts/test.sh runs it beside another

TOLERANCE_M = 0.005
DEFAULT_EFFORT_N = 1.0


@pytest.fixture(scope="module")
def kinematics():
    return build_kinematics("l0")


def start(loop, position_m, max_effort_n=0.0):
    goal = start_gripper_goal(loop.fsm, position_m, max_effort_n, DEFAULT_EFFORT_N, TOLERANCE_M,
                              loop.now)
    loop._forward()
    return goal


def run_to_end(loop, goal, timeout=5.0):
    loop.run_until(lambda s: gripper_progress(loop.fsm, goal, TOLERANCE_M).outcome.ended, timeout)
    return gripper_progress(loop.fsm, goal, TOLERANCE_M)


def test_an_opening_goal_opens_to_its_tip_spacing_and_reports_reaching_it(kinematics):
    loop = GraspLoop(kinematics, GraspConfig())
    loop.run_for(0.05)
    goal = start(loop, 0.05)
    assert not isinstance(goal, str) and not goal.closing
    assert loop.fsm.request.source == Source.SUPPLY
    progress = run_to_end(loop, goal)
    assert progress.outcome == GoalOutcome.SUCCEEDED
    assert progress.reached_goal and not progress.stalled
    assert loop.fsm.state.phase == Phase.ENVELOPED
    # the modelled D2: the opening aims at the goal's pressure
    assert progress.position_m == pytest.approx(0.05, abs=TOLERANCE_M)
    assert loop.fsm.request.target_gauge_pa == pytest.approx(
        kinematics.pressure_for_tip_spacing(0.05))
    assert progress.effort_n == 0.0


def test_a_closing_goal_squeezes_with_its_effort_and_ends_holding(kinematics):
    loop = GraspLoop(kinematics, GraspConfig())
    loop.run_for(0.05)
    opened = start(loop, 0.06)
    run_to_end(loop, opened)
    goal = start(loop, 0.03, max_effort_n=0.8)
    assert goal.closing and goal.task != opened.task
    law = loop.fsm.force_law
    target = law.pressure_for_force(0.8, 0.03, ObjectKind.ROUND)
    assert loop.fsm.request.target_gauge_pa == pytest.approx(target)
    progress = run_to_end(loop, goal)
    assert progress.outcome == GoalOutcome.SUCCEEDED and loop.fsm.state.phase == Phase.HOLDING
    # the modelled force: the clamp force law at the estimate, within the pressure tolerance
    slope = (law.normal_force_n(target - 1.5e3, 0.03, ObjectKind.ROUND) -
             law.normal_force_n(target + 1.5e3, 0.03, ObjectKind.ROUND)) / 3e3
    assert progress.effort_n == pytest.approx(0.8, abs=1.5e3 * slope)
    assert progress.reached_goal and not progress.stalled
    assert progress.position_m == pytest.approx(0.03, abs=TOLERANCE_M)


def test_effort_zero_means_the_default(kinematics):
    loop = GraspLoop(kinematics, GraspConfig())
    goal = start(loop, 0.0)
    assert goal.closing and goal.effort_n == DEFAULT_EFFORT_N


@pytest.mark.parametrize("position_m, effort_n, reason", [
    (math.nan, 1.0, "position must be a finite"),
    (-0.01, 1.0, "position must be a finite"),
    (0.5, 1.0, "wider than the gripper opens"),
    (0.0, -1.0, "max_effort must be"),
    (0.0, math.inf, "max_effort must be"),
    (0.0, 50.0, "needs more vacuum than the limit"),
])
def test_a_goal_it_cannot_do_is_refused_with_its_reason_and_nothing_moves(
        kinematics, position_m, effort_n, reason):
    loop = GraspLoop(kinematics, GraspConfig())
    loop.run_for(0.05)
    before = (loop.fsm.request, loop.fsm.state.phase, loop.fsm.task)
    refused = start(loop, position_m, effort_n)
    assert isinstance(refused, Rejection) and reason in refused.reason
    # control_msgs' results carry no text: grasp_state says why, as for a rejected GraspCommand
    assert loop.fsm.state.command_rejected and reason in loop.fsm.state.message
    assert (loop.fsm.request, loop.fsm.state.phase, loop.fsm.task) == before


def test_a_cancel_holds_the_present_pressure(kinematics):
    loop = GraspLoop(kinematics, GraspConfig())
    goal = start(loop, 0.07)
    loop.run_for(0.15)  # part way up
    pressure = loop.fsm.state.estimated_gauge_pa
    assert 0.0 < pressure and loop.fsm.state.phase == Phase.OPENING
    loop.fsm.hold_here(loop.now, "canceled: holding")
    loop._forward()
    assert loop.fsm.request == type(loop.fsm.request)(pressure, Source.HOLD)
    assert loop.fsm.state.phase == Phase.ENVELOPED
    assert gripper_progress(loop.fsm, goal, TOLERANCE_M).outcome == GoalOutcome.SUPERSEDED
    held = loop.gauge()
    loop.run_for(0.5)
    assert loop.gauge() == pytest.approx(held, abs=1.5e3)  # valves closed: it stays
    assert loop.fsm.state.phase == Phase.ENVELOPED


def test_another_command_supersedes_a_goal(kinematics):
    loop = GraspLoop(kinematics, GraspConfig())
    goal = start(loop, 0.05)
    loop.command(GraspRequest(GraspMode.STOP))
    assert gripper_progress(loop.fsm, goal, TOLERANCE_M).outcome == GoalOutcome.SUPERSEDED


GOAL_FLOATS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=0.0, max_value=0.12),  # tip spacings the gripper can reach, and beyond
    st.floats(min_value=0.0, max_value=5.0),   # efforts per finger
    st.sampled_from([0.0, -0.0, 5e-324, 1e300, -1e-9]))


@settings(max_examples=40, deadline=None)
@given(position_m=GOAL_FLOATS, effort_n=GOAL_FLOATS, opened_first=st.booleans())
def test_any_goal_is_refused_with_its_reason_or_ends_within_the_limits(
        position_m, effort_n, opened_first):
    """Any position and effort a GripperCommand can carry: refused at once with a reason and
    nothing moved, or a goal that reaches an end (succeeded, aborted or failed) within its
    phases' timeouts, the pressure inside the limits throughout (#52)."""
    kinematics = build_kinematics("l0")
    config = GraspConfig()
    loop = GraspLoop(kinematics, config)
    loop.run_for(0.05)
    if opened_first:
        run_to_end(loop, start(loop, 0.06))
    before = (loop.fsm.request, loop.fsm.state.phase, loop.fsm.task)
    started_s = loop.now
    goal = start(loop, position_m, effort_n)
    if isinstance(goal, Rejection):
        assert goal.reason and "\n" not in goal.reason
        assert loop.fsm.state.command_rejected and goal.reason in loop.fsm.state.message
        assert (loop.fsm.request, loop.fsm.state.phase, loop.fsm.task) == before
        return
    assert config.min_gauge_pa <= loop.fsm.request.target_gauge_pa <= config.max_gauge_pa
    progress = run_to_end(loop, goal, timeout=8.0)
    assert progress.outcome.ended
    assert math.isfinite(progress.position_m) and math.isfinite(progress.effort_n)
    pressures = loop.pressures_since(started_s)
    assert config.min_gauge_pa - 2e3 <= min(pressures) <= max(pressures) <= \
        config.max_gauge_pa + 2e3

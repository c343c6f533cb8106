"""The grasp state machine, closed around the pressure controller and the pneumatic plant
(tests/helpers/grasp_loop), with no ROS or CAN: phases, timings, rejections, faults."""
import math

import pytest
from hypothesis import event, given, settings
from hypothesis import strategies as st

from softgrip_ros.control.grasp_fsm import (GoalOutcome, GraspConfig, GraspRequest,
                                            GraspStateMachine, GraspMode, Phase, Rejection)
from softgrip_ros.control.pressure import Source
from softgrip_ros.model.calibration import build_kinematics
from softgrip_ros.model.force_law import G_M_PER_S2, ClampForceLaw, ObjectKind, load_table
from tests.helpers.grasp_loop import GraspLoop

pytestmark = pytest.mark.cpu  # computation only: scripts/test.sh runs it beside another


@pytest.fixture(scope="module")
def kinematics():
    return build_kinematics("l0")


def test_envelop_clamp_40mm_runs_its_phases_in_order_and_holds(kinematics):
    loop = GraspLoop(kinematics, GraspConfig(auto_clamp_delay_s=0.3))
    loop.command(
        GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04, object_mass_kg=0.02,
                     command_id="g1"))
    loop.run_until(lambda s: s.phase == Phase.HOLDING, 5.0)
    phases = [p for _, p in loop.phase_log]
    assert phases == [Phase.OPENING, Phase.ENVELOPED, Phase.CLAMPING, Phase.HOLDING]
    times = dict((p, t) for t, p in loop.phase_log)
    # opening: well under its 3 s timeout
    assert times[Phase.ENVELOPED] - times[Phase.OPENING] < 1.0
    assert times[Phase.HOLDING] - times[Phase.CLAMPING] < 1.0
    # D2 cleared the object plus margin
    assert loop.spacing_at_enveloped >= 0.04 + 0.01
    target = loop.fsm.request.target_gauge_pa
    law = loop.fsm.force_law
    expected = law.clamp_pressure_pa(0.02, 0.04, ObjectKind.ROUND)
    assert target == pytest.approx(expected)
    loop.run_for(2.0)  # HOLDING stays put for 2 s
    assert loop.fsm.state.phase == Phase.HOLDING
    assert max(abs(p - target) for p in loop.pressures_since(loop.now - 2.0)) < 2.5e3
    force = loop.fsm.state.clamp_force_n
    # holds with margin
    assert 2 * 0.5 * force >= 0.02 * G_M_PER_S2 * 0.9 * law.safety_factor


def test_a_hold_whose_pressure_is_unknown_for_a_tick_reports_an_unknown_force(kinematics):
    """A starved host can leave the grasp manager one tick with neither a fresh estimate nor a
    fresh reading (CI: one such state in a 2 s hold). Its force is then unknown (NaN), not 0 N,
    which a caller would read as the object let go; the next known pressure gives it back."""
    loop = GraspLoop(kinematics, GraspConfig(auto_clamp_delay_s=0.0))
    loop.command(
        GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04, object_mass_kg=0.02))
    loop.run_until(lambda s: s.phase == Phase.HOLDING, 5.0)
    known = loop.fsm.state.clamp_force_n
    assert known > 0.0
    state = loop.fsm.update(loop.now + 0.05, math.nan)
    assert state.phase == Phase.HOLDING and math.isnan(state.clamp_force_n)
    loop.run_for(0.1)
    assert loop.fsm.state.clamp_force_n == pytest.approx(known, rel=0.1)
    # not clamping: none
    loop.command(GraspRequest(GraspMode.RELEASE))
    loop.run_until(lambda s: s.phase == Phase.IDLE, 5.0)
    assert loop.fsm.update(loop.now + 0.05, math.nan).clamp_force_n == 0.0


def test_release_vents_then_opens_then_idles(kinematics):
    loop = GraspLoop(kinematics, GraspConfig(auto_clamp_delay_s=0.0))
    loop.command(
        GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.03, object_mass_kg=0.02))
    loop.run_until(lambda s: s.phase == Phase.HOLDING, 5.0)
    loop.command(GraspRequest(GraspMode.RELEASE))
    loop.run_until(lambda s: s.phase == Phase.IDLE, 5.0)
    assert "released" in loop.fsm.state.message
    assert loop.fsm.request.source == Source.HOLD and loop.fsm.state.tip_spacing_m >= 0.04 - 1e-3


def test_pinch_holds_a_tenth_of_a_millimetre_sheet(kinematics):
    loop = GraspLoop(kinematics)
    loop.command(GraspRequest(GraspMode.PINCH, object_diameter_m=1e-4, object_mass_kg=0.05))
    loop.run_until(lambda s: s.phase == Phase.HOLDING, 5.0)
    assert [p for _, p in loop.phase_log] == [Phase.CLAMPING, Phase.HOLDING]
    assert loop.fsm.request.source == Source.VACUUM and loop.fsm.state.clamp_force_n > 0.0
    # negative pressure only (noise aside)
    assert all(p <= 0.5e3 for p in loop.pressures_since(0.0))


def test_enveloped_waits_for_the_arm_then_clamps_on_request(kinematics):
    loop = GraspLoop(kinematics)  # no automatic clamp
    loop.command(
        GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04, object_mass_kg=0.02))
    loop.run_until(lambda s: s.phase == Phase.ENVELOPED, 5.0)
    loop.run_for(1.0)
    assert loop.fsm.state.phase == Phase.ENVELOPED
    loop.command(GraspRequest(GraspMode.CLAMP))
    loop.run_until(lambda s: s.phase == Phase.HOLDING, 5.0)


def test_stop_during_opening_vents_at_once(kinematics):
    loop = GraspLoop(kinematics)
    loop.command(
        GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04, object_mass_kg=0.02))
    loop.run_for(0.05)
    assert loop.fsm.state.phase == Phase.OPENING
    loop.command(GraspRequest(GraspMode.STOP))
    assert loop.fsm.request.source == Source.VENT and loop.fsm.state.phase == Phase.RELEASING
    # IDLE only once the pressure says vented
    loop.run_until(lambda s: s.phase == Phase.IDLE, 0.5)
    assert abs(loop.gauge()
               ) < loop.fsm.config.vented_below_pa and "stopped: vented" in loop.fsm.state.message
    loop.run_for(0.3)
    assert abs(loop.pressures_since(loop.now - 0.05)[-1]) < 1e3


def test_stop_and_release_never_report_success_while_the_pressure_stays(kinematics):
    """#20: with the valves stuck, RELEASE reached IDLE ("released") while the pressure went
    anywhere. Fed a pressure that never vents, STOP and RELEASE time out into FAULT instead."""
    for mode in (GraspMode.STOP, GraspMode.RELEASE):
        fsm = GraspStateMachine(kinematics, GraspConfig(releasing_timeout_s=0.5))
        fsm.command(GraspRequest(GraspMode.PINCH, object_diameter_m=1e-3, object_mass_kg=0.05),
                    0.0)
        fsm.command(GraspRequest(mode), 0.0)
        for k in range(70):
            fsm.update(0.01 * k, -9e3)
            assert fsm.state.phase != Phase.IDLE and "released" not in fsm.state.message
        assert fsm.state.phase == Phase.FAULT and "timed out" in fsm.state.message


def test_a_controller_fault_while_holding_gives_fault_and_vents(kinematics):
    loop = GraspLoop(kinematics, GraspConfig(auto_clamp_delay_s=0.0))
    loop.command(
        GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04, object_mass_kg=0.02))
    loop.run_until(lambda s: s.phase == Phase.HOLDING, 5.0)
    loop.controller_fault = "sensor disagree"
    loop.run_for(0.02)
    assert loop.fsm.state.phase == Phase.FAULT and "sensor disagree" in loop.fsm.state.message
    assert loop.fsm.request.source == Source.VENT and "venting" in loop.fsm.state.message
    assert "fault" in loop.fsm.command(GraspRequest(GraspMode.OPEN, target_tip_spacing_m=0.05),
                                       loop.now, "sensor disagree").reason
    loop.controller_fault = ""
    assert loop.fsm.command(GraspRequest(GraspMode.STOP), loop.now) is None
    assert loop.fsm.state.phase == Phase.RELEASING and loop.fsm.request.source == Source.VENT
    loop.run_until(lambda s: s.phase == Phase.IDLE, 1.0)
    assert "stopped: vented" in loop.fsm.state.message


def test_a_safety_fault_found_after_a_release_ended_gives_fault_from_idle(kinematics):
    """A fault found just after a grasp returned to IDLE (noise x10 during RELEASING, named
    0.3 s later) left grasp_state IDLE while the controller vented in its safe state, and the
    idle hold was re-sent. A fault that is no safe state (a command timeout) leaves IDLE be."""
    loop = GraspLoop(kinematics, GraspConfig(auto_clamp_delay_s=0.0))
    loop.command(GraspRequest(GraspMode.OPEN, target_tip_spacing_m=0.05))
    loop.run_until(lambda s: s.phase == Phase.ENVELOPED, 5.0)
    loop.command(GraspRequest(GraspMode.RELEASE))
    loop.run_until(lambda s: s.phase == Phase.IDLE, 5.0)
    loop.fsm.update(loop.now, loop.gauge(), 100.0, "command timeout")
    assert loop.fsm.state.phase == Phase.IDLE
    loop.fsm.update(loop.now, loop.gauge(), 100.0, "sensor noise", controller_safe_state=True)
    assert loop.fsm.state.phase == Phase.FAULT and "sensor noise" in loop.fsm.state.message
    assert loop.fsm.request.source == Source.VENT
    assert loop.fsm.command(GraspRequest(GraspMode.STOP), loop.now) is None


def test_a_blind_controller_gives_fault_with_the_valves_held_and_says_so(kinematics):
    """#20: with the bus silent the grasp said "venting" while every ValveCommand said CLOSED. A
    controller that cannot see the chamber holds the valves closed (design.md); the grasp now asks
    for the same, and says exactly that."""
    loop = GraspLoop(kinematics, GraspConfig(auto_clamp_delay_s=0.0))
    loop.command(
        GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04, object_mass_kg=0.02))
    loop.run_until(lambda s: s.phase == Phase.HOLDING, 5.0)
    loop.controller_fault, loop.controller_blind = "sensor timeout, bus silent", True
    loop.run_for(0.02)
    assert loop.fsm.state.phase == Phase.FAULT and loop.fsm.request.source == Source.HOLD
    assert ("venting" not in loop.fsm.state.message and
            "holds the valves closed" in loop.fsm.state.message)


def test_a_regulator_overshoot_while_holding_is_detected_and_gives_fault(kinematics):
    loop = GraspLoop(kinematics, GraspConfig(auto_clamp_delay_s=0.0))
    loop.command(
        GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04, object_mass_kg=0.02))
    loop.run_until(lambda s: s.phase == Phase.HOLDING, 5.0)
    loop.overshoot_pa = 20e3
    loop.run_until(lambda s: s.phase == Phase.FAULT, 2.0)
    assert "regulator" in loop.fsm.state.message and loop.fsm.request.source == Source.VENT


def test_holding_pressure_drifting_off_target_gives_fault(kinematics):
    loop = GraspLoop(kinematics, GraspConfig(auto_clamp_delay_s=0.0))
    loop.command(
        GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04, object_mass_kg=0.02))
    loop.run_until(lambda s: s.phase == Phase.HOLDING, 5.0)
    target, t = loop.fsm.request.target_gauge_pa, loop.now
    # a leak the controller cannot make up: 8 kPa off for 0.4 s
    for k in range(40):
        loop.fsm.update(t + 0.01 * k, target + 8e3)
    assert loop.fsm.state.phase == Phase.FAULT and "holding lost" in loop.fsm.state.message


def test_a_phase_that_cannot_finish_times_out_into_fault(kinematics):
    """The pressure never arrives, and nothing names a cause: the phase's own timeout ends it."""
    fsm = GraspStateMachine(kinematics, GraspConfig(opening_timeout_s=0.3))
    fsm.command(GraspRequest(GraspMode.OPEN, target_tip_spacing_m=0.08), 0.0)
    for k in range(40):
        fsm.update(0.01 * k, 2e3)
    assert fsm.state.phase == Phase.FAULT
    assert "opening timed out" in fsm.state.message and fsm.request.source == Source.VENT


def test_a_valve_that_does_not_open_is_named_by_the_controller_before_the_phase_times_out(
        kinematics):
    """Valves stuck closed: the pressure controller's response check finds that the chamber does
    not follow the supply valve, and the grasp ends in FAULT on that, not on the 3 s timeout."""
    loop = GraspLoop(kinematics, GraspConfig(), valve_stuck=True)
    loop.command(GraspRequest(GraspMode.OPEN, target_tip_spacing_m=0.08))
    loop.run_until(lambda s: s.phase == Phase.FAULT, 1.0)
    assert "response" in loop.fsm.state.message and loop.fsm.request.source == Source.VENT
    assert loop.now < 0.5


NAN = math.nan
REJECTIONS = [
    (GraspRequest(9), "unknown mode 9"),
    (GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=NAN,
                  object_mass_kg=0.02), "object_diameter_m must be finite"),
    (GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04,
                  object_mass_kg=NAN), "object_mass_kg must be finite"),
    (GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=-0.01,
                  object_mass_kg=0.02), "object_diameter_m must be finite and >= 0"),
    (GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04,
                  object_mass_kg=-1.0), "object_mass_kg must be finite and >= 0"),
    (GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.15,
                  object_mass_kg=0.02), "wider than the gripper opens"),
    (GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04, object_mass_kg=0.02,
                  open_pressure_pa=80e3), "beyond the pressure limits"),
    (GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04, object_mass_kg=0.02,
                  clamp_pressure_pa=-90e3), "beyond the pressure limits"),
    (GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04, object_mass_kg=0.02,
                  open_pressure_pa=5e3), "short of the object plus margin"),
    (GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04,
                  object_mass_kg=5.0), "too heavy"),
    (GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04, object_mass_kg=0.02,
                  friction_coefficient=-0.2), "friction_coefficient"),
    (GraspRequest(GraspMode.PINCH, object_diameter_m=0.02,
                  object_mass_kg=0.02), "PINCH takes objects up to 5.0 mm"),
    (GraspRequest(GraspMode.OPEN, target_tip_spacing_m=-0.01), "OPEN needs a finite"),
    (GraspRequest(GraspMode.OPEN, target_tip_spacing_m=math.inf), "OPEN needs a finite"),
    (GraspRequest(GraspMode.OPEN, target_tip_spacing_m=0.3), "wider than the gripper opens"),
    (GraspRequest(GraspMode.CLAMP), "CLAMP needs the ENVELOPED phase"),
    # #20: commands that contradict their mode
    (GraspRequest(GraspMode.OPEN, target_tip_spacing_m=0.1,
                  open_pressure_pa=-20e3), "open_pressure_pa must be > 0"),
    (GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04, object_mass_kg=0.02,
                  open_pressure_pa=-20e3), "open_pressure_pa must be > 0"),
    (GraspRequest(GraspMode.OPEN, target_tip_spacing_m=0.1,
                  open_pressure_pa=5e3), "short of target_tip_spacing_m"),
    (GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04, object_mass_kg=0.02,
                  clamp_pressure_pa=5e3), "clamp_pressure_pa must be <= 0"),
    (GraspRequest(GraspMode.PINCH, object_diameter_m=1e-3, object_mass_kg=0.02,
                  clamp_pressure_pa=5e3), "clamp_pressure_pa must be <= 0"),
    (GraspRequest(GraspMode.PINCH, object_diameter_m=1e-3, object_mass_kg=0.02,
                  open_pressure_pa=10e3), "PINCH does not open"),
    (GraspRequest(GraspMode.OPEN, target_tip_spacing_m=0.05,
                  clamp_pressure_pa=-10e3), "OPEN does not clamp"),
]


@pytest.mark.parametrize("request_, reason", REJECTIONS, ids=[r for _, r in REJECTIONS])
def test_every_invalid_command_is_rejected_with_its_reason_and_nothing_moves(
        kinematics, request_, reason):
    fsm = GraspStateMachine(kinematics)
    before = (fsm.state.phase, fsm.request)
    got = fsm.command(request_, 0.0)
    assert isinstance(got, Rejection) and reason in got.reason
    assert fsm.state.command_rejected and reason in fsm.state.message
    assert (fsm.state.phase, fsm.request) == before


def test_bad_configuration_is_refused():
    with pytest.raises(ValueError, match="settle_s"):
        GraspConfig(settle_s=0.0)
    with pytest.raises(ValueError, match="safety_factor"):
        ClampForceLaw(load_table("type_II", "l0"), safety_factor=0.5)


def test_controller_feedback_prefers_a_fresh_estimate_and_reports_silence():
    from softgrip_ros.control.grasp_fsm import ControllerFeedback
    from softgrip_ros.control.faults import Fault
    feedback = ControllerFeedback(estimate_timeout_s=0.1, status_timeout_s=1.0)
    assert math.isnan(feedback.pressure(0.0)[0])
    assert feedback.fault(0.0, idle=True) == ""
    # a grasp commanded before the first status (the suite still starting) waits status_timeout for
    # it
    assert feedback.fault(0.0, idle=False) == "" and feedback.fault(1.0, idle=False) == ""
    assert "no controller/status in 1.1 s" in feedback.fault(1.1, idle=False)
    feedback.on_status(int(Fault.SETPOINT_CLAMPED), 9e3, 0.0)
    feedback.on_estimate(10e3, 80.0, 0.0)
    assert feedback.pressure(0.05) == (10e3, 80.0)  # the estimate while fresh
    # then the measurement
    assert feedback.pressure(0.2)[0] == 9e3 and math.isnan(feedback.pressure(0.2)[1])
    # a clamped setpoint does not stop a grasp
    assert feedback.fault(0.5, idle=False) == ""
    feedback.on_status(int(Fault.SENSOR_TIMEOUT | Fault.REGULATOR), math.nan, 0.5)
    # the sensor timeout within its grace
    assert feedback.fault(0.6, idle=False) == "regulator"
    assert feedback.fault(0.85, idle=False) == "sensor timeout, regulator"
    assert "no controller/status for 1.6 s" in feedback.fault(2.1, idle=False)


def test_a_sensor_timeout_stops_a_grasp_only_once_it_lasts():
    """The controller holds during a sensor timeout and resumes by itself: a grasp rides out a gap
    shorter than the grace (frames delayed on a loaded machine), and faults on a dropout that
    lasts."""
    from softgrip_ros.control.grasp_fsm import ControllerFeedback
    from softgrip_ros.control.faults import Fault
    feedback = ControllerFeedback(estimate_timeout_s=0.1, status_timeout_s=1.0,
                                  transient_grace_s=0.3)
    feedback.on_status(int(Fault.SENSOR_TIMEOUT), math.nan, 0.0)
    assert feedback.fault(0.29, idle=False) == ""
    # readings back: the clock restarts
    feedback.on_status(0, 1e3, 0.1)
    feedback.on_status(int(Fault.SENSOR_TIMEOUT), math.nan, 0.2)
    assert feedback.fault(0.45, idle=False) == ""
    assert feedback.fault(0.51, idle=False) == "sensor timeout"
    feedback = ControllerFeedback(estimate_timeout_s=0.1, status_timeout_s=1.0,
                                  transient_grace_s=0.3)
    feedback.on_status(int(Fault.OVERPRESSURE | Fault.SENSOR_TIMEOUT), math.nan, 0.0)
    assert feedback.fault(0.0, idle=False) == "overpressure"  # no grace for the rest


def test_controller_feedback_tells_the_safe_state_from_other_faults():
    from softgrip_ros.control.grasp_fsm import ControllerFeedback
    from softgrip_ros.control.faults import Fault
    feedback = ControllerFeedback(estimate_timeout_s=0.1, status_timeout_s=1.0)
    assert not feedback.safe_state(0.0)  # no status yet
    feedback.on_status(int(Fault.COMMAND_TIMEOUT | Fault.SENSOR_TIMEOUT), 0.0, 0.0)
    assert not feedback.safe_state(0.1)
    feedback.on_status(int(Fault.SENSOR_NOISE), 0.0, 0.2)
    # a stale status says nothing
    assert feedback.safe_state(0.3) and not feedback.safe_state(1.3)


def test_a_rejected_command_leaves_a_running_grasp_untouched(kinematics):
    loop = GraspLoop(kinematics, GraspConfig(auto_clamp_delay_s=0.0))
    loop.command(
        GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04, object_mass_kg=0.02))
    loop.run_until(lambda s: s.phase == Phase.HOLDING, 5.0)
    before = (loop.fsm.request, loop.fsm.state.phase, loop.fsm._contact_pa, loop.fsm._clamp_pa,
              loop.fsm._open_pa)
    force = loop.fsm.state.clamp_force_n
    assert "too heavy" in loop.command(
        GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.01, object_mass_kg=5.0)).reason
    assert "does not squeeze" in loop.command(
        GraspRequest(GraspMode.PINCH, object_diameter_m=1e-4, object_mass_kg=0.02,
                     clamp_pressure_pa=0.0)).reason
    assert (loop.fsm.request, loop.fsm.state.phase, loop.fsm._contact_pa, loop.fsm._clamp_pa,
            loop.fsm._open_pa) == before
    loop.run_for(0.1)
    assert loop.fsm.state.clamp_force_n == pytest.approx(force, rel=0.1)


def test_a_settled_hold_traps_its_air_and_tops_it_up_when_it_drifts(kinematics):
    """hold_air trap: settle_s into HOLDING the valves close on the clamp's pressure (HOLD at
    the same target); a drift past the tolerance regulates again, then traps again once
    settled. hold_air regulate (the default) keeps the regulated line."""
    loop = GraspLoop(kinematics, GraspConfig(auto_clamp_delay_s=0.0, hold_air="trap"))
    loop.command(
        GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04, object_mass_kg=0.02))
    loop.run_until(lambda s: s.phase == Phase.HOLDING, 5.0)
    target = loop.fsm.request.target_gauge_pa
    loop.run_for(0.5)
    assert loop.fsm.request.source == Source.HOLD
    assert loop.fsm.request.target_gauge_pa == target
    assert loop.fsm.air_trapped_since is not None
    # a leak: 2 kPa off
    loop.fsm.update(loop.now + 0.01, target + 2e3)
    assert loop.fsm.request.source in (Source.SUPPLY, Source.VACUUM)
    assert loop.fsm.air_trapped_since is None and loop.fsm.top_ups == 1
    loop.run_for(0.5)
    assert loop.fsm.request.source == Source.HOLD and loop.fsm.state.phase == Phase.HOLDING
    regulated = GraspLoop(kinematics, GraspConfig(auto_clamp_delay_s=0.0))
    regulated.command(
        GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04, object_mass_kg=0.02))
    regulated.run_until(lambda s: s.phase == Phase.HOLDING, 5.0)
    regulated.run_for(0.5)
    assert regulated.fsm.request.source in (Source.SUPPLY, Source.VACUUM)


def test_without_sensing_a_grasp_that_reaches_holding_does_not_claim_the_object(kinematics):
    """object_held is the air's verdict: with the sensing off, nothing says an object is there,
    so a grasp succeeds at HOLDING with object_held false."""
    loop = GraspLoop(kinematics, GraspConfig(auto_clamp_delay_s=0.0))
    loop.command(GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04,
                              object_mass_kg=0.02, command_id="g"))
    task = loop.fsm.task
    loop.run_until(lambda s: s.phase == Phase.HOLDING, 5.0)
    assert loop.fsm.outcome(task, GraspMode.ENVELOP_CLAMP) == GoalOutcome.SUCCEEDED
    assert not loop.fsm.object_held()


@pytest.mark.parametrize("on_lost", ["hold", "release", "fault"])
def test_the_sensed_verdicts_end_the_goal_and_act_on_a_loss(kinematics, on_lost):
    """With sensing on, a HOLDING goal waits for the closing's verdict; NO_OBJECT fails it
    "closed on nothing" (the fingers stay closed); LOST does what on_object_lost says."""
    from softgrip_ros.estimation.grasp_sensing import Detection, ObjectStatus
    loop = GraspLoop(kinematics, GraspConfig(auto_clamp_delay_s=0.0, on_object_lost=on_lost))
    loop.fsm.sensing_enabled = True
    loop.command(GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04,
                              object_mass_kg=0.02, command_id="g"))
    task = loop.fsm.task
    loop.run_until(lambda s: s.phase == Phase.HOLDING, 5.0)
    # the verdict is awaited
    assert loop.fsm.outcome(task, GraspMode.ENVELOP_CLAMP) == GoalOutcome.RUNNING
    assert not loop.fsm.object_held()
    loop.fsm.sensed(Detection(ObjectStatus.HELD, 0.99, "held: felt 41 mm", loop.now, 0.041),
                    loop.now)
    assert loop.fsm.outcome(task, GraspMode.ENVELOP_CLAMP) == GoalOutcome.SUCCEEDED
    assert loop.fsm.object_held() and loop.fsm.state.object_size_m == 0.041
    loop.fsm.sensed(Detection(ObjectStatus.LOST, 0.9, "stepped +400 Pa", loop.now), loop.now)
    expected = {"hold": Phase.HOLDING, "release": Phase.RELEASING, "fault": Phase.FAULT}
    assert loop.fsm.state.phase == expected[on_lost]
    assert "lost" in loop.fsm.state.message and not loop.fsm.object_held()
    if on_lost != "hold":
        assert loop.fsm.request.source == Source.VENT
    nothing = GraspLoop(kinematics, GraspConfig(auto_clamp_delay_s=0.0))
    nothing.fsm.sensing_enabled = True
    nothing.command(GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04,
                                 object_mass_kg=0.02))
    nothing.run_until(lambda s: s.phase == Phase.HOLDING, 5.0)
    nothing.fsm.sensed(Detection(ObjectStatus.NO_OBJECT, 0.99, "as if free", nothing.now, 0.0),
                       nothing.now)
    assert nothing.fsm.outcome(nothing.fsm.task, GraspMode.ENVELOP_CLAMP) == GoalOutcome.FAILED
    assert nothing.fsm.state.message.startswith("closed on nothing")
    assert nothing.fsm.state.phase == Phase.HOLDING


def test_a_goal_stops_waiting_for_a_verdict_that_never_comes(kinematics):
    loop = GraspLoop(kinematics, GraspConfig(auto_clamp_delay_s=0.0, sensing_wait_s=0.3))
    loop.fsm.sensing_enabled = True
    loop.command(GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=0.04,
                              object_mass_kg=0.02))
    loop.run_until(lambda s: s.phase == Phase.HOLDING, 5.0)
    loop.run_for(0.4)
    assert loop.fsm.outcome(loop.fsm.task, GraspMode.ENVELOP_CLAMP) == GoalOutcome.SUCCEEDED


def test_bad_sensing_configuration_is_refused():
    with pytest.raises(ValueError, match="hold_air"):
        GraspConfig(hold_air="pump")
    with pytest.raises(ValueError, match="on_object_lost"):
        GraspConfig(on_object_lost="panic")
    with pytest.raises(ValueError, match="sensing_wait_s"):
        GraspConfig(sensing_wait_s=math.inf)


FIELD_RANGES = {"object_diameter_m": (0.0, 0.1), "object_mass_kg": (0.0, 0.2),
                "target_tip_spacing_m": (0.0, 0.1), "friction_coefficient": (0.05, 2.0),
                "open_pressure_pa": (-70e3, 70e3), "clamp_pressure_pa": (-70e3, 70e3)}


@st.composite
def grasp_requests(draw):
    """A GraspCommand's request: each field not given (NaN) or plausible, and in half of them
    one field anything a float holds; any mode number."""
    fields = {name: draw(st.one_of(st.just(math.nan), st.floats(low, high)))
              for name, (low, high) in FIELD_RANGES.items()}
    if draw(st.booleans()):
        fields[draw(st.sampled_from(sorted(fields)))] = draw(st.one_of(
            st.floats(allow_nan=True, allow_infinity=True),
            st.sampled_from([0.0, -0.0, 5e-324, 1e300, -1e300, -1.0])))
    mode = draw(st.one_of(st.sampled_from(list(GraspMode)), st.integers(-2, 8)))
    return GraspRequest(mode, command_id=draw(st.text(max_size=20)), **fields)


@settings(max_examples=40, deadline=None)
@given(request=grasp_requests(), opened_first=st.booleans())
def test_any_grasp_command_is_refused_in_one_line_or_runs_within_the_limits(request,
                                                                           opened_first):
    """Any GraspCommand's fields (#52's property tests over each goal: the Grasp action carries
    a GraspCommand), from rest or from an open gripper: refused with a one-line reason and
    nothing moved, or accepted with a pressure inside the limits, which the plant then keeps
    for the next 3 s."""
    config = GraspConfig()
    loop = GraspLoop(build_kinematics("l0"), config)
    loop.run_for(0.05)
    if opened_first:
        loop.command(GraspRequest(GraspMode.OPEN, target_tip_spacing_m=0.05))
        loop.run_until(lambda s: s.phase == Phase.ENVELOPED, 5.0)
    before = (loop.fsm.request, loop.fsm.state.phase, loop.fsm.task)
    started_s = loop.now
    refused = loop.command(request)
    event("refused" if refused is not None else "accepted")
    if refused is not None:
        assert isinstance(refused, Rejection) and refused.reason
        assert "\n" not in refused.reason and len(refused.reason) < 400, refused.reason
        assert (loop.fsm.request, loop.fsm.state.phase, loop.fsm.task) == before
        return
    assert config.min_gauge_pa <= loop.fsm.request.target_gauge_pa <= config.max_gauge_pa
    loop.run_for(3.0)
    pressures = loop.pressures_since(started_s)
    assert config.min_gauge_pa - 2e3 <= min(pressures) <= max(pressures) <= \
        config.max_gauge_pa + 2e3

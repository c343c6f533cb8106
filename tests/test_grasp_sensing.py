"""Grasp sensing from the air (estimation/grasp_sensing.py): the contact fit on synthetic
records whose truth is known, its verdicts, and a closing in the physics world."""
import math

import numpy as np
import pytest

from softgrip_ros.estimation import grasp_sensing as gs
from softgrip_ros.model.pneumatics import P_ATM_PA, PlantInputs, PneumaticPlant, Valve

pytestmark = pytest.mark.cpu  # computation only: scripts/test.sh runs it beside another


@pytest.fixture(scope="module")
def model():
    pytest.importorskip("mujoco")
    return gs.contact_model_for()


def clamp_record(opening_pa: float = 12e3, clamp_pa: float = -30e3) -> gs.AirRecord:
    """A closing as the controller runs one: the valve to the pump, then the regulated line."""
    record = gs.AirRecord(0.0, opening_pa)
    record.add_inputs(0.0, PlantInputs(clamp_pa, True, (Valve.VACUUM,)))
    record.add_inputs(0.045, PlantInputs(clamp_pa, True, (Valve.SUPPLY,)))
    return record


def synthetic(model, contact_pa, noise_pa=(300.0, 150.0), seed=0, until_s=0.4):
    """A record whose readings come from the fit's own simulation of ``contact_pa``."""
    record = clamp_record()
    times, traces = gs.simulate_hypotheses(record, model, np.array([contact_pa]), until_s)
    rng = np.random.default_rng(seed)
    for std, period_s in zip(noise_pa, (0.002, 0.005)):
        for stamp in np.arange(period_s, until_s, period_s):
            truth = float(np.interp(stamp, times, traces[:, 0]))
            record.add_sample(stamp, truth + std * rng.standard_normal(), std)
    return record


def test_the_model_refuses_a_share_outside_0_1_and_a_bad_mode(model):
    import dataclasses
    with pytest.raises(ValueError, match="bending_volume_share"):
        dataclasses.replace(model, bending_volume_share=1.2)
    with pytest.raises(ValueError, match="finger_mode_rad_s"):
        dataclasses.replace(model, finger_mode_rad_s=math.nan)


def test_the_hypotheses_simulation_follows_the_plant_for_free_fingers(model):
    """No contact in the range: the fit's linearly implicit Euler against the plant's truth
    integrator, within 30 Pa over the clamp."""
    record = clamp_record()
    times, traces = gs.simulate_hypotheses(record, model, np.array([-math.inf]), 0.3)
    plant = PneumaticPlant(model.plant)
    state = plant.initial_state(12e3)
    state.regulator_gauge_pa = 12e3
    truth, now = [], 0.0
    for stamp in times:
        inputs = record.inputs[0][1] if stamp <= 0.045 else record.inputs[1][1]
        state = plant.advance(state, inputs, stamp - now)
        now = stamp
        truth.append(state.chamber_pa[0] - P_ATM_PA)
    assert np.max(np.abs(traces[:, 0] - np.array(truth))) < 30.0


@pytest.mark.parametrize("contact_pa", [-0.4e3, 5e3, 9e3])
def test_the_fit_finds_a_known_contact_within_three_standard_errors(model, contact_pa):
    record = synthetic(model, contact_pa)
    fit = gs.fit_contact(record, model, 0.4, -30e3, 12e3)
    assert abs(fit.contact_pa - contact_pa) < 3.0 * fit.contact_std_pa
    assert 200.0 < fit.contact_std_pa < 2000.0
    assert 0.8 < fit.reduced_chi2 < 1.2


def test_the_verdicts_object_nothing_and_what_the_air_cannot_tell(model):
    size = model.tip_spacing_m(9e3)
    found = gs.judge_closing(gs.fit_contact(synthetic(model, 9e3), model, 0.4, -30e3, 12e3),
                             model, 0.4, expected_size_m=size)
    assert found.status == gs.ObjectStatus.CONTACT_CLOSING
    assert abs(found.object_size_m - size) < 3e-3 and found.confidence > 0.99
    assert "kPa" in found.evidence
    nothing = gs.fit_contact(synthetic(model, model.meet_pressure_pa), model, 0.4, -30e3, 12e3)
    empty = gs.judge_closing(nothing, model, 0.4, expected_size_m=0.02)
    assert empty.status == gs.ObjectStatus.NO_OBJECT and empty.object_size_m == 0.0
    # a sheet closes the fingers as nothing does: unknown, not "no object"
    sheet = gs.judge_closing(nothing, model, 0.4, expected_size_m=1e-4)
    assert sheet.status == gs.ObjectStatus.UNKNOWN and "cannot tell" in sheet.evidence


def test_the_fit_refuses_an_empty_record_and_an_empty_range(model):
    with pytest.raises(ValueError, match="fewer than 3"):
        gs.fit_contact(clamp_record(), model, 0.4, -30e3, 12e3)
    with pytest.raises(ValueError, match="low_pa < high_pa"):
        gs.fit_contact(synthetic(model, 5e3), model, 0.4, 12e3, -30e3)


@pytest.mark.slow
def test_in_the_world_a_20mm_cylinder_is_felt_and_nothing_is_nothing(model):
    """The product's state machine and sensing around the world, which they never read, each
    clamped at -30 kPa: the cylinder is HELD, felt within 10 mm of its size (sizes read large:
    docs/grasp_sensing.md), and the grasp succeeds; the empty hand, opened for it, is NO_OBJECT
    and the grasp fails "closed on nothing"."""
    from softgrip_ros.devtools import sensing_bench as sb
    from softgrip_ros.devtools.grasp_bench import GraspCase
    case = GraspCase("cylinder", 0.02, 0.02, 0.8)
    held = sb.run_trial(model, sb.Trial(case, clamp_pa=-30e3, seed=3))
    assert held.object_present and held.closing_correct, held.evidence
    assert 0.02 <= held.closing_size_m < 0.03
    empty = sb.run_trial(model, sb.Trial(None, opened_for=case, clamp_pa=-30e3, seed=3))
    assert not empty.object_present and empty.closing_correct, empty.evidence
    assert empty.message.startswith("closed on nothing")


# ---- the hold: loss from the trapped air --------------------------------------------------------
def trapped_readings(detector, step_at_s=None, step_pa=0.0, ramp_pa_per_s=0.0, only=None,
                     until_s=1.2, seed=0, rise_s=0.05):
    """Feed ``detector`` a trapped hold at -30 kPa from t = 0 (chamber_a 300 Pa at 500 Hz,
    chamber_b 150 Pa at 200 Hz): a step of ``step_pa`` rising over ``rise_s`` from
    ``step_at_s``, a ramp, on every sensor or ``only`` one; the first LOST's time, or None."""
    rng = np.random.default_rng(seed)
    detector.trapped(0.0)
    for k in range(1, int(until_s / 0.001)):
        now = k * 0.001
        true = -30e3 + ramp_pa_per_s * now
        for name, std, period in (("chamber_a", 300.0, 2), ("chamber_b", 150.0, 5)):
            if k % period:
                continue
            value = true
            if step_at_s is not None and now > step_at_s and only in (None, name):
                value += step_pa * min((now - step_at_s) / rise_s, 1.0)
            detector.reading(name, now, value + std * rng.standard_normal(), std)
        if detector.check(now) is not None:
            return now
    return None


def test_a_step_of_the_expected_size_on_both_sensors_is_a_loss_within_200ms():
    detector = gs.LossDetector(350.0)
    found = trapped_readings(detector, step_at_s=0.6, step_pa=350.0)
    assert found is not None and found - 0.6 < 0.2
    assert detector.lost.status == gs.ObjectStatus.LOST and "chamber_b" in detector.lost.evidence


@pytest.mark.parametrize("what", ["quiet", "one sensor", "too large", "ramp", "wrong sign"])
def test_what_is_not_a_loss(what):
    """A quiet hold, a step on one sensor (a sensor's fault), a step far beyond what a loss
    makes (a +20 kPa bias), a ramp (a valve stuck open), a step the wrong way: no LOST."""
    detector = gs.LossDetector(350.0)
    kwargs = {"quiet": {}, "one sensor": {"step_at_s": 0.6, "step_pa": 350.0, "only": "chamber_a"},
              "too large": {"step_at_s": 0.6, "step_pa": 20e3},
              "ramp": {"ramp_pa_per_s": 3e3},
              "wrong sign": {"step_at_s": 0.6, "step_pa": -350.0}}[what]
    assert trapped_readings(detector, **kwargs) is None


def test_the_loss_step_is_the_trapped_airs_response_to_the_fingers_closing(model):
    """+322 Pa for a 20 mm contact (7 kPa) at -30 kPa: p dV / (V + p dV/dp) at a fixed mass."""
    step = gs.loss_step_pa(model, -30e3, 7e3)
    volume = model.loss_volume_m3(7e3)
    p = P_ATM_PA - 30e3
    plant = PneumaticPlant(model.plant)
    capacitance = plant.air_terms(p, float(model.held_back_m3(-30e3, 7e3)))[1]
    assert step == pytest.approx(p * volume / capacitance, rel=0.05)
    assert 250.0 < step < 400.0


def test_the_loss_config_refuses_nonsense():
    with pytest.raises(ValueError, match="min_fraction"):
        gs.LossConfig(min_fraction=2.0)
    with pytest.raises(ValueError, match="test_s"):
        gs.LossConfig(test_s=math.nan)
    with pytest.raises(ValueError, match="expected_step_pa"):
        gs.LossDetector(0.0)


@pytest.mark.slow
def test_in_the_world_a_quiet_hold_is_held_with_its_air_trapped(model):
    """The product's state machine and sensing around the world (never read by them): a 20 mm
    cylinder clamped at -30 kPa (a closing deep enough to judge) and held still reads HELD
    throughout, with no LOST. (A loss is judged by bench_grasp's quick test.)"""
    from softgrip_ros.devtools import sensing_bench as sb
    from softgrip_ros.devtools.grasp_bench import GraspCase
    held = sb.run_trial(model, sb.Trial(GraspCase("cylinder", 0.02, 0.02, 0.8), moves=("lift",),
                                        clamp_pa=-30e3, hold_s=1.5, seed=1))
    assert held.final_status == gs.ObjectStatus.HELD and held.false_lost == 0
    assert math.isnan(held.loss_time_s)


def test_a_judgement_that_raises_leaves_the_status_unknown_and_says_why(model):
    """ObjectSensingLink through a pinch to HOLDING, its runner failing: the verdict is UNKNOWN
    with the error in its evidence, and the HOLDING goal is not held up for it."""
    from softgrip_ros.control.grasp_fsm import (GoalOutcome, GraspMode, GraspRequest,
                                                GraspStateMachine, Phase)
    from softgrip_ros.control.object_sensing import ObjectSensingLink
    from softgrip_ros.devtools.sensing_bench import sensor_noise
    from softgrip_ros.model.calibration import build_kinematics

    fsm = GraspStateMachine(build_kinematics("l0"))
    link = ObjectSensingLink(fsm, gs.GraspSensing(model, sensor_noise()),
                             run=lambda job, done: done(RuntimeError("no CPU left")))
    fsm.command(GraspRequest(GraspMode.PINCH, object_diameter_m=1e-4, object_mass_kg=0.005), 0.0)
    link.after(0.0, 0.0)
    target = fsm.request.target_gauge_pa
    for k in range(1, 40):
        fsm.update(0.01 * k, target)
        link.after(0.01 * k, target)
    assert fsm.state.phase == Phase.HOLDING
    assert fsm.state.object_status == gs.ObjectStatus.UNKNOWN
    assert "no CPU left" in fsm.state.object_evidence
    assert fsm.outcome(fsm.task, GraspMode.PINCH) == GoalOutcome.SUCCEEDED
    assert not fsm.object_held()


def test_the_judge_process_runs_nicer_than_the_controller_but_not_starved(model):
    """By default the judge's child runs JUDGE_NICE_INCREMENT above this process, less than
    the other workers' WORKER_NICE_INCREMENT: its verdicts have a deadline."""
    import os
    from softgrip_ros.runtime.motion_judge import JUDGE_NICE_INCREMENT, MotionJudgeProcess
    from softgrip_ros.runtime.worker_process import WORKER_NICE_INCREMENT
    assert 0 < JUDGE_NICE_INCREMENT < WORKER_NICE_INCREMENT
    judge = MotionJudgeProcess("type_II", "l0", model.plant)
    try:
        nice_in_child = judge._worker.submit(os.nice, 0).result(timeout=60.0)
    finally:
        judge.close()
    assert nice_in_child == min(os.nice(0) + JUDGE_NICE_INCREMENT, 19)


def test_the_judge_process_gives_the_verdict_of_an_in_process_judgement(model):
    """MotionJudgeProcess judges in a child of its own (another PID, which builds its own
    model, with the plant file's identified share), with the verdict judge_motion gives here;
    closed, it refuses more work."""
    import dataclasses
    import os
    from softgrip_ros.runtime.motion_judge import MotionJudgeProcess
    job = gs.MotionJob(synthetic(model, 9e3), False, model.tip_spacing_m(9e3), -30e3, 0.4)
    identified = dataclasses.replace(model, bending_volume_share=0.16, share_identified=True)
    here = gs.judge_motion(identified, job)
    assert "identified on this gripper" in here.evidence
    judge = MotionJudgeProcess("type_II", "l0", model.plant, 0.16, nice_increment=0)
    try:
        apart = judge.submit(job).result(timeout=60.0)
        child = judge._worker.submit(os.getpid).result(timeout=10.0)
    finally:
        judge.close()
    assert child != os.getpid()
    assert (apart.status, apart.evidence) == (here.status, here.evidence)
    assert apart.object_size_m == pytest.approx(here.object_size_m, abs=1e-9)
    with pytest.raises(RuntimeError):
        judge.submit(job)

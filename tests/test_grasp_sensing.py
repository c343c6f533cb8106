"""Grasp sensing from the air (estimation/grasp_sensing.py): the contact fit on synthetic
records whose truth is known, its verdicts, and a closing in the physics world."""
import math

import numpy as np
import pytest

from softgrip_ros.estimation import grasp_sensing as gs
from softgrip_ros.model.pneumatics import P_ATM_PA, PlantInputs, PneumaticPlant, Valve


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
    """The closed loop with the world, which the detector never reads: the cylinder is found
    within 5 mm of its size; the empty hand, opened for it, is NO_OBJECT."""
    from softgrip_ros.devtools import sensing_bench as sb
    from softgrip_ros.devtools.grasp_bench import GraspCase
    case = GraspCase("cylinder", 0.02, 0.02, 0.8)
    held = sb.closing_trial(model, case, seed=3)
    assert held.object_present and sb.correct(held), held.detection
    assert abs(held.detection.object_size_m - 0.02) < 5e-3
    empty = sb.closing_trial(model, None, seed=3, opened_for=case)
    assert not empty.object_present and sb.correct(empty), empty.detection

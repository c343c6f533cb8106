"""The known-object step's share fit (estimation/contact_identification.py) on synthetic clamps
whose truth is known, and what it refuses; the plant file's contact section."""
import dataclasses
import math

import numpy as np
import pytest

from softgrip_ros.estimation import contact_identification as ci
from softgrip_ros.estimation import grasp_sensing as gs
from softgrip_ros.model import plant_file
from tests.test_grasp_sensing import clamp_record

pytestmark = pytest.mark.cpu  # computation only: scripts/test.sh runs it beside another

SHARES = tuple(np.round(np.linspace(0.05, 0.5, 91), 3))


@pytest.fixture(scope="module")
def model():
    pytest.importorskip("mujoco")
    return gs.contact_model_for()


def clamp_on(model, share: float, size_m: float, seed: int, until_s=0.4) -> gs.MotionJob:
    """A clamp from 12 kPa on a rigid object of ``size_m``, read by two noisy sensors, on
    fingers whose bending makes ``share`` of dV/dp."""
    truth = dataclasses.replace(model, bending_volume_share=share)
    record = clamp_record()
    contact = float(model.pressure_for_tip_spacing(size_m))
    times, traces = gs.simulate_hypotheses(record, truth, np.array([contact]), until_s)
    rng = np.random.default_rng(seed)
    for std, period_s in ((300.0, 0.002), (150.0, 0.005)):
        for stamp in np.arange(period_s, until_s, period_s):
            value = float(np.interp(stamp, times, traces[:, 0]))
            record.add_sample(stamp, value + std * rng.standard_normal(), std)
    return gs.MotionJob(record, False, size_m, -30e3, until_s)


@pytest.mark.parametrize("share", [0.12, 0.3])
def test_the_fit_recovers_the_share_of_known_clamps_within_its_interval(model, share):
    """Three clamps on a 30 mm object and two on nothing, simulated with a share the model does
    not assume: the
    fit finds it inside its 95 % interval, the interval is narrower than 0.1, and each clamp's
    size felt under it is the object's within the 5 mm the sensing is asked for."""
    jobs = [clamp_on(model, share, 0.03, seed) for seed in range(3)]
    told = []
    fit = ci.fit_bending_share(jobs, empty_hands(model, share), model, 0.03, shares=SHARES,
                               progress=told.append)
    assert fit.ci95[0] <= share <= fit.ci95[1], fit
    assert fit.ci95[1] - fit.ci95[0] < 0.1
    assert abs(fit.bending_volume_share - share) < 0.03
    assert all(abs(size - 0.03) < 5e-3 for size in fit.felt_sizes_m), fit.felt_sizes_m
    assert 0.7 < fit.reduced_chi2 < 1.3
    assert len(told) == 5 and "closing 1/5 under 91 shares" in told[0]


def empty_hands(model, share: float, count: int = 2) -> list:
    """Clamps on nothing: the fingers meet each other."""
    meet_m = model.tip_spacing_m(model.meet_pressure_pa)
    return [clamp_on(model, share, meet_m + 1e-5, 10 + seed) for seed in range(count)]


def test_the_fit_refuses_what_cannot_say_the_share(model):
    job, empty = clamp_on(model, 0.2, 0.03, 0), empty_hands(model, 0.2)
    with pytest.raises(ValueError, match="closings on nothing, got 1 and 0"):
        ci.fit_bending_share([job], [], model, 0.03)
    with pytest.raises(ValueError, match="an opening is not a closing"):
        ci.fit_bending_share([dataclasses.replace(job, opening=True)], empty, model, 0.03)
    with pytest.raises(ValueError, match="positive length"):
        ci.fit_bending_share([job], empty, model, math.nan)
    # wider than the opening the clamp started from
    with pytest.raises(ValueError, match="open wider first"):
        ci.fit_bending_share([job], empty, model, 0.08, shares=SHARES)
    # the object never placed: on one kind of closing alone a smaller share would pass these
    # for a 30 mm object; beside the empty hands' they cannot be
    with pytest.raises(ValueError, match="edge of the shares|is not judged so"):
        ci.fit_bending_share(empty_hands(model, 0.2, 3), empty, model, 0.03, shares=SHARES)


def test_the_identified_share_is_the_sensing_model_and_its_evidence_says_so(model):
    identified = gs.contact_model_for(bending_volume_share=0.25)
    assert identified.bending_volume_share == 0.25 and identified.share_identified
    assert not model.share_identified
    job = clamp_on(model, model.bending_volume_share, 0.03, 2)
    predicted = gs.judge_motion(model, job)
    assert predicted.status == gs.ObjectStatus.CONTACT_CLOSING
    assert "not identified on this gripper" in predicted.evidence
    assert "identified on this gripper" in gs.judge_motion(identified, job).evidence
    with pytest.raises(ValueError, match="bending_volume_share"):
        gs.contact_model_for(bending_volume_share=1.5)


def test_the_plant_file_keeps_an_identified_share_and_refuses_a_bad_one(tmp_path):
    base = plant_file.default_description()
    assert base.bending_volume_share is None
    assert "contact" not in plant_file.document(base)
    with_share = dataclasses.replace(base, bending_volume_share=0.21, details={
        "contact.bending_volume_share": {"source": "identified", "ci95": [0.18, 0.24],
                                         "known_object_m": 0.03}})
    back = plant_file.load(plant_file.save(with_share, tmp_path / "plant.yaml"))
    assert back.bending_volume_share == 0.21
    assert back.details["contact.bending_volume_share"]["ci95"] == [0.18, 0.24]
    document = plant_file.document(back)
    document["contact"]["bending_volume_share"]["value"] = 1.5
    with pytest.raises(ValueError, match=r"contact.bending_volume_share: 1.5 1 lies outside"):
        plant_file.parse(document)
    document["contact"] = {"share": {"value": 0.2}}
    with pytest.raises(ValueError, match=r"contact: unknown \['share'\]"):
        plant_file.parse(document)
    document["contact"] = [0.2]
    with pytest.raises(ValueError, match="contact must be a mapping"):
        plant_file.parse(document)

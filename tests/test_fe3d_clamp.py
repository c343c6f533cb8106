"""The 3-D finger clamping the sheet and a cylinder, on the coarsest mesh (seconds each)."""
import math

import numpy as np
import pytest

pytest.importorskip("ngsolve")

from softgrip_ros.model import gripper_models  # noqa: E402
from softgrip_ros.model.fe3d import clamp  # noqa: E402
from softgrip_ros.model.fe3d.finger import MAX_INTERPENETRATION_M  # noqa: E402
from softgrip_ros.model.force_law import ObjectKind  # noqa: E402

COARSE_M = 6e-3


@pytest.fixture(scope="module")
def geometry():
    return gripper_models.resolve("type_II")[0]


@pytest.fixture(scope="module")
def sheet(geometry):
    return clamp.clamp_sweep(geometry, ObjectKind.FLAT, clamp.SHEET_THICKNESS_M,
                             element_size_m=COARSE_M, lowest_pa=-20e3, progress=lambda m: None,
                             use_cache=False)


def test_sheet_is_put_in_once_the_finger_opens_clear_and_pressed_harder_as_pressure_falls(sheet):
    # at rest the tip block reaches past the centre line, so the finger must open first
    assert sheet.opening_pa > 0.0
    assert sheet.states[0].normal_force_n == 0.0
    pressures = [s.pressure_pa for s in sheet.states]
    assert pressures == sorted(pressures, reverse=True)
    assert pressures[-1] == pytest.approx(-20e3)
    forces = [s.normal_force_n for s in sheet.states]
    # the finger as Table 1 is read here is stiff: tens of millinewtons (docs/benchmarks.md)
    assert forces[-1] > 0.02
    assert all(b >= a - 1e-9 for a, b in zip(forces, forces[1:])), forces
    last = sheet.states[-1]
    # a plane's tractions all point along its normal (-x on the left finger): their sum equals
    # the resultant, which the residual gives independently (1 %)
    assert -last.resultant_n[0] == pytest.approx(last.normal_force_n, rel=0.01)
    assert abs(last.resultant_n[1]) < 0.01 * last.normal_force_n
    # the contact lies on the sheet's face, and the penalty's penetration stays within bounds
    assert last.contact_centre_m[0] == pytest.approx(-0.5 * clamp.SHEET_THICKNESS_M, abs=5e-5)
    assert sheet.interpenetration_max_m <= MAX_INTERPENETRATION_M
    # the peak, at the penalty's points, is at least the mean over the contact
    assert last.peak_contact_pressure_pa >= last.normal_force_n / last.contact_area_m2
    contact = sheet.contact_pressure_pa()
    assert last.pressure_pa < contact <= sheet.opening_pa


def test_an_object_the_finger_cannot_clear_gives_no_states_and_says_how_far_it_opened(
        geometry, monkeypatch):
    monkeypatch.setattr(clamp, "MAX_OPENING_PA", 2.5e3)
    result = clamp.clamp_sweep(geometry, ObjectKind.ROUND, 0.010, element_size_m=COARSE_M,
                               progress=lambda m: None, use_cache=False)
    assert result.states == []
    assert "does not open clear of a 10 mm round object: D2 at 2.5 kPa is" in result.stop
    assert math.isnan(result.normal_force_n(-30e3))
    assert math.isnan(result.contact_pressure_pa())


def test_a_sweep_survives_its_cache(sheet):
    again = clamp.FE3DClampSweep.from_dict(sheet.to_dict())
    assert again.object_kind is ObjectKind.FLAT
    assert [s.normal_force_n for s in again.states] == [s.normal_force_n for s in sheet.states]
    np.testing.assert_allclose(again.states[-1].finger.backbone_m,
                               sheet.states[-1].finger.backbone_m, atol=1e-6)
    assert again.contact_pressure_pa() == sheet.contact_pressure_pa()


@pytest.mark.parametrize("size_m, lowest_pa, match", [
    (0.0, -20e3, "size"), (math.nan, -20e3, "size"), (0.5, -20e3, "size"),
    (0.01, 5e3, "lowest pressure"), (0.01, -200e3, "lowest pressure"),
])
def test_bad_scenes_are_refused_before_any_mesh(geometry, size_m, lowest_pa, match):
    with pytest.raises(ValueError, match=match):
        clamp.clamp_sweep(geometry, ObjectKind.ROUND, size_m, lowest_pa=lowest_pa,
                          use_cache=False)

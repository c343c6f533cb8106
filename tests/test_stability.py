"""Stability where methods fail: each test pins the failure of the naive method and shows that
the one we use holds there. (Explicit Euler on the stiff pneumatics: test_model_pneumatics.py;
the rod solver at contact onset and at the largest pressure: test_model_rod.py; a Kalman filter
with a wrong noise model flagged by the NIS: test_estimation.py.)"""
import dataclasses
import math

import numpy as np
import pytest

from softgrip_ros.model.calibration import PaperNumbers, build_kinematics, mean_curvature_per_m
from softgrip_ros.model.geometry import CHAMBER_COUNT
from softgrip_ros.model.kinematics import GripperKinematics

pytestmark = pytest.mark.cpu  # computation only: scripts/test.sh runs it beside another

L0 = build_kinematics("l0", max_pressure_pa=60e3)


def naive_segment_advance(length_m, theta):
    """The textbook PCC step, [s sin(theta)/theta, s (1 - cos theta)/theta]."""
    with np.errstate(divide="ignore", invalid="ignore"):
        theta = np.float64(theta)
        return length_m * np.sin(theta) / theta, length_m * (1.0 - np.cos(theta)) / theta


@pytest.mark.parametrize("theta", [0.0, 1e-9, -1e-9, 1e-12])
def test_naive_pcc_form_fails_near_straight_and_ours_holds(theta):
    s = L0.geometry.segment_length_m
    along, lateral = naive_segment_advance(s, theta)
    # series of s (1 - cos t) / t
    exact_lateral = s * theta / 2.0 * (1.0 - theta * theta / 12.0)
    if theta == 0.0:
        # 0/0: the straight finger is undefined
        assert math.isnan(along) and math.isnan(lateral)
    else:
        # 1 - cos t cancels to nothing
        assert abs(lateral - exact_lateral) > 0.1 * abs(exact_lateral)
    # ours: the whole chain at theta against the series form (exact to rounding), and continuous at
    # 0
    tip = L0.tip_for_angles([theta] * CHAMBER_COUNT)
    straight = L0.tip_for_angles([0.0] * CHAMBER_COUNT)
    assert all(math.isfinite(v) for v in tip)
    assert max(abs(a - b) for a, b in zip(tip, straight)) <= 10.0 * abs(theta) + 1e-17


def test_linear_l0_runs_away_beyond_46kpa_and_the_saturating_model_follows_the_fea():
    """The paper's FEA: curvature +7.5 % from 50 to 55 kPa, +0.61 % from 55 to 60 kPa. The linear
    law without saturation gives +10 % and +9.1 %; ours matches the FEA's two growths (fitted to
    them: the check is that the fit took, and that the linear law really misses)."""
    paper = PaperNumbers.load()
    linear = GripperKinematics(
        L0.geometry, dataclasses.replace(L0.calibration, saturation_pressure_pa=math.inf),
        model="l0", max_pressure_pa=60e3)

    def growths(model):
        c = [mean_curvature_per_m(model, p) for p in (50e3, 55e3, 60e3)]
        return [100.0 * (b / a - 1.0) for a, b in zip(c, c[1:])]

    fea = [100.0 * paper.growth_50_55, 100.0 * paper.growth_55_60]
    assert growths(linear) == pytest.approx([10.0, 100.0 / 11.0], abs=1e-6)  # runs away
    # follows the FEA
    assert growths(L0) == pytest.approx(fea, abs=0.05)
    # and the models flag pressures beyond the validated range
    assert L0.pose(45e3).in_validated_range and not L0.pose(47e3).in_validated_range

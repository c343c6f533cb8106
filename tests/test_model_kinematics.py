"""Bending laws and PCC kinematics: exactness, monotonicity, symmetry, inverse, derivatives, bad
input."""
import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.integrate import solve_ivp

from softgrip_ros.model.bending import BendingCalibration, LinearBending, YeohMomentBalance
from softgrip_ros.model.calibration import build_kinematics
from softgrip_ros.model.geometry import CHAMBER_COUNT, FingerGeometry, load_geometry

pytestmark = pytest.mark.cpu  # computation only: scripts/test.sh runs it beside another

L0 = build_kinematics("l0", max_pressure_pa=50e3)
L1 = build_kinematics("l1", max_pressure_pa=50e3)
MODELS = [L0, L1]
GEOMETRY = L0.geometry
P_MAX = 60e3
pressures = st.floats(min_value=L0.contact_pressure_pa, max_value=P_MAX, allow_nan=False)


def series_tip(thetas):
    """Reference tip for tiny bends: each segment's displacement by its Taylor series in theta."""
    g = GEOMETRY
    x, z, phi = -g.root_x_m, g.vertical_height_m, g.inclination_rad
    x += g.first_chamber_offset_m * math.sin(phi)
    z += g.first_chamber_offset_m * math.cos(phi)
    s = g.segment_length_m
    for th in thetas:
        along = s * (1 - th**2 / 6 + th**4 / 120)  # s sin(th)/th
        # s (1 - cos th)/th, towards -n (outward)
        across = s * (th / 2 - th**3 / 24 + th**5 / 720)
        t = (math.sin(phi), math.cos(phi))
        n = (math.cos(phi), -math.sin(phi))
        x += along * t[0] - across * n[0]
        z += along * t[1] - across * n[1]
        phi -= th
    return x + g.tip_length_m * math.sin(phi), z + g.tip_length_m * math.cos(phi), phi


@pytest.mark.parametrize("theta", [0.0, 1e-12, -1e-12, 1e-6, -1e-6])
def test_chain_is_exact_and_continuous_near_straight(theta):
    thetas = [theta] * CHAMBER_COUNT
    tip = L0.tip_for_angles(thetas)
    reference = series_tip(thetas)
    assert tip == pytest.approx(reference, abs=1e-16, rel=1e-15)
    straight = L0.tip_for_angles([0.0] * CHAMBER_COUNT)
    # continuity: the pose moves by O(theta) from the straight finger, never by a jump
    assert max(abs(a - b) for a, b in zip(tip, straight)) <= 10.0 * abs(theta) + 1e-17


def test_rest_pose_is_the_paper_layout():
    pose = L0.pose(0.0)
    assert pose.segment_angles_rad == (0.0,) * CHAMBER_COUNT
    assert pose.tip_spacing_m == pytest.approx(1e-3, abs=1e-15)  # v = 1 mm
    assert pose.included_angle_rad == pytest.approx(math.radians(15.0), abs=1e-15)
    assert pose.left_tip_angle_rad == GEOMETRY.inclination_rad
    # the total height h1 + L2 cos(15 deg) is Table 1's L1 = 126 mm within 0.1 mm
    assert pose.left_tip_z_m == pytest.approx(0.126, abs=1e-4)


def frenet_tip(thetas):
    """Independent reference: integrate dx/ds = sin(phi), dz/ds = cos(phi), dphi/ds = -kappa(s)."""
    g = GEOMETRY
    pieces = ([(g.first_chamber_offset_m, 0.0)] + [(g.segment_length_m, th / g.segment_length_m)
                                                   for th in thetas] + [(g.tip_length_m, 0.0)])
    state = np.array([-g.root_x_m, g.vertical_height_m, g.inclination_rad])
    for length, kappa in pieces:
        sol = solve_ivp(lambda s, y, k=kappa: [math.sin(y[2]), math.cos(y[2]), -k], (0.0, length),
                        state, method="DOP853", rtol=1e-13, atol=1e-15)
        state = sol.y[:, -1]
    return tuple(state)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(-1.5, 1.5), min_size=CHAMBER_COUNT, max_size=CHAMBER_COUNT))
def test_chain_matches_numerical_integration_of_the_frenet_equations(thetas):
    assert L0.tip_for_angles(thetas) == pytest.approx(frenet_tip(thetas), abs=1e-9)


@pytest.mark.parametrize("kin", MODELS, ids=lambda k: k.model)
def test_tip_spacing_is_monotone_in_pressure(kin):
    grid = np.linspace(kin.contact_pressure_pa, P_MAX, 4001)
    d2 = kin.poses(grid).tip_spacing_m
    assert np.all(np.diff(d2) > 0.0), "D2 must grow strictly with pressure above tip contact"


@settings(max_examples=60, deadline=None)
@given(pressures, pressures)
def test_tip_spacing_order_follows_pressure_order(p1, p2):
    low, high = sorted((p1, p2))
    assert L0.pose(low).tip_spacing_m <= L0.pose(high).tip_spacing_m


def right_finger_by_integration(thetas):
    """The right finger integrated on its own: root at +x, inclined towards -x, bends mirrored."""
    g = GEOMETRY
    pieces = ([(g.first_chamber_offset_m, 0.0)] + [(g.segment_length_m, th / g.segment_length_m)
                                                   for th in thetas] + [(g.tip_length_m, 0.0)])
    # heading psi measured from +z towards +x; the right finger starts at -inclination and opens
    # towards +x
    state = np.array([g.root_x_m, g.vertical_height_m, -g.inclination_rad])
    for length, kappa in pieces:
        sol = solve_ivp(lambda s, y, k=kappa: [math.sin(y[2]), math.cos(y[2]), +k], (0.0, length),
                        state, method="DOP853", rtol=1e-13, atol=1e-15)
        state = sol.y[:, -1]
    return tuple(state)


@pytest.mark.parametrize("pressure", [-5e3, 0.0, 12e3, 37e3, 55e3])
def test_the_fingers_mirror_each_other(pressure):
    pose = L1.pose(pressure)
    right = right_finger_by_integration(pose.segment_angles_rad)
    assert pose.right_tip() == pytest.approx(right, abs=1e-9)


@settings(max_examples=60, deadline=None)
@given(st.floats(min_value=100.0, max_value=50e3))
def test_inverse_of_forward_is_identity(pressure):
    for kin in MODELS:
        d2 = kin.pose(pressure).tip_spacing_m
        assert kin.pressure_for_tip_spacing(d2) == pytest.approx(pressure, rel=1e-9)


def test_inverse_rejects_unreachable_spacing_with_the_range():
    low, high = L0.tip_spacing_range_m()
    assert low == 0.0 and high == pytest.approx(0.151, rel=0.01)
    with pytest.raises(ValueError, match=r"out of reach.*0\.00 mm.*at the 50\.0 kPa limit"):
        L0.pressure_for_tip_spacing(0.2)
    with pytest.raises(ValueError, match="out of reach"):
        L0.pressure_for_tip_spacing(-1e-3)
    with pytest.raises(ValueError, match="finite"):
        L0.pressure_for_tip_spacing(float("nan"))


def test_l1_slope_equals_l0_slope_at_zero_pressure():
    geometry, calibration = GEOMETRY, L0.calibration
    l0, l1 = LinearBending(geometry, L0.material,
                           calibration), YeohMomentBalance(geometry, L0.material, calibration)
    assert np.asarray(l1.angle_slopes(0.0)) == pytest.approx(np.asarray(l0.angle_slopes(0.0)),
                                                             rel=1e-9)
    for eps in (1.0, -1.0):
        assert np.asarray(l1.angles(eps)) / eps == pytest.approx(np.asarray(l0.gains_rad_per_pa),
                                                                 rel=1e-4)
    # and they part above: the planar Yeoh stress softens first, then C20 stiffens it
    assert sum(l1.angles(40e3)) != pytest.approx(sum(l0.angles(40e3)), rel=0.01)


@settings(max_examples=30, deadline=None)
@given(st.lists(pressures, min_size=1, max_size=20))
def test_vectorised_equals_scalar(values):
    for kin in MODELS:
        batch = kin.poses(np.array(values))
        for i, p in enumerate(values):
            single = kin.pose(p)
            for field in ("left_tip_x_m", "left_tip_z_m", "left_tip_angle_rad",
                          "included_angle_rad", "root_spacing_m", "tip_spacing_m"):
                assert getattr(batch, field)[i] == pytest.approx(getattr(single, field), rel=1e-12,
                                                                 abs=1e-15), field
            assert bool(batch.in_validated_range[i]) == single.in_validated_range
            assert bool(batch.in_contact[i]) == single.in_contact


def test_large_batches_assemble_chunks_and_match_scalar_poses():
    from softgrip_ros.model.kinematics import BATCH_CHUNK
    grid = np.linspace(-20e3, 58e3, 2 * BATCH_CHUNK + 17)  # three chunks, the last one short
    for kin in MODELS:
        batch = kin.poses(grid)
        assert batch.segment_angles_rad.shape == (grid.size, CHAMBER_COUNT)
        for i in (0, BATCH_CHUNK - 1, BATCH_CHUNK, 2 * BATCH_CHUNK + 3, grid.size - 1):
            single = kin.pose(grid[i])
            assert batch.tip_spacing_m[i] == pytest.approx(single.tip_spacing_m, rel=1e-12,
                                                           abs=1e-15)
            assert batch.left_tip_z_m[i] == pytest.approx(single.left_tip_z_m, rel=1e-12)
            assert batch.included_angle_rad[i] == pytest.approx(single.included_angle_rad,
                                                                rel=1e-12)
            assert batch.segment_angles_rad[i] == pytest.approx(single.segment_angles_rad,
                                                                rel=1e-12, abs=1e-18)
            assert (bool(batch.in_contact[i]),
                    bool(batch.in_validated_range[i])) == (single.in_contact,
                                                           single.in_validated_range)


def test_small_angle_trig_kernel_is_exact_to_rounding():
    from softgrip_ros.model.kinematics import _trig_array, _trig_small_array
    x = np.concatenate([np.linspace(-0.999, 0.999, 20001), [0.0, 1e-300, -1e-12, 1e-6]])
    fast, reference = _trig_small_array(x), _trig_array(x)
    for name, got, want in zip(("sin", "cos", "sinc"), fast, reference):
        assert np.max(np.abs(got - want)) <= 4 * np.finfo(float).eps, name
    assert np.all(fast[2][x == 0.0] == 1.0)


def test_a_bend_beyond_the_small_angle_kernel_uses_the_general_trigonometry():
    # a gain 8x the calibrated one bends a segment beyond 2 rad, where sqrt(1 - sin^2) loses cos's
    # sign
    strong = type(L0)(GEOMETRY, dataclasses.replace(L0.calibration, gain=8 * L0.calibration.gain),
                      L0.material)
    pressures = np.array([10e3, 40e3])
    assert max(strong.pose(40e3).segment_angles_rad) > 2.0
    batch = strong.poses(pressures)
    for i, p in enumerate(pressures):
        assert batch.left_tip_x_m[i] == pytest.approx(
            strong.pose(p).left_tip_x_m, rel=1e-12, abs=1e-15)
        assert batch.left_tip_z_m[i] == pytest.approx(
            strong.pose(p).left_tip_z_m, rel=1e-12, abs=1e-15)


def test_saturation_batch_path_equals_the_scalar_one_and_survives_a_narrow_knee():
    from softgrip_ros.model.bending import Saturation
    grid = np.linspace(-100e3, 60e3, 1601)
    for width in (L0.calibration.saturation_width_pa, 1.0):  # 1 Pa: exp((p - p_sat)/w) overflows
        saturation = Saturation(dataclasses.replace(L0.calibration, saturation_width_pa=width))
        batch = saturation.effective_pressure(grid)
        assert np.all(np.isfinite(batch))
        assert batch == pytest.approx([saturation.effective_pressure(float(p)) for p in grid],
                                      rel=1e-12, abs=1e-9)


@pytest.mark.parametrize("kin", MODELS, ids=lambda k: k.model)
def test_tip_slope_matches_finite_differences(kin):
    grid = np.array([kin.contact_pressure_pa + 50.0, 0.0, 5e3, 25e3, 45e3, 52e3, 58e3])
    h = 0.5
    analytic = kin.tip_slope(grid)
    for row, p in zip(analytic, grid):
        plus, minus = kin.pose(p + h), kin.pose(p - h)
        numeric = [(plus.left_tip_x_m - minus.left_tip_x_m) / (2 * h),
                   (plus.left_tip_z_m - minus.left_tip_z_m) / (2 * h),
                   (plus.left_tip_angle_rad - minus.left_tip_angle_rad) / (2 * h)]
        assert row == pytest.approx(numeric, rel=1e-5, abs=1e-14)
        # the scalar path agrees
        assert kin.tip_slope_at(float(p)) == pytest.approx(row, rel=1e-12, abs=1e-18)
    assert np.all(kin.tip_slope(np.array([kin.contact_pressure_pa - 1e3])) == 0.0)
    assert kin.tip_slope_at(kin.contact_pressure_pa - 1e3) == (0.0, 0.0, 0.0)


def test_negative_pressure_closes_down_to_tip_contact():
    assert -2e3 < L0.contact_pressure_pa < 0.0
    closing = L0.pose(L0.contact_pressure_pa / 2)
    assert 0.0 < closing.tip_spacing_m < 1e-3 and not closing.in_contact
    clamped = L0.pose(-30e3)
    assert clamped.in_contact and clamped.tip_spacing_m == pytest.approx(0.0, abs=1e-9)
    assert clamped.segment_angles_rad == L0.pose(L0.contact_pressure_pa).segment_angles_rad
    assert all(t < 0.0 for t in clamped.segment_angles_rad)


def test_validated_range_flag():
    assert L0.pose(46e3).in_validated_range and not L0.pose(47e3).in_validated_range
    assert not L0.pose(-20e3).in_validated_range
    flags = L0.poses(np.array([0.0, 30e3, 55e3])).in_validated_range
    assert flags.tolist() == [True, True, False]


def test_saturation_keeps_predictions_from_running_away():
    linear_growth = 60.0 / 50.0
    for kin in MODELS:
        assert kin.pose(60e3).tip_spacing_m / kin.pose(50e3).tip_spacing_m < 0.5 * (1 +
                                                                                    linear_growth)
        bends = [sum(kin.pose(p).segment_angles_rad) for p in (45e3, 50e3, 55e3, 60e3)]
        assert bends == sorted(bends)


def test_backbone_polyline_ends_at_the_tip():
    for p in (0.0, 30e3):
        points = L1.backbone(p, points_per_segment=6)
        pose = L1.pose(p)
        assert points.shape == (1 + 1 + 1 + 5 * 6 + 1, 2)
        assert points[0] == pytest.approx([-GEOMETRY.root_x_m, 0.0])
        assert points[-1] == pytest.approx([pose.left_tip_x_m, pose.left_tip_z_m], abs=1e-12)


@pytest.mark.parametrize("bad, message", [(float("nan"), "finite"), (float("inf"), "finite"),
                                          ("abc", "number"), (np.zeros(2), "single number"),
                                          (70e3, "out of the model's range"),
                                          (-200e3, "out of the model's range")])
def test_bad_scalar_pressure_is_rejected(bad, message):
    with pytest.raises(ValueError, match=message):
        L0.pose(bad)


@pytest.mark.parametrize("bad, message", [(np.zeros((2, 2)), "1-D"),
                                          (np.array([0.0, np.nan]), "element 1"),
                                          (np.array([np.inf]), "element 0")])
def test_bad_pressure_arrays_are_rejected(bad, message):
    with pytest.raises(ValueError, match=message):
        L0.poses(bad)
    with pytest.raises(ValueError, match=message):
        L0.tip_slope(bad)


def _geometry(**changes):
    fields = {f: getattr(GEOMETRY, f) for f in GEOMETRY.__dataclass_fields__}
    fields.update(changes)
    return FingerGeometry(**fields)


@pytest.mark.parametrize("changes, message", [
    ({"chamber_depths_m": (0.019, 0.016, 0.013, 0.010)}, "needs 5 depths"),
    ({"chamber_length_m": -0.014}, r"chamber_length_m must lie in \(0, 1\] m"),
    ({"wall_thickness_m": float("nan")}, "wall_thickness_m must lie in"),
    ({"root_width_m": 1e300}, "root_width_m must lie in"),  # was accepted (#52, class 6)
    ({"tip_gap_m": 1e300}, "tip_gap_m must lie in"),
    ({"chamber_depths_m": (1e300,) * 5}, "chamber 1 depth"),
    ({"chamber_depths_m": (0.019, 0.016, 0.013, 0.010, 0.005)}, "chamber 5 depth"),
    ({"inclined_length_m": 0.080}, "do not fit"),
    ({"total_length_m": 0.2}, "disagrees with total_length_m"),
    ({"inclination_rad": math.radians(95)}, "inclination"),
])
def test_invalid_geometry_is_rejected(changes, message):
    with pytest.raises(ValueError, match=message):
        _geometry(**changes)


def test_geometry_file_errors_name_the_problem(tmp_path):
    path = tmp_path / "g.yaml"
    path.write_text("types:\n  a: {based_on: b}\n  b: {based_on: a}\n")
    with pytest.raises(ValueError, match="loop"):
        load_geometry("a", path)
    with pytest.raises(ValueError, match="unknown cavity type 'zz'"):
        load_geometry("zz", path)
    path.write_text("types:\n  a: {vertical_height_m: 0.015, colour: red}\n")
    with pytest.raises(ValueError, match="unknown field 'colour'"):
        load_geometry("a", path)
    path.write_text("types:\n  a: [1, 2]\n")  # a list where a mapping belongs: a TypeError
    with pytest.raises(ValueError, match="a must map field names to values"):
        load_geometry("a", path)


def test_types_i_and_iii_load_with_their_initial_angle():
    assert load_geometry("type_I").initial_included_angle_rad == 0.0
    assert load_geometry("type_III").initial_included_angle_rad == pytest.approx(math.radians(15))


def test_bad_calibration_is_rejected():
    with pytest.raises(ValueError, match="gain"):
        BendingCalibration(gain=0.0)
    with pytest.raises(ValueError, match="saturation_width"):
        BendingCalibration(saturation_width_pa=float("nan"))


@pytest.mark.parametrize("model", ["l0", "l1"])
def test_tip_table_matches_its_model(model):
    """The tabulated tip (cubic Hermite on a 100 Pa grid) against the model itself: within 0.1 um
    and 1e-6 rad everywhere, blocked below contact, and its slope within 1e-4 of the analytic one
    (measured 8e-6)."""
    from softgrip_ros.model.kinematics import TipTable
    kinematics = build_kinematics(model, max_pressure_pa=60e3)
    table = TipTable(kinematics)
    assert table.max_error_m < 1e-7 and table.max_angle_error_rad < 1e-6
    # the build's self-check evaluates every midpoint at once: what a lookup there gives
    cells = round((table.high_pa - table.low_pa) / table.step_pa)
    midpoints = table.low_pa + (np.arange(cells) + 0.5) * table.step_pa
    assert np.allclose(table._midpoint_values(table._values, table._slopes),
                       [table.tip(p)[0] for p in midpoints], rtol=0.0, atol=1e-12)
    rng = np.random.default_rng(3)
    pressures = np.concatenate([
        rng.uniform(kinematics.contact_pressure_pa, 60e3, 300),
        [kinematics.contact_pressure_pa + 1e-3, 60e3, 0.0]
    ])
    for p in pressures:
        (x, z, angle), slope = table.tip(p)
        pose = kinematics.pose(p)
        assert math.hypot(x - pose.left_tip_x_m, z - pose.left_tip_z_m) < 1e-7
        assert abs(angle - pose.left_tip_angle_rad) < 1e-6
        assert np.allclose(slope, kinematics.tip_slope_at(p), rtol=1e-4, atol=1e-12)
    blocked = table.tip(kinematics.contact_pressure_pa - 5e3)
    pose = kinematics.pose(kinematics.contact_pressure_pa - 5e3)
    assert blocked[0] == pytest.approx(
        (pose.left_tip_x_m, pose.left_tip_z_m, pose.left_tip_angle_rad), abs=1e-12)
    assert blocked[1] == (0.0, 0.0, 0.0)


def test_tip_table_refuses_bad_grids_and_pressures():
    from softgrip_ros.model.kinematics import TipTable
    kinematics = build_kinematics("l1", max_pressure_pa=50e3)
    with pytest.raises(ValueError, match="use a finer step"):
        TipTable(kinematics, step_pa=5e3)  # ~1e-5 m off mid-cell
    with pytest.raises(ValueError, match="step_pa"):
        TipTable(kinematics, step_pa=0.0)
    table = TipTable(kinematics)
    for bad in (math.nan, 55e3, -200e3, "x"):
        with pytest.raises(ValueError):
            table.tip(bad)


def test_spacings_for_a_model_s_own_angles_are_its_pose_s():
    from softgrip_ros.model.calibration import build_kinematics
    kin = build_kinematics("l1", max_pressure_pa=60e3)
    for pressure in (0.0, 12e3, 40e3):
        pose = kin.pose(pressure)
        d1, d2 = kin.spacings_for_angles(pressure, pose.segment_angles_rad)
        assert d1 == pytest.approx(pose.root_spacing_m, abs=1e-12)
        assert d2 == pytest.approx(pose.tip_spacing_m, abs=1e-12)
    with pytest.raises(ValueError, match="5 finite segment angles"):
        kin.spacings_for_angles(10e3, [0.1, 0.2])

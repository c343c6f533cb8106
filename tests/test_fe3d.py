"""The 3-D finite-element finger (softgrip_ros.model.fe3d): its verification on coarse meshes and
its behaviour against the plane-strain FE.

Needs the FE extra (NGSolve), which scripts/test.sh installs. About a minute in all."""
import math

import pytest

from softgrip_ros.model.fe.solver import NotConverged
from softgrip_ros.model.fe3d.finger import MAX_INTERPENETRATION_M, Finger3D
from softgrip_ros.model.fe3d.verification import (lame_cylinder, mesh_convergence,
                                                  plane_strain_limit)
from softgrip_ros.model.geometry import CHAMBER_COUNT, load_geometry

GEOMETRY = load_geometry()
COARSE_M = 3e-3


@pytest.fixture(scope="module", autouse=True)
def two_threads():
    import ngsolve as ng

    ng.SetNumThreads(2)
    with ng.TaskManager():
        yield


def test_the_plane_strain_run_matches_the_2d_fe_within_one_percent():
    """The same code on a slab, against scikit-fem's plane-strain FE at 2 kPa (measured: 0.53 %
    on the 1.5 mm mesh)."""
    case = plane_strain_limit(GEOMETRY)
    assert case.worst_error_pct < 1.0, case
    assert case.fe3d[0] > 1e-3  # the tip does move (about 2.4 mm)


def test_lame_thick_cylinder_matches_within_one_percent():
    """The follower pressure as an energy, on a curved wall cut by two symmetry planes
    (measured: 0.07 % on a 2 mm mesh)."""
    case = lame_cylinder(element_size_m=2.5e-3)
    assert case.worst_error_pct < 1.0, case


def test_a_mesh_study_refines_and_reports_how_far_the_tip_moved():
    """Two very coarse meshes at 2 kPa, so that it stays cheap (the 2 and 1.4 mm meshes agree
    within 0.14 % at 10 kPa; docs/model_validation.md)."""
    study = mesh_convergence(GEOMETRY, (6e-3, 4.5e-3), 2e3)
    assert study.elements[0] < study.elements[1]
    assert study.tip_displacement_m > 0.3e-3  # about 0.8 mm at 2 kPa
    assert 0.0 <= study.change_pct < 10.0


def test_the_rest_state_measures_the_layout():
    finger = Finger3D(GEOMETRY, element_size_m=COARSE_M)
    rest = finger.measure()
    assert rest.tip_spacing_m == pytest.approx(GEOMETRY.tip_gap_m, abs=1e-6)
    assert math.degrees(rest.included_angle_rad) == pytest.approx(15.0, abs=1e-6)
    wall, width = GEOMETRY.wall_thickness_m, 0.020
    for depth, volume in zip(GEOMETRY.chamber_depths_m, rest.chamber_volumes_m3):
        cavity = (GEOMETRY.chamber_length_m - 2 * wall) * (depth - wall) * (width - 2 * wall)
        assert volume == pytest.approx(cavity, rel=1e-9)
    assert all(gap == pytest.approx(GEOMETRY.chamber_spacing_m, abs=1e-6)
               for gap in rest.block_gaps_m)
    assert rest.volume_change == pytest.approx(0.0, abs=1e-12)


def test_side_walls_stiffen_the_finger_and_it_stays_incompressible():
    """At 10 kPa a 20 mm finger with 3 mm side walls turns about a third as much as plane strain
    (the audit's 1 - 12.7 mm / w = 0.37), its chambers swell, the first gap closes most, and the
    solid keeps its volume within 0.5 %."""
    walled = Finger3D(GEOMETRY, element_size_m=COARSE_M)
    slab = Finger3D(GEOMETRY, element_size_m=COARSE_M, plane_strain=True)
    turns, states = [], []
    for finger in (walled, slab):
        rest = finger.measure()
        finger.solve(10e3)
        states.append(finger.measure())
        turns.append(states[-1].included_angle_rad - rest.included_angle_rad)
    assert 0.25 < turns[0] / turns[1] < 0.5, turns
    loaded = states[0]
    assert loaded.tip_spacing_m > GEOMETRY.tip_gap_m + 2e-3
    assert all(v > v0 for v, v0 in zip(loaded.chamber_volumes_m3,
                                       walled.reference_chamber_volumes_m3()))
    gaps = loaded.block_gaps_m
    assert len(gaps) == CHAMBER_COUNT - 1 and gaps[0] == min(gaps) < GEOMETRY.chamber_spacing_m
    assert loaded.volume_change < 0.005


def test_neighbouring_blocks_touch_and_do_not_pass_through_each_other():
    """At 32 kPa a 20 mm finger's blocks 1 and 2 are pressed together (without contact they would
    overlap by about 0.5 mm there); no surface lies inside another by more than 0.05 mm."""
    finger = Finger3D(GEOMETRY, element_size_m=COARSE_M)
    finger.solve(32e3, first_step_pa=16e3)
    state = finger.measure()
    assert -MAX_INTERPENETRATION_M < state.block_gaps_m[0] < 0.02e-3, state.block_gaps_m
    assert state.block_gaps_m[1] > state.block_gaps_m[0]
    assert finger.interpenetration_m() < MAX_INTERPENETRATION_M
    assert state.volume_change < 0.005


def test_a_load_that_fails_leaves_the_finger_at_its_last_converged_pressure():
    finger = Finger3D(GEOMETRY, element_size_m=COARSE_M)
    finger.solve(5e3)
    before = finger.measure()
    with pytest.raises(NotConverged):
        finger.solve(10e3, max_iterations=1, min_step_pa=2e3)
    assert finger.pressure_pa == 5e3
    assert finger.measure().tip == before.tip


@pytest.mark.parametrize("kwargs, words", [
    ({"width_m": 0.002}, "width must lie"),
    ({"width_m": float("nan")}, "width must lie"),
    ({"width_m": 0.010, "side_wall_m": 0.004}, "side walls"),
    ({"element_size_m": 0.1}, "element size"),
])
def test_bad_inputs_are_refused_with_a_reason(kwargs, words):
    with pytest.raises(ValueError, match=words):
        Finger3D(GEOMETRY, **kwargs)


def test_an_unknown_cavity_is_refused():
    finger = Finger3D(GEOMETRY, element_size_m=COARSE_M)
    with pytest.raises(ValueError, match="no such cavity"):
        finger.solid.solve({"chamber_9": 1e3})

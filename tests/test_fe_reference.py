"""The finite-element finger (softgrip_ros.model.fe): its verification on coarse meshes, the
behaviour of the sweep, and the committed config/fe_reference.yaml against its inputs.

Needs the FE extra (scikit-fem, gmsh), which scripts/test.sh installs. The checks here run on
coarse meshes (about half a minute in all); scripts/bench_fe.py runs them on the sweep's meshes,
and its --quick test (tests/test_model_scripts.py) checks the mesh convergence on coarse ones."""
import math

import numpy as np
import pytest
import yaml

from softgrip_ros.config_paths import config_file
from softgrip_ros.model.fe import finger as fe_finger
from softgrip_ros.model.fe.finger import FingerFE, inputs_hash, sweep
from softgrip_ros.model.fe.solver import HyperelasticSolid, YeohMaterial
from softgrip_ros.model.fe.verification import lame_cylinder, planar_tension
from softgrip_ros.model.geometry import load_geometry

pytestmark = pytest.mark.cpu  # computation only: scripts/test.sh runs it beside another

GEOMETRY = load_geometry()


def test_planar_tension_matches_the_closed_form_yeoh_law_within_one_percent():
    """Up to twice the length: the constitutive law and its tangent (measured: 1e-9 %)."""
    case = planar_tension()
    assert case.worst_error_pct < 1.0, case
    assert case.fe[-1] > case.fe[0] > 0.0


def test_lame_thick_cylinder_matches_within_one_percent():
    """The follower pressure on a curved wall, on a 2 mm mesh (measured: 0.8 %; 0.15 % at 1 mm)."""
    case = lame_cylinder(element_size_m=2e-3)
    assert case.worst_error_pct < 1.0, case


def test_the_finger_is_incompressible_and_opens_outwards_under_pressure():
    """... and is a truth only up to PLANE_STRAIN_VALID_TO_PA: it has no contact between
    neighbouring blocks, and 2.5 kPa later blocks 1 and 2 are closer than its wall-contact gap
    (the committed sweep refuses to be read beyond)."""
    from softgrip_ros.model.fe_data import PLANE_STRAIN_VALID_TO_PA, load_fe_reference
    finger = FingerFE(GEOMETRY, element_size_m=4e-3)
    rest = finger.measure()
    # the faces are sampled 0.1 um inside the solid, so that each point finds its triangle
    assert rest.tip_spacing_m == pytest.approx(GEOMETRY.tip_gap_m, abs=1e-6)
    assert rest.root_spacing_m == pytest.approx(0.01398, abs=1e-5)  # the geometry's D1(0)
    assert math.degrees(rest.included_angle_rad) == pytest.approx(15.0, abs=1e-6)
    finger.solve(PLANE_STRAIN_VALID_TO_PA)
    assert min(finger.block_gaps_m()) > fe_finger.WALL_CONTACT_GAP_M
    finger.solve(PLANE_STRAIN_VALID_TO_PA + 2.5e3)
    assert finger.block_gaps_m()[0] < fe_finger.WALL_CONTACT_GAP_M
    reference = load_fe_reference()
    assert max(p.pressure_pa for p in reference.positive()) == PLANE_STRAIN_VALID_TO_PA
    reference.at(5e3)
    with pytest.raises(KeyError, match="blocks meet"):
        reference.at(50e3)
    finger.solve(20e3)
    loaded = finger.measure()
    assert loaded.tip_spacing_m > rest.tip_spacing_m + 0.01  # opens by more than 1 cm
    assert loaded.included_angle_rad > rest.included_angle_rad
    assert all(a > b for a, b in zip(loaded.cavity_areas_m2, rest.cavity_areas_m2))
    assert loaded.volume_change < 0.005  # the parts' volumes within 0.5 %
    assert abs(finger.solid.volume_ratio() - 1.0) < 1e-8


def test_a_failing_load_step_is_cut_and_the_state_stays_at_the_last_converged_load():
    finger = FingerFE(GEOMETRY, element_size_m=4e-3)
    finger.solve(10e3)
    with pytest.raises(fe_finger.NotConverged, match="stopped at"):
        finger.solve(20e3, max_iterations=1, min_step_pa=5e3)
    assert finger.pressure_pa == pytest.approx(10e3)


def test_a_sweep_stops_the_vacuum_side_where_cavity_walls_would_touch(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    messages = []
    result = sweep(GEOMETRY, element_size_m=4e-3, pressures_pa=(0.0, 10e3, 20e3),
                   progress=messages.append)
    assert [s.pressure_pa for s in result.states if s.pressure_pa >= 0] == [0.0, 10e3, 20e3]
    assert "walls within 0.2 mm" in result.vacuum_stop
    assert -20e3 < result.vacuum_limit_pa < 0.0
    assert all(s.min_wall_gap_m >= fe_finger.WALL_CONTACT_GAP_M for s in result.states)
    assert messages and "kPa" in messages[-1]
    # the second call comes from the cache, with the same numbers
    again = sweep(GEOMETRY, element_size_m=4e-3, pressures_pa=(0.0, 10e3, 20e3),
                  progress=messages.append)
    assert again.seconds == result.seconds
    assert again.at(20e3).tip_spacing_m == result.at(20e3).tip_spacing_m


def test_bad_inputs_are_refused_with_a_reason():
    with pytest.raises(ValueError, match="element size"):
        FingerFE(GEOMETRY, element_size_m=0.05)
    with pytest.raises(ValueError, match="start at 0 and ascend"):
        sweep(GEOMETRY, pressures_pa=(10e3, 0.0))
    with pytest.raises(ValueError, match="C10 must be positive"):
        YeohMaterial(c10_pa=float("nan"))


def test_the_follower_load_tangent_is_the_derivative_of_the_residual():
    """Newton converges quadratically only with the exact tangent: compare it with central
    differences of the residual on a pressurised coarse finger (relative 1e-5)."""
    finger = FingerFE(GEOMETRY, element_size_m=5e-3)
    finger.solve(10e3)
    solid: HyperelasticSolid = finger.solid
    residual, matrix = solid._residual_and_tangent(solid.u, solid.p, solid.gas_pressures)
    rng = np.random.default_rng(0)
    direction = rng.normal(size=solid.n_u + solid.n_p) * 1e-7
    x = np.concatenate([solid.u, solid.p])
    h = 1.0

    def r(at):
        return solid._residual_and_tangent(at[:solid.n_u], at[solid.n_u:], solid.gas_pressures,
                                           tangent=False)[0]

    numeric = (r(x + h * direction) - r(x - h * direction)) / (2 * h)
    analytic = matrix @ direction
    assert np.linalg.norm(numeric - analytic) < 1e-5 * np.linalg.norm(analytic)


def test_the_committed_fe_reference_matches_its_inputs():
    """config/fe_reference.yaml was written by scripts/bench_fe.py from today's geometry,
    material, mesh and FE code: its hash says so."""
    document = yaml.safe_load(config_file("fe_reference.yaml").read_text())
    sweep_doc = document["sweep"]
    expected = inputs_hash(GEOMETRY, YeohMaterial(), sweep_doc["element_size_m"],
                           sweep_doc["pressures_pa"])
    assert sweep_doc["inputs_hash"] == expected, (
        "config/fe_reference.yaml is stale: run python scripts/bench_fe.py")


def test_meshing_leaves_python_s_signal_handling_as_it_was():
    """gmsh's initialise resets SIGPIPE to its default action: a later write to a closed pipe
    then killed the process (pytest died with no traceback). Checked in a child process, so a
    regression cannot take the test run down with it."""
    import subprocess
    import sys
    code = ("import os, signal\n"
            "from softgrip_ros.model.fe.mesh import rectangle\n"
            "handler = signal.getsignal(signal.SIGINT)\n"
            "rectangle(0.01, 0.01, 0.004)\n"
            "assert signal.getsignal(signal.SIGINT) is handler\n"
            "r, w = os.pipe(); os.close(r)\n"
            "try:\n    os.write(w, b'x')\nexcept BrokenPipeError:\n    print('EPIPE')\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0 and result.stdout.strip() == "EPIPE", (result.returncode,
                                                                          result.stderr)


def test_the_fe_truth_is_the_3d_default_sweep():
    """load_fe_truth reads the 3-D FE's default sweep, from its vacuum limit to +50 kPa."""
    from softgrip_ros.model.fe_data import load_fe3d_reference, load_fe_truth
    truth, document = load_fe_truth(), load_fe3d_reference()
    assert len(truth.points) == len(document["states"])
    assert min(p.pressure_pa for p in truth.points) == pytest.approx(
        1e3 * document["figures"]["fe3d_vacuum_limit_kpa"])
    assert math.degrees(truth.at(25e3).alpha_rad) == pytest.approx(
        next(s["alpha_deg"] for s in document["states"] if s["pressure_pa"] == 25e3))
    assert truth.at(50e3).d2_m > truth.at(25e3).d2_m > truth.at(0.0).d2_m

"""The clamp force law (softgrip_ros.model.force_law): the packaged tables are current and are the
L2 rod's or the 3-D FE's, the law inverts itself, and a user's calibration gets a table of its
own."""
import math

import numpy as np
import pytest

from softgrip_ros.model import force_law, gripper_models
from softgrip_ros.model.fidelity import cylinder_scene
from softgrip_ros.model.force_law import ClampForceLaw, ObjectKind, load_table
from softgrip_ros.model.kinematics import GripperKinematics
from softgrip_ros.model.rod import RodFinger, Sheet

pytestmark = pytest.mark.cpu  # computation only: scripts/test.sh runs it beside another


@pytest.mark.parametrize("model", list(gripper_models.built_in()))
@pytest.mark.parametrize("law", ["l0", "l1"])
def test_every_built_in_model_has_a_current_table(model, law):
    table = load_table(model, law, compute_if_missing=False)
    assert table.gripper_model == model and table.bending == law


@pytest.mark.parametrize("kind, size_m, pressure_pa", [
    (ObjectKind.ROUND, 0.04, -30e3), (ObjectKind.ROUND, 0.01, -60e3),
    (ObjectKind.FLAT, 1e-4, -20e3)])
def test_the_packaged_table_is_what_the_rod_gives(kind, size_m, pressure_pa):
    """One entry of type_II's L0 table solved again with the rod, as the table was built."""
    table = load_table("type_II", "l0")
    geometry, calibration = gripper_models.resolve("type_II")
    rod = RodFinger(geometry, calibration, bending="l0",
                    elements_per_segment=force_law.ROD_ELEMENTS)
    kinematics = GripperKinematics(geometry, calibration, model="l0")
    if kind == ObjectKind.ROUND:
        opening = (kinematics.pressure_for_tip_spacing(size_m + force_law.ENVELOP_MARGIN_M) +
                   force_law.PRESSURE_TOLERANCE_PA)
        obstacle = cylinder_scene(rod, size_m, opening).obstacle
    else:
        opening, obstacle = 2e3, Sheet(size_m)
    solution = rod.solve(pressure_pa, obstacle, from_pressure_pa=opening, steps=8)
    assert solution.converged
    assert table.normal_force_n(pressure_pa, size_m, kind) == pytest.approx(
        float(solution.contact_forces_n.sum()), rel=1e-5, abs=1e-6)


def test_the_law_inverts_itself_and_grows_with_vacuum():
    law = ClampForceLaw(load_table("type_II", "l0"))
    for kind, size in ((ObjectKind.ROUND, 0.03), (ObjectKind.ROUND, 0.055),
                       (ObjectKind.FLAT, 1e-4)):
        forces = [law.normal_force_n(p, size, kind) for p in (-5e3, -20e3, -40e3, -60e3)]
        assert forces == sorted(forces) and forces[-1] > forces[0] > 0.0
        for force in (0.3, 0.6, 1.0):
            pressure = law.pressure_for_force(force, size, kind)
            assert law.normal_force_n(pressure, size, kind) == pytest.approx(force, rel=1e-6)
        assert law.contact_pressure_pa(size, kind) > law.pressure_for_force(0.3, size, kind)


def test_the_clamp_holds_the_mass_with_the_safety_factor_or_goes_past_the_limit():
    law = ClampForceLaw(load_table("type_II", "l0"), safety_factor=2.0)
    light = law.clamp_pressure_pa(0.02, 0.04, ObjectKind.ROUND, 0.5)
    assert -60e3 < light < law.contact_pressure_pa(0.04, ObjectKind.ROUND) - 3e3 + 1e-6
    force = law.normal_force_n(light, 0.04, ObjectKind.ROUND)
    assert 2 * 0.5 * force == pytest.approx(2.0 * 0.02 * force_law.G_M_PER_S2, rel=1e-6)
    # the mass a force holds is the inverse of the force a mass needs
    assert law.mass_held_kg(force, 0.5) == pytest.approx(0.02, rel=1e-6)
    assert force_law.mass_held_kg(force, 0.5) == pytest.approx(2.0 * 0.02, rel=1e-6)
    # past what -60 kPa gives: extrapolated below the limit, which the grasp manager refuses
    assert law.clamp_pressure_pa(0.5, 0.04, ObjectKind.ROUND, 0.5) < -60e3
    # beyond the fingers' reach where the law places an object: no force at all
    assert math.isnan(law.contact_pressure_pa(0.1, ObjectKind.ROUND))


def test_a_users_calibration_gets_its_table_computed_once_and_cached(tmp_path, monkeypatch):
    monkeypatch.setenv("SOFTGRIP_CALIBRATION_DIR", str(tmp_path))
    geometry, calibration = gripper_models.resolve("type_II")
    gripper_models.write_file(tmp_path / "mine.yaml", "mine", geometry, calibration, {}, {})
    computed = []
    real = force_law.compute_table

    def small(model, bending, *args, **kwargs):
        computed.append(model)
        return real(model, bending, 8, (-60e3, -30e3, 0.0, 30e3))

    monkeypatch.setattr(force_law, "compute_table", small)
    monkeypatch.setattr(force_law, "inputs_hash", lambda *args: "cafe")
    table = load_table("mine", "l0")
    assert computed == ["mine"] and (tmp_path / "mine.l0.clamp_force.yaml").is_file()
    again = load_table("mine", "l0")
    assert computed == ["mine"]  # read from the cache
    assert again.normal_force_n(-30e3, 0.04, ObjectKind.ROUND) == pytest.approx(
        table.normal_force_n(-30e3, 0.04, ObjectKind.ROUND))


# ---- the FE's tables (type_II_fe, type_II_fe_l1) ------------------------------------------------
def _fe_table_file(model="type_II_fe", law="l0"):
    import yaml
    from softgrip_ros.config_paths import config_dir
    path = config_dir() / force_law.TABLE_DIR / force_law.table_file_name(model, law)
    return yaml.safe_load(path.read_text())


@pytest.mark.parametrize("model", ["type_II_fe", "type_II_fe_l1"])
def test_the_fe_models_take_the_fes_table_and_the_paper_types_the_rods(model):
    assert force_law.table_source(model) is force_law.TableSource.FE3D
    assert load_table(model, "l1").source is force_law.TableSource.FE3D
    assert load_table("type_II", "l1").source is force_law.TableSource.ROD


def test_the_fe_table_was_built_from_todays_fe_clamp_sweeps():
    """Each sweep the table records has the input hash the FE code gives today (so a change to
    the FE makes the table stale), and the table's entries are the committed sweeps' F_n."""
    import yaml
    from softgrip_ros.config_paths import config_file
    from softgrip_ros.model.fe.solver import YeohMaterial
    from softgrip_ros.model.fe3d.clamp import LOWEST_PRESSURE_PA, inputs_hash
    from softgrip_ros.model.fe3d.finger import DEFAULT_WIDTH_M
    from softgrip_ros.model.fe3d.sweep import SWEEP_ELEMENT_SIZE_M

    from softgrip_ros.model.fe_data import FE_GEOMETRY_NAME
    from softgrip_ros.model.geometry import load_geometry
    geometry = load_geometry(FE_GEOMETRY_NAME)
    document = _fe_table_file()
    recorded = {(s["kind"], s["size_m"]): s for s in document["fe_sweeps"]}
    assert set(recorded) == ({("round", d) for d in force_law.FE_ROUND_SIZES_M} |
                             {("flat", t) for t in force_law.FE_FLAT_SIZES_M})
    for (kind, size), sweep in recorded.items():
        assert sweep["inputs_hash"] == inputs_hash(
            geometry, YeohMaterial(), ObjectKind(kind), size, DEFAULT_WIDTH_M,
            SWEEP_ELEMENT_SIZE_M, LOWEST_PRESSURE_PA), (kind, size)
    table = load_table("type_II_fe", "l0")
    reference = yaml.safe_load(config_file("fe3d_reference.yaml").read_text())
    checked = 0
    for clamp in reference["clamp"]:
        key = (clamp["kind"], clamp["size_mm"] * 1e-3)
        if not clamp.get("states") or not any(
                k == key[0] and s == pytest.approx(key[1]) for k, s in recorded):
            continue
        for state in clamp["states"]:
            pressure = state["pressure_kpa"] * 1e3
            if pressure % 5e3 == 0.0:
                # the table makes F_n non-decreasing as the pressure falls; the FE's own is
                assert table.normal_force_n(pressure, key[1], ObjectKind(key[0])) >= (
                    state["normal_force_n"] - 1e-6)
                assert table.normal_force_n(pressure, key[1], ObjectKind(key[0])) == (
                    pytest.approx(state["normal_force_n"], rel=0.02, abs=2e-3))
                checked += 1
    assert checked >= 20


def test_an_fe_row_is_zero_above_the_opening_and_holds_its_last_force_below_the_sweep():
    from types import SimpleNamespace

    from softgrip_ros.model.fe3d.clamp import FE3DClampSweep
    states = [SimpleNamespace(pressure_pa=p, normal_force_n=f)
              for p, f in ((10e3, 0.0), (5e3, 0.01), (0.0, 0.03), (-5e3, 0.02), (-10e3, 0.05))]
    sweep = FE3DClampSweep("h", "flat", 1e-4, 0.02, 0.003, 1, 10e3, (0.0, 0.0), states, "", 1.0)
    row, lowest = force_law.fe_row(sweep, (-20e3, -10e3, -5e3, 0.0, 5e3, 10e3, 15e3))
    assert lowest == -10e3
    # below the sweep: its last force; the dip at -5 kPa lifted to what 0 kPa pressed
    assert list(row) == pytest.approx([0.05, 0.05, 0.03, 0.03, 0.01, 0.0, 0.0])
    empty = FE3DClampSweep("h", "round", 0.06, 0.02, 0.003, 1, 50e3, (0.0, 0.0), [], "no", 1.0)
    row, lowest = force_law.fe_row(empty, (-10e3, 0.0))
    assert np.isnan(row).all() and math.isnan(lowest)


def test_the_fe_law_refuses_what_the_fe_cannot_hold():
    """Below the lowest pressure the FE solved the force stays flat: a mass that needs more is
    planned past any pressure (the grasp manager refuses it), a light one is planned."""
    law = ClampForceLaw(load_table("type_II_fe", "l0"))
    most = law.normal_force_n(-60e3, 1e-4, ObjectKind.FLAT)
    assert most == pytest.approx(law.normal_force_n(-100e3, 1e-4, ObjectKind.FLAT))
    assert 0.0 < most < 0.5
    light = law.clamp_pressure_pa(0.002, 1e-4, ObjectKind.FLAT, 0.5)
    assert -40e3 < light < law.contact_pressure_pa(1e-4, ObjectKind.FLAT)
    assert law.clamp_pressure_pa(0.1, 1e-4, ObjectKind.FLAT, 0.5) == -math.inf
    # a cylinder the FE finger cannot open around
    assert math.isnan(law.contact_pressure_pa(0.03, ObjectKind.ROUND))

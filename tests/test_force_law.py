"""The clamp force law (softgrip_ros.model.force_law): the packaged tables are current and are the
L2 rod's, the law inverts itself, and a user's calibration gets a table of its own."""
import math

import pytest

from softgrip_ros.model import force_law, gripper_models
from softgrip_ros.model.fidelity import cylinder_scene
from softgrip_ros.model.force_law import ClampForceLaw, ObjectKind, load_table
from softgrip_ros.model.kinematics import GripperKinematics
from softgrip_ros.model.rod import RodFinger, Sheet


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

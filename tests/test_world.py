"""The physics world (softgrip_ros.model.world): the fingers bend as the kinematics says, press as
L2 says, the scene files are validated, the arm moves as told, and the chambers' volume follows
the bending."""
import math

import numpy as np
import pytest

from softgrip_ros.model import gripper_models
from softgrip_ros.model.calibration import build_kinematics
from softgrip_ros.model.fidelity import cylinder_scene
from softgrip_ros.model.rod import RodFinger, Sheet
from softgrip_ros.model.world.fingers import PseudoRigidFinger
from softgrip_ros.model.world.scene import SceneError, load_scene, scene_from_document
from softgrip_ros.model.world.world import (TABLE_RANGE_PA, GraspTruthState, GripperWorld)

pytestmark = pytest.mark.cpu  # computation only: scripts/test.sh runs it beside another

BASE_Z = 0.3
FREE_PRESSURES = np.linspace(-60e3, 50e3, 12)


def free_world(model: str, law: str, **kwargs) -> GripperWorld:
    geometry, calibration = gripper_models.resolve(model)
    finger = PseudoRigidFinger(geometry, calibration, bending=law)
    scene = scene_from_document({"name": "free", "arm": {"start_m": [0, 0, BASE_Z]}})
    return GripperWorld(scene, finger, **kwargs)


def settle(world: GripperWorld, pressure_pa: float, ramp_s: float = 0.2,
           rest_s: float = 0.5) -> None:
    start = world.pressure_pa
    for fraction in np.linspace(0.0, 1.0, max(2, int(ramp_s / world.timestep_s))):
        world.set_pressure(start + fraction * (pressure_pa - start))
        world.advance_to(world.time_s + world.timestep_s)
    world.advance_to(world.time_s + rest_s)


@pytest.mark.parametrize("model,law", [("type_II", "l0"), ("type_II", "l1"),
                                       ("type_II_fe", "l0"), ("type_II_fe_l1", "l1")])
def test_a_free_finger_bends_as_the_kinematics_says_within_1_mm(model, law):
    """Tip and D2 of the world's free fingers (not touching each other, so that the vacuum side
    bends on as the law says) against the PCC kinematics with its ballooning, -60 to +50 kPa.
    Measured: within 0.23 mm."""
    world = free_world(model, law, fingers_collide=False)
    kinematics = build_kinematics(law, model)
    worst_tip = worst_d2 = 0.0
    for pressure in FREE_PRESSURES:
        settle(world, pressure)
        tip, d2 = kinematics.free_shape(pressure)
        tips = world.in_gripper_frame(world.tip_points_m())
        faces = world.in_gripper_frame(world.face_points_m())
        worst_tip = max(worst_tip, math.hypot(tips[0, 0] - tip[0], tips[0, 1] - tip[1]))
        assert tips[1, 0] == pytest.approx(-tips[0, 0], abs=1e-6)  # the mirror image
        worst_d2 = max(worst_d2, abs(faces[1, 4, 0] - faces[0, 4, 0] - d2))
    assert worst_tip < 1e-3 and worst_d2 < 1e-3, (worst_tip, worst_d2)


def test_the_drive_table_interpolates_the_law_within_a_microradian():
    world = free_world("type_II", "l1")
    law = world.finger.law
    pressures = np.random.default_rng(3).uniform(*TABLE_RANGE_PA, 200)
    looked_up = np.array([world._lookup(p)[:5] for p in pressures])
    assert np.max(np.abs(looked_up - np.asarray(law.angles(pressures)))) < 1e-6


def test_free_fingers_hold_the_air_of_free_fingers_and_blocked_ones_less():
    """The volume offset is 0 for a free finger at rest at any pressure; a finger held back by a
    post while the pressure opens it holds less air."""
    world = free_world("type_II", "l0", fingers_collide=False)
    for pressure in (30e3, -20e3):
        settle(world, pressure)
        assert abs(world.volume_offset_m3()) < 2e-9  # 0.002 mL of a 20 mL chamber
    geometry, calibration = gripper_models.resolve("type_II")
    finger = PseudoRigidFinger(geometry, calibration, bending="l0")
    # a post just outside the left finger's backbone at its last chamber: opening presses on it
    chain = finger.planar_chain(np.zeros(finger.hinge_count))
    end, heading = chain["backbone"][-2], geometry.inclination_rad
    centre = end + 0.0055 * np.array([-math.cos(heading), math.sin(heading)])
    post = {"shape": "cylinder", "diameter_m": 0.01, "mass_kg": 0.01, "friction": 0.5,
            "fixed": True, "position_m": [float(centre[0]), 0.0, BASE_Z - float(centre[1])]}
    scene = scene_from_document({"name": "post", "floor": False, "object": post,
                                 "arm": {"start_m": [0, 0, BASE_Z]}})
    blocked = GripperWorld(scene, finger)
    settle(blocked, 30e3)
    assert blocked.truth().touching[0]
    assert blocked.volume_offset_m3() < -0.2e-6  # at least 0.2 mL less


def rod_force(rod, pressure_pa, obstacle, from_pressure_pa):
    solution = rod.solve(pressure_pa, obstacle, from_pressure_pa=from_pressure_pa, steps=8)
    assert solution.converged, solution.message
    return float(solution.contact_forces_n.sum())


@pytest.mark.parametrize("diameter_m", [0.02, 0.03, 0.06])
def test_the_worlds_fingers_press_a_cylinder_as_the_rod_within_15_percent(diameter_m):
    """Frictionless, as the L2 law assumes: a post of the diameter level with the tip chambers,
    the fingers opened to clear it by 10 mm, then clamped to -10, -30 and -60 kPa. Measured: the
    world's normal force per finger within 6 % of L2's (32 elements per segment). A 10 mm post
    meets the tip chambers' domes alone, where both models are sensitive to where it sits
    (-17 % at -60 kPa; docs/world.md)."""
    geometry, calibration = gripper_models.resolve("type_II")
    rod = RodFinger(geometry, calibration, bending="l0", elements_per_segment=32)
    opening = build_kinematics("l0", "type_II").pressure_for_tip_spacing(diameter_m + 0.01)
    circle = cylinder_scene(rod, diameter_m, opening).obstacle
    post = {"shape": "cylinder", "diameter_m": diameter_m, "mass_kg": 0.01, "friction": 0.01,
            "fixed": True, "position_m": [0.0, 0.0, BASE_Z - circle.center_z_m]}
    scene = scene_from_document({"name": "post", "floor": False, "object": post,
                                 "arm": {"start_m": [0, 0, BASE_Z]}})
    world = GripperWorld(scene, PseudoRigidFinger(geometry, calibration, bending="l0"),
                         start_pressure_pa=opening)
    for pressure in (-10e3, -30e3, -60e3):
        settle(world, pressure)
        left, right = world.truth().normal_force_n
        assert left == pytest.approx(right, rel=0.02)
        expected = rod_force(rod, pressure, circle, opening)
        assert left == pytest.approx(expected, rel=0.15), (pressure, left, expected)


def test_the_worlds_fingers_pinch_a_sheet_as_the_rod_within_15_percent():
    geometry, calibration = gripper_models.resolve("type_II")
    rod = RodFinger(geometry, calibration, bending="l0", elements_per_segment=32)
    tip_face_z = rod.chamber_face_point_m(0.0, 4)[1]
    sheet = {"shape": "sheet", "mass_kg": 0.005, "friction": 0.01, "fixed": True,
             "position_m": [0.0, 0.0, BASE_Z - tip_face_z]}
    scene = scene_from_document({"name": "sheet", "floor": False, "object": sheet,
                                 "arm": {"start_m": [0, 0, BASE_Z]}})
    world = GripperWorld(scene, PseudoRigidFinger(geometry, calibration, bending="l0"))
    for pressure in (-5e3, -30e3, -60e3):
        settle(world, pressure)
        left, _ = world.truth().normal_force_n
        expected = rod_force(rod, pressure, Sheet(1e-4), 2e3)
        assert left == pytest.approx(expected, rel=0.15), (pressure, left, expected)


def test_the_arm_lifts_at_the_acceleration_asked_and_stops_on_target():
    scene = scene_from_document({"name": "lift", "arm": {"start_m": [0, 0, 0.1], "moves": {
        "lift": [{"to_m": [0, 0, 0.3], "accel_m_s2": 9.81}],
        "shake": [{"shake": {"axis": "y", "accel_m_s2": 4.9, "frequency_hz": 2.0,
                             "duration_s": 1.0}}]}}})
    world = GripperWorld(scene, PseudoRigidFinger(*gripper_models.resolve("type_II")))
    world.play("lift")
    heights, times = [], []
    while world.arm.moving:
        world.advance_to(world.time_s + 0.005)
        heights.append(world.truth().base_position_m[2])
        times.append(world.time_s)
    assert heights[-1] == pytest.approx(0.3, abs=1e-6)
    duration = 2.0 * math.sqrt(0.2 / 9.81)
    assert times[-1] == pytest.approx(duration, abs=0.006)
    speed = np.gradient(heights, times)
    assert np.max(np.abs(np.gradient(speed, times))) == pytest.approx(9.81, rel=0.05)
    world.play("shake")
    sideways = []
    while world.arm.moving:
        world.advance_to(world.time_s + 0.002)
        sideways.append(world.truth().base_position_m[1])
    assert max(sideways) == pytest.approx(2 * 4.9 / (2 * math.pi * 2.0) ** 2, rel=0.01)
    assert sideways[-1] == pytest.approx(0.0, abs=1e-4)
    with pytest.raises(ValueError, match="no arm move 'wave'"):
        world.play("wave")


def test_a_held_cylinder_is_lifted_and_a_heavy_one_is_dropped():
    """A 40 mm cylinder presented level with the tip chambers (its weight borne until the
    fingers have clamped at -60 kPa): 10 g rides a 1 g lift; 400 g, many times what the fingers
    hold, falls out, and the truth says so."""
    geometry, calibration = gripper_models.resolve("type_II")
    finger = PseudoRigidFinger(geometry, calibration, bending="l0")
    opening = build_kinematics("l0", "type_II").pressure_for_tip_spacing(0.05)
    z_face = RodFinger(geometry, calibration).chamber_face_point_m(opening, 4)[1]
    outcomes = {}
    for mass in (0.01, 0.4):
        document = {"name": "lift", "floor": False, "object": {
            "shape": "cylinder", "diameter_m": 0.04, "mass_kg": mass, "friction": 0.5,
            "position_m": [0, 0, BASE_Z - z_face], "held_until": "settle"},
            "arm": {"start_m": [0, 0, BASE_Z], "moves": {
                "settle": [{"wait_s": 0.5}],
                "lift": [{"to_m": [0, 0, BASE_Z + 0.1], "accel_m_s2": 9.81}]}}}
        world = GripperWorld(scene_from_document(document), finger, start_pressure_pa=opening)
        settle(world, -60e3, rest_s=0.3)
        assert world.truth().state == GraspTruthState.IN_HAND
        for move in ("settle", "lift"):
            world.play(move)
            while world.arm.moving:
                world.advance_to(world.time_s + 0.01)
        world.advance_to(world.time_s + 0.3)
        outcomes[mass] = world.truth()
    assert outcomes[0.01].state == GraspTruthState.LIFTED
    assert outcomes[0.01].slip_distance_m < 0.005
    assert outcomes[0.4].state == GraspTruthState.DROPPED
    assert not any(outcomes[0.4].touching)


@pytest.mark.parametrize("change,reason", [
    ({"object": {"shape": "cone"}}, "object.shape must be one of"),
    ({"object": {"shape": "sphere", "diameter_m": 0.03, "mass_kg": -1.0, "friction": 0.5}},
     r"object.mass_kg must lie in \[0.0001, 20\], got -1.0"),
    ({"object": {"shape": "box", "size_m": [0.03, 0.03], "mass_kg": 0.1, "friction": 0.5}},
     "object.size_m must be a list of 3 numbers"),
    ({"object": {"shape": "sphere", "diameter_m": 0.03, "mass_kg": 0.1, "friction": 0.5,
                 "length_m": 0.1}}, "length_m does not apply to a sphere"),
    ({"arm": {"moves": {"lift": [{"to_m": [0, 0, 0.3]}]}}}, r"lift\[0\].accel_m_s2 is missing"),
    ({"arm": {"moves": {"shake": [{"shake": {"accel_m_s2": 4.9, "frequency_hz": 2.0,
                                             "duration_s": 1.3}}]}}}, "whole periods"),
    ({"colour": "red"}, "unknown field 'colour'"),
])
def test_a_bad_scene_is_refused_with_its_reason(change, reason):
    document = {"name": "bad", **change}
    with pytest.raises(SceneError, match=reason):
        scene_from_document(document)


def test_an_object_that_starts_inside_a_finger_is_refused():
    """A 40 mm cylinder where the closed fingers' tip chambers are."""
    scene = scene_from_document({"name": "inside", "floor": False, "object": {
        "shape": "cylinder", "diameter_m": 0.04, "mass_kg": 0.1, "friction": 0.5,
        "position_m": [0, 0, 0.3 - 0.09]}, "arm": {"start_m": [0, 0, 0.3]}})
    with pytest.raises(SceneError, match=r"the object starts [\d.]+ mm inside the (left|right) "
                       "finger"):
        GripperWorld(scene, PseudoRigidFinger(*gripper_models.resolve("type_II")))


def test_a_scene_file_that_is_not_yaml_or_missing_says_so(tmp_path):
    broken = tmp_path / "broken.yaml"
    broken.write_text("object: [unclosed\n")
    with pytest.raises(SceneError, match="broken.yaml: not YAML"):
        load_scene(broken)
    with pytest.raises(SceneError, match="cannot read"):
        load_scene(tmp_path / "missing.yaml")


def test_the_bending_share_of_the_chambers_volume_is_the_fes():
    from softgrip_ros.model.fe_data import load_fe_reference
    from softgrip_ros.model.world.fingers import FE_BENDING_VOLUME_SHARE, bending_volume_share
    finger = PseudoRigidFinger(*gripper_models.resolve("type_II"))
    share = bending_volume_share(finger, load_fe_reference())
    assert share == pytest.approx(FE_BENDING_VOLUME_SHARE, abs=0.005)


def test_pushing_the_object_needs_one_and_a_finite_force():
    pytest.importorskip("mujoco")
    from softgrip_ros.model import gripper_models
    from softgrip_ros.model.world.fingers import PseudoRigidFinger
    from softgrip_ros.model.world.scene import scene_from_document
    from softgrip_ros.model.world.world import GripperWorld
    finger = PseudoRigidFinger(*gripper_models.resolve("type_II"))
    empty = GripperWorld(scene_from_document({"name": "empty", "arm": {"start_m": [0, 0, 0.3]}}),
                         finger)
    with pytest.raises(ValueError, match="no object"):
        empty.push_object((0.0, 0.0, -1.0))

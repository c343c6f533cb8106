"""The physics world: the two fingers, the object and the floor in MuJoCo, stepped with the chamber
pressure, and what really happens to the object (the ground truth the suite never reads).

MuJoCo (``mujoco`` on PyPI, Apache-2.0) does the rigid-body dynamics and the contacts; this module
builds its model from the finger geometry (:mod:`.fingers`) and the scene (:mod:`.scene`),
drives the hinges from the pressure, moves the gripper base along the scene's arm moves, and
reads the contacts back.

**The base** hangs from three slide joints whose positions and velocities are set from the arm's
trajectory before every step (a kinematic arm: the object feels the base's real velocity
through friction, and nothing pushes the arm off its path). Gravity acts on the object; the
fingers' own weight is compensated, because the bending laws were calibrated on hanging fingers
and already hold it (their mass still resists the arm's accelerations).

**Contacts.** The object's friction coefficient applies to all its contacts (it has the higher
priority); contacts are elliptic cones with torsional friction, and the object's contacts are
stiffer than MuJoCo's default so that a 0.1 mm sheet is not squeezed through. The fingers do not
collide with themselves (their chambers' mutual contact is not in the bending laws), but with
each other, the object and the floor.

**Volume.** :meth:`GripperWorld.volume_offset_m3` is how much more air the chambers hold than
free fingers would at this pressure: lambda w sum a_i dtheta_i over both fingers' segments,
dtheta_i the bend the contacts impose on segment i (its hinges' constraint torques over their
stiffnesses) and a_i the cavity's first moment of area about the backbone (see
:meth:`~softgrip_ros.model.world.fingers.PseudoRigidFinger.bending_volume_per_rad_m3`). The
chambers' compliance dV/dp is the plant file's; the FE's free sweep says which share of it the
bending makes (``FE_BENDING_VOLUME_SHARE``, the rest being the walls ballooning), and lambda
scales the first moments to that share. A finger blocked by an object under positive pressure
holds less air; under vacuum, more.
"""
from __future__ import annotations

import dataclasses
import enum
import math
import time

import numpy as np

from softgrip_ros.model.geometry import CHAMBER_COUNT
from softgrip_ros.model.pneumatics import PneumaticParameters
from softgrip_ros.model.world.fingers import FE_BENDING_VOLUME_SHARE, PseudoRigidFinger
from softgrip_ros.model.world.scene import ObjectShape, Scene, SceneError, Shake, Wait

INSTALL_HINT = "the physics world needs MuJoCo: scripts/setup.sh installs it (pip install mujoco)"
DEFAULT_TIMESTEP_S = 1.0e-3
# the fingers' first mode is critically damped: silicone fingers do not ring, and a ringing chain
# would pump air (the volume follows the bending) that no bending law has
DEFAULT_DAMPING_RATIO = 1.0
# the pressures the drive is tabulated on (Pa), and its step: linear interpolation between 25 Pa
# nodes is within 1e-6 rad of the laws' angles (tests/test_world.py)
TABLE_RANGE_PA = (-100.0e3, 60.0e3)
TABLE_STEP_PA = 25.0
# a finger touches the object when their contacts push with more than this (N)
TOUCH_FORCE_N = 0.02
# the object moving faster than this relative to the base, while in the hand: slipping (m/s)
SLIP_SPEED_M_S = 0.02
# lifted: off the floor and this far above where it rested (m)
LIFT_HEIGHT_M = 0.005
LEFT, RIGHT = 0, 1
# MuJoCo collision bits: fingers collide with the object, the floor and each other, not
# themselves
_OBJECT_BITS = (1, 7)  # contype, conaffinity
_FINGER_BITS = ((2, 5), (4, 3))


class GraspTruthState(enum.IntEnum):
    """What happens to the object (sim/grasp_truth's ``state``)."""

    FREE = 0  # not held by both fingers, and not since the start
    IN_HAND = 1  # touched by both fingers, not lifted
    LIFTED = 2  # held, off the floor
    SLIPPING = 3  # held, moving relative to the gripper
    DROPPED = 4  # it was held and is no longer (also after a release: the truth knows no intent)


@dataclasses.dataclass(frozen=True)
class WorldTruth:
    """The world at one instant. Forces in N, positions in m (world frame), time in s."""

    time_s: float
    state: GraspTruthState
    object_position_m: tuple
    object_quaternion_wxyz: tuple
    normal_force_n: tuple  # (left, right): the object's contacts with each finger
    touching: tuple  # (left, right)
    on_floor: bool
    slip_distance_m: float  # its largest drift from the tip chambers since the arm moved it
    base_position_m: tuple
    arm_move: str  # the move being played, '' when the arm rests
    cpu_s: float = 0.0  # CPU time spent stepping this world
    scene: str = ""
    hinge_angles_rad: tuple = ((), ())  # (left, right), each finger's hinges (for drawings)
    gauge_pressure_pa: float = 0.0


def _require_mujoco():
    try:
        import mujoco
    except ImportError:
        raise RuntimeError(INSTALL_HINT) from None
    return mujoco


# ---- the arm ------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class _Profile:
    start_m: np.ndarray
    duration_s: float
    step: object

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(position, velocity) at ``t`` s into the step."""
        t = min(max(t, 0.0), self.duration_s)
        step = self.step
        if isinstance(step, Wait):
            return self.start_m, np.zeros(3)
        if isinstance(step, Shake):
            omega = 2.0 * math.pi * step.frequency_hz
            amplitude = step.accel_m_s2 / (omega * omega)
            position, velocity = self.start_m.copy(), np.zeros(3)
            position[step.axis] += amplitude * (1.0 - math.cos(omega * t))
            velocity[step.axis] = amplitude * omega * math.sin(omega * t)
            return position, velocity
        target = np.asarray(step.target_m, dtype=float)
        distance = float(np.linalg.norm(target - self.start_m))
        if distance == 0.0:
            return self.start_m, np.zeros(3)
        unit = (target - self.start_m) / distance
        s, v = _trapezoid(distance, step.accel_m_s2, step.max_speed_m_s, t)
        return self.start_m + s * unit, v * unit


def _trapezoid_times(distance: float, accel: float, max_speed: float) -> tuple[float, float]:
    """(accelerating time, cruising time) of a rest-to-rest move."""
    if distance * accel <= max_speed * max_speed:
        return math.sqrt(distance / accel), 0.0
    return max_speed / accel, (distance - max_speed * max_speed / accel) / max_speed


def _trapezoid(distance: float, accel: float, max_speed: float, t: float) -> tuple[float, float]:
    t_accel, t_cruise = _trapezoid_times(distance, accel, max_speed)
    peak = accel * t_accel
    if t < t_accel:
        return 0.5 * accel * t * t, accel * t
    covered = 0.5 * accel * t_accel * t_accel
    if t < t_accel + t_cruise:
        return covered + peak * (t - t_accel), peak
    braking = min(t - t_accel - t_cruise, t_accel)
    return (covered + peak * t_cruise + peak * braking - 0.5 * accel * braking * braking,
            peak - accel * braking)


def _duration(step, start_m: np.ndarray) -> float:
    if isinstance(step, Wait):
        return step.duration_s
    if isinstance(step, Shake):
        return step.duration_s
    distance = float(np.linalg.norm(np.asarray(step.target_m) - start_m))
    t_accel, t_cruise = _trapezoid_times(distance, step.accel_m_s2, step.max_speed_m_s)
    return 2.0 * t_accel + t_cruise


class ArmPlayer:
    """Plays the scene's named moves one after another from where the base is."""

    def __init__(self, scene: Scene):
        self.scene = scene
        self._position = np.asarray(scene.start_m, dtype=float)
        self._queue: list = []  # (move name, _Profile)
        self._started_s = 0.0

    def play(self, name: str, now_s: float) -> None:
        """Queue the move ``name``; ValueError naming the scene's moves when it has none so."""
        if name not in self.scene.moves:
            raise ValueError(f"scene {self.scene.name!r} has no arm move {name!r}; it has "
                             f"{sorted(self.scene.moves) or 'none'}")
        start = self._queue[-1][1].at(math.inf)[0] if self._queue else self._position
        if not self._queue:
            self._started_s = now_s
        for step in self.scene.moves[name]:
            profile = _Profile(start.copy(), _duration(step, start), step)
            self._queue.append((name, profile))
            start = profile.at(math.inf)[0]

    def at(self, now_s: float) -> tuple[np.ndarray, np.ndarray, str]:
        """(base position, velocity, the move playing or '') at ``now_s``; finished steps drop."""
        while self._queue:
            name, profile = self._queue[0]
            elapsed = now_s - self._started_s
            if elapsed < profile.duration_s:
                position, velocity = profile.at(elapsed)
                return position, velocity, name
            self._position = profile.at(math.inf)[0]
            self._started_s += profile.duration_s
            self._queue.pop(0)
        return self._position, np.zeros(3), ""

    @property
    def moving(self) -> bool:
        return bool(self._queue)

    @property
    def carrying(self) -> bool:
        """Whether the step playing moves the base (a wait does not)."""
        return bool(self._queue) and not isinstance(self._queue[0][1].step, Wait)


# ---- the model ----------------------------------------------------------------------------------
def _fmt(values) -> str:
    return " ".join(f"{float(v):.9g}" for v in values)


def _rotation_y_quat(angle: float) -> tuple:
    return (math.cos(0.5 * angle), 0.0, math.sin(0.5 * angle), 0.0)


def build_mjcf(scene: Scene, finger: PseudoRigidFinger, timestep_s: float = DEFAULT_TIMESTEP_S,
               fingers_collide: bool = True) -> str:
    """The MuJoCo model (MJCF XML) of the gripper, the object and the floor (see the module)."""
    g = finger.geometry
    width = finger.finger_width_m
    half_width = 0.5 * width
    base_layer = g.chamber_bottom_to_sidewall_m
    assets, bodies = [], []
    near, far = finger.tip_thicknesses_m()
    for side, sign in (("left", 1.0), ("right", -1.0)):
        contype, conaffinity = _FINGER_BITS[LEFT if sign > 0 else RIGHT]
        if not fingers_collide:
            conaffinity = 1
        geom_class = f'contype="{contype}" conaffinity="{conaffinity}" rgba="0.85 0.55 0.35 1"'
        # the rigid root: vertical part, then h2 inclined, then the chain's first half sub-arc
        phi = g.inclination_rad
        root_x = -g.root_x_m
        root = [f'<geom name="{side}_root" type="box" {geom_class} '
                f'size="{0.5 * base_layer:.9g} {half_width:.9g} {0.5 * g.vertical_height_m:.9g}" '
                f'pos="{sign * (root_x + 0.5 * base_layer):.9g} 0 '
                f'{-0.5 * g.vertical_height_m:.9g}"/>']
        start_x = root_x + g.first_chamber_offset_m * math.sin(phi)
        start_z = g.vertical_height_m + g.first_chamber_offset_m * math.cos(phi)
        first_half = 0.5 * finger.sub_arcs[0].length_m
        offset_len = g.first_chamber_offset_m + first_half
        mid_x = root_x + 0.5 * offset_len * math.sin(phi) + 0.5 * base_layer * math.cos(phi)
        mid_z = g.vertical_height_m + 0.5 * offset_len * math.cos(phi) - \
            0.5 * base_layer * math.sin(phi)
        root.append(f'<geom name="{side}_offset" type="box" {geom_class} '
                    f'size="{0.5 * base_layer:.9g} {half_width:.9g} {0.5 * offset_len:.9g}" '
                    f'pos="{sign * mid_x:.9g} 0 {-mid_z:.9g}" '
                    f'quat="{_fmt(_rotation_y_quat(-sign * phi))}"/>')
        bodies.append((side, sign, root))
        hinge_x = start_x + first_half * math.sin(phi)
        hinge_z = start_z + first_half * math.cos(phi)
        chain = []
        arcs = finger.sub_arcs
        for j, arc in enumerate(arcs):
            span = 0.5 * arc.length_m + (0.5 * arcs[j + 1].length_m if j + 1 < len(arcs) else 0.0)
            k = finger.hinge_stiffness_nm_per_rad[j]
            mass = finger.linear_density_kg_per_m * span
            pieces = [f'<joint name="{side}_h{j}" type="hinge" axis="0 {sign:g} 0" '
                      f'stiffness="{k:.9g}" armature="{_ARMATURE:.3g}"/>']
            if span > 0.0:
                pieces.append(
                    f'<inertial pos="{sign * 0.5 * base_layer:.9g} 0 {-0.5 * span:.9g}" '
                    f'mass="{max(mass, 1e-6):.9g}" '
                    f'diaginertia="{_fmt([mass * span * span / 12] * 3)}"/>')
                pieces.append(f'<geom name="{side}_base{j}" type="box" {geom_class} '
                              f'size="{0.5 * base_layer:.9g} {half_width:.9g} {0.5 * span:.9g}" '
                              f'pos="{sign * 0.5 * base_layer:.9g} 0 {-0.5 * span:.9g}"/>')
            middle = arc.segment * g.segment_length_m + 0.5 * g.chamber_length_m
            if abs(arc.start_m + arc.length_m - middle) < 1e-12:
                i = arc.segment
                radius = finger.dome_radius_m(i)
                depth = g.chamber_depths_m[i]
                along = -0.5 * arc.length_m
                block = depth - radius
                if block > 1e-6:
                    pieces.append(
                        f'<geom name="{side}_block{i}" type="box" {geom_class} '
                        f'size="{0.5 * block:.9g} {half_width:.9g} '
                        f'{0.5 * g.chamber_length_m:.9g}" '
                        f'pos="{sign * (base_layer + 0.5 * block):.9g} 0 {along:.9g}"/>')
                pieces.append(
                    f'<geom name="{side}_dome{i}" type="capsule" {geom_class} '
                    f'size="{radius:.9g} {max(half_width - radius, 1e-4):.9g}" '
                    f'pos="{sign * (g.chamber_face_offset_m(i) - radius):.9g} 0 {along:.9g}" '
                    f'quat="0.7071068 0.7071068 0 0"/>')
                pieces.append(f'<site name="{side}_face{i}" size="0.0005" '
                              f'pos="{sign * g.chamber_face_offset_m(i):.9g} 0 {along:.9g}"/>')
            if j + 1 == len(arcs):
                z0, z1 = -0.5 * arc.length_m, -0.5 * arc.length_m - g.tip_length_m
                vertices = [(0.0, y, z0) for y in (-half_width, half_width)] + \
                    [(0.0, y, z1) for y in (-half_width, half_width)] + \
                    [(sign * near, y, z0) for y in (-half_width, half_width)] + \
                    [(sign * far, y, z1) for y in (-half_width, half_width)]
                assets.append(f'<mesh name="{side}_tip" vertex="{_fmt(np.ravel(vertices))}"/>')
                tip_mass = finger.linear_density_kg_per_m * g.tip_length_m
                pieces.append(f'<geom name="{side}_tip" type="mesh" mesh="{side}_tip" '
                              f'{geom_class} mass="{tip_mass:.9g}"/>')
                pieces.append(f'<site name="{side}_tip" size="0.0005" pos="0 0 {z1:.9g}"/>')
            if j == 0:
                x0, z0_ = hinge_x, hinge_z
                heading = phi
                chain.append((f'pos="{sign * x0:.9g} 0 {-z0_:.9g}" '
                              f'quat="{_fmt(_rotation_y_quat(-sign * heading))}"', pieces))
            else:
                previous = arcs[j - 1]
                gap = 0.5 * previous.length_m + 0.5 * arc.length_m
                chain.append((f'pos="0 0 {-gap:.9g}"', pieces))
        bodies[-1] = (side, sign, root, chain)
    return _document(scene, bodies, assets, timestep_s)


# the object's contacts: as stiff as a 1 ms step allows (time constant 2 steps): MuJoCo's
# default (20 ms) let a held object creep down its fingers under a steady load, and squeezed a
# 0.1 mm sheet through them
_OBJECT_SOLREF = "0.002 1"
_OBJECT_SOLIMP = "0.95 0.99 0.0005"
_OPTION = 'cone="elliptic" impratio="10"'
_ARMATURE = 2e-6  # kg m^2 on each hinge: bounds the stiffest mode for the time step


def _document(scene: Scene, fingers, assets, timestep_s: float) -> str:
    lines = ['<mujoco model="softgrip_world">',
             '<compiler angle="radian" inertiafromgeom="auto"/>',
             f'<option timestep="{timestep_s:.9g}" integrator="implicitfast" {_OPTION} '
             'gravity="0 0 -9.80665"/>',
             '<size memory="4M"/>']
    if assets:
        lines += ['<asset>', *assets, '</asset>']
    lines.append('<worldbody>')
    if scene.floor:
        lines.append('<geom name="floor" type="plane" size="1 1 0.01" contype="1" conaffinity="7" '
                     'rgba="0.8 0.8 0.8 1"/>')
    start = scene.start_m
    lines.append(f'<body name="base" pos="{_fmt(start)}">')
    for axis, name in zip(("1 0 0", "0 1 0", "0 0 1"), "xyz"):
        lines.append(f'<joint name="arm_{name}" type="slide" axis="{axis}" armature="1000"/>')
    lines.append('<inertial pos="0 0 0" mass="1" diaginertia="0.01 0.01 0.01"/>')
    for side, _, root, chain in fingers:
        lines += root
        for index, (attributes, pieces) in enumerate(chain):
            lines.append(f'<body name="{side}_link{index}" {attributes} gravcomp="1">')
            lines += pieces
        lines += ['</body>'] * len(chain)
    lines.append('</body>')
    obj = scene.object
    if obj is not None:
        lines.append(f'<body name="object" pos="{_fmt(obj.position_m)}">')
        if not obj.fixed:
            lines.append('<freejoint name="object"/>')
        lines.append(_object_geom(obj))
        lines.append('</body>')
    lines.append('</worldbody>')
    lines.append('</mujoco>')
    return "\n".join(lines)


def _object_geom(obj) -> str:
    sx, sy, sz = obj.size_m
    if obj.shape in (ObjectShape.BOX, ObjectShape.SHEET):
        shape = f'type="box" size="{0.5 * sx:.9g} {0.5 * sy:.9g} {0.5 * sz:.9g}"'
    elif obj.shape == ObjectShape.SPHERE:
        shape = f'type="sphere" size="{0.5 * sx:.9g}"'
    else:  # a capsule: its ends lie beyond the fingers, and its contacts are MuJoCo's analytic
        # ones, where a cylinder's (general convex) gave one point that hopped, and chattered
        shape = (f'type="capsule" size="{0.5 * sx:.9g} {max(0.5 * (sy - sx), 1e-4):.9g}" '
                 'quat="0.7071068 0.7071068 0 0"')
    return (f'<geom name="object" {shape} mass="{obj.mass_kg:.9g}" '
            f'friction="{obj.friction:.9g} 0.005 0.0001" priority="1" condim="4" '
            f'contype="{_OBJECT_BITS[0]}" conaffinity="{_OBJECT_BITS[1]}" '
            f'solref="{_OBJECT_SOLREF}" solimp="{_OBJECT_SOLIMP}" rgba="0.2 0.45 0.8 1"/>')


# ---- the world ----------------------------------------------------------------------------------
class GripperWorld:
    """The scene's world, stepped by :meth:`advance_to` with the chamber pressure of
    :meth:`set_pressure`. Not thread-safe: its owner (the simulated device) serialises the calls.

    ``start_pressure_pa``: the fingers start bent freely as at this pressure, and see it (a
    device starts at 0 Pa; tests start opened around an object). ``plant``: the pneumatics whose
    compliance the bending shares (default: the default plant's). Raises SceneError when the scene
    cannot start (an object inside a finger), RuntimeError when MuJoCo is missing.
    """

    def __init__(self, scene: Scene, finger: PseudoRigidFinger,
                 timestep_s: float = DEFAULT_TIMESTEP_S, fingers_collide: bool = True,
                 damping_ratio: float = DEFAULT_DAMPING_RATIO, start_pressure_pa: float = 0.0,
                 plant: PneumaticParameters | None = None):
        mujoco = _require_mujoco()
        self._mujoco = mujoco
        if not (math.isfinite(timestep_s) and 1e-4 <= timestep_s <= 2e-3):
            raise ValueError(f"timestep_s must lie in [0.0001, 0.002] s, got {timestep_s}")
        if not (math.isfinite(damping_ratio) and 0.05 <= damping_ratio <= 5.0):
            raise ValueError(f"damping_ratio must lie in [0.05, 5], got {damping_ratio}")
        self.scene, self.finger = scene, finger
        self.timestep_s = float(timestep_s)
        self.xml = build_mjcf(scene, finger, timestep_s, fingers_collide)
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        self.data = mujoco.MjData(self.model)
        model = self.model
        name = lambda kind, n: mujoco.mj_name2id(model, kind, n)  # noqa: E731
        hinges = [[name(mujoco.mjtObj.mjOBJ_JOINT, f"{side}_h{j}")
                   for j in range(finger.hinge_count)] for side in ("left", "right")]
        self._hinge_qpos = np.array([[model.jnt_qposadr[h] for h in row] for row in hinges])
        self._hinge_dof = np.array([[model.jnt_dofadr[h] for h in row] for row in hinges])
        arm = [name(mujoco.mjtObj.mjOBJ_JOINT, f"arm_{a}") for a in "xyz"]
        self._arm_qpos = np.array([model.jnt_qposadr[j] for j in arm])
        self._arm_dof = np.array([model.jnt_dofadr[j] for j in arm])
        self._domes = np.array([[name(mujoco.mjtObj.mjOBJ_GEOM, f"{side}_dome{i}")
                                 for i in range(CHAMBER_COUNT)] for side in ("left", "right")])
        self._faces = np.array([[name(mujoco.mjtObj.mjOBJ_SITE, f"{side}_face{i}")
                                 for i in range(CHAMBER_COUNT)] for side in ("left", "right")])
        self._tips = [name(mujoco.mjtObj.mjOBJ_SITE, f"{side}_tip") for side in ("left", "right")]
        self._dome_rest = model.geom_pos[self._domes].copy()
        self._face_rest = model.site_pos[self._faces].copy()
        self._normal_sign = np.array([1.0, -1.0])
        self._finger_of_body = np.full(model.nbody, -1)
        for body in range(model.nbody):
            body_name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, body) or ""
            if body_name.startswith("left_"):
                self._finger_of_body[body] = LEFT
            elif body_name.startswith("right_"):
                self._finger_of_body[body] = RIGHT
        self._base_body = name(mujoco.mjtObj.mjOBJ_BODY, "base")
        root_geoms = np.flatnonzero(model.geom_bodyid == self._base_body)
        self._finger_of_geom = self._finger_of_body[model.geom_bodyid].copy()
        for geom in root_geoms:
            geom_name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, geom) or ""
            self._finger_of_geom[geom] = LEFT if geom_name.startswith("left_") else RIGHT
        self._object_geom = name(mujoco.mjtObj.mjOBJ_GEOM, "object")
        self._object_body = name(mujoco.mjtObj.mjOBJ_BODY, "object")
        if scene.object is not None and scene.object.held_until:
            # its weight borne until the move: it floats where it is, free to be centred by the
            # closing fingers (a weld stored the closing's friction and let it go at once)
            model.body_gravcomp[self._object_body] = 1.0
        self._floor_geom = name(mujoco.mjtObj.mjOBJ_GEOM, "floor")
        self.first_mode_rad_s = self._damp(damping_ratio)
        self._table = self._drive_table()
        plant = plant or PneumaticParameters()
        geometric = finger.bending_compliance_m3_per_pa()
        # the scale of the first moments above and below atmosphere (see the module)
        self._volume_scale = tuple(FE_BENDING_VOLUME_SHARE * k / geometric for k in (
            plant.chamber_compliance_m3_per_pa, plant.vacuum_compliance_m3_per_pa))
        self._volume_per_rad = finger.bending_volume_per_rad_m3()
        self._force = np.zeros(6)
        self.arm = ArmPlayer(scene)
        if not math.isfinite(start_pressure_pa):
            raise ValueError(f"start_pressure_pa must be finite, got {start_pressure_pa}")
        self.pressure_pa = float(start_pressure_pa)
        self._drive = self._lookup(self.pressure_pa)
        self._apply_drive()
        start_angles = finger.hinge_angles(self.pressure_pa)
        for side in (LEFT, RIGHT):
            self.data.qpos[self._hinge_qpos[side]] = start_angles
        self._set_arm(0.0)
        mujoco.mj_forward(model, self.data)
        self._check_start()
        self.time_s = 0.0
        # the owner's clock when this world's began (a simulated device replacing its world)
        self.time_offset_s = 0.0
        self.cpu_s = 0.0
        self.steps = 0
        self._rest_z = (float(self.data.xpos[self._object_body][2]) if self._object_body >= 0
                        else 0.0)
        self._slip_reference = None
        self._slip_distance = 0.0
        self._was_held = False
        self._dropped = False
        self._volume_offset = 0.0

    def _damp(self, damping_ratio: float) -> float:
        """Damp every hinge by its stiffness times 2 zeta / omega_1, omega_1 the first mode of a
        straight finger (the chain's mass matrix against the hinges' stiffness), so that mode has
        the damping ratio zeta and the stiffer ones more. Returns omega_1 (rad/s)."""
        model = self.model
        stiffness = self.finger.hinge_stiffness_nm_per_rad
        inertia = self.hinge_mass_matrix()
        # K v = w^2 M v for the symmetric pair, via M^-1/2 K M^-1/2
        values, vectors = np.linalg.eigh(inertia)
        root_inverse = vectors @ np.diag(values ** -0.5) @ vectors.T
        omega_1 = math.sqrt(float(np.linalg.eigvalsh(
            root_inverse @ np.diag(stiffness) @ root_inverse)[0]))
        for side in (LEFT, RIGHT):
            model.dof_damping[self._hinge_dof[side]] = stiffness * 2.0 * damping_ratio / omega_1
        return omega_1

    def hinge_mass_matrix(self) -> np.ndarray:
        """(hinge_count, hinge_count): one finger's chain mass matrix over its hinges (kg m^2),
        in the present pose (the chain's; both fingers are alike)."""
        mujoco, model = self._mujoco, self.model
        mujoco.mj_forward(model, self.data)
        mass = np.zeros((model.nv, model.nv))
        mujoco.mj_fullM(model, self.data, mass)
        dofs = self._hinge_dof[LEFT]
        return mass[np.ix_(dofs, dofs)]

    def hinge_damping(self) -> np.ndarray:
        """(hinge_count,): one finger's hinge damping (N m s/rad), as :meth:`_damp` set it."""
        return self.model.dof_damping[self._hinge_dof[LEFT]].copy()

    # ---- drive ---------------------------------------------------------------------------------
    def _drive_table(self) -> np.ndarray:
        low, high = TABLE_RANGE_PA
        pressures = np.arange(low, high + 0.5 * TABLE_STEP_PA, TABLE_STEP_PA)
        finger = self.finger
        angles = np.asarray(finger.law.angles(pressures), dtype=float)  # (N, 5)
        bulge = np.outer(finger.law.saturation.effective_pressure(
            np.maximum(pressures, finger.contact_pressure_pa)), finger._bulge_per_pa)
        return np.hstack([angles, bulge])

    def _lookup(self, pressure_pa: float) -> np.ndarray:
        """The five free segment angles and five bulges at ``pressure_pa`` (clamped to the
        table's range: a faulty device may go beyond what any law describes)."""
        low, high = TABLE_RANGE_PA
        position = (min(max(pressure_pa, low), high) - low) / TABLE_STEP_PA
        index = min(int(position), len(self._table) - 2)
        t = position - index
        return (1.0 - t) * self._table[index] + t * self._table[index + 1]

    def set_pressure(self, gauge_pa: float) -> None:
        """The chamber pressure both fingers see from now on (Pa gauge; one channel feeds both)."""
        if not math.isfinite(gauge_pa):
            raise ValueError(f"pressure must be finite, got {gauge_pa}")
        if gauge_pa == self.pressure_pa:
            return
        self.pressure_pa = float(gauge_pa)
        self._drive = self._lookup(self.pressure_pa)
        self._apply_drive()

    def _apply_drive(self) -> None:
        finger = self.finger
        theta = self._drive[:CHAMBER_COUNT]
        torques = finger.hinge_stiffness_nm_per_rad * theta[finger._segment_of] * finger._share
        applied = self.data.qfrc_applied
        applied[self._hinge_dof[LEFT]] = torques
        applied[self._hinge_dof[RIGHT]] = torques
        bulge = self._drive[CHAMBER_COUNT:]
        for side in (LEFT, RIGHT):
            shift = np.zeros((CHAMBER_COUNT, 3))
            shift[:, 0] = self._normal_sign[side] * bulge
            self.model.geom_pos[self._domes[side]] = self._dome_rest[side] + shift
            self.model.site_pos[self._faces[side]] = self._face_rest[side] + shift

    # ---- arm -----------------------------------------------------------------------------------
    def play(self, move: str) -> None:
        """Queue the scene's arm move ``move``; ValueError when the scene has none so named. The
        move the object is ``held_until`` lets it go (its weight is no longer borne)."""
        self.arm.play(move, self.time_s)
        obj = self.scene.object
        if obj is not None and obj.held_until == move:
            self.model.body_gravcomp[self._object_body] = 0.0


    def _set_arm(self, now_s: float) -> str:
        position, velocity, move = self.arm.at(now_s)
        start = np.asarray(self.scene.start_m)
        self.data.qpos[self._arm_qpos] = position - start
        self.data.qvel[self._arm_dof] = velocity
        return move

    # ---- stepping ------------------------------------------------------------------------------
    def advance_to(self, time_s: float) -> int:
        """Step until the world's time is within half a step of ``time_s`` (never more than half a
        step ahead); the number of steps taken."""
        taken = 0
        started = time.thread_time()
        mujoco, model, data = self._mujoco, self.model, self.data
        while self.time_s + 0.5 * self.timestep_s <= time_s:
            self._set_arm(self.time_s)
            mujoco.mj_step(model, data)
            self.time_s += self.timestep_s
            taken += 1
        if taken:
            self._set_arm(self.time_s)
            self.steps += taken
            follow = 1.0 - math.exp(-taken * self.timestep_s * 0.5 * self.first_mode_rad_s)
            self._volume_offset += follow * (self._contact_volume_m3() - self._volume_offset)
            self._track()
        self.cpu_s += time.thread_time() - started
        return taken

    def _check_start(self) -> None:
        """Refuse a scene whose object starts inside a finger or the floor."""
        worst, where = 0.0, ""
        for contact in self.data.contact[:self.data.ncon]:
            geoms = (contact.geom1, contact.geom2)
            if self._object_geom not in geoms:
                continue
            other = geoms[1] if geoms[0] == self._object_geom else geoms[0]
            if contact.dist < -worst:
                worst = -contact.dist
                where = ("the floor" if other == self._floor_geom else
                         f"the {('left', 'right')[self._finger_of_geom[other]]} finger")
        if worst > 0.5e-3:
            raise SceneError(f"scene {self.scene.name!r}: the object starts {worst * 1e3:.1f} mm "
                             f"inside {where}")

    # ---- what happens to the object -------------------------------------------------------------
    def segment_angles(self) -> np.ndarray:
        """(2, 5): each finger's segment bends now (rad), hinges summed."""
        qpos = self.data.qpos
        return np.array([self.finger.segment_angles_of_hinges(qpos[self._hinge_qpos[side]])
                         for side in (LEFT, RIGHT)])

    def volume_offset_m3(self) -> float:
        """The air the chambers hold beyond free fingers at this pressure (m^3; see the module):
        negative for fingers held back from opening, positive for fingers held open under
        vacuum. It counts the bending the contacts impose, each hinge's constraint torque over
        its stiffness, not the fingers' lag behind a changing pressure: the chambers' V(p) is
        the quasi-static law of free fingers, and the world must not change it. The torques
        are followed with the fingers' own response time (2 / omega_1): a contact's impulse
        does not move the fingers' walls, and so the air, within one step."""
        return self._volume_offset

    def _contact_volume_m3(self) -> float:
        finger = self.finger
        held_back = self.data.qfrc_constraint[self._hinge_dof] / finger.hinge_stiffness_nm_per_rad
        per_segment = np.array([finger.segment_angles_of_hinges(row) for row in held_back])
        scale = self._volume_scale[0 if self.pressure_pa >= 0.0 else 1]
        return scale * float(np.sum(per_segment * self._volume_per_rad[None, :]))

    def contact_forces(self) -> tuple[np.ndarray, bool]:
        """(normal force of the object's contacts with each finger (2,), N; whether the object
        touches the floor)."""
        forces, on_floor = np.zeros(2), False
        data, obj = self.data, self._object_geom
        if obj < 0:
            return forces, False
        for index in range(data.ncon):
            contact = data.contact[index]
            if contact.geom1 != obj and contact.geom2 != obj:
                continue
            other = contact.geom2 if contact.geom1 == obj else contact.geom1
            self._mujoco.mj_contactForce(self.model, data, index, self._force)
            if other == self._floor_geom:
                on_floor = on_floor or bool(self._force[0] > TOUCH_FORCE_N)
            elif self._finger_of_geom[other] >= 0:
                forces[self._finger_of_geom[other]] += self._force[0]
        return forces, on_floor

    def in_hand(self) -> bool:
        forces, _ = self.contact_forces()
        return bool(np.all(forces > TOUCH_FORCE_N))

    def push_object(self, force_n) -> None:
        """An external force (3,) N on the object's centre, world frame, from now until changed
        (a benchmark pulling the object out of the hand). ValueError without an object."""
        if self._object_body < 0:
            raise ValueError(f"scene {self.scene.name!r} has no object to push")
        force = np.asarray(force_n, dtype=float)
        if force.shape != (3,) or not np.all(np.isfinite(force)):
            raise ValueError(f"force_n must be 3 finite components, got {force_n!r}")
        self.data.xfrc_applied[self._object_body][:3] = force

    def object_in_hand_m(self) -> np.ndarray:
        """The object's position relative to the hand: the middle between the two tip chambers'
        faces, which carry it (a drift of the object from there is slip; the fingers flexing
        under its weight is not)."""
        faces = self.data.site_xpos[self._faces[:, CHAMBER_COUNT - 1]]
        return (self.data.xpos[self._object_body] - faces.mean(axis=0)).copy()

    def _track(self) -> None:
        """Slip and drop bookkeeping after a batch of steps."""
        if self._object_body < 0:
            return
        forces, on_floor = self.contact_forces()
        held = bool(np.all(forces > TOUCH_FORCE_N))
        if held:
            self._was_held, self._dropped = True, False
        elif self._was_held and not any(forces > TOUCH_FORCE_N):
            self._dropped, self._was_held = True, False
        if held and self._slip_reference is None and self.arm.carrying:
            # slip counts from the first move that carries the object
            self._slip_reference = self.object_in_hand_m()
            self._slip_distance = 0.0
        if held and self._slip_reference is not None:
            drift = float(np.linalg.norm(self.object_in_hand_m() - self._slip_reference))
            self._slip_distance = max(self._slip_distance, drift)
        if not held and not self._dropped:
            self._slip_reference = None

    def truth(self) -> WorldTruth:
        """The world now (see :class:`WorldTruth`)."""
        data = self.data
        base = tuple(float(v) for v in data.xpos[self._base_body])
        move = self.arm.at(self.time_s)[2]
        if self._object_body < 0:
            return WorldTruth(self.time_s, GraspTruthState.FREE, (math.nan,) * 3,
                              (math.nan,) * 4, (0.0, 0.0), (False, False), False, 0.0, base, move,
                              self.cpu_s, self.scene.name, self._hinges(), self.pressure_pa)
        forces, on_floor = self.contact_forces()
        touching = tuple(bool(f > TOUCH_FORCE_N) for f in forces)
        held = all(touching)
        velocity = np.zeros(6)
        self._mujoco.mj_objectVelocity(self.model, data, self._mujoco.mjtObj.mjOBJ_BODY,
                                       self._object_body, velocity, 0)
        relative_speed = float(np.linalg.norm(velocity[3:] - data.qvel[self._arm_dof]))
        lifted = held and not on_floor and (
            data.xpos[self._object_body][2] > self._rest_z + LIFT_HEIGHT_M)
        if self._dropped:
            state = GraspTruthState.DROPPED
        elif held and relative_speed > SLIP_SPEED_M_S:
            state = GraspTruthState.SLIPPING
        elif lifted:
            state = GraspTruthState.LIFTED
        elif held:
            state = GraspTruthState.IN_HAND
        else:
            state = GraspTruthState.FREE
        return WorldTruth(
            time_s=self.time_s, state=state,
            object_position_m=tuple(float(v) for v in data.xpos[self._object_body]),
            object_quaternion_wxyz=tuple(float(v) for v in data.xquat[self._object_body]),
            normal_force_n=(float(forces[0]), float(forces[1])), touching=touching,
            on_floor=on_floor, slip_distance_m=self._slip_distance, base_position_m=base,
            arm_move=move, cpu_s=self.cpu_s, scene=self.scene.name,
            hinge_angles_rad=self._hinges(), gauge_pressure_pa=self.pressure_pa)

    def _hinges(self) -> tuple:
        return tuple(tuple(float(v) for v in row) for row in self.hinge_angles())

    # ---- shapes, for the tests and drawings -----------------------------------------------------
    def hinge_angles(self) -> np.ndarray:
        """(2, hinge_count) rad."""
        return np.array([self.data.qpos[self._hinge_qpos[side]] for side in (LEFT, RIGHT)])

    def face_points_m(self) -> np.ndarray:
        """(2, 5, 3): each chamber face's middle in the world frame."""
        return self.data.site_xpos[self._faces].copy()

    def tip_points_m(self) -> np.ndarray:
        """(2, 3): the end of each finger's backbone in the world frame."""
        return self.data.site_xpos[self._tips].copy()

    def in_gripper_frame(self, points_m: np.ndarray) -> np.ndarray:
        """World points (..., 3) as the gripper's (x, z): x across, z from the base to the tips."""
        base = self.data.xpos[self._base_body]
        relative = np.asarray(points_m) - base
        return np.stack([relative[..., 0], -relative[..., 2]], axis=-1)

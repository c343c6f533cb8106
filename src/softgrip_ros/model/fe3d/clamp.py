"""The 3-D finger clamping a rigid object: the normal force F_n(p) down to -60 kPa, with the
contact pressure and where the contact lies.

The scenes are the grasp manager's (:mod:`softgrip_ros.model.force_law`'s docstring), on one
finger, the other being its mirror image:

* ``FLAT``: a sheet ``size_m`` thick on the centre line. The finger is opened until its chamber
  side clears the sheet by CLEARANCE_M (at rest the tip block reaches past the centre line), the
  sheet is put in, and the pressure falls.
* ``ROUND``: a cylinder of diameter ``size_m``, its axis across the finger, on the centre line,
  level with the middle of the tip block's face. The finger is first opened until its own D2
  clears the cylinder by ENVELOP_MARGIN_M (as the manager opens by its model) and its chamber
  side by CLEARANCE_M; then the cylinder is put in, and the pressure falls.

The object is rigid and held in place (a fixed support, as the force law's rod assumes), in
frictionless contact by penalty (:mod:`softgrip_ros.model.fe3d.solid`) with the finger's chamber
side: the blocks' tops and end walls, and the tip. The penalty acts at each surface triangle's
corners, edge midpoints and centroid, since the finger's edges meet the object first. F_n is the
contact tractions' magnitudes summed over the whole finger (what friction can use), as the force
law's F_n.

On a cylinder the contact moves from point to point of the faceted finger, and with a penalty
whose stiffness jumps where a point meets the object Newton cycled at the first contact; there
the penalty acts on a softplus of the depth over 1 um (PENALTY_SMOOTHING_M), which presses with
under 1 Pa at a 5 um gap. The sheet converges without it. Either sweep ends where Newton fails
(on the vacuum side, where the cavities collapse, as without an object) and says so.
"""
from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from softgrip_ros.model.fe.finger import (SweepProgress, finger_frame_to_global, hash_inputs,
                                         read_cache, write_cache)
from softgrip_ros.model.fe.solver import NotConverged, YeohMaterial
from softgrip_ros.model.fe3d.finger import INSET_M, DEFAULT_WIDTH_M, FE3DState, Finger3D
from softgrip_ros.model.fe3d.solid import Obstacle
from softgrip_ros.model.fe3d.sweep import NEGATIVE_PRESSURES_PA, SWEEP_ELEMENT_SIZE_M
from softgrip_ros.model.force_law import ENVELOP_MARGIN_M, ObjectKind
from softgrip_ros.model.geometry import FingerGeometry

# bump when a change to this module changes its results
FE3D_CLAMP_VERSION = 3
# the objects: the 0.1 mm sheet and three cylinders
SHEET_THICKNESS_M = 1e-4
CYLINDER_DIAMETERS_M = (0.010, 0.030, 0.060)
CLEARANCE_M = 0.5e-3
OPENING_STEP_PA = 2.5e3
MAX_OPENING_PA = 50e3
PRESSURE_STEP_PA = 5e3
LOWEST_PRESSURE_PA = min(NEGATIVE_PRESSURES_PA)
SIZE_RANGE_M = (1e-5, 0.2)
# the finger's chamber side, which an object between the fingers can meet
CHAMBER_SIDE = "top[0-9]|near[0-9]|far[0-9]|tip_top|tip_end"
# the penalty's softplus length per object: Newton cycled as a cylinder's contact moved from
# point to point of the faceted finger; on the sheet it converges without (solid.Obstacle)
PENALTY_SMOOTHING_M = {ObjectKind.FLAT: 0.0, ObjectKind.ROUND: 1e-6}
# an obstacle's parameters that keep it clear of everything until it is put in place
_PARKED_FACE_M = 1.0


@dataclasses.dataclass
class FE3DClampState:
    """The finger pressing the object at one pressure. Forces of the whole finger (N), positions
    and directions in the left finger's (x, z), m."""

    pressure_pa: float
    normal_force_n: float
    resultant_n: tuple  # (x, z) the object's force on the finger
    contact_area_m2: float
    peak_contact_pressure_pa: float
    contact_centre_m: tuple  # (x, z), NaN without contact
    penetration_m: float  # into the object, by the penalty
    finger: FE3DState  # the finger's own measures (alpha, D2, interpenetration...)

    def to_dict(self) -> dict:
        out = {k: (list(v) if isinstance(v, tuple) else v)
               for k, v in dataclasses.asdict(self).items() if k != "finger"}
        out["finger"] = self.finger.to_dict()
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "FE3DClampState":
        data = dict(data)
        data["finger"] = FE3DState.from_dict(data["finger"])
        for key in ("resultant_n", "contact_centre_m"):
            data[key] = tuple(float(v) for v in data[key])
        return cls(**data)


@dataclasses.dataclass
class FE3DClampSweep:
    """One object clamped by the finger of ``width_m``; ``states`` descending in pressure, the
    first at the opening (no contact)."""

    inputs_hash: str
    kind: str  # ObjectKind's value
    size_m: float
    width_m: float
    element_size_m: float
    tetrahedra: int
    opening_pa: float
    object_centre_m: tuple  # (x, z): the sheet's mid-plane point level with the tip, or the axis
    states: list
    stop: str  # why the sweep ended before its lowest pressure ('' if it did not)
    seconds: float

    @property
    def object_kind(self) -> ObjectKind:
        return ObjectKind(self.kind)

    def normal_force_n(self, pressure_pa: float) -> float:
        """F_n at ``pressure_pa``, linear between the sweep's pressures; NaN outside them."""
        if not self.states:
            return math.nan
        pressures = np.array([s.pressure_pa for s in self.states])[::-1]
        forces = np.array([s.normal_force_n for s in self.states])[::-1]
        if not (pressures[0] - 1e-6 <= pressure_pa <= pressures[-1] + 1e-6):
            return math.nan
        return float(np.interp(pressure_pa, pressures, forces))

    def contact_pressure_pa(self) -> float:
        """The highest pressure at which the finger presses the object (the first pressing
        state's line back to F_n = 0, within the step before it); NaN if it never does."""
        for before, after in zip(self.states, self.states[1:]):
            if after.normal_force_n > 0.0:
                if before.normal_force_n > 0.0:
                    return before.pressure_pa
                following = self.states[self.states.index(after) + 1:]
                if following and following[0].normal_force_n > after.normal_force_n:
                    slope = ((following[0].normal_force_n - after.normal_force_n)
                             / (following[0].pressure_pa - after.pressure_pa))
                    reach = after.pressure_pa - after.normal_force_n / slope
                    return float(min(reach, before.pressure_pa))
                return after.pressure_pa
        return math.nan

    @property
    def interpenetration_max_m(self) -> float:
        return max((s.finger.interpenetration_m for s in self.states), default=0.0)

    def to_dict(self) -> dict:
        out = dataclasses.asdict(self)
        out["object_centre_m"] = list(self.object_centre_m)
        out["states"] = [s.to_dict() for s in self.states]
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "FE3DClampSweep":
        data = dict(data)
        data["states"] = [FE3DClampState.from_dict(s) for s in data["states"]]
        data["object_centre_m"] = tuple(data["object_centre_m"])
        return cls(**data)


class _PlacedObject:
    """The sheet or the cylinder as an obstacle whose place is set after the finger opens."""

    def __init__(self, geometry: FingerGeometry, kind: ObjectKind, size_m: float):
        import ngsolve as ng

        self.kind, self.size_m = kind, float(size_m)
        th = geometry.inclination_rad
        x0, z0 = -geometry.root_x_m, geometry.vertical_height_m
        self._sin, self._cos = math.sin(th), math.cos(th)
        self.face_x = ng.Parameter(_PARKED_FACE_M)  # the sheet's face towards this finger
        self.radius = ng.Parameter(0.0)
        self.centre_z = ng.Parameter(0.0)

        def depth(position):
            x = x0 + position[0] * self._sin + position[1] * self._cos
            if kind is ObjectKind.FLAT:
                return x - self.face_x
            z = z0 + position[0] * self._cos - position[1] * self._sin
            return self.radius - ng.sqrt(x * x + (z - self.centre_z) ** 2 + 1e-18)

        # the finger's edges meet the object first, where a Gauss rule has no point
        self.obstacle = Obstacle(kind.value, CHAMBER_SIDE, depth, corner_points=True,
                                 smoothing_m=PENALTY_SMOOTHING_M[kind])

    def place(self, centre_z_m: float, inflate_m: float = 0.0) -> None:
        if self.kind is ObjectKind.FLAT:
            self.face_x.Set(-0.5 * self.size_m - inflate_m)
        else:
            self.radius.Set(0.5 * self.size_m + inflate_m)
            self.centre_z.Set(centre_z_m)

    def park(self) -> None:
        self.face_x.Set(_PARKED_FACE_M)
        self.radius.Set(0.0)

    def to_global(self, vector_sn) -> tuple:
        """A (s, n) direction of the finger's frame in the left finger's (x, z)."""
        s, n = vector_sn
        return (s * self._sin + n * self._cos, s * self._cos - n * self._sin)


def _check(kind: ObjectKind, size_m: float) -> ObjectKind:
    kind = ObjectKind(kind)
    lo, hi = SIZE_RANGE_M
    if not (math.isfinite(size_m) and lo <= size_m <= hi):
        raise ValueError(f"the object's size must lie in [{lo * 1e3:g}, {hi * 1e3:g}] mm, got "
                         f"{size_m * 1e3!r} mm")
    return kind


def inputs_hash(geometry: FingerGeometry, material: YeohMaterial, kind: ObjectKind,
                size_m: float, width_m: float, element_size_m: float,
                lowest_pa: float) -> str:
    return "fe3d-clamp-" + hash_inputs(geometry, material, {
        "kind": kind.value, "size_m": round(float(size_m), 9),
        "width_m": round(float(width_m), 9), "element_size_m": round(float(element_size_m), 9),
        "lowest_pa": round(float(lowest_pa), 3), "step_pa": PRESSURE_STEP_PA,
        "opening_step_pa": OPENING_STEP_PA, "clearance_m": CLEARANCE_M,
        "margin_m": ENVELOP_MARGIN_M, "version": FE3D_CLAMP_VERSION,
        # left out at its neutral value, so that the sheet's caches stand
        **({"smoothing_m": PENALTY_SMOOTHING_M[kind]} if PENALTY_SMOOTHING_M[kind] else {}),
    })


def clamp_sweep(geometry: FingerGeometry, kind: ObjectKind, size_m: float,
                width_m: float = DEFAULT_WIDTH_M, element_size_m: float = SWEEP_ELEMENT_SIZE_M,
                *, lowest_pa: float = LOWEST_PRESSURE_PA, material: YeohMaterial | None = None,
                progress=print, use_cache: bool = True) -> FE3DClampSweep:
    """The finger opened clear of the object (``kind``, ``size_m`` across), the object put in,
    and the pressure lowered in PRESSURE_STEP_PA steps to ``lowest_pa``, measured at each.
    ValueError for an object size or a lowest pressure out of range (and Finger3D's for a width or
    mesh). Where the finger cannot open clear of the object by MAX_OPENING_PA, the sweep has
    no states and ``stop`` says how far it opened."""
    kind = _check(kind, size_m)
    if not (math.isfinite(lowest_pa) and -100e3 <= lowest_pa < 0.0):
        raise ValueError(f"the lowest pressure must lie in [-100, 0) kPa, got {lowest_pa!r} Pa")
    material = material or YeohMaterial()
    key = inputs_hash(geometry, material, kind, size_m, width_m, element_size_m, lowest_pa)
    if use_cache:
        found = read_cache(key, FE3DClampSweep.from_dict)
        if found is not None:
            return found
    import ngsolve as ng

    started = time.perf_counter()
    placed = _PlacedObject(geometry, kind, size_m)
    with ng.TaskManager():
        finger = Finger3D(geometry, width_m, material, element_size_m,
                          obstacles=[placed.obstacle])
        opening, centre_z, stop = _open_clear(finger, placed, progress)
        placed.place(centre_z)
        object_centre = (-0.5 * size_m if kind is ObjectKind.FLAT else 0.0, centre_z)
        grid = np.arange(math.floor(opening / PRESSURE_STEP_PA) * PRESSURE_STEP_PA,
                         lowest_pa - 1.0, -PRESSURE_STEP_PA)
        pressures = [] if stop else [p for p in grid if p < opening - 1.0]
        report = SweepProgress(1 + len(pressures), progress)
        states = [] if stop else [_measure(finger, placed)]
        report(opening, stop or _describe(states[-1]))
        for pressure in pressures:
            try:
                finger.solve(float(pressure), first_step_pa=PRESSURE_STEP_PA)
            except NotConverged as error:
                stop = f"Newton failed beyond {finger.pressure_pa / 1e3:+.2f} kPa ({error})"
                report(pressure, stop)
                break
            states.append(_measure(finger, placed))
            report(pressure, _describe(states[-1]))
    result = FE3DClampSweep(key, kind.value, float(size_m), float(width_m),
                            float(element_size_m), finger.tetrahedra, float(opening),
                            object_centre, states, stop, time.perf_counter() - started)
    if use_cache:
        write_cache(key, result.to_dict())
    return result


def _tip_face_centre_m(finger: Finger3D) -> np.ndarray:
    """(x, z) of the middle of the tip block's face, deformed."""
    block = finger.layout.profile.blocks[-1]
    point = np.array([[0.5 * (block.s0 + block.s1), block.n1 - INSET_M, INSET_M]])
    moved = point + finger.solid.displacement_at(point)
    return finger_frame_to_global(finger.geometry, moved[:, :2].T)[:, 0]


def _open_clear(finger: Finger3D, placed: _PlacedObject, progress) -> tuple:
    """Open the finger in OPENING_STEP_PA steps until the object, grown by CLEARANCE_M, would
    touch nothing (and, for a cylinder, D2 clears it by ENVELOP_MARGIN_M): (pressure Pa, the
    height z of the tip block's face centre there m, '' or why it never does by
    MAX_OPENING_PA)."""
    pressure = 0.0
    while True:
        centre_z = float(_tip_face_centre_m(finger)[1])
        placed.place(centre_z, inflate_m=CLEARANCE_M)
        touching = finger.solid.obstacle_contact(placed.obstacle.name).area_m2 > 0.0
        placed.park()
        spacing_m = finger.measure().tip_spacing_m
        wide_enough = (placed.kind is ObjectKind.FLAT
                       or spacing_m >= placed.size_m + ENVELOP_MARGIN_M)
        if not touching and wide_enough:
            progress(f"opened clear of the {placed.kind.value} object at "
                     f"{pressure / 1e3:+.1f} kPa")
            return pressure, centre_z, ""
        if pressure + OPENING_STEP_PA > MAX_OPENING_PA + 1.0:
            return pressure, centre_z, (
                f"the finger does not open clear of a {placed.size_m * 1e3:g} mm "
                f"{placed.kind.value} object: D2 at {pressure / 1e3:g} kPa is "
                f"{spacing_m * 1e3:.1f} mm")
        pressure += OPENING_STEP_PA
        finger.solve(pressure, first_step_pa=PRESSURE_STEP_PA)


def _measure(finger: Finger3D, placed: _PlacedObject) -> FE3DClampState:
    contact = finger.solid.obstacle_contact(placed.obstacle.name)
    half_to_whole = finger.whole_finger_scale
    if contact.normal_force_n > 0.0:
        centre = tuple(float(v) for v in
                       finger_frame_to_global(finger.geometry, contact.centre_m[:2, None])[:, 0])
    else:
        centre = (math.nan, math.nan)
    return FE3DClampState(
        pressure_pa=finger.pressure_pa,
        normal_force_n=half_to_whole * contact.normal_force_n,
        resultant_n=tuple(half_to_whole * float(v) for v in placed.to_global(contact.force_n[:2])),
        contact_area_m2=half_to_whole * contact.area_m2,
        peak_contact_pressure_pa=contact.peak_pressure_pa,
        contact_centre_m=centre,
        penetration_m=contact.deepest_m,
        finger=finger.measure())


def _describe(state: FE3DClampState) -> str:
    return (f"F_n {state.normal_force_n:6.3f} N  D2 {state.finger.tip_spacing_m * 1e3:6.1f} mm")

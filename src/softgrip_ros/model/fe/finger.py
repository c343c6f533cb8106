"""The finite-element finger: one finger of Table 1 in plane strain, pressurised, and measured
as the paper measures its FEA (alpha, D1, D2, the mean curvature, the tip pose, the backbone and
the chamber volumes).

This is the independent truth of ``scripts/bench_speed_accuracy.py`` and
``scripts/validate_model.py``: it shares the geometry file and the Yeoh constants with L0-L2,
and nothing of their bending laws. The layout's assumptions are in
:class:`~softgrip_ros.model.fe.mesh.FingerLayout`; the mechanics in
:mod:`~softgrip_ros.model.fe.solver`.

The left finger is built in its own frame (s along the backbone, n towards the chambers) and
placed like the kinematic models' left finger: the inclined part starts at (-root_x, h1), at
the inclination towards the centre line. The right finger is its mirror image, so D1 and D2 are
twice the |x| of the left finger's root and tip chamber faces, and alpha is the initial included
angle plus the turn between the root and the tip chamber faces (as in
``GripperKinematics``).
"""
from __future__ import annotations

import dataclasses
import math
import sys
import time

import numpy as np

from softgrip_ros import cache
from softgrip_ros.cache import key_of
from softgrip_ros.model.fe.mesh import CORNER_REFINEMENT, FingerLayout
from softgrip_ros.model.fe.solver import HyperelasticSolid, NotConverged, YeohMaterial
from softgrip_ros.model.fe_data import at_pressure
from softgrip_ros.model.geometry import CHAMBER_COUNT, FingerGeometry

INSTALL_HINT = ("the FE reference needs scikit-fem and gmsh: bash scripts/setup.sh "
                "--with-reference (or pip install 'softgrip_ros[fe]')")
# bump when a change to the FE code changes its results, so that caches and the committed
# config/fe_reference.yaml are recognised as stale
FE_MODEL_VERSION = 2
FE_CACHE_KIND = "fe"  # softgrip_ros.cache's directory of the sweeps
# the paper's FEA pressures: 0 to 60 kPa in 5 kPa steps, 13 in all
SWEEP_PRESSURES_PA = tuple(5e3 * k for k in range(13))
# under vacuum the cavity walls move towards each other; without a contact model the sweep stops
# when two opposite walls of a cavity come closer than this
WALL_CONTACT_GAP_M = 0.2e-3
# the sweep's converged mesh, and the three sizes of the convergence study (coarse to fine)
SWEEP_ELEMENT_SIZE_M = 1.0e-3
CONVERGENCE_SIZES_M = (2.0e-3, 1.4142e-3, 1.0e-3)
# under vacuum, load steps of this size at most, each checked for touching walls; then the
# contact is bracketed to 1/8 of a step
VACUUM_STEP_PA = 1.25e3
CONTACT_BISECTIONS = 3
PERIMETER_SAMPLES = 64  # per cavity wall, for its deformed area and wall gaps
FACE_SAMPLES = 21
BACKBONE_POINTS = 47


def fe_available() -> bool:
    try:
        import gmsh  # noqa: F401
        import skfem  # noqa: F401
    except ImportError:
        return False
    return True


@dataclasses.dataclass
class FEState:
    """The measured finger at one pressure. Lengths in m, angles in rad; x, z as the kinematic
    models' frame (left finger)."""

    pressure_pa: float
    included_angle_rad: float  # alpha
    root_spacing_m: float  # D1
    tip_spacing_m: float  # D2
    mean_curvature_per_m: float  # backbone turn over the five segments / their length
    tip: tuple  # (x, z, tangent angle from +z) of the backbone's end
    backbone_m: np.ndarray  # (K, 2) x, z of the backbone (outer side)
    cavity_areas_m2: tuple  # per chamber, per unit width (plane strain)
    min_wall_gap_m: float  # the closest two opposite walls of any cavity come
    # the largest |deformed / reference area - 1| of the solid's parts (the base, each chamber
    # block, the tip): the discrete incompressibility. The whole solid's is exact by
    # construction (a constant lies in the P1 pressure space), so the parts are the check.
    volume_change: float
    newton_iterations: int

    def to_dict(self) -> dict:
        out = dataclasses.asdict(self)
        out["backbone_m"] = [[round(float(x), 7), round(float(z), 7)] for x, z in self.backbone_m]
        out["tip"] = [float(v) for v in self.tip]
        out["cavity_areas_m2"] = [float(v) for v in self.cavity_areas_m2]
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "FEState":
        data = dict(data)
        data["backbone_m"] = np.asarray(data["backbone_m"], dtype=float)
        data["tip"] = tuple(data["tip"])
        data["cavity_areas_m2"] = tuple(data["cavity_areas_m2"])
        return cls(**data)


class _WallContact(Exception):
    """Two opposite cavity walls came within WALL_CONTACT_GAP_M during a load step."""


class FingerFE:
    """The plane-strain FE model of one finger on a mesh of ``element_size_m``."""

    def __init__(self, geometry: FingerGeometry, material: YeohMaterial | None = None,
                 element_size_m: float = SWEEP_ELEMENT_SIZE_M,
                 corner_refinement: float = CORNER_REFINEMENT):
        if not (math.isfinite(element_size_m) and 0.1e-3 <= element_size_m <= 5e-3):
            raise ValueError(f"element size must lie in [0.1, 5] mm, got {element_size_m!r} m")
        self.geometry = geometry
        self.material = material or YeohMaterial()
        self.element_size_m = float(element_size_m)
        self.corner_refinement = float(corner_refinement)
        self.layout = FingerLayout.from_geometry(geometry)
        self.mesh = self.layout.mesh(element_size_m, corner_refinement)
        cavities = self.layout.cavity_facets(self.mesh)
        if any(len(f) == 0 for f in cavities):
            raise RuntimeError("a cavity has no boundary facets: the mesh lost a chamber")
        self.chambers = {f"chamber_{i + 1}": facets for i, facets in enumerate(cavities)}
        clamp = self.layout.clamp_facets(self.mesh)
        self.solid = HyperelasticSolid(self.mesh, self.material, self.chambers)
        self.solid.fix(self.solid.dofs_on(clamp))
        self._build_probes()

    # ---- where things are measured -----------------------------------------------------------
    def _build_probes(self):
        g, lay = self.geometry, self.layout
        eps = 1e-7  # inside the solid, off its boundary by a hair, so each point finds a triangle
        self._face_points = []
        for i in (0, CHAMBER_COUNT - 1):
            block = lay.blocks[i]
            s = np.linspace(block.s0 + eps, block.s1 - eps, FACE_SAMPLES)
            self._face_points.append(np.vstack([s, np.full_like(s, block.n1 - eps)]))
        bend_start = g.first_chamber_offset_m
        bend_end = bend_start + CHAMBER_COUNT * g.segment_length_m
        half = 0.5e-3
        self._curvature_points = np.array([[bend_start + eps, bend_start + half,
                                            bend_end - half, bend_end],
                                           [eps] * 4])
        s = np.linspace(eps, lay.length_m - eps, BACKBONE_POINTS)
        self._backbone_points = np.vstack([s, np.full_like(s, eps)])
        self._tip_points = np.array([[lay.length_m - 2e-3, lay.length_m - eps], [eps, eps]])
        self._walls = [self._cavity_walls(c, eps) for c in lay.cavities]
        every = np.hstack([*self._face_points, self._curvature_points, self._backbone_points,
                           self._tip_points] + [w for walls in self._walls for w in walls])
        self._probe = self.solid.basis_u.probes(every)
        self._probe_points = every

    @staticmethod
    def _cavity_walls(cavity, eps):
        """The four walls of a cavity as sample points just inside the solid: floor, far end,
        top and near end, in order round the cavity."""
        k = PERIMETER_SAMPLES
        s = np.linspace(cavity.s0, cavity.s1, k)
        n = np.linspace(cavity.n0, cavity.n1, k)
        return (np.vstack([s, np.full(k, cavity.n0 - eps)]),
                np.vstack([np.full(k, cavity.s1 + eps), n]),
                np.vstack([s[::-1], np.full(k, cavity.n1 + eps)]),
                np.vstack([np.full(k, cavity.s0 - eps), n[::-1]]))

    def _to_global(self, local):
        return finger_frame_to_global(self.geometry, local)

    # ---- solving and measuring ---------------------------------------------------------------
    def solve(self, pressure_pa: float, **kwargs):
        """Load every chamber to ``pressure_pa`` from the present state. NotConverged leaves
        the model at the last pressure it reached."""
        self.solid.solve({name: float(pressure_pa) for name in self.chambers}, **kwargs)

    @property
    def pressure_pa(self) -> float:
        return next(iter(self.solid.gas_pressures.values()))

    def measure(self) -> FEState:
        g = self.geometry
        displaced = self._probe_points + self._probe_displacement()
        world = self._to_global(displaced)
        cursor = 0

        def take(count):
            nonlocal cursor
            out = world[:, cursor:cursor + count]
            cursor += count
            return out

        faces = [take(FACE_SAMPLES) for _ in range(2)]
        curvature_points = take(4)
        backbone = take(BACKBONE_POINTS)
        tip_points = take(2)
        walls = [[take(PERIMETER_SAMPLES) for _ in range(4)] for _ in self._walls]

        centres, angles = [], []
        for face in faces:
            centres.append(face[:, FACE_SAMPLES // 2])
            angles.append(heading(line_direction(face)))
        root_heading = heading(curvature_points[:, 1] - curvature_points[:, 0])
        end_heading = heading(curvature_points[:, 3] - curvature_points[:, 2])
        bend_length = CHAMBER_COUNT * g.segment_length_m
        tip_heading = heading(tip_points[:, 1] - tip_points[:, 0])
        areas, gaps = [], []
        for floor, far, top, near in walls:
            areas.append(abs(_polygon_area(np.hstack([floor, far, top, near]))))
            gaps.append(min(_closest(floor, top), _closest(far, near)))
        return FEState(
            pressure_pa=self.pressure_pa,
            included_angle_rad=g.initial_included_angle_rad + (angles[0] - angles[1]),
            root_spacing_m=-2.0 * float(centres[0][0]),
            tip_spacing_m=-2.0 * float(centres[1][0]),
            mean_curvature_per_m=(root_heading - end_heading) / bend_length,
            tip=(float(tip_points[0, 1]), float(tip_points[1, 1]), tip_heading),
            backbone_m=backbone.T.copy(),
            cavity_areas_m2=tuple(areas),
            min_wall_gap_m=float(min(gaps)),
            volume_change=self._largest_part_volume_change(),
            newton_iterations=self.solid.stats.newton_iterations)

    def _parts(self):
        """Element masks of the solid's parts: the base, each chamber block, the tip piece."""
        lay = self.layout
        s, n = self.mesh.p[:, self.mesh.t].mean(axis=1)
        parts = [n < lay.base_m, (s > lay.tip_start_m) & (n >= lay.base_m)]
        parts += [(n >= lay.base_m) & (s > b.s0) & (s < b.s1) for b in lay.blocks]
        return parts

    def _largest_part_volume_change(self) -> float:
        deformed, reference = self.solid.element_areas()
        return max(abs(float(deformed[m].sum() / reference[m].sum()) - 1.0)
                   for m in self._parts())

    def _probe_displacement(self):
        return (self._probe @ self.solid.u).reshape(2, -1)

    def block_gaps_m(self) -> tuple:
        """Between blocks i and i + 1: the closest approach of block i's far end wall and block
        i + 1's near one (m, sampled up to the lower block's top). This FE has no contact between
        them, so below the suite's gap (WALL_CONTACT_GAP_M) it is no longer a truth."""
        if not hasattr(self, "_gap_probe"):
            eps, walls = 1e-7, []
            for a, b in zip(self.layout.blocks, self.layout.blocks[1:]):
                n = np.linspace(a.n0 + eps, min(a.n1, b.n1) - eps, PERIMETER_SAMPLES)
                walls += [np.vstack([np.full_like(n, a.s1 - eps), n]),
                          np.vstack([np.full_like(n, b.s0 + eps), n])]
            self._gap_points = np.hstack(walls)
            self._gap_probe = self.solid.basis_u.probes(self._gap_points)
        moved = self._gap_points + (self._gap_probe @ self.solid.u).reshape(2, -1)
        k = PERIMETER_SAMPLES
        return tuple(_closest(moved[:, 2 * i * k:(2 * i + 1) * k],
                              moved[:, (2 * i + 1) * k:(2 * i + 2) * k])
                     for i in range(len(self.layout.blocks) - 1))


def finger_frame_to_global(geometry: FingerGeometry, local) -> np.ndarray:
    """(2, K) points of a finger's own (s, n) frame to the left finger's (x, z), m."""
    th = geometry.inclination_rad
    x0, z0 = -geometry.root_x_m, geometry.vertical_height_m
    s, n = local
    return np.vstack([x0 + s * math.sin(th) + n * math.cos(th),
                      z0 + s * math.cos(th) - n * math.sin(th)])


def heading(direction) -> float:
    """The angle of a direction from +z, positive towards +x (the kinematic models' phi)."""
    return math.atan2(float(direction[0]), float(direction[1]))


def line_direction(points) -> np.ndarray:
    """The least-squares direction of (2, K) points, oriented from the first to the last."""
    centred = points - points.mean(axis=1, keepdims=True)
    direction = np.linalg.svd(centred, full_matrices=False)[0][:, 0]
    return direction if np.dot(direction, points[:, -1] - points[:, 0]) >= 0 else -direction


def _polygon_area(points) -> float:
    x, y = points
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def _closest(a, b) -> float:
    return float(np.min(np.hypot(a[0][:, None] - b[0][None, :], a[1][:, None] - b[1][None, :])))


# ---- the sweep --------------------------------------------------------------------------------
@dataclasses.dataclass
class FESweep:
    """One finger loaded from 0 to +max and, on a fresh model, from 0 to -max. ``states`` holds
    every measured pressure in ascending order; the vacuum side ends early where the cavity walls
    would touch (``vacuum_stop``)."""

    inputs_hash: str
    element_size_m: float
    states: list
    vacuum_stop: str  # why the vacuum side ended before its last pressure ('' if it did not)
    vacuum_limit_pa: float  # the most negative pressure measured
    seconds: float  # the solve time of the whole sweep, when it was computed (the cache keeps it)
    triangles: int

    def at(self, pressure_pa: float) -> FEState:
        return at_pressure(self.states, pressure_pa, "the FE sweep")

    def to_dict(self) -> dict:
        out = dataclasses.asdict(self)
        out["states"] = [s.to_dict() for s in self.states]
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "FESweep":
        data = dict(data)
        data["states"] = [FEState.from_dict(s) for s in data["states"]]
        return cls(**data)


def inputs_hash(geometry: FingerGeometry, material: YeohMaterial, element_size_m: float,
                pressures_pa, corner_refinement: float = CORNER_REFINEMENT) -> str:
    """What a sweep's results depend on: the geometry, the material, the mesh, the pressures and
    the FE code's version."""
    return hash_inputs(geometry, material, {
        "element_size_m": round(float(element_size_m), 9),
        "corner_refinement": float(corner_refinement),
        "pressures_pa": [round(float(p), 3) for p in pressures_pa],
        "wall_contact_gap_m": WALL_CONTACT_GAP_M,
        "version": FE_MODEL_VERSION,
    })


def hash_inputs(geometry: FingerGeometry, material: YeohMaterial, rest: dict) -> str:
    """16 hex digits of the SHA-256 of a sweep's inputs: the geometry, the material and ``rest``
    (plain values), so that any change to them makes a new cache key."""
    return key_of({
        "geometry": {k: (list(v) if isinstance(v, tuple) else v)
                     for k, v in dataclasses.asdict(geometry).items()},
        "material": dataclasses.asdict(material), **rest,
    })


def read_cache(key: str, parse):
    """``parse(document)`` of the cached sweep ``key`` (see :mod:`softgrip_ros.cache`), or None
    (it is then recomputed and overwritten)."""
    return cache.read_cache(FE_CACHE_KIND, key, parse)


def write_cache(key: str, document: dict) -> None:
    """Store ``document`` as sweep ``key``, whole or not at all."""
    cache.write_cache(FE_CACHE_KIND, key, document)


def _stderr_progress(message: str) -> None:
    print(f"[fe] {message}", file=sys.stderr, flush=True)


class SweepProgress:
    """A sweep's progress bar: ``report(pressure_pa, state_or_reason)`` after each of ``total``
    pressures sends one line to ``progress(message)``: the bar, the count, the pressure, the tip
    spacing D2 of a state (or the reason a side ended), and the time so far."""

    def __init__(self, total: int, progress):
        self.total, self.done, self.progress = int(total), 0, progress
        self.started = time.perf_counter()

    def __call__(self, pressure_pa: float, state_or_reason) -> None:
        self.done += 1
        what = (state_or_reason if isinstance(state_or_reason, str) else
                f"D2 {state_or_reason.tip_spacing_m * 1e3:7.2f} mm")
        bar = "#" * int(20 * min(self.done, self.total) / self.total)
        self.progress(f"[{bar:<20}] {self.done:2d}/{self.total} {pressure_pa / 1e3:+6.1f} kPa  "
                      f"{what}  {time.perf_counter() - self.started:5.1f} s")


def sweep(geometry: FingerGeometry, material: YeohMaterial | None = None,
          element_size_m: float = SWEEP_ELEMENT_SIZE_M, pressures_pa=SWEEP_PRESSURES_PA,
          progress=_stderr_progress, use_cache: bool = True) -> FESweep:
    """The finger at +p and -p for every p of ``pressures_pa`` (>= 0, ascending), cached by
    :func:`inputs_hash` in :func:`softgrip_ros.cache.cache_dir` ("fe"). ``progress(message)``
    hears of each pressure."""
    material = material or YeohMaterial()
    pressures = [float(p) for p in pressures_pa]
    if not pressures or pressures[0] != 0.0 or any(
            b <= a for a, b in zip(pressures, pressures[1:])):
        raise ValueError(f"pressures must start at 0 and ascend, got {pressures_pa!r}")
    key = inputs_hash(geometry, material, element_size_m, pressures)
    if use_cache:
        found = read_cache(key, FESweep.from_dict)
        if found is not None:
            return found
    started = time.perf_counter()
    report = SweepProgress(2 * len(pressures) - 1, progress)

    finger = FingerFE(geometry, material, element_size_m)
    positive = []
    for p in pressures:
        if p:
            finger.solve(p)
        positive.append(finger.measure())
        report(p, positive[-1])
    finger = FingerFE(geometry, material, element_size_m)
    negative, stop = [], ""
    last_good = [positive[0]]

    def stop_at_contact(_gas):
        state = finger.measure()
        if state.min_wall_gap_m < WALL_CONTACT_GAP_M:
            raise _WallContact()
        last_good[0] = state

    for p in pressures[1:]:
        try:
            finger.solve(-p, first_step_pa=VACUUM_STEP_PA, progress=stop_at_contact)
        except NotConverged as error:
            stop = f"Newton failed beyond {finger.pressure_pa / 1e3:+.2f} kPa ({error})"
        except _WallContact:
            touching = finger.pressure_pa
            closest = _bracket_wall_contact(finger, last_good[0].pressure_pa, touching)
            if closest is not None:
                last_good[0] = closest
            negative.append(last_good[0])
            stop = (f"cavity walls within {WALL_CONTACT_GAP_M * 1e3:.1f} mm of each other "
                    f"between {last_good[0].pressure_pa / 1e3:+.2f} and {touching / 1e3:+.2f} "
                    f"kPa (no contact modelled): the vacuum side ends there")
        else:
            negative.append(finger.measure())
            report(-p, negative[-1])
            continue
        report(-p, stop)
        break
    result = FESweep(
        inputs_hash=key, element_size_m=float(element_size_m),
        states=sorted(negative + positive, key=lambda s: s.pressure_pa), vacuum_stop=stop,
        vacuum_limit_pa=min([s.pressure_pa for s in negative] + [0.0]),
        seconds=time.perf_counter() - started, triangles=int(finger.mesh.t.shape[1]))
    if use_cache:
        write_cache(key, result.to_dict())
    return result


def _bracket_wall_contact(finger: FingerFE, good_pa: float, touching_pa: float,
                          halvings: int = CONTACT_BISECTIONS):
    """The most negative pressure, to within (good - touching) / 2^halvings, at which no two
    cavity walls come within WALL_CONTACT_GAP_M; its state, or None if none beyond ``good``."""
    best = None
    for _ in range(halvings):
        middle = 0.5 * (good_pa + touching_pa)
        try:
            finger.solve(middle)
        except NotConverged:
            touching_pa = middle
            continue
        state = finger.measure()
        if state.min_wall_gap_m >= WALL_CONTACT_GAP_M:
            good_pa, best = middle, state
        else:
            touching_pa = middle
    return best

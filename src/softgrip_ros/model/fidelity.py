"""Model no more than a scene needs: pick L0, L1 or L2 for a pressure and a scene, and evaluate it.

A :class:`Scene` is free bending or a contact with an object (a
:class:`~softgrip_ros.model.rod.Circle` seen end-on, or a :class:`~softgrip_ros.model.rod.Sheet`).
With the pressure it falls in one of three scene classes:

    free         free bending inside the validated range (tip contact < p <= 46 kPa)
    free_beyond  free bending outside it (above 46 kPa, where the linear law runs away)
    contact      an object between the fingers (L0 and L1 ignore it and pass through it)

``config/model_error_bounds.yaml`` (written by ``scripts/bench_speed_accuracy.py``) holds, per
model, the largest tip-position error seen in each scene class and the median cost of one pose:
in free bending against the finite-element finger (``softgrip_ros.model.fe``), each law fitted
to it, so the bound is the law's own error once calibrated; in contact against the PyElastica
rod (the FE has no contact). ``auto`` picks the cheapest model whose bound meets
``tolerance_m``; when none does, the one with the smallest bound, and says so.
"""
from __future__ import annotations

import dataclasses
import math
import pathlib
import typing

import numpy as np
import yaml

from softgrip_ros.health import Health, Report
from softgrip_ros.model.calibration import build_kinematics
from softgrip_ros.model.geometry import CHAMBER_COUNT
from softgrip_ros.model.kinematics import TipTable, chord_joints, pcc_joints
from softgrip_ros.model.rod import Circle, RodFinger, Sheet

BOUNDS_FILE = "model_error_bounds.yaml"
# The pressures scripts/bench_speed_accuracy.py measures the contact bound at (cylinders clamped
# from 0 to -20 kPa and released up to their 30 kPa opening, a sheet pinched at -5 and -20 kPa):
# L2 in a contact scene is validated there. The bounds file records the range it was measured on;
# this is the default when it does not.
CONTACT_VALIDATED_RANGE_PA = (-20e3, 30e3)
MODELS = ("l0", "l1", "l2")
SCENE_CLASSES = ("free", "free_beyond", "contact")
CHOICES = MODELS + ("auto",)


@dataclasses.dataclass(frozen=True)
class Scene:
    """What the fingers meet. ``opening_gauge_pa``: the free-bending pressure the fingers were
    opened to around the object (where the L2 solve starts; it must clear the object)."""

    obstacle: Circle | Sheet | None = None
    opening_gauge_pa: float = 0.0

    @property
    def contact(self) -> bool:
        return self.obstacle is not None

    def describe(self) -> str:
        if isinstance(self.obstacle, Circle):
            return (f"a {2e3 * self.obstacle.radius_m:.1f} mm cylinder at z = "
                    f"{1e3 * self.obstacle.center_z_m:.1f} mm")
        if isinstance(self.obstacle, Sheet):
            return f"a {1e3 * self.obstacle.thickness_m:.2f} mm sheet"
        return "free bending"


FREE = Scene()


def cylinder_scene(rod: RodFinger, diameter_m: float, opening_gauge_pa: float) -> Scene:
    """A cylinder of ``diameter_m`` on the centre line, level with the middle of the tip chambers
    at the opening pressure (where D2, which the grasp opens to clear it, is measured)."""
    if not (math.isfinite(diameter_m) and diameter_m > 0 and math.isfinite(opening_gauge_pa)):
        raise ValueError(
            f"a cylinder scene needs a positive diameter and a finite opening pressure, "
            f"got {diameter_m} m at {opening_gauge_pa} Pa")
    z_m = float(rod.chamber_face_point_m(opening_gauge_pa, CHAMBER_COUNT - 1)[1])
    return Scene(Circle(0.0, z_m, 0.5 * diameter_m), opening_gauge_pa)


@dataclasses.dataclass(frozen=True)
class ErrorBounds:
    """Per model: the tip error bound (m) in each scene class, and the median cost of a pose
    (s)."""

    tip_error_bound_m: dict  # {model: {scene class: m}}
    median_cost_s: dict  # {model: s}
    source: str = ""
    contact_range_pa: tuple = CONTACT_VALIDATED_RANGE_PA  # where the contact bound was measured

    @classmethod
    def load(cls, path=None) -> "ErrorBounds":
        if path is None:
            from softgrip_ros.config_paths import config_file
            path = config_file(BOUNDS_FILE)
        with pathlib.Path(path).open() as handle:
            doc = yaml.safe_load(handle) or {}
        try:
            models = doc["models"]
            bounds = {
                m: {c: float(models[m]["tip_error_bound_m"][c])
                    for c in SCENE_CLASSES}
                for m in MODELS
            }
            costs = {m: float(models[m]["median_cost_s"]) for m in MODELS}
            low, high = (float(v)
                         for v in doc.get("contact_pressure_range_pa", CONTACT_VALIDATED_RANGE_PA))
        except (KeyError, TypeError, ValueError) as error:
            raise ValueError(f"{path}: not a model error-bound table ({error!r}); "
                             "regenerate it with scripts/bench_speed_accuracy.py") from None
        return cls(bounds, costs, str(path), (low, high))


ROD_CONTINUATION_STEPS = 4


@dataclasses.dataclass(frozen=True)
class Choice:
    model: str
    scene_class: str
    bound_m: float
    meets_tolerance: bool


class ModelSelector:
    """``fidelity``: l0, l1, l2 (always that one) or auto (the cheapest that meets
    ``tolerance_m``)."""

    def __init__(self, fidelity: str, tolerance_m: float, bounds: ErrorBounds,
                 validated_range_pa: tuple):
        if fidelity not in CHOICES:
            raise ValueError(f"fidelity must be one of {list(CHOICES)}, got {fidelity!r}")
        if not (math.isfinite(tolerance_m) and tolerance_m > 0):
            raise ValueError(f"tolerance_m must be a positive length, got {tolerance_m}")
        self.fidelity, self.tolerance_m, self.bounds = fidelity, tolerance_m, bounds
        self.validated_range_pa = validated_range_pa
        self._by_class = {}  # the choice per scene class: it is asked at 200 Hz

    def scene_class(self, pressure_pa: float, scene: Scene) -> str:
        if scene.contact:
            return "contact"
        low, high = self.validated_range_pa
        return "free" if low < pressure_pa <= high else "free_beyond"

    def choose(self, pressure_pa: float, scene: Scene = FREE) -> Choice:
        return self.choose_for_class(self.scene_class(pressure_pa, scene))

    def choose_for_class(self, scene_class: str) -> Choice:
        choice = self._by_class.get(scene_class)
        if choice is None:
            choice = self._by_class[scene_class] = self._choose_for_class(scene_class)
        return choice

    def _choose_for_class(self, scene_class: str) -> Choice:
        bound = {m: self.bounds.tip_error_bound_m[m][scene_class] for m in MODELS}
        if self.fidelity != "auto":
            model = self.fidelity
        else:
            meeting = [m for m in MODELS if bound[m] <= self.tolerance_m]
            model = ((min(meeting, key=self.bounds.median_cost_s.get) if meeting else min(
                MODELS, key=bound.get)))
        return self.choice(model, scene_class)

    def choice(self, model: str, scene_class: str) -> Choice:
        """``model`` in ``scene_class``, with its bound and whether that meets the tolerance."""
        bound = self.bounds.tip_error_bound_m[model][scene_class]
        return Choice(model, scene_class, bound, bound <= self.tolerance_m)


@dataclasses.dataclass
class Evaluation:
    """One pose of the left finger (the right one mirrors it) by the chosen model."""

    model: str
    scene_class: str
    pressure_pa: float
    tip: tuple  # (x, z, tangent angle from +z)
    tip_slope: tuple  # d tip / dp (per Pa)
    backbone: object  # () -> [(x, z), ...] for markers, computed only when asked for
    in_validated_range: bool
    contact_force_n: float  # L2 only (0 otherwise)
    bound_m: float
    meets_tolerance: bool
    message: str
    # () -> (five (turn, chord, turn) joints of the left finger's segments, D2 m): the shape as
    # joint_states gives it (see kinematics.pcc_joints), computed only when asked for
    joints: object = None

    def report(self, l2_solves: int) -> Report:
        """OK while the pressure lies in the validated range and the bound meets the tolerance."""
        good = self.in_validated_range and self.meets_tolerance
        message = (f"{self.model} at {self.pressure_pa:.0f} Pa, {self.message}" +
                   ("" if self.in_validated_range else "; outside the validated range") +
                   ("" if self.meets_tolerance else
                    f"; error bound {1e3 * self.bound_m:.2f} mm exceeds the tolerance"))
        return Report(
            Health.OK if good else Health.WARN, message, {
                "model_fidelity": self.model, "scene_class": self.scene_class,
                "error_bound_m": f"{self.bound_m:.3g}", "pressure_in_validated_range": bool(
                    self.in_validated_range), "contact_force_n": f"{self.contact_force_n:.3f}",
                "l2_solves": l2_solves
            })


class _RodSolve(typing.NamedTuple):
    scene: Scene
    pressure_pa: float
    solution: object  # RodSolution
    tip: tuple  # the solution's tip as floats
    tip_slope: tuple
    time_s: float  # when it was asked for (NaN: no clock given)


class SceneModel:
    """Evaluate the chosen model. An L2 solve costs milliseconds of CPU, so for the same scene it
    runs again only when the pressure moved by more than ``resolve_pressure_pa`` and, when the
    caller gives times, at most once per ``min_solve_interval_s`` (during a clamp the pressure
    sweeps tens of kPa in a fraction of a second: without the cap the solves take a whole core
    from the pressure loop and the simulated device). A new scene solves at once. A failed solve
    falls back to L1 (which ignores the object) and says so."""

    def __init__(self, fidelity: str = "auto", tolerance_m: float = 1e-2,
                 gripper_model: str = "type_II", max_pressure_pa: float = 60e3,
                 bounds: ErrorBounds | None = None, resolve_pressure_pa: float = 200.0,
                 min_solve_interval_s: float = 0.1, rod_solver=None):
        """rod_solver(pressure_pa, obstacle, from_pressure_pa) -> RodSolution; default:
        ``self.rod`` in the calling thread (see :class:`RodSolverProcess` for a process of its
        own)."""
        self.free = {m: build_kinematics(m, gripper_model, max_pressure_pa) for m in ("l0", "l1")}
        # microseconds a pose, within 0.1 um
        self.tips = {m: TipTable(k) for m, k in self.free.items()}
        l1 = self.free["l1"]
        self.rod = RodFinger(l1.geometry, l1.calibration)
        self.selector = ModelSelector(
            fidelity, tolerance_m, bounds or ErrorBounds.load(),
            (l1.contact_pressure_pa, l1.calibration.validated_max_pressure_pa))
        if not (math.isfinite(resolve_pressure_pa) and resolve_pressure_pa >= 0):
            raise ValueError(f"resolve_pressure_pa must be >= 0, got {resolve_pressure_pa}")
        if not (math.isfinite(min_solve_interval_s) and min_solve_interval_s >= 0):
            raise ValueError(f"min_solve_interval_s must be >= 0, got {min_solve_interval_s}")
        self.resolve_pressure_pa = resolve_pressure_pa
        self.min_solve_interval_s = min_solve_interval_s
        self.solves = 0
        self._descriptions = {}
        self._rod: _RodSolve | None = None
        self._rod_solver = rod_solver or (lambda pressure, obstacle, opening: self.rod.solve(
            pressure, obstacle=obstacle, from_pressure_pa=opening, steps=ROD_CONTINUATION_STEPS))

    def evaluate(self, gauge_pa: float, scene: Scene = FREE, solve: bool = True,
                 now_s: float | None = None) -> Evaluation:
        """The chosen model's pose at ``gauge_pa`` (at time ``now_s``, s, for the solve-rate cap).
        solve=False never runs an L2 solve: it uses the last one for this scene (whatever its
        pressure; see :meth:`needs_solve`), or L1 until there is one."""
        if not math.isfinite(gauge_pa):
            raise ValueError(f"gauge pressure must be finite, got {gauge_pa}")
        choice = self.selector.choose(gauge_pa, scene)
        free = self.free["l0" if choice.model == "l0" else "l1"]
        pressure = min(max(gauge_pa, free.MODEL_MIN_PRESSURE_PA), free.max_pressure_pa)
        low, high = self.selector.validated_range_pa
        validated = low <= pressure <= high
        message = self._descriptions.get(scene)
        if message is None:
            message = self._descriptions[scene] = scene.describe()
        if choice.model == "l2":
            # validated where the contact bound was measured, not free bending's range
            if scene.contact:
                contact_low, contact_high = self.selector.bounds.contact_range_pa
                validated = contact_low <= pressure <= contact_high
            if solve and self._stale(pressure, scene, now_s):
                self.solve_rod(pressure, scene, now_s)
            last = self._rod
            if last is not None and last.scene == scene and last.solution.converged:
                solution = last.solution
                return Evaluation(
                    "l2", choice.scene_class, pressure, last.tip, last.tip_slope,
                    lambda nodes=solution.nodes_m: [tuple(map(float, p)) for p in nodes],
                    validated, solution.contact_force_n, choice.bound_m, choice.meets_tolerance,
                    message + (f" (l2 at {last.pressure_pa:.0f} Pa)"
                               if last.pressure_pa != pressure else ""),
                    lambda: rod_joints(solution, free.geometry))
            reason = (f"l2 failed ({last.solution.message})"
                      if last is not None and last.scene == scene else "l2 pending")
            message = f"{reason}; l1 used, which ignores {scene.describe()}"
            choice = self.selector.choice("l1", choice.scene_class)
        tip, slope = self.tips[free.model].tip(pressure)
        free_validated = (free.contact_pressure_pa <= pressure <=
                          free.calibration.validated_max_pressure_pa)
        table = self.tips[free.model]

        def joints():
            angles, tip_spacing_m = table.shape(pressure)
            return pcc_joints(angles, free.geometry.segment_length_m), tip_spacing_m

        return Evaluation(choice.model, choice.scene_class, pressure, tip, slope,
                          lambda: [tuple(p) for p in free.backbone(pressure)], free_validated, 0.0,
                          choice.bound_m, choice.meets_tolerance, message, joints)

    def needs_solve(self, gauge_pa: float, scene: Scene, now_s: float | None = None) -> bool:
        """Whether L2 is chosen here and its last solve is for another scene, or too far in
        pressure and (given ``now_s``) at least ``min_solve_interval_s`` old."""
        return (self.selector.choose(gauge_pa, scene).model == "l2" and
                self._stale(gauge_pa, scene, now_s))

    def _stale(self, gauge_pa: float, scene: Scene, now_s: float | None) -> bool:
        last = self._rod
        if last is None or (last.scene is not scene and last.scene != scene):
            return True
        recent = now_s is not None and now_s - last.time_s < self.min_solve_interval_s
        return abs(gauge_pa - last.pressure_pa) > self.resolve_pressure_pa and not recent

    def solve_rod(self, gauge_pa: float, scene: Scene, now_s: float | None = None):
        """Solve L2 at ``gauge_pa`` (milliseconds) and keep it; callable from a worker thread. The
        tip slope comes from the previous solve of the scene when it is near, else from L1."""
        solution = self._rod_solver(gauge_pa, scene.obstacle, scene.opening_gauge_pa)
        previous = self._rod
        slope = tuple(self.free["l1"].tip_slope_at(gauge_pa))
        if (previous is not None and previous.scene == scene and previous.solution.converged and
                solution.converged and 0.0 < abs(gauge_pa - previous.pressure_pa) <=
                10 * max(self.resolve_pressure_pa, 100.0)):
            slope = tuple((a - b) / (gauge_pa - previous.pressure_pa)
                          for a, b in zip(solution.tip, previous.solution.tip))
        self._rod = _RodSolve(scene, gauge_pa, solution, tuple(float(v) for v in solution.tip),
                              slope, math.nan if now_s is None else now_s)  # one assignment
        self.solves += 1
        return solution


def rod_joints(solution, geometry) -> tuple:
    """An L2 shape as joint_states gives it: each segment's (turn, chord, turn) from the rod's
    nodes at the segment ends (exact there: :func:`kinematics.chord_joints`), and D2 from the
    chamber-side surface at the tip chamber's centre."""
    nodes = np.asarray(solution.nodes_m)
    per_segment = (len(nodes) - 1) // CHAMBER_COUNT
    element_m = geometry.segment_length_m / per_segment
    angles = geometry.inclination_rad - np.concatenate(
        [[0.0], np.cumsum(np.asarray(solution.curvatures_per_m) * element_m)])
    ends = range(0, len(nodes), per_segment)
    joints = chord_joints([(float(nodes[k][0]), float(nodes[k][1]), float(angles[k]))
                           for k in ends])
    centre = (CHAMBER_COUNT - 1) * per_segment + round(
        per_segment * 0.5 * geometry.chamber_length_m / geometry.segment_length_m)
    return joints, -2.0 * float(np.asarray(solution.surface_m)[centre][0])

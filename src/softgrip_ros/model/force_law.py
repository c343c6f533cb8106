"""The clamp force law: the normal force with which each finger presses an object, against the
chamber pressure, tabulated per object size (as the tip tables are), and the clamp pressure for a
mass that follows from it.

Two sources, by gripper model (:func:`table_source`):

* **The 3-D FE** (:mod:`softgrip_ros.model.fe3d.clamp`) for the models fitted to it
  (``type_II_fe``, ``type_II_fe_l1``): the walled finger with contact, w = 20 mm, clamping a
  rigid, fixed, frictionless sheet or cylinder (FE_FLAT_SIZES_M, FE_ROUND_SIZES_M), at
  FE_PRESSURES_PA. Newton stops near -35 kPa, where the cavities collapse; below the lowest
  pressure a sweep reached, the row holds its last force (no force is credited that the FE did
  not compute). The finger cannot open around a cylinder wider than about 15 mm: NaN there.
* **The L2 rod** (:class:`~softgrip_ros.model.rod.RodFinger`, 32 elements per segment,
  frictionless) for the paper's cavity types and users' calibrations, whose bending the FE does
  not reproduce. Its assumptions are the rod's: the finger's width (20 mm), its bending stiffness
  from the same wall-stretch chain as the bending law (EI = 16 C10 t w d^2 / g), no ballooning of
  the faces in contact, a rigid object fixed in place. It presses about nine times what the FE
  does on the same sheet (docs/model_validation.md).

Two kinds of object, as the grasp manager plans them:

* ``ROUND``: a cylinder of diameter d on the centre line, level with the tip chambers when the
  fingers are opened to clear it (D2 = d + 10 mm, plus the grasp's 1.5 kPa pressure tolerance:
  the grasp manager's defaults), then clamped (ENVELOP_CLAMP, CLAMP, a gripper goal's close);
* ``FLAT``: a sheet of thickness t on the centre line, pinched from the rest (PINCH).

F_n is the sum of the magnitudes of each finger's contact forces (what friction can use), made
non-decreasing as the pressure falls. Where the fingers cannot reach an object (wider than they
open) the table holds NaN.

**The clamp.** Two fingers hold a weight by friction when 2 mu F_n >= SF m g; the clamp pressure
for a mass is where the table's F_n(p) reaches SF m g / (2 mu), at least ``min_squeeze_pa`` below
the contact. Beyond the table's lowest pressure the law follows its last cell (flat for the FE's
tables) and says so; the grasp manager refuses pressures below its limit.

The tables of the built-in gripper models are in ``config/clamp_force/`` (written by
``scripts/build_force_tables.py``; tests check their inputs hash against the code and the
models); a user's calibration gets its rod table computed on first use, coarser (``USER_*``), and
cached beside it.
"""
from __future__ import annotations

import dataclasses
import enum
import hashlib
import json
import logging
import math
import pathlib

import numpy as np
import yaml

from softgrip_ros.fileio import write_text_atomically
from softgrip_ros.settings import check_settings, setting

LOG = logging.getLogger(__name__)
G_M_PER_S2 = 9.80665
TABLE_DIR = "clamp_force"
# bump when the table's computation changes its numbers
FORCE_TABLE_VERSION = 1
PRESSURES_PA = tuple(np.arange(-100e3, 50e3 + 1.0, 2.5e3))
ROUND_SIZES_M = (0.002, 0.005, 0.01, 0.015, 0.02, 0.03, 0.04, 0.05, 0.06, 0.07, 0.08, 0.1, 0.12)
FLAT_SIZES_M = (1e-4, 5e-4, 0.001, 0.002, 0.003, 0.005, 0.01, 0.02)
ROD_ELEMENTS = 32
# a user's calibration gets its table at first use, coarser, so that a node starts in seconds:
# 8 elements per segment (L2's default) and 5 kPa steps (about 7 s here)
USER_ROD_ELEMENTS = 8
USER_PRESSURES_PA = tuple(np.arange(-100e3, 50e3 + 1.0, 5e3))
# the grasp manager's defaults, which place a round object (see the module docstring)
ENVELOP_MARGIN_M = 0.01
PRESSURE_TOLERANCE_PA = 1.5e3


# the FE's tables (the module docstring): the objects it clamps and its pressures
FE_TABLE_VERSION = 1
FE_ROUND_SIZES_M = (0.005, 0.010, 0.015)
FE_FLAT_SIZES_M = (1e-4, 0.002, 0.005, 0.010)
FE_PRESSURES_PA = tuple(np.arange(-60e3, 50e3 + 1.0, 5e3))


def mass_held_kg(force_n: float, friction_coefficient: float,
                 safety_factor: float = 1.0) -> float:
    """The mass two fingers hold by friction, each pressing ``force_n`` N: 2 mu F_n / (SF g)."""
    return 2.0 * friction_coefficient * force_n / (safety_factor * G_M_PER_S2)


class ObjectKind(enum.Enum):
    ROUND = "round"
    FLAT = "flat"


class TableSource(enum.Enum):
    ROD = "rod"  # the L2 rod
    FE3D = "fe3d"  # the 3-D FE with contact


def table_source(gripper_model: str) -> TableSource:
    """Where a gripper model's table comes from: the FE for the models fitted to it."""
    from softgrip_ros.model.fe_data import FE_CALIBRATION_NAMES
    return (TableSource.FE3D if gripper_model in FE_CALIBRATION_NAMES.values()
            else TableSource.ROD)


@dataclasses.dataclass(frozen=True)
class ForceTable:
    """F_n per finger (N) on a grid: ``forces_n[kind]`` has shape (sizes, pressures)."""

    gripper_model: str
    bending: str
    finger_width_m: float
    pressures_pa: np.ndarray
    sizes_m: dict
    forces_n: dict
    inputs_hash: str
    source: TableSource = TableSource.ROD

    def normal_force_n(self, pressure_pa: float, size_m: float, kind: ObjectKind) -> float:
        """F_n at ``pressure_pa`` for an object ``size_m`` across (linear in both; NaN beyond the
        sizes the fingers reach; below the lowest pressure, along the last cell)."""
        row = self._row(size_m, kind)
        p = self.pressures_pa
        if pressure_pa < p[0]:
            slope = (row[1] - row[0]) / (p[1] - p[0])
            return float(row[0] + slope * (pressure_pa - p[0]))
        return float(np.interp(pressure_pa, p, row))

    def contact_pressure_pa(self, size_m: float, kind: ObjectKind) -> float:
        """The highest pressure at which the fingers press the object (F_n > 0): the last
        pressing cell's line followed to F_n = 0, within the cell after it (the force has a kink
        at the contact, which no interpolation across it finds); NaN when the fingers never reach
        it."""
        row = self._row(size_m, kind)
        if not np.isfinite(row).all():
            return math.nan
        touching = np.flatnonzero(row > 0.0)
        if touching.size == 0:
            return math.nan
        last = touching[-1]
        p = self.pressures_pa
        if last + 1 >= len(row):
            return float(p[-1])
        if last == 0 or row[last - 1] <= row[last]:
            return float(p[last + 1])
        reach = row[last] * (p[last] - p[last - 1]) / (row[last - 1] - row[last])
        return float(min(p[last] + reach, p[last + 1]))

    def pressure_for_force(self, force_n: float, size_m: float, kind: ObjectKind) -> float:
        """The highest pressure at which F_n reaches ``force_n`` (below the table along its last
        cell); NaN when the fingers never reach the object."""
        row = self._row(size_m, kind)
        if not np.isfinite(row).all():
            return math.nan
        p = self.pressures_pa
        # F_n(p) falls with p; the first node from the top at or above the force
        enough = np.flatnonzero(row >= force_n)
        if enough.size == 0:
            slope = (row[1] - row[0]) / (p[1] - p[0])
            return float(p[0] + (force_n - row[0]) / slope) if slope < 0.0 else -math.inf
        k = enough[-1]
        if k + 1 >= len(row):
            return float(p[-1])
        return float(p[k] + (p[k + 1] - p[k]) * (row[k] - force_n) / (row[k] - row[k + 1]))

    def _row(self, size_m: float, kind: ObjectKind) -> np.ndarray:
        if not (math.isfinite(size_m) and size_m >= 0.0):
            raise ValueError(f"object size must be finite and >= 0, got {size_m}")
        sizes, forces = self.sizes_m[kind], self.forces_n[kind]
        if size_m > sizes[-1]:
            return np.full(len(self.pressures_pa), math.nan)
        if size_m <= sizes[0]:
            return forces[0]
        k = int(np.searchsorted(sizes, size_m)) - 1
        t = (size_m - sizes[k]) / (sizes[k + 1] - sizes[k])
        return (1.0 - t) * forces[k] + t * forces[k + 1]

    def most_force_n(self, size_m: float, kind: ObjectKind, min_pressure_pa: float) -> float:
        return self.normal_force_n(min_pressure_pa, size_m, kind)


# ---- the computation ---------------------------------------------------------------------------
def inputs_hash(geometry, calibration, bending: str, finger_width_m: float,
                elements: int = ROD_ELEMENTS, pressures_pa=PRESSURES_PA) -> str:
    """What a table depends on: the model, the law, the width, the grid, the rod's resolution and
    this code's version."""
    document = {"geometry": dataclasses.asdict(geometry),
                "calibration": {k: repr(v) for k, v in dataclasses.asdict(calibration).items()},
                "bending": bending, "width": finger_width_m, "version": FORCE_TABLE_VERSION,
                "pressures": [float(p) for p in pressures_pa], "round": ROUND_SIZES_M,
                "flat": FLAT_SIZES_M, "elements": elements}
    text = json.dumps(document, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def fe_inputs_hash(geometry) -> str:
    """What an FE table depends on that is known without the FE library: the geometry, the grid
    and this code's version (tests check the FE sweeps' own input hashes, recorded in the
    table's file, against the FE code)."""
    document = {"geometry": dataclasses.asdict(geometry), "version": FE_TABLE_VERSION,
                "pressures": [float(p) for p in FE_PRESSURES_PA], "round": FE_ROUND_SIZES_M,
                "flat": FE_FLAT_SIZES_M, "source": TableSource.FE3D.value}
    text = json.dumps(document, sort_keys=True, default=str)
    return "fe3d-" + hashlib.sha256(text.encode()).hexdigest()[:16]


def fe_row(sweep, pressures_pa) -> tuple:
    """One table row from an FE clamp sweep (:class:`~softgrip_ros.model.fe3d.clamp.
    FE3DClampSweep`): (F_n per pressure, the lowest pressure solved). 0 above the pressure the
    finger was opened to, the sweep's F_n down to its lowest state, that state's F_n below it;
    all NaN when the finger could not open clear of the object."""
    pressures = np.asarray(pressures_pa, dtype=float)
    if not sweep.states:
        return np.full(len(pressures), math.nan), math.nan
    lowest = sweep.states[-1]
    row = np.array([0.0 if p > sweep.opening_pa + 1e-6 else
                    lowest.normal_force_n if p < lowest.pressure_pa - 1e-6 else
                    sweep.normal_force_n(p) for p in pressures])
    return _credited_as_growing(row), lowest.pressure_pa


def compute_fe_table(gripper_model: str, bending: str, progress=print) -> tuple:
    """The FE's table of ``gripper_model`` (a model fitted to the FE): (ForceTable, a list of
    the sweeps it read, each {kind, size_m, inputs_hash, opening_pa, lowest_solved_pa, stop}).
    Runs each clamp sweep (minutes each) unless it is cached; needs the FE extra."""
    from softgrip_ros.model.fe3d.clamp import clamp_sweep
    from softgrip_ros.model.fe3d.finger import DEFAULT_WIDTH_M
    from softgrip_ros.model.fe_data import FE_GEOMETRY_NAME
    from softgrip_ros.model.geometry import load_geometry

    if table_source(gripper_model) is not TableSource.FE3D:
        raise ValueError(f"{gripper_model} is not fitted to the FE: its table is the rod's")
    # the FE's clamp sweeps run on the geometry the FE truth was computed on
    geometry = load_geometry(FE_GEOMETRY_NAME)
    forces, sweeps = {}, []
    for kind, sizes in ((ObjectKind.ROUND, FE_ROUND_SIZES_M), (ObjectKind.FLAT, FE_FLAT_SIZES_M)):
        rows = []
        for size in sizes:
            sweep = clamp_sweep(geometry, kind, size, DEFAULT_WIDTH_M, progress=progress)
            row, lowest = fe_row(sweep, FE_PRESSURES_PA)
            rows.append(row)
            sweeps.append({"kind": kind.value, "size_m": size, "inputs_hash": sweep.inputs_hash,
                           "opening_pa": sweep.opening_pa, "lowest_solved_pa": lowest,
                           "stop": sweep.stop})
        forces[kind] = np.array(rows)
    table = ForceTable(gripper_model, bending, DEFAULT_WIDTH_M, np.array(FE_PRESSURES_PA),
                       {ObjectKind.ROUND: np.array(FE_ROUND_SIZES_M),
                        ObjectKind.FLAT: np.array(FE_FLAT_SIZES_M)},
                       forces, fe_inputs_hash(geometry), TableSource.FE3D)
    return table, sweeps


def compute_table(gripper_model: str, bending: str, elements: int = ROD_ELEMENTS,
                  pressures_pa=PRESSURES_PA, progress=None) -> ForceTable:
    """The table of ``gripper_model`` under its ``bending`` law, solved by the L2 rod;
    ``progress(done, total)`` after each object size."""
    from softgrip_ros.model import gripper_models
    from softgrip_ros.model.fidelity import cylinder_scene
    from softgrip_ros.model.kinematics import GripperKinematics
    from softgrip_ros.model.rod import RodFinger, Sheet

    geometry, calibration = gripper_models.resolve(gripper_model)
    rod = RodFinger(geometry, calibration, bending=bending, elements_per_segment=elements)
    kinematics = GripperKinematics(geometry, calibration, model=bending)
    _, widest = kinematics.tip_spacing_range_m()
    pressures = np.asarray(pressures_pa, dtype=float)
    forces = {kind: [] for kind in ObjectKind}
    total, done = len(ROUND_SIZES_M) + len(FLAT_SIZES_M), 0
    for size in ROUND_SIZES_M:
        row = np.full(len(pressures), math.nan)
        if size + ENVELOP_MARGIN_M <= widest:
            opening = min(kinematics.pressure_for_tip_spacing(size + ENVELOP_MARGIN_M) +
                          PRESSURE_TOLERANCE_PA, kinematics.max_pressure_pa)
            circle = cylinder_scene(rod, size, opening).obstacle
            row = _solve_row(rod, circle, pressures, opening)
        forces[ObjectKind.ROUND].append(row)
        done += 1
        if progress:
            progress(done, total)
    for size in FLAT_SIZES_M:
        opening = max(2e3, kinematics.pressure_for_tip_spacing(size + 1e-3))
        forces[ObjectKind.FLAT].append(_solve_row(rod, Sheet(size), pressures, opening))
        done += 1
        if progress:
            progress(done, total)
    return ForceTable(gripper_model, bending, rod.finger_width_m, pressures,
                      {ObjectKind.ROUND: np.array(ROUND_SIZES_M),
                       ObjectKind.FLAT: np.array(FLAT_SIZES_M)},
                      {kind: np.array(rows) for kind, rows in forces.items()},
                      inputs_hash(geometry, calibration, bending, rod.finger_width_m, elements,
                                  pressures))


def _solve_row(rod, obstacle, pressures: np.ndarray, opening_pa: float) -> np.ndarray:
    """F_n at each pressure, the fingers opened to ``opening_pa`` first; 0 above the contact,
    NaN where the rod cannot solve (the object in the way of the opened fingers)."""
    row = np.zeros(len(pressures))
    for k, pressure in enumerate(pressures):
        solution = rod.solve(float(pressure), obstacle, from_pressure_pa=opening_pa, steps=8)
        if not solution.converged:
            if "overlaps" in solution.message:
                return np.full(len(pressures), math.nan)
            raise RuntimeError(f"the L2 rod did not converge at {pressure:.0f} Pa on "
                               f"{obstacle}: {solution.message}")
        row[k] = float(solution.contact_forces_n.sum())
    return _credited_as_growing(row)


def _credited_as_growing(row: np.ndarray) -> np.ndarray:
    """``row`` (ascending pressures) made non-increasing in p: as the pressure falls no less
    force is credited than at any higher pressure (a solver's rounding, or a contact that moves,
    aside; the law's inverse needs it)."""
    return np.maximum.accumulate(row[::-1])[::-1]


# ---- files -------------------------------------------------------------------------------------
def table_file_name(gripper_model: str, bending: str) -> str:
    return f"{gripper_model}.{bending}.yaml"


def write_table(table: ForceTable, path, provenance: dict, fe_sweeps=None) -> pathlib.Path:
    """Write ``table`` atomically; ``fe_sweeps``: an FE table's sweeps (compute_fe_table)."""
    path = pathlib.Path(path)
    document = {
        "format": "softgrip_clamp_force/1",
        "provenance": provenance,
        "source": table.source.value,
        "gripper_model": table.gripper_model, "bending": table.bending,
        "finger_width_m": table.finger_width_m, "inputs_hash": table.inputs_hash,
        "pressures_pa": [float(p) for p in table.pressures_pa],
    }
    for kind in ObjectKind:
        document[kind.value] = {
            "sizes_m": [float(s) for s in table.sizes_m[kind]],
            "normal_force_n": [[None if not math.isfinite(v) else round(float(v), 6) for v in row]
                               for row in table.forces_n[kind]]}
    if fe_sweeps is not None:
        document["fe_sweeps"] = [{k: (float(v) if isinstance(v, float) else v)
                                  for k, v in sweep.items()} for sweep in fe_sweeps]
    return write_text_atomically(
        path, "# The clamp force law of one gripper model: each finger's normal force (N) "
              "against the pressure, per object size. Written by softgrip_ros.model.force_law; "
              "do not edit.\n" + yaml.safe_dump(document, sort_keys=False,
                                                default_flow_style=None, width=100000))


def read_table(path) -> ForceTable:
    path = pathlib.Path(path)
    try:
        document = yaml.load(path.read_text(), Loader=getattr(yaml, "CSafeLoader",
                                                                yaml.SafeLoader))
        forces, sizes = {}, {}
        for kind in ObjectKind:
            sizes[kind] = np.array(document[kind.value]["sizes_m"], dtype=float)
            forces[kind] = np.array([[math.nan if v is None else v for v in row]
                                     for row in document[kind.value]["normal_force_n"]],
                                    dtype=float)
        return ForceTable(document["gripper_model"], document["bending"],
                          float(document["finger_width_m"]),
                          np.array(document["pressures_pa"], dtype=float), sizes, forces,
                          str(document["inputs_hash"]),
                          TableSource(document.get("source", TableSource.ROD.value)))
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as error:
        raise ValueError(f"{path}: not a clamp force table: {error}") from None


def load_table(gripper_model: str, bending: str, compute_if_missing: bool = True) -> ForceTable:
    """The table of a gripper model: the packaged one of a built-in type, else the one cached
    beside the user's calibration, computed (and cached) when there is none or it is stale.
    ValueError naming what is missing."""
    from softgrip_ros.config_paths import config_dir
    from softgrip_ros.model import gripper_models

    geometry, calibration = gripper_models.resolve(gripper_model)
    model_path = gripper_models.model_path(gripper_model)
    resolution = ((ROD_ELEMENTS, PRESSURES_PA) if model_path is None else
                  (USER_ROD_ELEMENTS, USER_PRESSURES_PA))
    if model_path is None and table_source(gripper_model) is TableSource.FE3D:
        from softgrip_ros.model.fe_data import FE_GEOMETRY_NAME
        from softgrip_ros.model.geometry import load_geometry
        expected = fe_inputs_hash(load_geometry(FE_GEOMETRY_NAME))
    else:
        expected = inputs_hash(geometry, calibration, bending, _default_width(), *resolution)
    name = table_file_name(pathlib.Path(gripper_model).stem, bending)
    path = (config_dir() / TABLE_DIR / name if model_path is None else
            model_path.with_name(model_path.stem + f".{bending}.clamp_force.yaml"))
    if path.is_file():
        table = read_table(path)
        if table.inputs_hash == expected:
            return table
        stale = f"{path} is stale (its model or the code changed)"
    else:
        stale = f"no table at {path}"
    if not compute_if_missing or model_path is None:
        raise ValueError(f"clamp force law of {gripper_model} ({bending}): {stale}; run "
                         "scripts/build_force_tables.py")
    LOG.warning("clamp force law of %s (%s): %s; computing it with the L2 rod (seconds, once)",
                gripper_model, bending, stale)
    table = compute_table(gripper_model, bending, *resolution)
    try:
        write_table(table, path, {"written_by": "softgrip_ros.model.force_law.load_table"})
    except OSError as error:
        LOG.warning("could not cache the clamp force table at %s: %s", path, error)
    return table


def _default_width() -> float:
    from softgrip_ros.model.rod import DEFAULT_FINGER_WIDTH_M
    return DEFAULT_FINGER_WIDTH_M


# ---- the law the grasp manager plans with -------------------------------------------------
@dataclasses.dataclass(frozen=True)
class ClampForceLaw:
    """The tabulated law with the friction and safety the plan needs.

    friction_coefficient: mu when a command gives none; safety_factor: SF (>= 1);
    min_squeeze_pa: the least squeeze below contact, even for a weightless object: 10 kPa, as the
        physics world's grasps of a 0.1 mm sheet let go at 3-5 kPa below contact (within the hold's
        pressure tolerance and the sensors' noise) and held from 10 kPa (docs/world.md).
    """

    table: ForceTable
    friction_coefficient: float = setting(0.5, "friction when a command gives none", "", 0.05,
                                          2.0)
    safety_factor: float = setting(2.0, "clamp force over what the weight needs", "", 1.0, 10.0)
    min_squeeze_pa: float = setting(
        10e3, "a clamp presses at least this far below the contact pressure, even for a "
        "weightless object", "Pa", 0.0, 50e3)

    def __post_init__(self):
        check_settings(self)

    def normal_force_n(self, pressure_pa: float, size_m: float, kind: ObjectKind) -> float:
        """F_n of one finger at ``pressure_pa`` on an object ``size_m`` across (0 before
        contact)."""
        return max(self.table.normal_force_n(pressure_pa, size_m, kind), 0.0)

    def contact_pressure_pa(self, size_m: float, kind: ObjectKind) -> float:
        return self.table.contact_pressure_pa(size_m, kind)

    def required_normal_force_n(self, mass_kg: float,
                                friction_coefficient: float | None = None) -> float:
        mu = self.friction_coefficient if friction_coefficient is None else friction_coefficient
        return self.safety_factor * mass_kg * G_M_PER_S2 / (2.0 * mu)

    def mass_held_kg(self, force_n: float, friction_coefficient: float | None = None) -> float:
        """The inverse of :meth:`required_normal_force_n`: the mass ``force_n`` per finger holds
        with this law's safety factor."""
        mu = self.friction_coefficient if friction_coefficient is None else friction_coefficient
        return mass_held_kg(force_n, mu, self.safety_factor)

    def clamp_pressure_pa(self, mass_kg: float, size_m: float, kind: ObjectKind,
                          friction_coefficient: float | None = None) -> float:
        """The gauge pressure that holds ``mass_kg`` with the safety factor (below the table:
        extrapolated; -inf when the force does not grow there)."""
        contact = self.contact_pressure_pa(size_m, kind)
        needed = self.table.pressure_for_force(
            self.required_normal_force_n(mass_kg, friction_coefficient), size_m, kind)
        return min(needed, contact - self.min_squeeze_pa)

    def pressure_for_force(self, force_n: float, size_m: float, kind: ObjectKind) -> float:
        """The pressure at which each finger presses ``force_n``, at least min_squeeze_pa below
        the contact."""
        contact = self.contact_pressure_pa(size_m, kind)
        return min(self.table.pressure_for_force(force_n, size_m, kind),
                   contact - self.min_squeeze_pa)

"""Scene files of the physics world: the object, and the moves of the arm that carries the gripper.

A scene is YAML (``config/scenes/*.yaml``), validated here with a one-line reason for the first
thing wrong. World frame: z up, the floor at z = 0; x from the left finger to the right, y along
the fingers' width. Lengths in m, masses in kg, times in s::

    format: softgrip_scene/1
    name: cylinder_40mm
    object:
      shape: cylinder          # cylinder (its axis along y) | sphere | box | sheet
      diameter_m: 0.04         # cylinder, sphere
      length_m: 0.06           # cylinder: along y
      size_m: [0.03, 0.03, 0.05]  # box: x, y, z extents; sheet: [width along y, height]
      mass_kg: 0.05
      friction: 0.5            # Coulomb, object against the fingers and the floor
      position_m: [0, 0, 0.02] # its centre at the start (default: on the floor at x = y = 0)
      fixed: false             # true: held in place (a post; the force-law checks use it)
      held_until: lift         # its weight borne (it floats where it is) until this move begins
    arm:
      start_m: [0, 0, 0.25]    # the gripper base (the frame of tip_pose) at the start
      moves:                   # named; each plays when asked (sim/arm_move), one after another
        approach: [{to_m: [0, 0, 0.115], max_speed_m_s: 0.2, accel_m_s2: 2.0}]
        lift:     [{to_m: [0, 0, 0.315], accel_m_s2: 9.81}]
        shake:    [{shake: {axis: x, accel_m_s2: 4.9, frequency_hz: 2.0, duration_s: 2.0}}]
        hold:     [{wait_s: 2.0}]

A sheet is 0.1 mm thick (its thickness is not a choice: it is the paper's pinch case); it starts
hanging between the fingertips if no position is given, held up by nothing, so its scenes start
with the fingers closing at once. A move ``to_m`` accelerates at ``accel_m_s2`` up to
``max_speed_m_s`` (no limit: a triangle), then brakes at the same rate; ``shake`` moves the base
by ``A (1 - cos(2 pi f t)) / (2 pi f)^2`` along x or y (peak acceleration A, at rest at each
period's end); ``wait_s`` holds still.
"""
from __future__ import annotations

import dataclasses
import enum
import math
import pathlib
import re


from softgrip_ros.fileio import read_yaml
FORMAT = "softgrip_scene/1"
# a move is asked for by name (sim/play_arm_move)
MOVE_NAME = re.compile(r"[A-Za-z0-9_-]+")
SHEET_THICKNESS_M = 1.0e-4
MAX_OBJECT_SIZE_M = 0.3
MAX_MASS_KG = 20.0
MAX_ACCEL_M_S2 = 100.0
MAX_SPEED_M_S = 5.0
MAX_MOVE_S = 600.0


class ObjectShape(enum.Enum):
    CYLINDER = "cylinder"
    SPHERE = "sphere"
    BOX = "box"
    SHEET = "sheet"


@dataclasses.dataclass(frozen=True)
class SceneObject:
    """The object. ``size_m``: the box's (x, y, z) extents, the cylinder's (diameter, length,
    diameter), the sphere's (d, d, d), the sheet's (0.1 mm, width, height)."""

    shape: ObjectShape
    size_m: tuple
    mass_kg: float
    friction: float
    position_m: tuple
    fixed: bool = False
    held_until: str = ""

    @property
    def grip_size_m(self) -> float:
        """Its extent across the fingers (along x): what a grasp command calls its diameter."""
        return self.size_m[0]

    @property
    def half_height_m(self) -> float:
        return 0.5 * self.size_m[2]


@dataclasses.dataclass(frozen=True)
class MoveTo:
    target_m: tuple
    accel_m_s2: float
    max_speed_m_s: float = math.inf


@dataclasses.dataclass(frozen=True)
class Shake:
    axis: int  # 0: x, 1: y
    accel_m_s2: float
    frequency_hz: float
    duration_s: float


@dataclasses.dataclass(frozen=True)
class Wait:
    duration_s: float


@dataclasses.dataclass(frozen=True)
class Scene:
    name: str
    object: SceneObject | None
    start_m: tuple
    moves: dict  # name -> tuple of MoveTo | Shake | Wait
    floor: bool = True


class SceneError(ValueError):
    """A scene file that cannot be used; the message names the file and what is wrong."""


def load_scene(path) -> Scene:
    """The scene of a YAML file; SceneError with a one-line reason."""
    path = pathlib.Path(path)
    try:
        document = read_yaml(path)
    except ValueError as error:
        raise SceneError(str(error)) from None
    try:
        return scene_from_document(document, default_name=path.stem)
    except SceneError as error:
        raise SceneError(f"{path}: {error}") from None


def scene_from_document(document, default_name: str = "scene") -> Scene:
    """The scene of a parsed document (see the module docstring); SceneError naming the field."""
    _mapping(document, "the scene")
    _known(document, {"format", "name", "object", "arm", "floor"}, "the scene")
    if document.get("format", FORMAT) != FORMAT:
        raise SceneError(f"format must be {FORMAT!r}, got {document.get('format')!r}")
    name = document.get("name", default_name)
    if not isinstance(name, str) or not name:
        raise SceneError(f"name must be a non-empty string, got {name!r}")
    floor = document.get("floor", True)
    if not isinstance(floor, bool):
        raise SceneError(f"floor must be true or false, got {floor!r}")
    obj = None if document.get("object") is None else _object(document["object"], floor)
    arm = document.get("arm") or {}
    _mapping(arm, "arm")
    _known(arm, {"start_m", "moves"}, "arm")
    start = _vector(arm.get("start_m", [0.0, 0.0, 0.25]), "arm.start_m")
    moves_doc = arm.get("moves") or {}
    _mapping(moves_doc, "arm.moves")
    moves = {}
    for move_name, steps in moves_doc.items():
        if not isinstance(move_name, str) or not MOVE_NAME.fullmatch(move_name):
            raise SceneError("arm.moves: a move's name must be letters, digits, '_' or '-', "
                             f"got {move_name!r}")
        if not isinstance(steps, list) or not steps:
            raise SceneError(f"arm.moves.{move_name} must be a non-empty list of steps")
        moves[move_name] = tuple(_step(step, f"arm.moves.{move_name}[{k}]")
                                 for k, step in enumerate(steps))
    if obj is not None and obj.held_until and obj.held_until not in moves:
        raise SceneError(f"object.held_until names the move {obj.held_until!r}, which arm.moves "
                         f"lacks (it has {sorted(moves) or 'none'})")
    return Scene(name=name, object=obj, start_m=start, moves=moves, floor=floor)


def _object(doc, floor: bool) -> SceneObject:
    _mapping(doc, "object")
    _known(doc, {"shape", "diameter_m", "length_m", "size_m", "mass_kg", "friction",
                 "position_m", "fixed", "held_until"}, "object")
    fixed = doc.get("fixed", False)
    if not isinstance(fixed, bool):
        raise SceneError(f"object.fixed must be true or false, got {fixed!r}")
    try:
        shape = ObjectShape(doc.get("shape"))
    except ValueError:
        raise SceneError(f"object.shape must be one of {[s.value for s in ObjectShape]}, got "
                         f"{doc.get('shape')!r}") from None
    if shape in (ObjectShape.CYLINDER, ObjectShape.SPHERE):
        diameter = _number(doc, "diameter_m", "object", low=1e-3, high=MAX_OBJECT_SIZE_M)
        length = (_number(doc, "length_m", "object", low=1e-3, high=MAX_OBJECT_SIZE_M,
                          default=0.06) if shape == ObjectShape.CYLINDER else diameter)
        size = (diameter, length, diameter)
        _unused(doc, ("size_m",) + (("length_m",) if shape == ObjectShape.SPHERE else ()), shape)
    elif shape == ObjectShape.BOX:
        size = _vector(doc.get("size_m"), "object.size_m", low=1e-3, high=MAX_OBJECT_SIZE_M)
        _unused(doc, ("diameter_m", "length_m"), shape)
    else:
        extents = doc.get("size_m", [0.06, 0.08])
        if not (isinstance(extents, list) and len(extents) == 2):
            raise SceneError(f"object.size_m of a sheet is [width, height], got {extents!r}")
        width, height = (_checked(v, f"object.size_m[{k}]", 5e-3, MAX_OBJECT_SIZE_M)
                         for k, v in enumerate(extents))
        size = (SHEET_THICKNESS_M, width, height)
        _unused(doc, ("diameter_m", "length_m"), shape)
    mass = _number(doc, "mass_kg", "object", low=1e-4, high=MAX_MASS_KG)
    friction = _number(doc, "friction", "object", low=0.01, high=3.0)
    default_z = 0.5 * size[2] if floor else 0.1
    position = _vector(doc.get("position_m", [0.0, 0.0, default_z]), "object.position_m")
    if floor and position[2] - 0.5 * size[2] < -1e-9:
        depth_mm = 1e3 * (0.5 * size[2] - position[2])
        raise SceneError(f"object.position_m puts the object {depth_mm:.1f} mm into the floor")
    held_until = doc.get("held_until", "")
    if not isinstance(held_until, str):
        raise SceneError(f"object.held_until must name an arm move, got {held_until!r}")
    if held_until and fixed:
        raise SceneError("object: a fixed object is never let go: held_until does not apply")
    return SceneObject(shape, tuple(float(v) for v in size), mass, friction, position, fixed,
                       held_until)


def _step(doc, where: str):
    _mapping(doc, where)
    kinds = [k for k in ("to_m", "shake", "wait_s") if k in doc]
    if len(kinds) != 1:
        raise SceneError(f"{where} needs exactly one of to_m, shake, wait_s, got {sorted(doc)}")
    if kinds[0] == "wait_s":
        _known(doc, {"wait_s"}, where)
        return Wait(_number(doc, "wait_s", where, low=0.0, high=MAX_MOVE_S))
    if kinds[0] == "to_m":
        _known(doc, {"to_m", "accel_m_s2", "max_speed_m_s"}, where)
        return MoveTo(_vector(doc["to_m"], f"{where}.to_m"),
                      _number(doc, "accel_m_s2", where, low=1e-3, high=MAX_ACCEL_M_S2),
                      _number(doc, "max_speed_m_s", where, low=1e-3, high=MAX_SPEED_M_S,
                              default=math.inf))
    _known(doc, {"shake"}, where)
    shake = doc["shake"]
    _mapping(shake, f"{where}.shake")
    _known(shake, {"axis", "accel_m_s2", "frequency_hz", "duration_s"}, f"{where}.shake")
    axis = shake.get("axis", "x")
    if axis not in ("x", "y"):
        raise SceneError(f"{where}.shake.axis must be x or y, got {axis!r}")
    frequency = _number(shake, "frequency_hz", f"{where}.shake", low=0.1, high=50.0, default=2.0)
    duration = _number(shake, "duration_s", f"{where}.shake", low=0.0, high=MAX_MOVE_S)
    periods = duration * frequency
    if abs(periods - round(periods)) > 1e-6:
        raise SceneError(f"{where}.shake lasts {periods:g} periods: a shake ends at rest only "
                         "after whole periods (duration_s x frequency_hz an integer)")
    return Shake("xy".index(axis), _number(shake, "accel_m_s2", f"{where}.shake", low=0.0,
                                           high=MAX_ACCEL_M_S2), frequency, duration)


def _mapping(doc, where: str) -> None:
    if not isinstance(doc, dict):
        raise SceneError(f"{where} must be a mapping, got {type(doc).__name__}")


def _known(doc: dict, known: set, where: str) -> None:
    unknown = sorted(set(doc) - known, key=str)
    if unknown:
        raise SceneError(f"{where}: unknown field {unknown[0]!r}; known: {sorted(known)}")


def _unused(doc: dict, fields, shape: ObjectShape) -> None:
    for field in fields:
        if field in doc:
            raise SceneError(f"object: {field} does not apply to a {shape.value}")


def _checked(value, where: str, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SceneError(f"{where} must be a number, got {value!r}")
    if not (math.isfinite(value) and low <= value <= high):
        raise SceneError(f"{where} must lie in [{low:g}, {high:g}], got {value!r}")
    return float(value)


def _number(doc: dict, key: str, where: str, low: float, high: float, default=None) -> float:
    if key not in doc:
        if default is None:
            raise SceneError(f"{where}.{key} is missing")
        return default
    return _checked(doc[key], f"{where}.{key}", low, high)


def _vector(value, where: str, low: float = -10.0, high: float = 10.0) -> tuple:
    if not (isinstance(value, list) and len(value) == 3):
        raise SceneError(f"{where} must be a list of 3 numbers, got {value!r}")
    return tuple(_checked(v, f"{where}[{k}]", low, high) for k, v in enumerate(value))

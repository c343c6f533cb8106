"""Finger geometry of the two-finger gripper (paper Table 1), loaded from YAML and validated.

The planar frame of both fingers: origin at the centre of the gripper base, x from the
left finger towards the right finger, z along the approach direction (towards the tips).
The left finger's backbone (its outer, strain-limiting side) starts at (-root_x, 0),
runs straight along +z for h1, then turns ``inclination`` towards the centre line and
runs h2 straight, five bending segments (a chamber of length L3 plus the gap h3
after it) and a rigid tip. The chamber faces lie on the inner side, at
``d2 + m_i`` from the backbone. The right finger is the mirror image (x -> -x).
"""
from __future__ import annotations

import dataclasses
import math
import pathlib


from softgrip_ros.fileio import read_yaml
CHAMBER_COUNT = 5
# h1 + L2 cos(theta0) and Table 1's L1 agree to 0.1 mm; allow for rounding in the table.
TOTAL_LENGTH_TOLERANCE_M = 0.002
# no length of a hand-sized soft finger comes near this: a larger one is a typo or a unit slip
MAX_LENGTH_M = 1.0


@dataclasses.dataclass(frozen=True)
class FingerGeometry:
    """One finger and the two-finger layout. Lengths in m, angles in rad."""

    vertical_height_m: float
    inclined_length_m: float
    total_length_m: float
    inclination_rad: float
    chamber_length_m: float
    first_chamber_offset_m: float
    chamber_spacing_m: float
    wall_thickness_m: float
    chamber_depths_m: tuple
    chamber_bottom_to_sidewall_m: float
    root_width_m: float
    terminal_width_m: float
    tip_gap_m: float
    initial_included_angle_rad: float
    name: str = "type_II"

    def __post_init__(self):
        positive = ("vertical_height_m", "inclined_length_m", "total_length_m", "chamber_length_m",
                    "chamber_spacing_m", "wall_thickness_m", "chamber_bottom_to_sidewall_m",
                    "root_width_m", "terminal_width_m")
        for field in positive:
            value = getattr(self, field)
            if not isinstance(value, (int, float)) or not (0.0 < value <= MAX_LENGTH_M):
                raise ValueError(
                    f"geometry {self.name}: {field} must lie in (0, {MAX_LENGTH_M:g}] m, got "
                    f"{value!r}")
        for field in ("first_chamber_offset_m", "tip_gap_m"):
            value = getattr(self, field)
            if not 0.0 <= value <= MAX_LENGTH_M:
                raise ValueError(f"geometry {self.name}: {field} must lie in [0, "
                                 f"{MAX_LENGTH_M:g}] m, got {value!r}")
        if not 0.0 <= self.inclination_rad < math.pi / 2:
            raise ValueError(f"geometry {self.name}: inclination must lie in [0, 90) deg, "
                             f"got {math.degrees(self.inclination_rad)}")
        if not math.isfinite(self.initial_included_angle_rad):
            raise ValueError(f"geometry {self.name}: initial_included_angle must be finite")
        depths = tuple(self.chamber_depths_m)
        if len(depths) != CHAMBER_COUNT:
            raise ValueError(
                f"geometry {self.name}: chamber_depths_m needs {CHAMBER_COUNT} depths "
                f"(root to tip), got {len(depths)}")
        for index, depth in enumerate(depths, start=1):
            if not 2.0 * self.wall_thickness_m < depth <= MAX_LENGTH_M:
                raise ValueError(
                    f"geometry {self.name}: chamber {index} depth {depth} m must exceed "
                    f"two wall thicknesses ({2 * self.wall_thickness_m} m) and stay within "
                    f"{MAX_LENGTH_M:g} m")
        object.__setattr__(self, "chamber_depths_m", depths)
        if self.tip_length_m < 0.0:
            raise ValueError(
                f"geometry {self.name}: the chambers "
                f"({self.first_chamber_offset_m + CHAMBER_COUNT * self.segment_length_m:.4f} m) "
                f"do not fit on the inclined part ({self.inclined_length_m} m)")
        height = self.vertical_height_m + self.inclined_length_m * math.cos(self.inclination_rad)
        if abs(height - self.total_length_m) > TOTAL_LENGTH_TOLERANCE_M:
            raise ValueError(
                f"geometry {self.name}: h1 + L2 cos(inclination) = {height:.4f} m disagrees "
                f"with total_length_m = {self.total_length_m} m")
        if self.root_x_m <= 0.0:
            raise ValueError(
                f"geometry {self.name}: the tip gap and chamber depths put the finger root "
                f"on the wrong side of the centre line")

    @property
    def segment_length_m(self) -> float:
        """Arc length of one bending segment: a chamber and the gap after it (L3 + h3)."""
        return self.chamber_length_m + self.chamber_spacing_m

    @property
    def tip_length_m(self) -> float:
        """Rigid tip after the last segment."""
        return (self.inclined_length_m - self.first_chamber_offset_m -
                CHAMBER_COUNT * self.segment_length_m)

    def chamber_face_offset_m(self, index: int) -> float:
        """Distance from the backbone to chamber ``index``'s face (d2 + m_i), at rest."""
        return self.chamber_bottom_to_sidewall_m + self.chamber_depths_m[index]

    def dome_radius_m(self, index: int) -> float:
        """Radius of chamber ``index``'s rounded face (m): half its length or depth, whichever is
        smaller. The faces are tilted by the inclination, so flat ones would cross the centre
        line at rest where Table 1 puts their middles v/2 from it; the contact models (L2, the
        physics world) round them."""
        return 0.5 * min(self.chamber_length_m, self.chamber_depths_m[index])

    def chamber_surface_offset_m(self, index: int, along_m: float) -> float:
        """Distance from the backbone to chamber ``index``'s outer surface at ``along_m`` from the
        face's middle along the finger (m): a block d2 + m_i - r_i high crowned by a dome of
        radius r_i (:meth:`dome_radius_m`) whose crest is the face, d2 + m_i from the backbone;
        the base layer, d2, beyond the chamber's length."""
        if abs(along_m) > 0.5 * self.chamber_length_m + 1e-12:
            return self.chamber_bottom_to_sidewall_m
        radius = self.dome_radius_m(index)
        crown = self.chamber_face_offset_m(index) - radius
        return crown + math.sqrt(max(radius * radius - along_m * along_m, 0.0))

    @property
    def root_x_m(self) -> float:
        """|x| of each finger's backbone root, fixed by the tip gap v between the tip-chamber
        faces."""
        arc_to_tip_chamber = (self.first_chamber_offset_m +
                              (CHAMBER_COUNT - 1) * self.segment_length_m +
                              0.5 * self.chamber_length_m)
        face_x_from_root = (
            arc_to_tip_chamber * math.sin(self.inclination_rad) +
            self.chamber_face_offset_m(CHAMBER_COUNT - 1) * math.cos(self.inclination_rad))
        return face_x_from_root + 0.5 * self.tip_gap_m


def default_geometry_path() -> pathlib.Path:
    from softgrip_ros.config_paths import config_file

    return config_file("gripper_geometry.yaml")


def load_geometry(cavity_type: str | None = None, path=None) -> FingerGeometry:
    """One finger type (default: the file's ``default_type``) from a geometry YAML: the format
    of config/gripper_geometry.yaml (``types``, each maybe ``based_on`` another), or a user's
    file holding one finger's fields at its top level. ValueError naming what is wrong."""
    path = pathlib.Path(path) if path is not None else default_geometry_path()
    document = read_yaml(path)
    if not isinstance(document, dict):
        raise ValueError(f"{path}: expected a mapping of geometry fields or a 'types' section")
    if "types" not in document:
        return geometry_from_fields(document, cavity_type or path.stem, path)
    types = document["types"]
    if not isinstance(types, dict):
        raise ValueError(f"{path}: 'types' must map type names to their fields")
    cavity_type = cavity_type or document.get("default_type", "type_II")
    if cavity_type not in types:
        raise ValueError(f"{path}: unknown cavity type {cavity_type!r}; known: {sorted(types)}")
    return geometry_from_fields(_resolve(types, cavity_type, path, seen=()), cavity_type, path)


def geometry_from_fields(fields: dict, name: str, path) -> FingerGeometry:
    """A FingerGeometry from the YAML fields (angles ``*_deg``); ValueError naming the field."""
    known = {f.name for f in dataclasses.fields(FingerGeometry)}
    renamed = {
        "inclination_deg": "inclination_rad",
        "initial_included_angle_deg": "initial_included_angle_rad"
    }
    values = {}
    for key, value in fields.items():
        target = renamed.get(key, key)
        if target not in known or target == "name":
            raise ValueError(f"{path}: {name}: unknown field {key!r}")
        depths = target == "chamber_depths_m"
        numbers = value if depths and isinstance(value, list) else [value]
        if (depths and not isinstance(value, list)) or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in numbers):
            raise ValueError(f"{path}: {name}: {key} must be "
                             f"{'a list of numbers' if depths else 'a number'}, got {value!r}")
        values[target] = math.radians(value) if key in renamed else value
    missing = known - set(values) - {"name"}
    if missing:
        raise ValueError(f"{path}: {name}: missing fields {sorted(missing)}")
    try:
        return FingerGeometry(name=name, **values)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None


def _resolve(types: dict, name: str, path, seen: tuple) -> dict:
    if name in seen:
        raise ValueError(f"{path}: 'based_on' loop through {' -> '.join(seen + (name,))}")
    if not isinstance(types[name] or {}, dict):
        raise ValueError(f"{path}: {name} must map field names to values, got {types[name]!r}")
    entry = dict(types[name] or {})
    base = entry.pop("based_on", None)
    if base is None:
        return entry
    if not isinstance(base, str) or base not in types:
        raise ValueError(f"{path}: {name} is based_on unknown type {base!r}")
    return {**_resolve(types, base, path, seen + (name,)), **entry}

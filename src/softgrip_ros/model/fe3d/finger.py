"""The 3-D finite-element finger: Table 1's layout with side walls and a width, pressurised, and
measured as the 2-D FE and the paper measure (alpha, D1, D2, the mean curvature, the tip pose,
the backbone), plus what only 3-D has: the chambers' volumes and the gaps between neighbouring
chamber blocks.

The profile is the 2-D FE's (:class:`~softgrip_ros.model.fe.mesh.FingerLayout`, whose docstring
states the readings of Table 1) extruded to the width ``w``. Each cavity is closed at both sides
by a side wall ``side_wall_m`` thick (Table 1's overall wall thickness m1 by default), so it is
``w - 2 m1`` wide. The finger is symmetric about its mid-plane; half of it is meshed, with a
symmetry condition there, and everything is measured on that plane.

A **plane-strain run** of the same code meshes a slab of the profile with the cavities open at
both faces and holds the out-of-plane displacement there: the limit of a very wide finger without
side walls, which the 2-D FE computes.

**Contact** (``contact=True``, the default): each block's far end wall with the next block's
near end wall, which meet under pressure; each cavity's ceiling with its floor and its far end
wall with its near one, and its side wall with the mid-plane (its mirror image), which meet under
vacuum. :meth:`Finger3D.interpenetration_m` says how deep any of them went.

Frame: s along the backbone (NGSolve's x), n from the backbone towards the chambers (y), and the
width (z), with the clamp at s = 0. Metres, Pa.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from softgrip_ros.model.fe.finger import finger_frame_to_global, heading, line_direction
from softgrip_ros.model.fe.mesh import FingerLayout
from softgrip_ros.model.fe.solver import YeohMaterial
from softgrip_ros.model.fe3d.solid import Obstacle, Solid3D
from softgrip_ros.model.geometry import CHAMBER_COUNT, FingerGeometry

# L2's width, which the project reads as the finger's until the band (fe3d_band) says otherwise
DEFAULT_WIDTH_M = 0.020
WIDTH_RANGE_M = (0.008, 0.5)
PLANE_STRAIN_SLAB_M = 1.0e-3
DEFAULT_ELEMENT_SIZE_M = 2.0e-3
ELEMENT_SIZE_RANGE_M = (0.5e-3, 6e-3)
INSET_M = 1e-7  # probe points sit this far inside the solid, so that each finds a tetrahedron
FACE_SAMPLES = 21
BACKBONE_POINTS = 47
GAP_SAMPLES = (7, 5)  # over an end wall: along n, across the half width
# the bound on how far any surface may lie inside another
MAX_INTERPENETRATION_M = 0.05e-3


@dataclasses.dataclass(frozen=True)
class Finger3DLayout:
    """The profile, the width and the side walls; ``plane_strain`` for the slab run."""

    profile: FingerLayout
    width_m: float
    side_wall_m: float
    plane_strain: bool = False

    def __post_init__(self):
        lo, hi = WIDTH_RANGE_M
        walled = not self.plane_strain
        if walled and not (math.isfinite(self.width_m) and lo <= self.width_m <= hi):
            raise ValueError(f"the finger width must lie in [{lo * 1e3:g}, {hi * 1e3:g}] mm, "
                             f"got {self.width_m * 1e3!r} mm")
        if walled and not (math.isfinite(self.side_wall_m)
                           and 0.0 < self.side_wall_m < 0.5 * self.width_m - 1e-3):
            raise ValueError(f"the side walls ({self.side_wall_m * 1e3:g} mm) must leave the "
                             f"cavities at least 2 mm of a {self.width_m * 1e3:g} mm width")

    @property
    def half_width_m(self) -> float:
        """The meshed extent across: half the finger, or the plane-strain slab."""
        return PLANE_STRAIN_SLAB_M if self.plane_strain else 0.5 * self.width_m

    def mesh(self, element_size_m: float):
        """A tetrahedral NGSolve mesh. Its boundaries: ``clamp``, ``symmetry``, ``backbone`` (the
        outer side, n = 0); per chamber block i
        ``near<i>``, ``far<i>`` (its end walls) and ``top<i>``; ``tip_top``, ``tip_end``; per
        cavity ``cavity<i>_`` + ``near``, ``far``, ``floor``, ``ceiling`` and ``side``."""
        import ngsolve as ng
        from netgen.occ import X, Y, Z, Box, OCCGeometry, Pnt

        lay, top = self.profile, self.half_width_m
        body = Box(Pnt(0.0, 0.0, 0.0), Pnt(lay.length_m, lay.base_m, top))
        body.faces.Min(Y).name = "backbone"
        tip = Box(Pnt(lay.tip_start_m, 0.0, 0.0), Pnt(lay.length_m, lay.tip_thickness_m, top))
        tip.faces.Min(Y).name = "backbone"
        tip.faces.Max(Y).name = "tip_top"
        tip.faces.Max(X).name = "tip_end"
        body = body + tip
        for index, block in enumerate(lay.blocks):
            # reaching into the base, so that the union has no coincident faces to resolve
            piece = Box(Pnt(block.s0, 0.5 * lay.base_m, 0.0), Pnt(block.s1, block.n1, top))
            piece.faces.Min(X).name = f"near{index + 1}"
            piece.faces.Max(X).name = f"far{index + 1}"
            piece.faces.Max(Y).name = f"top{index + 1}"
            body = body + piece
        inner = 2.0 * top if self.plane_strain else top - self.side_wall_m
        for index, cavity in enumerate(lay.cavities):
            hole = Box(Pnt(cavity.s0, cavity.n0, -top), Pnt(cavity.s1, cavity.n1, inner))
            for pick, wall in ((hole.faces.Min(X), "near"), (hole.faces.Max(X), "far"),
                               (hole.faces.Min(Y), "floor"), (hole.faces.Max(Y), "ceiling"),
                               (hole.faces.Max(Z), "side")):
                pick.name = f"cavity{index + 1}_{wall}"
            body = body - hole
        body.faces.Min(X).name = "clamp"
        body.faces.Min(Z).name = "symmetry"
        if self.plane_strain:
            body.faces.Max(Z).name = "symmetry"
        return ng.Mesh(OCCGeometry(body).GenerateMesh(maxh=element_size_m))


@dataclasses.dataclass
class FE3DState:
    """The measured finger at one pressure, on its mid-plane. Lengths in m, angles in rad; x, z
    as the kinematic models' frame (left finger)."""

    pressure_pa: float
    included_angle_rad: float  # alpha
    root_spacing_m: float  # D1
    tip_spacing_m: float  # D2
    mean_curvature_per_m: float
    tip: tuple  # (x, z, tangent angle from +z) of the backbone's end
    backbone_m: np.ndarray  # (K, 2)
    # per chamber: the whole finger's cavity (per metre of width in a plane-strain run)
    chamber_volumes_m3: tuple
    # between blocks i and i + 1: the least signed distance of one end wall from the other
    # (negative: they overlap; by the penalty's depth with contact, freely without)
    block_gaps_m: tuple
    volume_change: float  # the largest |deformed / reference volume - 1| of the solid's parts
    newton_iterations: int
    interpenetration_m: float = 0.0  # Finger3D.interpenetration_m (0 without contact)

    def to_dict(self) -> dict:
        """Plain floats and lists (JSON, YAML)."""
        out = dataclasses.asdict(self)
        out["backbone_m"] = [[round(float(x), 7), round(float(z), 7)] for x, z in self.backbone_m]
        for key in ("tip", "chamber_volumes_m3", "block_gaps_m"):
            out[key] = [float(v) for v in getattr(self, key)]
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "FE3DState":
        data = dict(data)
        data["backbone_m"] = np.asarray(data["backbone_m"], dtype=float)
        for key in ("tip", "chamber_volumes_m3", "block_gaps_m"):
            data[key] = tuple(data[key])
        return cls(**data)


class Finger3D:
    """The 3-D FE model of one finger of ``width_m`` on a mesh of ``element_size_m``;
    ``obstacles`` (solid.Obstacle) are rigid bodies it may press, besides its own contacts."""

    def __init__(self, geometry: FingerGeometry, width_m: float = DEFAULT_WIDTH_M,
                 material: YeohMaterial | None = None,
                 element_size_m: float = DEFAULT_ELEMENT_SIZE_M, plane_strain: bool = False,
                 side_wall_m: float | None = None, contact: bool = True, obstacles=()):
        lo, hi = ELEMENT_SIZE_RANGE_M
        if not (math.isfinite(element_size_m) and lo <= element_size_m <= hi):
            raise ValueError(f"element size must lie in [{lo * 1e3:g}, {hi * 1e3:g}] mm, got "
                             f"{element_size_m * 1e3!r} mm")
        self.geometry = geometry
        self.material = material or YeohMaterial()
        self.element_size_m = float(element_size_m)
        self.layout = Finger3DLayout(
            FingerLayout.from_geometry(geometry), float(width_m),
            geometry.wall_thickness_m if side_wall_m is None else float(side_wall_m),
            plane_strain)
        self.mesh = self.layout.mesh(element_size_m)
        self.chambers = {f"chamber_{i + 1}": f"cavity{i + 1}_.*" for i in range(CHAMBER_COUNT)}
        self.contact = bool(contact)
        self._contact_pairs = self._pairs()
        self.solid = Solid3D(self.mesh, self.material, self.chambers,
                             {"x": "clamp", "y": "clamp", "z": "clamp|symmetry"},
                             contacts=[(p.primary, p.secondary) for p in self._contact_pairs],
                             obstacles=self._obstacles() + list(obstacles))
        self._build_probes()
        self._reference_parts = [self.solid.volume_m3(False, part) for part in self._parts()]
        self._reference_chambers = [self.solid.cavity_volume_m3(name, deformed=False)
                                    for name in self.chambers]

    # ---- contact ------------------------------------------------------------------------------
    def _pairs(self):
        """The surfaces that may meet: neighbouring blocks' end walls (under pressure), and each
        cavity's ceiling with its floor and its two end walls (under vacuum)."""
        if not self.contact:
            return []
        lay, top = self.layout.profile, self.layout.half_width_m
        inner = top if self.layout.plane_strain else top - self.layout.side_wall_m
        pairs = []
        for i, (left, right) in enumerate(zip(lay.blocks, lay.blocks[1:]), start=1):
            pairs.append(_Pair(f"far{i}", f"near{i + 1}",
                               _face(0, left.s1, (lay.base_m, min(left.n1, right.n1)), (0, top))))
        for i, cavity in enumerate(lay.cavities, start=1):
            pairs.append(_Pair(f"cavity{i}_ceiling", f"cavity{i}_floor",
                               _face(1, cavity.n1, (cavity.s0, cavity.s1), (0, inner))))
            pairs.append(_Pair(f"cavity{i}_far", f"cavity{i}_near",
                               _face(0, cavity.s1, (cavity.n0, cavity.n1), (0, inner))))
        return pairs

    def _obstacles(self):
        out = []
        if self.contact and not self.layout.plane_strain:
            # a side wall pressed in by the vacuum meets its mirror image on the mid-plane
            out.append(Obstacle("mid_plane", "cavity[0-9]_side", lambda x: -x[2]))
        return out

    def interpenetration_m(self) -> float:
        """The deepest that any surface lies inside another (m; 0 if none does): every pair of
        :meth:`_pairs` sampled on a grid of its primary surface, and the side walls' depth past
        the mid-plane."""
        deepest = 0.0
        for index, pair in enumerate(self._contact_pairs):
            gaps = self.solid.contact_pair_gaps_m(index, pair.samples)
            if np.any(np.isfinite(gaps)):
                deepest = max(deepest, -float(np.nanmin(gaps)))
        for name in self.solid.obstacle_names:
            deepest = max(deepest, self.solid.obstacle_contact(name).deepest_m)
        return deepest

    @property
    def tetrahedra(self) -> int:
        return int(self.mesh.ne)

    # ---- where things are measured -----------------------------------------------------------
    def _build_probes(self):
        g, lay, eps = self.geometry, self.layout.profile, INSET_M
        groups = []
        for i in (0, CHAMBER_COUNT - 1):
            block = lay.blocks[i]
            s = np.linspace(block.s0 + eps, block.s1 - eps, FACE_SAMPLES)
            groups.append(np.column_stack([s, np.full_like(s, block.n1 - eps),
                                           np.full_like(s, eps)]))
        start = g.first_chamber_offset_m
        end = start + CHAMBER_COUNT * g.segment_length_m
        half = 0.5e-3
        groups.append(np.array([[start + eps, eps, eps], [start + half, eps, eps],
                                [end - half, eps, eps], [end, eps, eps]]))
        s = np.linspace(eps, lay.length_m - eps, BACKBONE_POINTS)
        groups.append(np.column_stack([s, np.full_like(s, eps), np.full_like(s, eps)]))
        groups.append(np.array([[lay.length_m - 2e-3, eps, eps], [lay.length_m - eps, eps, eps]]))
        n_samples, z_samples = GAP_SAMPLES
        z = np.linspace(eps, self.layout.half_width_m - eps, z_samples)
        for left, right in zip(lay.blocks, lay.blocks[1:]):
            n = np.linspace(lay.base_m + eps, min(left.n1, right.n1) - eps, n_samples)
            nn, zz = np.meshgrid(n, z, indexing="ij")
            far = np.column_stack([np.full(nn.size, left.s1 - eps), nn.ravel(), zz.ravel()])
            near = np.column_stack([np.full(nn.size, right.s0 + eps), nn.ravel(), zz.ravel()])
            groups += [far, near]
        self._groups = [len(group) for group in groups]
        self._probe_points = np.vstack(groups)

    def _parts(self):
        """Indicator coefficients of the solid's parts: the base, the tip piece and each block."""
        import ngsolve as ng

        lay = self.layout.profile

        def between(coordinate, lo, hi):
            return ng.IfPos(coordinate - lo, 1.0, 0.0) * ng.IfPos(hi - coordinate, 1.0, 0.0)

        above = ng.IfPos(ng.y - lay.base_m, 1.0, 0.0)
        parts = [1.0 - above, above * between(ng.x, lay.tip_start_m, 1.0)]
        parts += [above * between(ng.x, b.s0, b.s1) for b in lay.blocks]
        return parts

    # ---- solving and measuring ---------------------------------------------------------------
    def solve(self, pressure_pa: float, **kwargs):
        """Load every chamber to ``pressure_pa`` from the present state (Solid3D.solve's
        keywords). NotConverged leaves the model at the last pressure it reached."""
        self.solid.solve({name: float(pressure_pa) for name in self.chambers}, **kwargs)

    @property
    def pressure_pa(self) -> float:
        return next(iter(self.solid.gas_pressures.values()))

    def measure(self) -> FE3DState:
        import ngsolve as ng

        g = self.geometry
        deformed = self._probe_points + self.solid.displacement_at(self._probe_points)
        groups = np.split(deformed, np.cumsum(self._groups)[:-1])
        faces = [finger_frame_to_global(g, group[:, :2].T) for group in groups[:2]]
        curvature_points, backbone, tip_points = (finger_frame_to_global(g, group[:, :2].T)
                                                  for group in groups[2:5])
        gaps = [_signed_gap(far, near) for far, near in zip(groups[5::2], groups[6::2])]
        angles = [heading(line_direction(face)) for face in faces]
        centres = [face[:, FACE_SAMPLES // 2] for face in faces]
        root_heading = heading(curvature_points[:, 1] - curvature_points[:, 0])
        end_heading = heading(curvature_points[:, 3] - curvature_points[:, 2])
        volumes = tuple(self.whole_finger_scale * self.solid.cavity_volume_m3(name)
                        for name in self.chambers)
        with ng.TaskManager():
            parts = [self.solid.volume_m3(True, part) for part in self._parts()]
        change = max(abs(d / r - 1.0) for d, r in zip(parts, self._reference_parts))
        return FE3DState(
            pressure_pa=self.pressure_pa,
            included_angle_rad=g.initial_included_angle_rad + (angles[0] - angles[1]),
            root_spacing_m=-2.0 * float(centres[0][0]),
            tip_spacing_m=-2.0 * float(centres[1][0]),
            mean_curvature_per_m=((root_heading - end_heading)
                                  / (CHAMBER_COUNT * g.segment_length_m)),
            tip=(float(tip_points[0, 1]), float(tip_points[1, 1]),
                 heading(tip_points[:, 1] - tip_points[:, 0])),
            backbone_m=backbone.T.copy(),
            chamber_volumes_m3=volumes,
            block_gaps_m=tuple(gaps),
            volume_change=float(change),
            newton_iterations=self.solid.stats.newton_iterations,
            interpenetration_m=self.interpenetration_m() if self.contact else 0.0)

    @property
    def whole_finger_scale(self) -> float:
        """From the meshed part's volumes to the whole finger's (per metre of width for a
        plane-strain slab)."""
        return (1.0 / PLANE_STRAIN_SLAB_M) if self.layout.plane_strain else 2.0

    def reference_chamber_volumes_m3(self) -> tuple:
        return tuple(self.whole_finger_scale * v for v in self._reference_chambers)


@dataclasses.dataclass(frozen=True)
class _Pair:
    primary: str
    secondary: str
    samples: np.ndarray  # (K, 3) reference points on the primary surface


def _face(axis: int, value: float, first: tuple, second: tuple, count: int = 9) -> np.ndarray:
    """(K, 3) points on the axis-aligned rectangle where coordinate ``axis`` (0: s, 1: n) is
    ``value`` and the other in-profile coordinate spans ``first``, the width ``second``."""
    a = np.linspace(first[0] + INSET_M, first[1] - INSET_M, count)
    b = np.linspace(second[0] + INSET_M, second[1] - INSET_M, count)
    aa, bb = (g.ravel() for g in np.meshgrid(a, b, indexing="ij"))
    columns = [aa, np.full_like(aa, value)] if axis == 1 else [np.full_like(aa, value), aa]
    return np.column_stack(columns + [bb])


def _signed_gap(far_wall, near_wall) -> float:
    """The least signed distance from the points of one deformed end wall (the block before the
    gap) to the next block's deformed end wall, along that wall's normal towards the gap: both
    (K, 3) on the same (n, z) grid (GAP_SAMPLES)."""
    n_samples, z_samples = GAP_SAMPLES
    grid = near_wall.reshape(n_samples, z_samples, 3)
    along_n = np.gradient(grid, axis=0)
    across = np.gradient(grid, axis=1)
    normals = np.cross(across, along_n).reshape(-1, 3)  # (n, z) right-handed: points to -s
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    flat = grid.reshape(-1, 3)
    nearest = np.argmin(np.linalg.norm(far_wall[:, None, :] - flat[None, :, :], axis=2), axis=1)
    return float(np.min(np.einsum("ij,ij->i", far_wall - flat[nearest], normals[nearest])))

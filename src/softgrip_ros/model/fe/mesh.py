"""Triangle meshes from gmsh's OpenCASCADE kernel, as scikit-fem meshes.

gmsh is a process-wide library: every mesh is made in its own initialise/finalise session, with
gmsh's console output and its SIGINT handler off, so that Ctrl-C still reaches Python. Its
initialise also resets SIGPIPE to the default action (found when a later test's write to a closed
pipe killed pytest with no traceback), so the session puts back the signal dispositions it found.
"""
from __future__ import annotations

import contextlib
import dataclasses
import signal
import threading

import numpy as np
from skfem import MeshTri

from softgrip_ros.model.geometry import CHAMBER_COUNT, FingerGeometry


_RESTORED_SIGNALS = ("SIGPIPE", "SIGINT", "SIGTERM")


@contextlib.contextmanager
def _gmsh_session():
    import gmsh

    restorable = [getattr(signal, name) for name in _RESTORED_SIGNALS if hasattr(signal, name)]
    main_thread = threading.current_thread() is threading.main_thread()
    saved = {sig: signal.getsignal(sig) for sig in restorable} if main_thread else {}
    gmsh.initialize(interruptible=False)
    for sig, handler in saved.items():
        if handler is not None:
            signal.signal(sig, handler)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("softgrip")
        yield gmsh
    finally:
        gmsh.finalize()


def _triangulate(gmsh, size_m: float, corner_refinement: float = 1.0) -> MeshTri:
    """Mesh the model's surfaces with triangles of ``size_m``; ``corner_refinement`` > 1 makes
    them that many times smaller at every corner of the geometry, where a re-entrant corner's
    stress singularity otherwise slows the convergence of the whole solution."""
    gmsh.model.occ.synchronize()
    gmsh.option.setNumber("Mesh.MeshSizeMax", size_m)
    if corner_refinement > 1.0:
        field = gmsh.model.mesh.field
        distance = field.add("Distance")
        field.setNumbers(distance, "PointsList", [tag for _, tag in gmsh.model.getEntities(0)])
        threshold = field.add("Threshold")
        field.setNumber(threshold, "InField", distance)
        field.setNumber(threshold, "SizeMin", size_m / corner_refinement)
        field.setNumber(threshold, "SizeMax", size_m)
        field.setNumber(threshold, "DistMin", 0.5 * size_m / corner_refinement)
        field.setNumber(threshold, "DistMax", 2.0 * size_m)
        field.setAsBackgroundMesh(threshold)
        gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
        gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
    else:
        gmsh.option.setNumber("Mesh.MeshSizeMin", size_m)
    gmsh.option.setNumber("Mesh.Algorithm", 6)  # Frontal-Delaunay: well-shaped triangles
    gmsh.model.mesh.generate(2)
    tags, coords, _ = gmsh.model.mesh.getNodes()
    index = np.full(int(tags.max()) + 1, -1, dtype=np.int64)
    index[tags.astype(np.int64)] = np.arange(len(tags))
    points = coords.reshape(-1, 3)[:, :2].T
    triangles = []
    for element_type, _, nodes in zip(*gmsh.model.mesh.getElements(dim=2)):
        if element_type != 2:  # 3-node triangles only
            raise RuntimeError(f"gmsh produced element type {element_type}, not triangles")
        triangles.append(index[nodes.astype(np.int64)].reshape(-1, 3).T)
    triangles = np.hstack(triangles)
    # only the nodes the triangles use (gmsh also keeps geometry points)
    used = np.unique(triangles)
    renumber = np.full(points.shape[1], -1, dtype=np.int64)
    renumber[used] = np.arange(len(used))
    return MeshTri(points[:, used], renumber[triangles])


def quarter_annulus(inner_radius_m: float, outer_radius_m: float, size_m: float) -> MeshTri:
    """The quarter ring inner <= r <= outer, x, y >= 0 (Lamé's thick cylinder by symmetry)."""
    with _gmsh_session() as gmsh:
        occ = gmsh.model.occ
        outer = occ.addDisk(0, 0, 0, outer_radius_m, outer_radius_m)
        inner = occ.addDisk(0, 0, 0, inner_radius_m, inner_radius_m)
        box = occ.addRectangle(0, 0, 0, 2 * outer_radius_m, 2 * outer_radius_m)
        ring, _ = occ.cut([(2, outer)], [(2, inner)])
        occ.intersect(ring, [(2, box)])
        return _triangulate(gmsh, size_m)


def rectangle(length_m: float, height_m: float, size_m: float) -> MeshTri:
    with _gmsh_session() as gmsh:
        gmsh.model.occ.addRectangle(0, 0, 0, length_m, height_m)
        return _triangulate(gmsh, size_m)


CORNER_REFINEMENT = 4.0


@dataclasses.dataclass(frozen=True)
class Box:
    """An axis-aligned rectangle [s0, s1] x [n0, n1] in the finger's own frame."""

    s0: float
    s1: float
    n0: float
    n1: float

    def on_boundary(self, s, n, tolerance):
        inside = ((s >= self.s0 - tolerance) & (s <= self.s1 + tolerance) &
                  (n >= self.n0 - tolerance) & (n <= self.n1 + tolerance))
        edge = ((np.abs(s - self.s0) < tolerance) | (np.abs(s - self.s1) < tolerance) |
                (np.abs(n - self.n0) < tolerance) | (np.abs(n - self.n1) < tolerance))
        return inside & edge


@dataclasses.dataclass(frozen=True)
class FingerLayout:
    """The inclined part of one finger in its own frame: s along the backbone from the end of
    the vertical root part, n from the backbone (the outer, strain-limiting side) towards the
    other finger. Metres.

    Assumptions where Table 1 is silent (docs/model_validation.md repeats them), and why:
      * the solid base between the backbone and the chamber bottoms is d2 thick along the whole
        inclined part: Table 1's d2 is "the distance from the bottom of the air chamber to the
        sidewall", and the kinematic models put the chamber faces at d2 + m_i on the same
        reading;
      * the tip piece after the last segment is d3 (the "terminal width") thick and ends square:
        the text gives no tip shape, and the piece has no chamber, so its shape changes where
        the tip point sits, not how the finger bends;
      * chamber i is a block L3 long and m_i deep on the base; its cavity is L3 - 2 m1 long and
        m_i - m1 deep, sitting on the base, so that its end and top walls have the stated
        "overall wall thickness" m1 = 3 mm and its face is d2 + m_i from the backbone;
      * the gap after each chamber is h3 (h2 before the first), with no material above the base:
        Table 1's chamber spacings;
      * the vertical root part is held by the gripper base, so the inclined part is clamped
        across its section at s = 0: the kinematic models start bending there too, so both
        measure from the same root;
      * plane strain: the finger's out-of-plane width (not in Table 1) and its side walls do not
        enter: it is the mid-plane of a wide finger, softer than the real, walled chambers.
      * one material: the outer side limits strain by its thickness (the 13 mm base), as no
        second, stiffer layer is named.
    """

    length_m: float
    base_m: float
    tip_thickness_m: float
    tip_start_m: float
    blocks: tuple  # Box per chamber block
    cavities: tuple  # Box per cavity

    @classmethod
    def from_geometry(cls, g: FingerGeometry) -> "FingerLayout":
        wall = g.wall_thickness_m
        blocks, cavities = [], []
        for i in range(CHAMBER_COUNT):
            s0 = g.first_chamber_offset_m + i * g.segment_length_m
            depth = g.chamber_depths_m[i]
            base = g.chamber_bottom_to_sidewall_m
            blocks.append(Box(s0, s0 + g.chamber_length_m, base, base + depth))
            cavities.append(Box(s0 + wall, s0 + g.chamber_length_m - wall, base,
                                base + depth - wall))
        return cls(length_m=g.inclined_length_m, base_m=g.chamber_bottom_to_sidewall_m,
                   tip_thickness_m=g.terminal_width_m,
                   tip_start_m=g.first_chamber_offset_m + CHAMBER_COUNT * g.segment_length_m,
                   blocks=tuple(blocks), cavities=tuple(cavities))

    def mesh(self, size_m: float, corner_refinement: float = CORNER_REFINEMENT) -> MeshTri:
        with _gmsh_session() as gmsh:
            occ = gmsh.model.occ
            parts = [occ.addRectangle(0, 0, 0, self.length_m, self.base_m),
                     occ.addRectangle(self.tip_start_m, 0, 0, self.length_m - self.tip_start_m,
                                      self.tip_thickness_m)]
            parts += [occ.addRectangle(b.s0, b.n0, 0, b.s1 - b.s0, b.n1 - b.n0)
                      for b in self.blocks]
            body, _ = occ.fuse([(2, parts[0])], [(2, t) for t in parts[1:]])
            holes = [occ.addRectangle(c.s0, c.n0, 0, c.s1 - c.s0, c.n1 - c.n0)
                     for c in self.cavities]
            occ.cut(body, [(2, h) for h in holes])
            return _triangulate(gmsh, size_m, corner_refinement)

    def cavity_facets(self, mesh: MeshTri, tolerance: float = 1e-7) -> list:
        return [boundary_facets_where(mesh, lambda s, n, c=c: c.on_boundary(s, n, tolerance))
                for c in self.cavities]

    def clamp_facets(self, mesh: MeshTri, tolerance: float = 1e-7) -> np.ndarray:
        return boundary_facets_where(mesh, lambda s, n: np.abs(s) < tolerance)


def boundary_facets_where(mesh: MeshTri, predicate) -> np.ndarray:
    """The boundary facets whose midpoints (x, y) satisfy predicate(x, y)."""
    facets = mesh.boundary_facets()
    mid = mesh.p[:, mesh.facets[:, facets]].mean(axis=1)
    return facets[predicate(mid[0], mid[1])]

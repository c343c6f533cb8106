"""Checks of the FE model before it judges anything: two cases with a closed-form answer, the
mesh convergence of the finger, and its discrete incompressibility (in :class:`FEState`).

* **Planar tension** of a Yeoh block (plane strain, lambda_2 = 1/lambda): the nominal stress
  P = 2 (lambda - lambda^-3) [C10 + 2 C20 (I1 - 3)], physics.md's planar law. It checks the
  constitutive law and its tangent at large stretch.
* **Lamé's thick cylinder** under internal pressure q, plane strain, incompressible, small strain:
  u_r(r) = q a^2 b^2 / (2 mu (b^2 - a^2) r). It checks the follower pressure on a curved wall.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from softgrip_ros.model.fe.finger import FingerFE
from softgrip_ros.model.fe.mesh import boundary_facets_where, quarter_annulus, rectangle
from softgrip_ros.model.fe.solver import HyperelasticSolid, YeohMaterial
from softgrip_ros.model.geometry import FingerGeometry

PLANAR_STRETCHES = (1.25, 1.5, 2.0)
LAME_INNER_M, LAME_OUTER_M = 0.010, 0.020
LAME_PRESSURE_PA = 100.0  # small strain (u/a ~ 1e-3), where Lamé's linear answer holds


@dataclasses.dataclass
class KnownAnswer:
    name: str
    fe: list
    exact: list
    worst_error_pct: float


def planar_tension(material: YeohMaterial | None = None, element_size_m: float = 4e-3,
                   stretches=PLANAR_STRETCHES) -> KnownAnswer:
    """A 20 x 10 mm block pulled to each stretch; the reaction over the height against P."""
    material = material or YeohMaterial()
    length, height = 0.02, 0.01
    mesh = rectangle(length, height, element_size_m)
    fe, exact = [], []
    for stretch in stretches:
        solid = HyperelasticSolid(mesh, material, {})
        pulled = solid.dofs_on(boundary_facets_where(mesh, lambda x, y: np.abs(x - length) < 1e-9),
                               (0,))
        solid.fix(np.concatenate([_symmetry_dofs(solid, mesh, axis=0), pulled,
                                  _symmetry_dofs(solid, mesh, axis=1)]),
                  {int(d): (stretch - 1) * length for d in pulled})
        solid.solve({}, dirichlet_scale=1.0)
        fe.append(solid.reaction(pulled) / height)
        x = stretch**2 + stretch**-2 - 2.0
        exact.append(2.0 * (stretch - stretch**-3) * (material.c10_pa + 2.0 * material.c20_pa * x))
    return KnownAnswer("planar tension, nominal stress (Pa)", fe, exact, _worst(fe, exact))


def lame_cylinder(material: YeohMaterial | None = None,
                  element_size_m: float = 1e-3) -> KnownAnswer:
    """A quarter of the thick cylinder, symmetric on both axes; u_r at the bore and the rim."""
    material = material or YeohMaterial()
    a, b, q = LAME_INNER_M, LAME_OUTER_M, LAME_PRESSURE_PA
    mesh = quarter_annulus(a, b, element_size_m)
    bore = boundary_facets_where(mesh,
                                 lambda x, y: np.abs(np.hypot(x, y) - a) < 0.25 * element_size_m)
    solid = HyperelasticSolid(mesh, material, {"bore": bore})
    solid.fix(np.concatenate([_symmetry_dofs(solid, mesh, axis=0),
                              _symmetry_dofs(solid, mesh, axis=1)]))
    solid.solve({"bore": q})
    radius = np.hypot(*mesh.p)
    displacement = solid.nodal_displacement()
    radial = np.sum(displacement * mesh.p, axis=0) / radius
    fe, exact = [], []
    for r in (a, b):
        on = np.abs(radius - r) < 1e-9
        fe.append(float(np.mean(radial[on])))
        exact.append(q * a * a * b * b / (2.0 * material.shear_modulus_pa * (b * b - a * a) * r))
    return KnownAnswer("Lame cylinder, u_r at the bore and the rim (m)", fe, exact,
                       _worst(fe, exact))


def _symmetry_dofs(solid: HyperelasticSolid, mesh, axis: int):
    """The normal displacement dofs on the line where coordinate ``axis`` is 0 (a symmetry plane,
    or the block's held end)."""
    return solid.dofs_on(boundary_facets_where(mesh, lambda x, y: np.abs((x, y)[axis]) < 1e-9),
                         (axis,))


def _worst(fe, exact) -> float:
    return max(100.0 * abs(f / e - 1.0) for f, e in zip(fe, exact))


@dataclasses.dataclass
class MeshConvergence:
    pressure_pa: float
    element_sizes_m: list
    elements: list  # triangles (2-D) or tetrahedra (3-D) at each size
    tips_m: list  # (x, z) of the left tip at each size
    tip_displacement_m: float  # on the finest mesh, from the rest pose
    change_pct: float  # tip movement between the two finest, per tip displacement
    seconds: list


def tip_convergence(build, count, sizes_m, pressure_pa: float, progress=None,
                    element_word: str = "elements") -> MeshConvergence:
    """A finger model at one pressure on meshes of each size (coarse to fine): ``build(size_m)``
    makes the model (with ``measure()`` and ``solve(pressure_pa)``), ``count(model)`` says how
    many elements its mesh has."""
    import time
    tips, elements, seconds = [], [], []
    rest = None
    for size in sizes_m:
        started = time.perf_counter()
        finger = build(size)
        rest = finger.measure().tip
        finger.solve(pressure_pa)
        tips.append(finger.measure().tip[:2])
        elements.append(int(count(finger)))
        seconds.append(time.perf_counter() - started)
        if progress is not None:
            progress(f"mesh {size * 1e3:.2f} mm: {elements[-1]} {element_word}, tip "
                     f"({tips[-1][0] * 1e3:.3f}, {tips[-1][1] * 1e3:.3f}) mm, "
                     f"{seconds[-1]:.1f} s")
    displacement = math.hypot(tips[-1][0] - rest[0], tips[-1][1] - rest[1])
    change = math.hypot(tips[-1][0] - tips[-2][0], tips[-1][1] - tips[-2][1])
    return MeshConvergence(pressure_pa, [float(s) for s in sizes_m], elements,
                           [list(t) for t in tips], displacement,
                           100.0 * change / displacement, seconds)


def mesh_convergence(geometry: FingerGeometry, sizes_m, pressure_pa: float,
                     progress=None) -> MeshConvergence:
    """The plane-strain finger at one pressure on meshes of each size (coarse to fine)."""
    return tip_convergence(lambda size: FingerFE(geometry, element_size_m=size),
                           lambda finger: finger.mesh.t.shape[1], sizes_m, pressure_pa,
                           progress, "triangles")

"""Checks of the 3-D FE before it judges anything.

* **The plane-strain limit**: the same code on a slab with the cavities open at its faces and no
  out-of-plane displacement, against the 2-D FE (:mod:`softgrip_ros.model.fe`) at a small
  pressure, before any two walls come near: the tip's displacement and the turn of the included
  angle.
* **Lamé's thick cylinder** under internal pressure q, plane strain, incompressible, small strain:
  u_r(r) = q a^2 b^2 / (2 mu (b^2 - a^2) r). It checks the follower pressure, as an energy, on a
  curved wall of a quarter model cut by two symmetry planes.
* **Mesh convergence**: the tip at three element sizes.
* **Contact against a support**: the finger opened onto a rigid plane below its backbone; the
  plane's force on it against the clamp's reaction, along the plane's normal.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from softgrip_ros.model.fe.solver import YeohMaterial
from softgrip_ros.model.fe.verification import MeshConvergence, tip_convergence
from softgrip_ros.model.fe3d.finger import Finger3D
from softgrip_ros.model.fe3d.solid import Solid3D
from softgrip_ros.model.geometry import FingerGeometry

PLANE_STRAIN_CHECK_PA = 2e3
PLANE_STRAIN_ELEMENT_SIZE_M = 1.5e-3
LAME_INNER_M, LAME_OUTER_M, LAME_SLAB_M = 0.010, 0.020, 2e-3
LAME_PRESSURE_PA = 100.0  # small strain (u/a ~ 1e-3), where Lamé's linear answer holds


@dataclasses.dataclass
class Comparison:
    """The 3-D FE's figures against a reference's, and the worst relative error in %."""

    name: str
    fe3d: list
    reference: list
    worst_error_pct: float


def _worst(a, b) -> float:
    return max(100.0 * abs(x / y - 1.0) for x, y in zip(a, b))


def plane_strain_limit(geometry: FingerGeometry, material: YeohMaterial | None = None,
                       element_size_m: float = PLANE_STRAIN_ELEMENT_SIZE_M,
                       pressure_pa: float = PLANE_STRAIN_CHECK_PA) -> Comparison:
    """The tip's displacement (m) and the included angle's turn (rad) at ``pressure_pa``, in the
    3-D code's plane-strain run and in the 2-D FE (on its sweep mesh)."""
    from softgrip_ros.model.fe.finger import FingerFE

    figures = []
    for model in (Finger3D(geometry, material=material, element_size_m=element_size_m,
                           plane_strain=True), FingerFE(geometry, material)):
        rest = model.measure()
        model.solve(pressure_pa)
        state = model.measure()
        figures.append([math.hypot(state.tip[0] - rest.tip[0], state.tip[1] - rest.tip[1]),
                        state.included_angle_rad - rest.included_angle_rad])
    return Comparison(f"plane-strain limit at {pressure_pa / 1e3:g} kPa: tip displacement (m), "
                      "turn of alpha (rad)", figures[0], figures[1],
                      _worst(figures[0], figures[1]))


def lame_cylinder(material: YeohMaterial | None = None,
                  element_size_m: float = 2e-3) -> Comparison:
    """A quarter of the thick cylinder as a slab, u_r at the bore and the rim (m)."""
    import ngsolve as ng
    from netgen.occ import X, Y, Z, Box, Cylinder, OCCGeometry, Pnt

    material = material or YeohMaterial()
    a, b, t, q = LAME_INNER_M, LAME_OUTER_M, LAME_SLAB_M, LAME_PRESSURE_PA
    bore = Cylinder(Pnt(0.0, 0.0, -t), Z, r=a, h=3.0 * t)
    bore.faces.name = "bore"
    ring = Cylinder(Pnt(0.0, 0.0, 0.0), Z, r=b, h=t) - bore
    quarter = ring * Box(Pnt(0.0, 0.0, -t), Pnt(2.0 * b, 2.0 * b, 2.0 * t))
    quarter.faces.Min(X).name = "symmetry_x"
    quarter.faces.Min(Y).name = "symmetry_y"
    quarter.faces.Min(Z).name = "slab"
    quarter.faces.Max(Z).name = "slab"
    mesh = ng.Mesh(OCCGeometry(quarter).GenerateMesh(maxh=element_size_m))
    mesh.Curve(3)
    solid = Solid3D(mesh, material, {"bore": "bore"},
                    {"x": "symmetry_x", "y": "symmetry_y", "z": "slab"})
    solid.solve({"bore": q})
    fe, exact = [], []
    for r in (a, b):
        angles = np.linspace(0.2, 1.37, 5)
        points = np.column_stack([r * np.cos(angles), r * np.sin(angles),
                                  np.full_like(angles, 0.5 * t)])
        inward = points - 1e-7 * points / r * (1.0 if r == b else -1.0)
        u = solid.displacement_at(inward)
        fe.append(float(np.mean(np.sum(u[:, :2] * points[:, :2], axis=1) / r)))
        exact.append(q * a * a * b * b / (2.0 * material.shear_modulus_pa * (b * b - a * a) * r))
    return Comparison("Lame cylinder, u_r at the bore and the rim (m)", fe, exact,
                      _worst(fe, exact))


def contact_balance(geometry: FingerGeometry, element_size_m: float = 3e-3,
                    pressure_pa: float = 20e3, gap_m: float = 1e-3) -> Comparison:
    """The finger at ``pressure_pa`` opened onto a rigid plane ``gap_m`` below its backbone: the
    clamp's reaction (negated) against the plane's force, along its normal (N, half model)."""
    from softgrip_ros.model.fe3d.solid import Obstacle

    floor = Obstacle("floor", "backbone|tip_end", lambda x: -gap_m - x[1])
    finger = Finger3D(geometry, element_size_m=element_size_m, obstacles=[floor])
    finger.solve(pressure_pa)
    force = finger.solid.obstacle_contact("floor").force_n[1]
    reaction = -finger.solid.reaction_n("clamp")[1]
    return Comparison(f"contact with a plane {gap_m * 1e3:g} mm below the backbone at "
                      f"{pressure_pa / 1e3:g} kPa: clamp reaction against the plane's force (N)",
                      [reaction], [force], _worst([reaction], [force]))


def mesh_convergence(geometry: FingerGeometry, sizes_m, pressure_pa: float,
                     width_m: float | None = None, progress=None) -> MeshConvergence:
    """The finger of ``width_m`` (the default width if None) at one pressure on meshes of each
    size (coarse to fine)."""
    kwargs = {} if width_m is None else {"width_m": width_m}
    return tip_convergence(lambda size: Finger3D(geometry, element_size_m=size, **kwargs),
                           lambda finger: finger.tetrahedra, sizes_m, pressure_pa, progress,
                           "tetrahedra")

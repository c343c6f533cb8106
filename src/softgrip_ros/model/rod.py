"""L2: a quasi-static planar Kirchhoff rod of one finger's backbone, for scenes with contact or
load.

The left finger's backbone follows the PCC layout of :mod:`softgrip_ros.model.kinematics`
(rigid vertical part and first offset, five bending segments, rigid tip piece). Each bending
segment is split into ``elements_per_segment`` arcs of constant curvature kappa_k, the unknowns.
Pressure gives each segment its free curvature kappa0_i = theta_i(p) / L_s from the L1 (or L0)
bending law. The rod's equilibrium minimises

    E(kappa) = sum_k 1/2 EI_i ds (kappa_k - kappa0_i)^2  -  sum_j m_j g . r_j

subject to contact: the finger's chamber-side surface (the backbone offset inwards by the
chambers' rounded outline, :meth:`FingerGeometry.chamber_surface_offset_m`, whose crests are the
faces at d2 + m_i) stays outside the object, a circle or a flat sheet on the centre
line. Without contact and gravity the minimiser is kappa = kappa0, and the node positions are
the PCC chain's to rounding.

Bending stiffness per segment, from the same wall-stretch chain as eq. 16 (see bending): the
pressure moment on a chamber end wall, p w (m_i - 2b)^2 / 2, is carried by the wall stress
acting on w d^2, and the wall stretch bends the section by (lambda - 1) / (2t) per length, so

    EI_i = 16 C10 t w d^2 / g      (N m^2; the same for every segment)

which reproduces L0's slope exactly. **Assumption:** the paper gives no out-of-plane finger
width w; ``finger_width_m`` (default 20 mm) sets it, and with it the scale of every force. The
stiffness is the small-strain one, also about a pressurised state (L1's stiffening is in kappa0,
not in EI). Chamber ballooning is not modelled here (the surface is the unpressurised one).

Contact forces are the constraints' Lagrange multipliers, recovered from the KKT condition
grad E = J_active^T lambda with lambda >= 0 (non-negative least squares): newtons, pushing the
finger off the object along the surface normal.

The solve is SLSQP with analytic gradients, with load continuation from a feasible start
(straight, or the free shape at ``from_pressure_pa``, e.g. opened around an object before
clamping). A solve that does not converge says so in ``RodSolution.converged`` and ``message``;
its shape is then not to be used.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.optimize import minimize, nnls

from softgrip_ros.model.bending import BendingCalibration, make_bending_law
from softgrip_ros.model.geometry import CHAMBER_COUNT, FingerGeometry
from softgrip_ros.model.material import YeohMaterial

SILICONE_DENSITY_KG_M3 = 1070.0
# the finger's out-of-plane width: not in the paper (see the module docstring)
DEFAULT_FINGER_WIDTH_M = 0.02


@dataclasses.dataclass(frozen=True)
class Circle:
    """A cylindrical object seen end-on: centre (x, z) in the gripper frame (m), radius (m)."""

    center_x_m: float
    center_z_m: float
    radius_m: float

    def __post_init__(self):
        if (not all(math.isfinite(v) for v in (self.center_x_m, self.center_z_m, self.radius_m)) or
                self.radius_m <= 0):
            raise ValueError(f"a circle needs a finite centre and a positive radius, got {self}")


@dataclasses.dataclass(frozen=True)
class Sheet:
    """A flat sheet on the centre line (x = 0), ``thickness_m`` thick, between the fingers."""

    thickness_m: float

    def __post_init__(self):
        if not (math.isfinite(self.thickness_m) and self.thickness_m > 0):
            raise ValueError(f"a sheet needs a positive thickness, got {self.thickness_m}")


@dataclasses.dataclass
class RodSolution:
    """One equilibrium of the left finger. Arrays over the K = N + 1 element nodes of the bending
    part."""

    pressure_pa: float
    curvatures_per_m: np.ndarray  # (N,)
    nodes_m: np.ndarray  # (K, 2) backbone x, z
    surface_m: np.ndarray  # (K, 2) chamber-side surface points
    tip: tuple  # (x, z, tangent angle from +z) of the backbone's end
    contact_points_m: np.ndarray  # (M, 2) surface points in contact
    contact_forces_n: np.ndarray  # (M,) normal force at each, on the finger
    contact_force_n: float  # magnitude of their sum
    segment_angles_rad: np.ndarray  # (5,) theta_i, each segment's elements summed
    converged: bool
    message: str
    iterations: int
    max_penetration_m: float


class RodFinger:
    """The L2 model of one finger (the right one is its mirror image).

    bending: "l1" (default) or "l0", the law that gives the free curvature.
    elements_per_segment: arcs per bending segment (resolution of contact and load).
    finger_width_m: out-of-plane width (an assumption, see the module docstring).
    linear_density_kg_per_m: mass per length for gravity (default: solid walls, rho w d2).
    """

    def __init__(self, geometry: FingerGeometry, calibration: BendingCalibration,
                 material: YeohMaterial | None = None, bending: str = "l1",
                 elements_per_segment: int = 8, finger_width_m: float = DEFAULT_FINGER_WIDTH_M,
                 linear_density_kg_per_m: float | None = None):
        if not (isinstance(elements_per_segment, int) and 1 <= elements_per_segment <= 200):
            raise ValueError("elements_per_segment must be an integer in [1, 200], got "
                             f"{elements_per_segment!r}")
        if not (math.isfinite(finger_width_m) and 1e-3 <= finger_width_m <= 0.2):
            raise ValueError(f"finger_width_m must lie in [0.001, 0.2] m, got {finger_width_m}")
        self.geometry, self.calibration = geometry, calibration
        self.material = material or YeohMaterial()
        self.law = make_bending_law(bending, geometry, self.material, calibration)
        g = geometry
        self.element_length_m = g.segment_length_m / elements_per_segment
        self.elements_per_segment = elements_per_segment
        n = CHAMBER_COUNT * elements_per_segment
        self.element_segment = np.repeat(np.arange(CHAMBER_COUNT), elements_per_segment)
        self.bending_stiffness_nm2 = (16.0 * self.material.c10_pa * g.wall_thickness_m *
                                      finger_width_m * g.chamber_bottom_to_sidewall_m**2 /
                                      calibration.gain)
        density = (SILICONE_DENSITY_KG_M3 * finger_width_m * g.chamber_bottom_to_sidewall_m
                   if linear_density_kg_per_m is None else linear_density_kg_per_m)
        if not (math.isfinite(density) and density >= 0):
            raise ValueError(f"linear_density_kg_per_m must be finite and >= 0, got {density}")
        # node masses: half of each adjacent element; the rigid tip piece's mass sits at its middle
        masses = np.full(n + 1, density * self.element_length_m)
        masses[0] = masses[-1] = 0.5 * density * self.element_length_m
        self.node_masses_kg = masses
        self.finger_width_m, self.linear_density_kg_per_m = finger_width_m, density
        self.tip_mass_kg = density * g.tip_length_m
        # the chamber faces span the first L3 of each segment, rounded (FingerGeometry's
        # chamber_surface_offset_m); the h3 gaps between them are recessed
        segment_of = [min(k // elements_per_segment, CHAMBER_COUNT - 1) for k in range(n + 1)]
        local = np.array([(k - i * elements_per_segment) * self.element_length_m
                          for k, i in enumerate(segment_of)])
        self.surface_offsets_m = np.array([
            g.chamber_surface_offset_m(i, a - 0.5 * g.chamber_length_m)
            for i, a in zip(segment_of, local)])
        self.contact_nodes = np.flatnonzero(local <= g.chamber_length_m + 1e-12)
        phi0 = g.inclination_rad
        self._start = (-g.root_x_m + g.first_chamber_offset_m * math.sin(phi0),
                       g.vertical_height_m + g.first_chamber_offset_m * math.cos(phi0), phi0)
        self._n = n

    # ---- the free shape ----------------------------------------------------------------------
    def free_curvatures(self, pressure_pa: float) -> np.ndarray:
        """kappa0 per element (1/m): theta_i(p) / L_s, from the bending law."""
        theta = np.asarray(self.law.angles(float(pressure_pa)), dtype=float)
        return (theta / self.geometry.segment_length_m)[self.element_segment]

    def chamber_face_node(self, chamber_index: int) -> int:
        """The node nearest the middle of chamber ``chamber_index``'s face (an index into
        ``RodSolution.surface_m``)."""
        if not 0 <= chamber_index < CHAMBER_COUNT:
            raise ValueError(
                f"chamber_index must lie in [0, {CHAMBER_COUNT - 1}], got {chamber_index}")
        return chamber_index * self.elements_per_segment + int(
            round(0.5 * self.geometry.chamber_length_m / self.element_length_m))

    def chamber_face_point_m(self, pressure_pa: float, chamber_index: int) -> np.ndarray:
        """(x, z) of the chamber-side surface at the middle of chamber ``chamber_index``'s face, in
        free bending at ``pressure_pa`` (the nearest node)."""
        node = self.chamber_face_node(chamber_index)
        return self._shape(self.free_curvatures(pressure_pa))[3][node]

    # ---- geometry of a shape -----------------------------------------------------------------
    def _shape(self, kappa: np.ndarray):
        """Nodes, headings, surface points and the tip for element curvatures ``kappa``."""
        ds = self.element_length_m
        theta = kappa * ds
        x0, z0, phi0 = self._start
        headings = phi0 - np.concatenate([[0.0], np.cumsum(theta)])  # (K,)
        half = 0.5 * theta
        sinc = np.where(half == 0.0, 1.0, np.sin(half) / np.where(half == 0.0, 1.0, half))
        chord = ds * sinc
        direction = headings[:-1] - half
        nodes = np.empty((self._n + 1, 2))
        nodes[0] = (x0, z0)
        nodes[1:, 0] = x0 + np.cumsum(chord * np.sin(direction))
        nodes[1:, 1] = z0 + np.cumsum(chord * np.cos(direction))
        # inwards, towards the centre line
        normals = np.column_stack([np.cos(headings), -np.sin(headings)])
        surface = nodes + self.surface_offsets_m[:, None] * normals
        tip_length = self.geometry.tip_length_m
        tip = (nodes[-1, 0] + tip_length * math.sin(headings[-1]),
               nodes[-1, 1] + tip_length * math.cos(headings[-1]), headings[-1])
        return nodes, headings, normals, surface, tip, theta, direction, chord

    def _tip_centre_of_mass(self, nodes, headings):
        """The middle of the rigid tip piece, where its weight acts."""
        return nodes[-1] + 0.5 * self.geometry.tip_length_m * np.array(
            [math.sin(headings[-1]), math.cos(headings[-1])])

    def _jacobians(self, kappa, shape):
        """d(nodes)/d(kappa), d(surface)/d(kappa), d(tip centre of mass)/d(kappa): (K, 2, N) and
        (2, N)."""
        nodes, headings, normals, surface, tip, theta, direction, chord = shape
        ds, n = self.element_length_m, self._n
        half = 0.5 * theta
        small = np.abs(half) < 1e-4
        safe = np.where(small, 1.0, half)
        sinc_slope = np.where(small, half * (-1.0 / 3.0 + half * half / 30.0),
                              (safe * np.cos(safe) - np.sin(safe)) / (safe * safe))
        dchord = 0.5 * ds * sinc_slope  # d chord / d theta
        own = np.column_stack([
            dchord * np.sin(direction) - 0.5 * chord * np.cos(direction),
            # (N, 2)
            dchord * np.cos(direction) + 0.5 * chord * np.sin(direction)
        ])
        ends = nodes[1:]  # end of element k
        # node j after element k
        later = np.arange(n + 1)[:, None] > np.arange(n)[None, :]
        rel = nodes[:, None, :] - ends[None, :, :]  # (K, N, 2)
        d_nodes = np.where(later[..., None],
                           own[None, :, :] + np.stack([-rel[..., 1], rel[..., 0]], axis=-1), 0.0)
        d_normals = np.where(later[..., None],
                             np.stack([np.sin(headings), np.cos(headings)], axis=-1)[:, None, :],
                             0.0)
        d_surface = d_nodes + self.surface_offsets_m[:, None, None] * d_normals
        tip_com = self._tip_centre_of_mass(nodes, headings)
        rel_tip = tip_com[None, :] - ends
        d_tip_com = (own + np.column_stack([-rel_tip[:, 1], rel_tip[:, 0]])).T  # (2, N)
        return (d_nodes * ds).transpose(0, 2, 1), (d_surface * ds).transpose(0, 2,
                                                                             1), d_tip_com * ds

    # ---- energy ------------------------------------------------------------------------------
    def _energy_and_gradient(self, kappa, kappa0, gravity):
        shape = self._shape(kappa)
        nodes, headings = shape[0], shape[1]
        ei, ds = self.bending_stiffness_nm2, self.element_length_m
        strain = kappa - kappa0
        energy = 0.5 * ei * ds * float(strain @ strain)
        gradient = ei * ds * strain
        if gravity is not None:
            tip_com = self._tip_centre_of_mass(nodes, headings)
            energy -= (float(self.node_masses_kg @ (nodes @ gravity)) +
                       self.tip_mass_kg * float(tip_com @ gravity))
            d_nodes, _, d_tip_com = self._jacobians(kappa, shape)
            gradient = gradient - np.einsum("j,jcn,c->n", self.node_masses_kg, d_nodes, gravity) \
                - self.tip_mass_kg * (gravity @ d_tip_com)
        return energy, gradient

    def _gaps(self, obstacle, surface):
        """Signed clearance of each chamber-face point from the object (m), >= 0 when outside."""
        if obstacle is None:
            return np.empty(0)
        surface = surface[self.contact_nodes]
        if isinstance(obstacle, Circle):
            return np.hypot(surface[:, 0] - obstacle.center_x_m,
                            surface[:, 1] - obstacle.center_z_m) - obstacle.radius_m
        return -0.5 * obstacle.thickness_m - surface[:, 0]

    def _gap_jacobian(self, obstacle, kappa):
        shape = self._shape(kappa)
        surface = shape[3][self.contact_nodes]
        d_surface = self._jacobians(kappa, shape)[1][self.contact_nodes]
        if isinstance(obstacle, Circle):
            rel = surface - np.array([obstacle.center_x_m, obstacle.center_z_m])
            unit = rel / np.linalg.norm(rel, axis=1)[:, None]
            return np.einsum("jc,jcn->jn", unit, d_surface)
        return -d_surface[:, 0, :]

    # ---- solve -------------------------------------------------------------------------------
    def solve(self, pressure_pa: float, obstacle: Circle | Sheet | None = None, gravity_m_s2=None,
              from_pressure_pa: float = 0.0, steps: int = 4,
              tolerance: float = 1e-12) -> RodSolution:
        """The equilibrium at ``pressure_pa`` with an optional object and gravity (a 2-vector in
        the gripper's x, z frame; None: no gravity). Load continuation in ``steps`` from the free
        shape at ``from_pressure_pa`` (0: straight), which must clear the object."""
        for name, value in (("pressure_pa", pressure_pa), ("from_pressure_pa", from_pressure_pa)):
            if not math.isfinite(value):
                raise ValueError(f"{name} must be finite, got {value}")
        if not (isinstance(steps, int) and steps >= 1):
            raise ValueError(f"steps must be a positive integer, got {steps!r}")
        if obstacle is not None and not isinstance(obstacle, (Circle, Sheet)):
            raise ValueError(f"obstacle must be a Circle, a Sheet or None, got {obstacle!r}")
        gravity = None if gravity_m_s2 is None else np.asarray(gravity_m_s2,
                                                               dtype=float).reshape(2)
        if gravity is not None and not np.all(np.isfinite(gravity)):
            raise ValueError(f"gravity must be finite, got {gravity_m_s2}")
        start, end = self.free_curvatures(from_pressure_pa), self.free_curvatures(pressure_pa)
        kappa = start.copy()
        start_gap = self._gaps(obstacle, self._shape(kappa)[3])
        if start_gap.size and start_gap.min() < 0.0:
            return self._solution(
                pressure_pa, kappa, obstacle, gravity, end, False, 0,
                f"the object overlaps the finger's start shape at {from_pressure_pa:.0f} Pa "
                f"(by {-start_gap.min() * 1e3:.2f} mm): open further first")
        if obstacle is None and gravity is None:  # the minimiser is known in closed form
            return self._solution(pressure_pa, end, None, None, end, True, 0,
                                  "free bending: kappa = kappa0")
        iterations, message = 0, ""
        scale = max(1.0, float(np.max(np.abs(end))))
        for fraction in np.linspace(1.0 / steps, 1.0, steps):
            kappa0 = start + fraction * (end - start)
            constraints = [] if obstacle is None else [{
                "type": "ineq", "fun": lambda u: self._gaps(obstacle,
                                                            self._shape(u * scale)[3]),
                "jac": lambda u: self._gap_jacobian(obstacle, u * scale) * scale
            }]
            result = minimize(lambda u: self._scaled(u, scale, kappa0, gravity), kappa / scale,
                              jac=True, method="SLSQP", constraints=constraints,
                              options={"maxiter": 500, "ftol": tolerance})
            iterations += int(result.nit)
            kappa = result.x * scale
            if not result.success:
                message = f"SLSQP did not converge at {fraction:.0%} of the load: {result.message}"
                return self._solution(pressure_pa, kappa, obstacle, gravity, kappa0, False,
                                      iterations, message)
        return self._solution(pressure_pa, kappa, obstacle, gravity, end, True, iterations,
                              "converged")

    def _scaled(self, u, scale, kappa0, gravity):
        energy, gradient = self._energy_and_gradient(u * scale, kappa0, gravity)
        norm = self.bending_stiffness_nm2 * self.element_length_m * scale * scale
        return energy / norm, gradient * scale / norm

    def _solution(self, pressure_pa, kappa, obstacle, gravity, kappa0, converged, iterations,
                  message) -> RodSolution:
        shape = self._shape(kappa)
        nodes, surface, tip = shape[0], shape[3], shape[4]
        gaps = self._gaps(obstacle, surface)
        penetration = float(max(0.0, -gaps.min())) if gaps.size else 0.0
        points, forces = np.empty((0, 2)), np.empty(0)
        if gaps.size and converged:
            active = np.flatnonzero(gaps < 1e-7)
            if active.size:
                _, gradient = self._energy_and_gradient(kappa, kappa0, gravity)
                jacobian = self._gap_jacobian(obstacle, kappa)[active]
                forces, residual = nnls(jacobian.T, gradient)
                keep = forces > 0.0
                points, forces = surface[self.contact_nodes][active][keep], forces[keep]
                if residual > 1e-6 * max(1.0, float(np.linalg.norm(gradient))):
                    converged, message = False, f"no equilibrium: KKT residual {residual:.3g} N m"
        if isinstance(obstacle, Circle) and forces.size:
            normals = points - np.array([obstacle.center_x_m, obstacle.center_z_m])
            normals /= np.linalg.norm(normals, axis=1)[:, None]
            total = float(np.linalg.norm(forces @ normals))
        else:
            total = float(forces.sum())
        return RodSolution(
            pressure_pa=float(pressure_pa), curvatures_per_m=kappa, nodes_m=nodes,
            surface_m=surface, tip=tip, contact_points_m=points, contact_forces_n=forces,
            contact_force_n=total,
            segment_angles_rad=kappa.reshape(CHAMBER_COUNT, -1).sum(axis=1) *
            self.element_length_m, converged=bool(converged), message=message,
            iterations=iterations, max_penetration_m=penetration)

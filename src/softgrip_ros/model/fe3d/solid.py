"""A large-deformation, nearly incompressible Yeoh solid in 3-D with follower gas pressure, on
NGSolve.

What NGSolve provides and this module uses: the tetrahedral meshes (netgen), the Taylor-Hood
spaces (P2 displacement, continuous P1 pressure), the automatic first and second variations of
the energy below, assembly, the search of contact pairs, and the sparse LDL^T factorisation.
What is written here: the energy, the Newton loop, and the load stepping.

Formulation (total Lagrangian, mixed u-p; Holzapfel, *Nonlinear Solid Mechanics*, sec. 8.4):
F = I + grad u, J = det F, Ibar1 = J^(-2/3) tr(F^T F), and the stationary point of

    Pi = int_body [C10 (Ibar1 - 3) + C20 (Ibar1 - 3)^2 + p (J - 1) - p^2 / (2 kappa)] dV
         - sum_cavities q_c V_c(u).

**Bulk treatment.** kappa = ``BULK_TO_SHEAR`` times the shear modulus (10^6: Poisson's ratio
0.4999995, incompressible to the solver's precision, as the paper's Assumption 1). The finite
kappa is there for the linear algebra: it makes the saddle-point tangent quasi-definite, so that
NGSolve's sparse LDL^T factorises it without pivoting (in a plane-strain run it gives the tip of
the exactly incompressible UMFPACK solve to 1e-6).

**Follower pressure as an energy.** The gas in cavity c does the work q_c V_c, with the cavity's
current volume from the divergence theorem on the in-plane part of the position,

    V_c = -1/2 int_walls (x_1 n_1 + x_2 n_2) da,   n da = cof(F) N dA  (Nanson),

N the solid's outward normal (into the cavity). cof(F) N needs only the surface gradient, which
is what NGSolve's trace gives on a boundary. Using x_1 and x_2 only, faces whose current normal
stays along x_3 (a symmetry plane, the faces of a plane-strain slab) add nothing, so the same
formula holds for a half model cut through its cavities. As an energy the load's tangent is
symmetric.

**Contact, by penalty.** Between two surfaces of the solid (``contacts``), NGSolve's
``ContactBoundary`` pairs each quadrature point of the primary surface with the closest point of
the secondary in the current configuration and adds the energy k/2 <d>_+^2 of the depth d along
the primary's current normal. Against a rigid obstacle (``obstacles``; NGSolve has none, so it is
written here) the same energy of the obstacle's signed distance. k = 100 shear moduli per mm
(1.6e10 Pa/m): a contact pressure of 16 kPa costs a penetration of 1 um. Ten times stiffer moved
alpha at 50 kPa by 0.02 deg and made Newton cycle; the pairing is therefore searched again only in
a step's first iterations, and checked once the step has converged.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from softgrip_ros.model.fe import solver as fe_solver
from softgrip_ros.model.fe.solver import NotConverged, YeohMaterial

BULK_TO_SHEAR = 1e6
LINE_SEARCH_LENGTHS = (1.0, 0.5, 0.25, 0.125)
# the penalty of contact: a penetration of CONTACT_LENGTH_M would cost this many shear moduli of
# pressure (1e-6 m per 16 kPa of contact pressure)
CONTACT_STIFFNESS_PER_SHEAR = 100.0
CONTACT_LENGTH_M = 1e-3
CONTACT_ORDER = 4
PAIR_SEARCHES = 2
# a state converged for its pairs is accepted when the pairs found again leave a residual this
# small against the step's first (their closest points slide a little with every search)
PAIRING_TOLERANCE = 1e-3


@dataclasses.dataclass(frozen=True)
class Obstacle:
    """A rigid body that the boundaries matching ``pattern`` may not enter: ``depth(x)`` gives,
    from NGSolve's coefficient of the current position x (3 components, m), how deep x lies
    inside the body (m, > 0 inside), with a gradient of unit length (a signed distance)."""

    name: str
    pattern: str
    depth: object
    # the penalty at each surface triangle's corners and edge midpoints too (a body with edges,
    # such as the clamped object, is met first where a Gauss rule has no point)
    corner_points: bool = False
    # > 0: the penalty acts on softplus(depth) over this length, not on max(depth, 0), so that
    # its stiffness does not jump where a point meets the obstacle (Newton cycled on a cylinder)
    smoothing_m: float = 0.0

    def penalised_depth(self, depth):
        """The depth the penalty acts on, and its derivative by the depth (coefficients)."""
        import ngsolve as ng

        if self.smoothing_m <= 0.0:
            return ng.IfPos(depth, depth, 0.0), ng.IfPos(depth, 1.0, 0.0)
        delta = self.smoothing_m
        # softplus, written so that neither branch overflows
        smooth = ng.IfPos(depth, depth + delta * ng.log(1.0 + ng.exp(-depth / delta)),
                          delta * ng.log(1.0 + ng.exp(depth / delta)))
        slope = ng.IfPos(depth, 1.0 / (1.0 + ng.exp(-depth / delta)),
                         ng.exp(depth / delta) / (1.0 + ng.exp(depth / delta)))
        return smooth, slope


@dataclasses.dataclass(frozen=True)
class ObstacleContact:
    """What a rigid obstacle and the solid exchange. Per reference area, the contact pressure is
    the penalty's k times the depth, along the obstacle's normal."""

    force_n: np.ndarray  # (3,) the resultant the obstacle exerts on the solid, from the residual
    normal_force_n: float  # the magnitudes of the contact tractions summed (what friction uses)
    area_m2: float  # the reference area in contact (within 5 smoothing lengths, if smoothed)
    deepest_m: float  # the largest penetration
    centre_m: np.ndarray  # (3,) the deformed contact's centre, weighted by pressure (NaN if none)
    peak_pressure_pa: float  # the largest traction at the penalty's points


@dataclasses.dataclass
class SolverStats(fe_solver.SolverStats):
    """The 2-D solver's counts, and where the time went."""

    seconds_assembling: float = 0.0
    seconds_factorising: float = 0.0


class Solid3D:
    """A Yeoh solid on an NGSolve mesh, loaded by gas pressure in named cavities.

    ``cavities`` maps a cavity's name to the regular expression of its wall boundaries;
    ``fixed`` maps a component ("x", "y" or "z") to the expression of the boundaries where that
    component of the displacement is held at zero (a clamp, a symmetry plane). Metres, Pa.
    """

    def __init__(self, mesh, material: YeohMaterial, cavities: dict, fixed: dict,
                 order: int = 2, contacts=(), obstacles=(), contact_search_m: float = 1e-3):
        import ngsolve as ng

        if order < 2:
            raise ValueError(f"the displacement order must be >= 2 (Taylor-Hood), got {order}")
        for name, pattern in cavities.items():
            if not any(mesh.Boundaries(pattern).Mask()):
                raise ValueError(f"cavity {name!r}: no boundary of the mesh matches {pattern!r}")
        self.mesh = mesh
        self.material = material
        self.stats = SolverStats()
        displacement = ng.VectorH1(mesh, order=order, **{
            f"dirichlet{axis}": fixed[axis] for axis in ("x", "y", "z") if axis in fixed})
        self.space = ng.FESpace([displacement, ng.H1(mesh, order=order - 1)])
        (u, p), _ = self.space.TnT()
        F = ng.Id(3) + ng.Grad(u)
        J = ng.Det(F)
        ibar = J ** (-2.0 / 3.0) * ng.Trace(F.trans * F) - 3.0
        kappa = BULK_TO_SHEAR * material.shear_modulus_pa
        energy = (material.c10_pa * ibar + material.c20_pa * ibar * ibar + p * (J - 1.0)
                  - p * p / (2.0 * kappa))
        self.form = ng.BilinearForm(self.space, symmetric=True)
        self.form += ng.Variation(energy.Compile() * ng.dx)
        self._gas = {}
        normal = ng.specialcf.normal(3)
        current = ng.Cof(ng.Id(3) + ng.Grad(u.Trace())) * normal
        position = ng.CoefficientFunction((ng.x, ng.y, ng.z)) + u
        in_plane = position[0] * current[0] + position[1] * current[1]
        self._volume_forms = {}
        for name, pattern in cavities.items():
            gas = ng.Parameter(0.0)
            self._gas[name] = gas
            self.form += ng.Variation((0.5 * gas * in_plane).Compile() * ng.ds(pattern))
            # the same expression, alone: its "energy" is the cavity's volume
            volume = ng.BilinearForm(self.space, symmetric=True)
            volume += ng.Variation((-0.5 * in_plane).Compile() * ng.ds(pattern))
            self._volume_forms[name] = volume
        self.state = ng.GridFunction(self.space)
        self.contact_search_m = float(contact_search_m)
        self.contact_stiffness_pa_per_m = (CONTACT_STIFFNESS_PER_SHEAR * material.shear_modulus_pa
                                           / CONTACT_LENGTH_M)
        self._contacts = []
        position0 = ng.CoefficientFunction((ng.x, ng.y, ng.z))
        for primary, secondary in contacts:
            for pattern in (primary, secondary):
                if not any(mesh.Boundaries(pattern).Mask()):
                    raise ValueError(f"contact: no boundary of the mesh matches {pattern!r}")
            pair = ng.ContactBoundary(mesh.Boundaries(primary), mesh.Boundaries(secondary))
            depth = (u - u.Other() + position0 - position0.Other()) * pair.normal
            pair.AddEnergy(ng.IfPos(depth, 0.5 * self.contact_stiffness_pa_per_m * depth * depth,
                                    0.0))
            self._contacts.append(pair)
        # rigid obstacles: a penalty on how deep each point of a boundary lies inside
        self._obstacles = []
        for obstacle in obstacles:
            if not any(mesh.Boundaries(obstacle.pattern).Mask()):
                raise ValueError(f"obstacle: no boundary of the mesh matches "
                                 f"{obstacle.pattern!r}")
            depth = obstacle.depth(position)
            if obstacle.smoothing_m > 0.0:
                penalised = obstacle.penalised_depth(depth)[0]
                density = 0.5 * self.contact_stiffness_pa_per_m * penalised * penalised
            else:
                density = ng.IfPos(depth, 0.5 * self.contact_stiffness_pa_per_m * depth * depth,
                                   0.0)
            energy = ng.Variation(density.Compile() * _obstacle_ds(obstacle))
            self.form += energy
            # the same term alone: its residual is the force the obstacle exerts
            alone = ng.BilinearForm(self.space, symmetric=True)
            alone += energy
            self._obstacles.append((obstacle, alone))
        self.gas_pressures = {name: 0.0 for name in cavities}
        self._corner_points = {}

    # ---- solving -----------------------------------------------------------------------------
    def _set_gas(self, gas: dict):
        for name, value in gas.items():
            self._gas[name].Set(value)

    def _energy_norm(self, residual, step) -> float:
        return math.sqrt(abs(step.InnerProduct(residual)))

    def _update_contact_pairs(self):
        for pair in self._contacts:
            pair.Update(self.displacement, self.form, CONTACT_ORDER, self.contact_search_m)

    def _newton(self, tolerance: float, max_iterations: int):
        """Newton's method from the present state. The contact pairs (each point of a primary
        surface with its closest point on the secondary) are searched again in the first
        PAIR_SEARCHES iterations only, then held, so that the pairing does not make the iteration
        cycle; once converged they are searched once more, and the iteration goes on (searching
        again) unless the new pairs leave the state within PAIRING_TOLERANCE."""
        import time

        import ngsolve as ng

        x = self.state.vec
        residual = x.CreateVector()
        step = x.CreateVector()
        trial = x.CreateVector()
        first = None
        checking = False
        searched_until = PAIR_SEARCHES
        for iteration in range(1, max_iterations + 1):
            started = time.perf_counter()
            if iteration <= searched_until:
                self._update_contact_pairs()
            self.form.AssembleLinearization(x)
            self.form.Apply(x, residual)
            assembled = time.perf_counter()
            try:
                inverse = self.form.mat.Inverse(self.space.FreeDofs(), inverse="sparsecholesky")
            except Exception as error:  # NGSolve raises its own type for a singular matrix
                raise NotConverged(f"the linear solve failed ({error})") from None
            step.data = inverse * residual
            self.stats.seconds_assembling += assembled - started
            self.stats.seconds_factorising += time.perf_counter() - assembled
            self.stats.newton_iterations += 1
            norm = self._energy_norm(residual, step)
            if not math.isfinite(norm):
                raise NotConverged("the residual is not finite (an element turned inside out)")
            if first is None:
                first = max(norm, 1e-30)
            if checking and norm <= PAIRING_TOLERANCE * first:
                x.data -= step  # the pairs found again change next to nothing
                return iteration
            checking = False
            if norm <= tolerance * first or norm < 1e-14:
                x.data -= step
                if not self._contacts or iteration <= searched_until:
                    return iteration
                searched_until = iteration + 1 + PAIR_SEARCHES  # search again, and check
                checking = True
                continue
            # the full step, shortened only where it turns an element inside out: the residual's
            # norm mixes forces and the constraint, so it is no merit function for a search
            for length in LINE_SEARCH_LENGTHS:
                trial.data = x - length * step
                self.form.Apply(trial, residual)
                if math.isfinite(ng.Norm(residual)):
                    break
            else:
                raise NotConverged("every step of the line search turned an element inside out")
            x.data = trial
        raise NotConverged(f"no convergence in {max_iterations} Newton iterations")

    def solve(self, gas_pressures: dict, first_step_pa: float = 10e3, min_step_pa: float = 100.0,
              tolerance: float = 1e-8, max_iterations: int = 25, progress=None):
        """Move from the present gas pressures to ``gas_pressures`` ({name: Pa}) in load steps,
        halving a step where Newton fails. NotConverged when a step below ``min_step_pa`` still
        fails; the state then stays at the last converged load. ``progress(gas)`` hears of each
        converged step."""
        unknown = set(gas_pressures) - set(self.gas_pressures)
        if unknown:
            raise ValueError(f"no such cavity: {sorted(unknown)}")
        start = dict(self.gas_pressures)
        target = {name: float(gas_pressures.get(name, start[name])) for name in start}
        span = max([abs(target[n] - start[n]) for n in start] + [0.0])
        if span == 0.0:
            return
        done, step = 0.0, min(1.0, first_step_pa / span)
        saved = self.state.vec.CreateVector()
        while done < 1.0:
            fraction = min(1.0, done + step)
            gas = {n: start[n] + fraction * (target[n] - start[n]) for n in start}
            saved.data = self.state.vec
            self._set_gas(gas)
            try:
                self._newton(tolerance, max_iterations)
            except NotConverged as error:
                self.state.vec.data = saved
                self._set_gas(self.gas_pressures)
                step *= 0.5
                self.stats.step_cuts += 1
                if step * span < min_step_pa:
                    raise NotConverged(f"stopped at {self._describe(self.gas_pressures)}: "
                                       f"{error}") from None
                continue
            self.gas_pressures = gas
            self.stats.load_steps += 1
            done = fraction
            step = min(2.0 * step, first_step_pa / span)
            if progress is not None:
                progress(gas)

    @staticmethod
    def _describe(gas):
        return ", ".join(f"{name} {q / 1e3:+.2f} kPa" for name, q in sorted(gas.items()))

    # ---- results -----------------------------------------------------------------------------
    @property
    def displacement(self):
        """The displacement field (an NGSolve GridFunction, m)."""
        return self.state.components[0]

    def displacement_at(self, points):
        """(K, 3) displacements at (K, 3) reference points inside or on the solid. ValueError
        if a point lies outside the mesh."""
        points = np.asarray(points, dtype=float)
        mapped = self.mesh(points[:, 0], points[:, 1], points[:, 2])
        if np.any(mapped["nr"] < 0):
            raise ValueError("a probe point lies outside the mesh")
        return np.asarray(self.displacement(mapped), dtype=float).reshape(-1, 3)

    def cavity_volume_m3(self, name: str, deformed: bool = True) -> float:
        """The volume the walls of cavity ``name`` enclose (with the symmetry planes that cut it),
        deformed or in the reference state."""
        if deformed:
            return float(self._volume_forms[name].Energy(self.state.vec))
        rest = self.state.vec.CreateVector()
        rest[:] = 0.0
        return float(self._volume_forms[name].Energy(rest))

    @property
    def obstacle_names(self) -> list:
        return [obstacle.name for obstacle, _ in self._obstacles]

    def _translation_work(self, residual, pattern=None) -> np.ndarray:
        """(3,) the work of ``residual`` under unit translations in x, y and z: of the whole
        solid, or (``pattern``) of those boundaries alone."""
        import ngsolve as ng

        translation = ng.GridFunction(self.space)
        out = np.zeros(3)
        for axis in range(3):
            translation.vec[:] = 0.0
            direction = tuple(1.0 if k == axis else 0.0 for k in range(3))
            if pattern is None:
                translation.components[0].Set(ng.CoefficientFunction(direction))
            else:
                translation.components[0].Set(ng.CoefficientFunction(direction),
                                              definedon=self.mesh.Boundaries(pattern))
            out[axis] = translation.vec.InnerProduct(residual)
        return out

    def obstacle_contact(self, name: str) -> "ObstacleContact":
        """How the solid presses the obstacle ``name`` (:class:`ObstacleContact`; on a half model
        the caller doubles the forces and the area)."""
        import ngsolve as ng

        obstacle, alone = next(pair for pair in self._obstacles if pair[0].name == name)
        residual = self.state.vec.CreateVector()
        alone.Apply(self.state.vec, residual)
        force = -self._translation_work(residual)
        position0 = ng.CoefficientFunction((ng.x, ng.y, ng.z))
        depth = obstacle.depth(position0 + self.displacement)
        penalised, slope = obstacle.penalised_depth(depth)
        # the traction per reference area is k times this, along the obstacle's normal
        pressing = penalised * slope
        region = self.mesh.Boundaries(obstacle.pattern)
        where = _obstacle_ds(obstacle)

        def integral(value, order=6):
            # at the penalty's own points where it has corner points, else a high Gauss order
            if obstacle.corner_points:
                return ng.Integrate(value * where, self.mesh)
            return ng.Integrate(value, self.mesh, definedon=region, order=order)

        weight = float(integral(pressing))
        current = position0 + self.displacement
        moments = [integral(pressing * current[axis]) for axis in range(3)]
        centre = (np.asarray(moments, dtype=float) / weight if weight > 0.0
                  else np.full(3, math.nan))
        # in contact: inside, or (a smoothed penalty) within a few of its lengths of the surface
        area = float(integral(ng.IfPos(depth + 5.0 * obstacle.smoothing_m, 1.0, 0.0)))
        stiffness = self.contact_stiffness_pa_per_m
        if obstacle.corner_points:
            # at the penalty's own points, exactly
            deepest = max(0.0, float(np.max(self._at_corner_points(depth, region))))
            peak = stiffness * max(0.0, float(np.max(self._at_corner_points(pressing, region))))
        else:
            # the largest depth, from a high norm of it over the boundary (exact as the power
            # grows)
            power = 16
            whole = float(ng.Integrate(1.0, self.mesh, definedon=region))
            deepest = (float(integral(pressing ** power, order=8)) / whole) ** (1.0 / power)
            peak = stiffness * deepest
        return ObstacleContact(force, stiffness * weight, area, deepest, centre, peak)

    def _at_corner_points(self, value, region) -> np.ndarray:
        """The scalar coefficient ``value`` at the corners, edge midpoints and centroids of the
        surface triangles of ``region`` (the obstacle rule's points)."""
        import ngsolve as ng

        key = region.Mask().__str__()
        if key not in self._corner_points:
            vertices = np.array([v.point for v in self.mesh.vertices])
            triangles = [[v.nr for v in element.vertices]
                         for element in region.Elements()]
            corners = vertices[np.unique(np.ravel(triangles))]
            edges = {tuple(sorted(pair)) for t in triangles
                     for pair in ((t[0], t[1]), (t[1], t[2]), (t[0], t[2]))}
            middles = np.array([0.5 * (vertices[a] + vertices[b]) for a, b in edges])
            centroids = vertices[np.array(triangles)].mean(axis=1)
            points = np.vstack([corners, middles, centroids])
            self._corner_points[key] = self.mesh(points[:, 0], points[:, 1], points[:, 2],
                                                 ng.BND)
        return np.asarray(value(self._corner_points[key]), dtype=float).ravel()

    def reaction_n(self, pattern: str) -> np.ndarray:
        """(3,) the force (N) that the supports on the boundaries matching ``pattern`` exert on
        the solid: the residual's work under a unit translation of those boundaries alone (the
        residual vanishes at every free degree of freedom once converged)."""
        residual = self.state.vec.CreateVector()
        self.form.Apply(self.state.vec, residual)
        return self._translation_work(residual, pattern)

    def contact_pair_gaps_m(self, index: int, points) -> np.ndarray:
        """The signed distance (m, < 0: overlapping) from each (K, 3) reference point of pair
        ``index``'s primary surface to the secondary, along the primary's current normal; NaN
        where no partner lies within the contact search distance."""
        import ngsolve as ng

        pair = self._contacts[index]
        pair.Update(self.displacement, self.form, CONTACT_ORDER, self.contact_search_m)
        points = np.asarray(points, dtype=float)
        mapped = self.mesh(points[:, 0], points[:, 1], points[:, 2], ng.BND)
        gap = np.asarray(pair.gap(mapped), dtype=float).reshape(-1, 3)
        normal = np.asarray(pair.normal(mapped), dtype=float).reshape(-1, 3)
        out = np.einsum("ij,ij->i", gap, normal)
        # no partner in reach; or a point that fell on a neighbouring face, where the gap is 0
        out[np.any(np.abs(gap) > 1.0, axis=1) | np.all(gap == 0.0, axis=1)] = math.nan
        return out

    def volume_m3(self, deformed: bool = True, where=None) -> float:
        """The solid's volume (int J dV), or that of the part where the coefficient ``where``
        is 1."""
        import ngsolve as ng

        J = ng.Det(ng.Id(3) + ng.Grad(self.displacement)) if deformed else 1.0
        weight = 1.0 if where is None else where
        return float(ng.Integrate(J * weight, self.mesh, order=4))


def _obstacle_ds(obstacle: Obstacle):
    """ds on the obstacle's boundaries: NGSolve's Gauss rule, or with ``corner_points`` each
    triangle's corners, edge midpoints and centroid (exact for cubics)."""
    import ngsolve as ng

    if not obstacle.corner_points:
        return ng.ds(obstacle.pattern)
    rule = ng.IntegrationRule(
        [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (0.5, 0.0), (0.5, 0.5), (0.0, 0.5), (1 / 3, 1 / 3)],
        [1 / 40] * 3 + [1 / 15] * 3 + [9 / 40])
    return ng.ds(obstacle.pattern, intrules={ng.TRIG: rule})

"""Large-deformation plane-strain Yeoh solid with follower pressure, on scikit-fem.

What scikit-fem provides and this module uses: the meshes, the Taylor-Hood element pair (P2
displacement, P1 pressure), quadrature, and the assembly of the forms below into sparse
matrices. What it lacks, written here by hand: the Yeoh constitutive law and its consistent
tangent, the follower-pressure load and its (non-symmetric) tangent, and the Newton loop with
load stepping, which solves each linearisation with scipy's sparse direct solver.

Formulation (total Lagrangian, mixed u-p; Holzapfel, *Nonlinear Solid Mechanics*, sec. 8.4):
the in-plane deformation gradient F (2x2, with F33 = 1 for plane strain), J = det F,
I1 = tr(F^T F) + 1 and the isochoric invariant Ibar1 = J^(-2/3) I1. The strain energy is the
Yeoh law of the paper's eq. 5 on the isochoric invariant,

    W = C10 (Ibar1 - 3) + C20 (Ibar1 - 3)^2 + p (J - 1) - p^2 / (2 kappa),

where the pressure field p enforces J = 1 (kappa = inf: exactly incompressible, as the paper's
Assumption 1; a finite kappa makes it nearly so). The nominal stress is
P = W'(Ibar1) dIbar1/dF + p J F^-T.

A gas pressure q on a cavity wall is a follower load: it acts along the current normal on the
current length. In 2-D that force per reference length is q R (F T), with T the reference unit
tangent of the wall and R the quarter turn taking T to the outward normal N; it is linear in the
displacement, so its tangent is q R (grad du T) exactly.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import scipy.sparse
import scipy.sparse.linalg
from skfem import (Basis, BilinearForm, ElementTriP1, ElementTriP2, ElementVector, FacetBasis,
                   LinearForm)
from skfem.helpers import grad

_I2 = np.eye(2)[:, :, None, None]
QUADRATURE_ORDER = 4  # exact for the P2 x P2 mass; the hyperelastic terms are not polynomial
# the incompressibility residual (m^2 per unit width) weighs as a force through mu / 1 mm
CONSTRAINT_LENGTH_M = 1e-3
LINE_SEARCH_LENGTHS = (1.0, 0.5, 0.25, 0.125)


@dataclasses.dataclass(frozen=True)
class YeohMaterial:
    """The paper's Yeoh constants (eq. 5, C30 = 0) and the bulk modulus of the volumetric part
    (inf: exactly incompressible). Pa."""

    c10_pa: float = 0.08e6
    c20_pa: float = 0.015e6
    bulk_modulus_pa: float = math.inf

    def __post_init__(self):
        if not (math.isfinite(self.c10_pa) and self.c10_pa > 0.0):
            raise ValueError(f"C10 must be positive, got {self.c10_pa!r}")
        if not (math.isfinite(self.c20_pa) and self.c20_pa >= 0.0):
            raise ValueError(f"C20 must be >= 0, got {self.c20_pa!r}")
        if not self.bulk_modulus_pa > 0.0:
            raise ValueError(f"the bulk modulus must be positive, got {self.bulk_modulus_pa!r}")

    @property
    def shear_modulus_pa(self) -> float:
        """The small-strain shear modulus, 2 C10."""
        return 2.0 * self.c10_pa


def _mat(a, b):
    return np.einsum("ik...,kj...->ij...", a, b)


def _ddot(a, b):
    return np.einsum("ij...,ij...->...", a, b)


class _Kinematics:
    """F and the quantities of the stress and tangent at every quadrature point of a state."""

    def __init__(self, grad_u, pressure, material: YeohMaterial):
        F = grad_u + _I2
        self.F = F
        self.J = F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]
        if np.any(self.J <= 0.0):
            raise FloatingPointError("an element turned inside out (J <= 0)")
        self.inv_t = np.array([[F[1, 1], -F[1, 0]], [-F[0, 1], F[0, 0]]]) / self.J  # F^-T
        self.I1 = _ddot(F, F) + 1.0
        self.j23 = self.J**(-2.0 / 3.0)
        ibar = self.j23 * self.I1
        self.dibar = self.j23 * (2.0 * F - (2.0 / 3.0) * self.I1 * self.inv_t)  # dIbar1/dF
        self.w1 = material.c10_pa + 2.0 * material.c20_pa * (ibar - 3.0)  # W'(Ibar1)
        self.w2 = 2.0 * material.c20_pa  # W''(Ibar1)
        self.p = pressure

    def stress(self):
        """The nominal (first Piola-Kirchhoff) stress P, in-plane."""
        return self.w1 * self.dibar + self.p * self.J * self.inv_t

    def stress_increment(self, dF):
        """dP/dF : dF at fixed p."""
        tr = _ddot(self.inv_t, dF)  # tr(F^-1 dF)
        inv_dft_inv = np.einsum("ik...,lk...,lj...->ij...", self.inv_t, dF, self.inv_t)
        d_dibar = (-(2.0 / 3.0) * tr * self.dibar + self.j23 *
                   (2.0 * dF - (4.0 / 3.0) * _ddot(self.F, dF) * self.inv_t +
                    (2.0 / 3.0) * self.I1 * inv_dft_inv))
        return (self.w2 * _ddot(self.dibar, dF) * self.dibar + self.w1 * d_dibar +
                self.p * self.J * (tr * self.inv_t - inv_dft_inv))


def _state_forms(state, inv_kappa):
    """The residual and tangent forms at one state (scikit-fem passes arrays, not objects, as
    form parameters, so the state is closed over)."""

    def k_uu(du, v, _):
        return _ddot(state.stress_increment(grad(du)), grad(v))

    def k_up(dp, v, _):
        return dp * _ddot(state.J * state.inv_t, grad(v))

    def r_u(v, _):
        return _ddot(state.stress(), grad(v))

    def r_p(q, _):
        return (state.J - 1.0 - state.p * inv_kappa) * q

    return BilinearForm(k_uu), BilinearForm(k_up), LinearForm(r_u), LinearForm(r_p)


@BilinearForm
def _m_pp(dp, q, w):
    return dp * q


def _quarter_turn(a):
    """R: the rotation taking the wall tangent T = (-N_y, N_x) to its outward normal N."""
    return np.array([a[1], -a[0]])


@LinearForm
def _follower_load(v, w):
    tangent = np.array([-w.n[1], w.n[0]])
    current = tangent + np.einsum("ij...,j...->i...", w.grad_u, tangent)  # F T
    return -w.q * np.einsum("i...,i...->...", v, _quarter_turn(current))


@BilinearForm
def _follower_tangent(du, v, w):
    tangent = np.array([-w.n[1], w.n[0]])
    return -w.q * np.einsum("i...,i...->...", v,
                            _quarter_turn(np.einsum("ij...,j...->i...", grad(du), tangent)))


class NotConverged(RuntimeError):
    """Newton failed at a load level even after cutting the step."""


@dataclasses.dataclass
class SolverStats:
    newton_iterations: int = 0
    load_steps: int = 0
    step_cuts: int = 0


class HyperelasticSolid:
    """A plane-strain Yeoh body on a triangle mesh, with Dirichlet displacements and gas
    pressure on named boundaries.

    mesh: a skfem.MeshTri (metres). pressure_facets: {name: facet indices} of walls that a gas
    pressure loads. :meth:`fix` holds displacement dofs (none at first).
    """

    def __init__(self, mesh, material: YeohMaterial, pressure_facets: dict,
                 quadrature_order: int = QUADRATURE_ORDER):
        self.mesh = mesh
        self.material = material
        self.basis_u = Basis(mesh, ElementVector(ElementTriP2()), intorder=quadrature_order)
        self.basis_p = self.basis_u.with_element(ElementTriP1())
        self.facet_bases = {
            name: FacetBasis(mesh, ElementVector(ElementTriP2()), facets=np.asarray(facets),
                             intorder=quadrature_order)
            for name, facets in pressure_facets.items()
        }
        self.n_u = self.basis_u.N
        self.n_p = self.basis_p.N
        self.u = np.zeros(self.n_u)
        self.p = np.zeros(self.n_p)
        self.gas_pressures = {name: 0.0 for name in pressure_facets}
        self.dirichlet_scale = 0.0
        self.stats = SolverStats()
        kappa = material.bulk_modulus_pa
        self._inv_kappa = 0.0 if math.isinf(kappa) else 1.0 / kappa
        self._m_pp = _m_pp.assemble(self.basis_p) if self._inv_kappa else None
        self.fix([])

    # ---- set-up helpers ----------------------------------------------------------------------
    def fix(self, dofs, displacement_m=None):
        """Hold these displacement dofs (from :meth:`dofs_on`); at ``solve``'s dirichlet_scale = 1
        they sit at ``displacement_m`` (a dof -> metres mapping of some of them; the rest 0)."""
        self.fixed_dofs = np.unique(np.asarray(dofs, dtype=np.int64))
        displacement_m = displacement_m or {}
        self.fixed_values = np.array([displacement_m.get(int(d), 0.0) for d in self.fixed_dofs])
        free = np.ones(self.n_u + self.n_p, dtype=bool)
        free[self.fixed_dofs] = False
        self._free = np.flatnonzero(free)

    def dofs_on(self, facets, components=(0, 1)):
        """Displacement dofs on the given boundary facets, for the given components."""
        dofs = self.basis_u.get_dofs(facets=np.asarray(facets))
        return np.concatenate([dofs.nodal[f"u^{c + 1}"] for c in components] +
                              [dofs.facet[f"u^{c + 1}"] for c in components])

    # ---- the equations -----------------------------------------------------------------------
    def _state(self, u, p):
        pressure = np.asarray(self.basis_p.interpolate(p))
        return _Kinematics(grad(self.basis_u.interpolate(u)), pressure, self.material)

    def _residual_and_tangent(self, u, p, gas, tangent=True):
        state = self._state(u, p)
        form_k_uu, form_k_up, form_r_u, form_r_p = _state_forms(state, self._inv_kappa)
        r_u = form_r_u.assemble(self.basis_u)
        r_p = form_r_p.assemble(self.basis_p)
        k_uu = form_k_uu.assemble(self.basis_u) if tangent else None
        for name, fbasis in self.facet_bases.items():
            q = gas[name]
            if q == 0.0:
                continue
            grad_u = grad(fbasis.interpolate(u))
            r_u = r_u - _follower_load.assemble(fbasis, q=q, grad_u=grad_u)
            if tangent:
                k_uu = k_uu - _follower_tangent.assemble(fbasis, q=q)
        residual = np.concatenate([r_u, r_p])
        if not tangent:
            return residual, None
        k_up = form_k_up.assemble(self.basis_p, self.basis_u)
        k_pp = (-self._inv_kappa * self._m_pp if self._inv_kappa else
                scipy.sparse.csr_matrix((self.n_p, self.n_p)))
        matrix = scipy.sparse.bmat([[k_uu, k_up], [k_up.T, k_pp]], format="csr")
        return residual, matrix

    def _newton(self, gas, dirichlet_scale, tolerance, max_iterations, guess=None):
        """Newton with a backtracking line search on the residual norm (a full step through a
        large rotation can turn an element inside out, or overshoot)."""
        u, p = (self.u.copy(), self.p.copy()) if guess is None else guess
        u[self.fixed_dofs] = dirichlet_scale * self.fixed_values
        residual, matrix = self._residual_and_tangent(u, p, gas)
        residual[self.fixed_dofs] = 0.0
        norm = self._norm(residual)
        scale = max(norm, self._force_scale(gas))
        free = self._free
        for iteration in range(1, max_iterations + 1):
            if not math.isfinite(norm):
                raise NotConverged("the residual is not finite")
            step = scipy.sparse.linalg.spsolve(matrix[free][:, free].tocsc(), -residual[free])
            if not np.all(np.isfinite(step)):
                raise NotConverged("the linear solve failed")
            self.stats.newton_iterations += 1
            x0 = np.concatenate([u, p])
            for length in LINE_SEARCH_LENGTHS:
                x = x0.copy()
                x[free] += length * step
                try:
                    trial = self._residual_and_tangent(x[:self.n_u], x[self.n_u:], gas)
                except FloatingPointError:
                    continue
                trial[0][self.fixed_dofs] = 0.0
                trial_norm = self._norm(trial[0])
                if trial_norm < norm or length == LINE_SEARCH_LENGTHS[-1]:
                    break
            else:
                raise NotConverged("every step of the line search turned an element inside out")
            u, p = x[:self.n_u], x[self.n_u:]
            (residual, matrix), norm = trial, trial_norm
            if norm <= tolerance * scale:
                return u, p, iteration
        raise NotConverged(f"no convergence in {max_iterations} Newton iterations")

    def _norm(self, residual):
        weight = self.material.shear_modulus_pa / CONSTRAINT_LENGTH_M
        return math.hypot(float(np.linalg.norm(residual[:self.n_u])),
                          weight * float(np.linalg.norm(residual[self.n_u:])))

    def _force_scale(self, gas):
        """A residual scale that does not vanish at zero load: the largest gas pressure's force,
        or the shear modulus's, on a unit length."""
        return max([abs(q) for q in gas.values()] + [1e-3 * self.material.shear_modulus_pa])

    def solve(self, gas_pressures: dict, dirichlet_scale: float | None = None,
              first_step_pa: float = 5e3, min_step_pa: float = 50.0, tolerance: float = 1e-9,
              max_iterations: int = 20, progress=None):
        """Move from the present gas pressures to ``gas_pressures`` ({name: Pa}), and the fixed
        dofs to ``dirichlet_scale`` times ``fixed_values``, in load steps, cutting a step in
        half when Newton fails there. NotConverged when a step below ``min_step_pa`` (of gas
        pressure; a thousandth of the scale for the displacement) still fails; the state then
        stays at the last converged load."""
        start = dict(self.gas_pressures)
        target = {name: float(gas_pressures.get(name, start[name])) for name in start}
        scale_start = self.dirichlet_scale
        scale_target = scale_start if dirichlet_scale is None else float(dirichlet_scale)
        span = max([abs(target[n] - start[n]) for n in start] +
                   [abs(scale_target - scale_start) * 1e5])  # 1 % of the scale ~ 1 kPa
        if span == 0.0:
            return
        done, step = 0.0, min(1.0, first_step_pa / span)
        last = None  # (increment of u, of p, of the load fraction): a secant predictor
        while done < 1.0:
            fraction = min(1.0, done + step)
            gas = {n: start[n] + fraction * (target[n] - start[n]) for n in start}
            scale = scale_start + fraction * (scale_target - scale_start)
            try:
                guess = None
                if last is not None:
                    ratio = (fraction - done) / last[2]
                    guess = (self.u + ratio * last[0], self.p + ratio * last[1])
                u, p, _ = self._newton(gas, scale, tolerance, max_iterations, guess)
            except (NotConverged, FloatingPointError) as error:
                step *= 0.5
                self.stats.step_cuts += 1
                if step * span < min_step_pa:
                    raise NotConverged(
                        f"stopped at {self._describe(self.gas_pressures)}: {error}") from None
                continue
            last = (u - self.u, p - self.p, fraction - done)
            self.u, self.p, self.gas_pressures, self.dirichlet_scale = u, p, gas, scale
            self.stats.load_steps += 1
            done = fraction
            step = min(2.0 * step, first_step_pa / span * 2.0)
            if progress is not None:
                progress(gas)

    @staticmethod
    def _describe(gas):
        return ", ".join(f"{name} {q / 1e3:+.2f} kPa" for name, q in sorted(gas.items()))

    # ---- results -----------------------------------------------------------------------------
    def nodal_displacement(self):
        """(2, n_vertices): the displacement of each mesh vertex."""
        return self.u[self.basis_u.nodal_dofs]

    def deformed_vertices(self):
        return self.mesh.p + self.nodal_displacement()

    def volume_ratio(self):
        """The deformed over the reference area of the body (plane strain: per unit width)."""
        deformed, reference = self.element_areas()
        return float(deformed.sum() / reference.sum())

    def element_areas(self):
        """Per element, its deformed and its reference area (per unit width)."""
        state = self._state(self.u, self.p)
        dx = self.basis_u.dx
        return np.sum(state.J * dx, axis=1), np.sum(dx, axis=1)

    def reaction(self, dofs):
        """The sum of the internal forces on the given displacement dofs (N per m of width)."""
        residual, _ = self._residual_and_tangent(self.u, self.p, self.gas_pressures,
                                                 tangent=False)
        return float(np.sum(residual[np.asarray(dofs)]))

"""Bending laws: gauge pressure p -> the five segment bend angles theta_i (rad).

Positive theta curls a finger outward (opens the gripper), negative inward.

**L0, the paper's linear law** (eq. 16-17)::

    theta_i = g * p * L_s * (m_i - 2 b)^2 / (32 t C10 d^2),   theta = sum_i theta_i

The paper's symbols are ambiguous (its "L1" in eq. 16 is the single section of its
Fig. 7 and eq. 10, not Table 1's total length). Our mapping to Table 1:

============  =====================================  ==========
paper         meaning                                Table 1
============  =====================================  ==========
L_s (L1)      arc length of one bending section      L3 + h3 = 17 mm
m_i           chamber depth                          m2..m6
b             wall of the simplified section          m1 = 3 mm
t             chamber wall thickness (eq. 10)        m1 = 3 mm
d             chamber bottom to sidewall             d2 = 13 mm
C1            Yeoh C10                               0.08 MPa
g             calibration gain per cavity type       (fitted)
============  =====================================  ==========

It is the linearisation of a chain that L1 keeps whole: the pressure moment on
a chamber's end wall loads the chamber wall with the stress
``sigma_w = g p (m_i - 2b)^2 / (2 d^2)``; the wall stretches by
``lambda - 1 = sigma_w / (8 C10)`` (planar small-strain modulus); the section bends by
``theta = (lambda - 1) L_s / (2 t)`` (eq. 10).

**L1, the nonlinear Yeoh moment balance**: the same chain with the full planar Yeoh
stress, ``P_planar(lambda_i) = sigma_w``, solved per segment with a bracketed root
finder. Its slope at p -> 0 equals L0's; above that the silicone stiffens.

**Saturation** (paper Sec. 4, Fig. 18): the FEA curvature follows the linear model up
to about 46 kPa, then grows only 7.5 % from 50 to 55 kPa and 0.61 % from 55 to 60 kPa.
Both laws see an effective pressure, a smooth minimum of p and the saturation
pressure p_sat with width w, shifted so that p_eff(0) = 0 exactly::

    p_eff = -w ln(exp(-p/w) + exp(-p_sat/w)) + w ln(1 + exp(-p_sat/w))
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.optimize import brentq

from softgrip_ros.model.geometry import FingerGeometry
from softgrip_ros.model.material import YeohMaterial


@dataclasses.dataclass(frozen=True)
class BendingCalibration:
    """The fitted constants of one cavity type (see softgrip_ros.model.calibration).

    gain: g of eq. 16 (dimensionless).
    ballooning_compliance_per_pa: chamber-face bulge per unit pressure, as a fraction of
        m_i^2 / L3 (1/Pa); see kinematics.
    saturation_pressure_pa, saturation_width_pa: p_sat and w of the saturation.
    validated_max_pressure_pa: the upper end of the pressure range in which the model
        was checked against the paper's FEA.
    """

    gain: float = 1.0
    ballooning_compliance_per_pa: float = 0.0
    saturation_pressure_pa: float = math.inf
    saturation_width_pa: float = 2.0e3
    validated_max_pressure_pa: float = 46.0e3

    def __post_init__(self):
        if not (math.isfinite(self.gain) and self.gain > 0.0):
            raise ValueError(f"calibration gain must be positive and finite, got {self.gain}")
        if not (math.isfinite(self.ballooning_compliance_per_pa) and
                self.ballooning_compliance_per_pa >= 0.0):
            raise ValueError("ballooning_compliance_per_pa must be finite and >= 0, "
                             f"got {self.ballooning_compliance_per_pa}")
        if not self.saturation_pressure_pa > 0.0:
            raise ValueError(
                f"saturation_pressure_pa must be > 0, got {self.saturation_pressure_pa}")
        if not (math.isfinite(self.saturation_width_pa) and self.saturation_width_pa > 0.0):
            raise ValueError(
                f"saturation_width_pa must be positive and finite, got {self.saturation_width_pa}")
        if not (math.isfinite(self.validated_max_pressure_pa) and
                self.validated_max_pressure_pa > 0.0):
            raise ValueError("validated_max_pressure_pa must be positive and finite")


class Saturation:
    """p -> p_eff, the smooth limit of the bending drive above about 50 kPa."""

    def __init__(self, calibration: BendingCalibration):
        self.pressure_pa = calibration.saturation_pressure_pa
        self.width_pa = calibration.saturation_width_pa
        self._enabled = math.isfinite(self.pressure_pa)
        self._offset = (self.width_pa * math.log1p(math.exp(-self.pressure_pa / self.width_pa))
                        if self._enabled else 0.0)

    def effective_pressure(self, pressure_pa):
        if not self._enabled:
            return pressure_pa
        w = self.width_pa
        if isinstance(pressure_pa, float):
            return -w * _logaddexp(-pressure_pa / w, -self.pressure_pa / w) + self._offset
        p = np.asarray(pressure_pa)
        excess = (p - self.pressure_pa) / w
        if excess.size and np.max(excess) > 700.0:  # exp would overflow: a very narrow knee
            return -w * np.logaddexp(-p / w, -self.pressure_pa / w) + self._offset
        # the same value as p - w log(1 + exp(excess)); np.exp is vectorised, np.logaddexp is not
        return p - w * np.log1p(np.exp(excess)) + self._offset

    def slope(self, pressure_pa):
        """d p_eff / d p, in (0, 1]."""
        if not self._enabled:
            return (1.0 if isinstance(pressure_pa, float) else np.ones_like(
                np.asarray(pressure_pa, dtype=float)))
        z = (np.asarray(pressure_pa, dtype=float) - self.pressure_pa) / self.width_pa
        if isinstance(pressure_pa, float):
            return 0.5 * (1.0 - math.tanh(0.5 * float(z)))
        return 0.5 * (1.0 - np.tanh(0.5 * z))


def _logaddexp(a: float, b: float) -> float:
    high = a if a > b else b
    return high + math.log1p(math.exp(-abs(a - b)))


class LinearBending:
    """L0: theta_i = k_i * p_eff with k_i from eq. 16 (rad/Pa)."""

    name = "l0"

    def __init__(self, geometry: FingerGeometry, material: YeohMaterial,
                 calibration: BendingCalibration):
        self.geometry, self.material, self.calibration = geometry, material, calibration
        self.saturation = Saturation(calibration)
        section = geometry.segment_length_m
        wall = geometry.wall_thickness_m
        d = geometry.chamber_bottom_to_sidewall_m
        self.gains_rad_per_pa = tuple(calibration.gain * section * (depth - 2.0 * wall)**2 /
                                      (32.0 * wall * material.c10_pa * d * d)
                                      for depth in geometry.chamber_depths_m)
        self._gains = np.array(self.gains_rad_per_pa)

    def angles(self, pressure_pa):
        """theta_i for one pressure (float -> tuple of 5) or an array (shape (N,) -> (N, 5))."""
        p_eff = self.saturation.effective_pressure(pressure_pa)
        if isinstance(p_eff, float):
            return tuple(k * p_eff for k in self.gains_rad_per_pa)
        return np.multiply.outer(p_eff, self._gains)

    def angle_columns(self, pressures_pa: np.ndarray, effective_pressures_pa=None) -> list:
        """theta_i for a 1-D batch as 5 contiguous arrays (the fast batch path).
        Pass the batch's effective pressures if they are already known."""
        if effective_pressures_pa is None:
            effective_pressures_pa = self.saturation.effective_pressure(pressures_pa)
        return [k * effective_pressures_pa for k in self.gains_rad_per_pa]

    def angle_slopes(self, pressure_pa):
        """d theta_i / d p (rad/Pa), same shapes as :meth:`angles`."""
        slope = self.saturation.slope(pressure_pa)
        if isinstance(slope, float):
            return tuple(k * slope for k in self.gains_rad_per_pa)
        return np.multiply.outer(slope, self._gains)


class YeohMomentBalance:
    """L1: per segment, P_planar(1 + e_i) = sigma_w,i(p_eff); theta_i = e_i L_s / (2 t).

    Solved for the wall strain e = lambda - 1 (not lambda), so that tiny pressures keep
    full relative precision.
    """

    name = "l1"
    STRAIN_FLOOR = -0.95  # a chamber wall compressed beyond this has collapsed

    def __init__(self, geometry: FingerGeometry, material: YeohMaterial,
                 calibration: BendingCalibration):
        self.geometry, self.material, self.calibration = geometry, material, calibration
        self.saturation = Saturation(calibration)
        d = geometry.chamber_bottom_to_sidewall_m
        wall = geometry.wall_thickness_m
        self.stress_per_pa = tuple(calibration.gain * (depth - 2.0 * wall)**2 / (2.0 * d * d)
                                   for depth in geometry.chamber_depths_m)
        self._stress_per_pa = np.array(self.stress_per_pa)
        self.angle_per_strain = geometry.segment_length_m / (2.0 * wall)
        c10, c20, c30 = material.c10_pa, material.c20_pa, material.c30_pa

        def planar_stress(e: float) -> float:
            one_plus = 1.0 + e
            x = (e * (2.0 + e) / one_plus)**2
            return 2.0 * e * (4.0 + e * (6.0 + e *
                                         (4.0 + e))) / one_plus**3 * (c10 + 2.0 * c20 * x +
                                                                      3.0 * c30 * x * x)

        self._planar_stress = planar_stress
        self._floor_stress = planar_stress(self.STRAIN_FLOOR)

    def strain(self, wall_stress_pa: float) -> float:
        """e with P_planar(1 + e) = wall_stress_pa, by Brent's method on a bracket."""
        if wall_stress_pa == 0.0:
            return 0.0
        if wall_stress_pa <= self._floor_stress:
            return self.STRAIN_FLOOR
        f = self._planar_stress
        guess = wall_stress_pa / self.material.planar_modulus_pa
        if wall_stress_pa > 0.0:
            low, high = 0.0, guess
            while f(high) < wall_stress_pa:
                low, high = high, 2.0 * high
        else:
            low, high = max(self.STRAIN_FLOOR, guess), 0.0
            if f(low) > wall_stress_pa:
                low = self.STRAIN_FLOOR
        return brentq(lambda e: f(e) - wall_stress_pa, low, high, xtol=1e-300,
                      rtol=4 * np.finfo(float).eps)

    def strains(self, wall_stress_pa: np.ndarray) -> np.ndarray:
        """Vectorised :meth:`strain`: Newton steps kept inside a bisection bracket."""
        sigma = np.asarray(wall_stress_pa, dtype=float)
        stress = self.material.planar_nominal_stress_of_strain
        e = sigma / self.material.planar_modulus_pa
        low = np.where(sigma >= 0.0, 0.0, self.STRAIN_FLOOR)
        high = np.where(sigma >= 0.0, np.maximum(e, 0.0), 0.0)
        while True:  # grow the upper bracket until it holds the root
            short = (sigma > 0.0) & (stress(high) < sigma)
            if not short.any():
                break
            low = np.where(short, high, low)
            high = np.where(short, 2.0 * high, high)
        e = np.clip(e, low, high)
        for _ in range(100):
            residual = stress(e) - sigma
            low = np.where(residual < 0.0, e, low)
            high = np.where(residual > 0.0, e, high)
            candidate = e - residual / self.material.planar_nominal_stress_slope(1.0 + e)
            outside = (candidate < low) | (candidate > high)
            candidate = np.where(outside, 0.5 * (low + high), candidate)
            # done when the step, the residual or the bracket is down to rounding
            # (a converged root can otherwise ping-pong between its two neighbours)
            rounding = 8 * np.finfo(float).eps
            done = ((np.abs(candidate - e) <= rounding * np.abs(e)) |
                    (np.abs(residual) <= rounding * np.abs(sigma))
                    | (high - low <= rounding * np.abs(e)))
            e = np.where(done, e, candidate)
            if done.all():
                break
        return np.where(sigma <= self._floor_stress, self.STRAIN_FLOOR, e)

    def angles(self, pressure_pa):
        p_eff = self.saturation.effective_pressure(pressure_pa)
        if isinstance(p_eff, float):
            return tuple(
                self.strain(s * p_eff) * self.angle_per_strain for s in self.stress_per_pa)
        return self.strains(np.multiply.outer(p_eff, self._stress_per_pa)) * self.angle_per_strain

    def angle_columns(self, pressures_pa: np.ndarray, effective_pressures_pa=None) -> list:
        """theta_i for a 1-D batch as 5 contiguous arrays."""
        if effective_pressures_pa is None:
            effective_pressures_pa = self.saturation.effective_pressure(pressures_pa)
        sigma = np.multiply.outer(effective_pressures_pa, self._stress_per_pa)
        return list(np.ascontiguousarray((self.strains(sigma) * self.angle_per_strain).T))

    def angle_slopes(self, pressure_pa):
        """d theta_i / d p by the implicit function theorem: de/dsigma = 1 / P'(1 + e)."""
        p = np.asarray(pressure_pa, dtype=float)
        sigma = np.multiply.outer(self.saturation.effective_pressure(p), self._stress_per_pa)
        e = self.strains(sigma)
        slopes = (self.angle_per_strain * self._stress_per_pa /
                  self.material.planar_nominal_stress_slope(1.0 + e) *
                  np.expand_dims(self.saturation.slope(p), -1))
        if isinstance(pressure_pa, float):
            return tuple(float(v) for v in slopes)
        return slopes


BENDING_LAWS = {LinearBending.name: LinearBending, YeohMomentBalance.name: YeohMomentBalance}


def make_bending_law(name: str, geometry: FingerGeometry, material: YeohMaterial,
                     calibration: BendingCalibration):
    try:
        law = BENDING_LAWS[name]
    except KeyError:
        raise ValueError(
            f"unknown bending model {name!r}; choose one of {sorted(BENDING_LAWS)}") from None
    return law(geometry, material, calibration)

"""The three pressure filters on filterpy 2.0, behind one small interface.

State (all three): ``x = [chamber gauge pressure, regulator output gauge pressure]`` in Pa,
shape (2, 1); covariance ``P`` shape (2, 2) in Pa^2. Inputs: the plant's
:class:`~softgrip_ros.model.pneumatics.PlantInputs` (regulator command, regulator enabled,
valve state). Measurements: chamber gauge pressures, ``z`` shape (m, 1) for m sensors at one
instant, each row of ``H`` picking the chamber (``[1, 0]``), ``R`` shape (m, m) diagonal.

- :class:`LinearFilter` (``kf``): a linear lag model. Over one step the chamber relaxes to its
  valve's source as ``exp(-lambda dt)``, with lambda the secant rate of the ISO 6358 flow at the
  current estimate, and the regulator relaxes to its command as ``exp(-dt/tau)``. It is linear in
  the state (F, B known each step), so filterpy's ``KalmanFilter`` runs it. Exponential
  discretisation keeps F in [0, 1] however stiff the flow, which explicit Euler would not.
- :class:`PlantEKF` (``ekf``): the ISO 6358 plant stepped by backward Euler
  (:meth:`PneumaticPlant.chamber_step`), with its exact Jacobian from the implicit function
  theorem.
- :class:`PlantUKF` (``ukf``): the same plant step on Merwe scaled sigma points.

Covariance updates use the Joseph form (filterpy's ``KalmanFilter`` and ``ExtendedKalmanFilter``
already do; the UKF's ``P - K S K'`` is replaced by it, which is exact here because h is linear),
and every update re-symmetrises P.

Process noise ``q_continuous`` (2, 2) is a spectral density in Pa^2/s; a step of dt adds
``q_continuous * dt``.
"""
from __future__ import annotations

import math

import numpy as np
from filterpy.kalman import (ExtendedKalmanFilter, KalmanFilter, MerweScaledSigmaPoints,
                             UnscentedKalmanFilter)

from softgrip_ros.estimation.config import FILTER_TYPES
from softgrip_ros.model.pneumatics import P_ATM_PA, PlantInputs, PneumaticPlant, Valve

CHAMBER, REGULATOR = 0, 1
_MIN_ABSOLUTE_PA = 1_000.0  # a sigma point or a wild estimate must not reach 0 Pa absolute
_MAX_SECANT_RATE_PER_S = 1e5  # lambda near equilibrium, where the flow's slope is unbounded


def _valve(inputs: PlantInputs) -> Valve:
    valve = inputs.valves[0]
    return valve if type(valve) is Valve else Valve(valve)  # an enum's call costs a microsecond


def plant_step(plant: PneumaticPlant, x: np.ndarray, dt: float, inputs: PlantInputs,
               jacobian: bool = False):
    """x (2,) or (2, 1) -> the plant's state after dt (and its 2x2 Jacobian when asked)."""
    chamber_gauge, regulator_gauge = float(x[CHAMBER]), float(x[REGULATOR])
    regulator_next, d_regulator = plant.regulator_step(regulator_gauge, inputs, dt)
    chamber_pa = max(chamber_gauge + P_ATM_PA, _MIN_ABSOLUTE_PA)
    chamber_next, d_chamber, d_chamber_d_regulator = plant.chamber_step(
        chamber_pa, _valve(inputs), regulator_next, dt, inputs.regulator_enabled)
    state = np.array([chamber_next - P_ATM_PA, regulator_next])
    if not jacobian:
        return state
    return state, np.array([[d_chamber, d_chamber_d_regulator * d_regulator], [0.0, d_regulator]])


def chamber_rate(plant: PneumaticPlant, x: np.ndarray, inputs: PlantInputs) -> float:
    """d(chamber)/dt (Pa/s) at the state x (2,) or (2, 1) under ``inputs``: the plant's flow
    law at that instant, with no step taken (a plant step's Newton solve costs several times
    more)."""
    chamber_pa = max(float(x[CHAMBER]) + P_ATM_PA, _MIN_ABSOLUTE_PA)
    return plant.chamber_rate(chamber_pa, _valve(inputs), float(x[REGULATOR]),
                              inputs.regulator_enabled)


def _upper_cholesky_2x2(A: np.ndarray) -> np.ndarray:
    """U with U' U = A for a 2x2 positive definite A (filterpy's sigma points take rows of U);
    closed form, a tenth of scipy's call overhead."""
    a = math.sqrt(A[0, 0])
    b = A[0, 1] / a
    return np.array([[a, b], [0.0, math.sqrt(A[1, 1] - b * b)]])


def _joseph(P_prior: np.ndarray, K: np.ndarray, H: np.ndarray, R: np.ndarray) -> np.ndarray:
    I_KH = np.eye(P_prior.shape[0]) - K @ H
    return _symmetric(I_KH @ P_prior @ I_KH.T + K @ R @ K.T)


def _inverse_small(S: np.ndarray) -> np.ndarray:
    """Inverse of the 1x1 or 2x2 innovation covariance (one or two sensors at an instant),
    closed form; numpy's general inv costs more than the rest of a KF update."""
    if S.shape == (1, 1):
        return np.array([[1.0 / S[0, 0]]])
    if S.shape == (2, 2):
        det = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
        return np.array([[S[1, 1], -S[0, 1]], [-S[1, 0], S[0, 0]]]) / det
    return np.linalg.inv(S)


def _symmetric(P: np.ndarray) -> np.ndarray:
    return 0.5 * (P + P.T)


def _symmetrise(P: np.ndarray) -> None:
    """Make the 2x2 ``P`` symmetric in place (a fresh array filterpy just computed): a third of
    the cost of building 0.5 (P + P')."""
    off_diagonal = 0.5 * (P[0, 1] + P[1, 0])
    P[0, 1] = P[1, 0] = off_diagonal


class PressureFilter:
    """The interface every filter type offers to
    :class:`~softgrip_ros.estimation.estimator.PressureEstimator`."""

    def __init__(self, plant: PneumaticPlant, x0: np.ndarray, P0: np.ndarray,
                 q_continuous: np.ndarray):
        self.plant = plant
        self.q_continuous = np.asarray(q_continuous, dtype=float)
        self._setup(np.asarray(x0, dtype=float).reshape(2, 1), np.asarray(P0, dtype=float))

    # filterpy object in self.f, with x (2, 1) and P (2, 2)
    @property
    def x(self) -> np.ndarray:
        return self.f.x

    @property
    def P(self) -> np.ndarray:
        return self.f.P

    def reset(self, x0, P0) -> None:
        self.f.x = np.asarray(x0, dtype=float).reshape(2, 1).copy()
        self.f.P = np.asarray(P0, dtype=float).copy()

    def add_covariance(self, extra: np.ndarray) -> None:
        """P += extra (2, 2), symmetric positive semi-definite (an uncertainty the model learns
        of)."""
        self.f.P = _symmetric(self.f.P + extra)

    def predict(self, dt: float, inputs: PlantInputs) -> None:
        raise NotImplementedError

    def update(self, z: np.ndarray, H: np.ndarray, R: np.ndarray) -> None:
        raise NotImplementedError

    def _setup(self, x0, P0):
        raise NotImplementedError


class LinearFilter(PressureFilter):
    """``kf``: filterpy ``KalmanFilter`` on the linear lag model (see the module docstring)."""

    def _setup(self, x0, P0):
        self.f = KalmanFilter(dim_x=2, dim_z=1)
        self.f.inv = _inverse_small
        self.reset(x0, P0)
        self._one = np.ones((1, 1))

    def transition(self, dt: float, inputs: PlantInputs) -> tuple[np.ndarray, np.ndarray]:
        """(F (2, 2), B (2, 1)) of one step from the current estimate: x' = F x + B.

        The chamber relaxes towards its source s as exp(-lambda dt). For the SUPPLY valve, s is
        the regulator's mid-step value, linear in the state: s = (r + r') / 2. lambda is the
        flow's secant rate (dp/dt) / (s - p) taken at the half step (a midpoint rule: second-order
        accurate in lambda dt, so the choked fill's constant flow is followed closely)."""
        valve = _valve(inputs)
        chamber_gauge, regulator_gauge = float(self.f.x[CHAMBER, 0]), float(self.f.x[REGULATOR, 0])
        # the regulator: r' = d r + u, its lag (d < 1) or, while rate-limited, a fixed slew (d = 1)
        regulator_next, decay_regulator = self.plant.regulator_step(regulator_gauge, inputs, dt)
        regulator_input = regulator_next - decay_regulator * regulator_gauge
        if valve == Valve.SUPPLY:  # s = a r + c
            a, c = 0.5 * (1.0 + decay_regulator), 0.5 * regulator_input
        else:
            a, c = 0.0, self.plant.source(valve, 0.0, inputs.regulator_enabled)[0] - P_ATM_PA
        source_gauge = a * regulator_gauge + c
        conductance, critical_ratio = self.plant.parameters.path(valve)
        decay = 1.0
        if conductance > 0.0:
            half = self._decay(chamber_gauge, source_gauge, conductance, critical_ratio, 0.5 * dt)
            midpoint = source_gauge + (chamber_gauge - source_gauge) * half
            decay = self._decay(midpoint, source_gauge, conductance, critical_ratio, dt)
        F = np.array([[decay, (1.0 - decay) * a], [0.0, decay_regulator]])
        B = np.array([[(1.0 - decay) * c], [regulator_input]])
        return F, B

    def _decay(self, chamber_gauge: float, source_gauge: float, conductance: float,
               critical_ratio: float, dt: float) -> float:
        gap = source_gauge - chamber_gauge
        if abs(gap) <= 1e-6:
            return math.exp(-_MAX_SECANT_RATE_PER_S * dt)
        rate = self.plant.rate_and_slopes(max(chamber_gauge + P_ATM_PA, _MIN_ABSOLUTE_PA),
                                          max(source_gauge + P_ATM_PA, _MIN_ABSOLUTE_PA),
                                          conductance, critical_ratio)[0]
        return math.exp(-min(max(rate / gap, 0.0), _MAX_SECANT_RATE_PER_S) * dt)

    def predict(self, dt: float, inputs: PlantInputs) -> None:
        # set as attributes, not passed: filterpy tests a passed Q (and R) with numpy's isscalar
        self.f.F, self.f.B = self.transition(dt, inputs)
        self.f.Q = self.q_continuous * dt
        self.f.predict(u=self._one)
        _symmetrise(self.f.P)

    def update(self, z, H, R) -> None:
        # filterpy shapes z by dim_z; the sensors present vary per instant
        self.f.dim_z = len(z)
        self.f.R = R
        self.f.update(z, H=H)  # (without H, filterpy reshapes z first)
        _symmetrise(self.f.P)


class _PlantEKFCore(ExtendedKalmanFilter):
    """filterpy's EKF with the plant as its state transition: predict_x sets x and F together."""

    def predict_x(self, u=0):
        plant, dt, inputs = u
        x, self.F = plant_step(plant, self.x[:, 0], dt, inputs, jacobian=True)
        self.x = x.reshape(2, 1)


class PlantEKF(PressureFilter):
    """``ekf``: backward-Euler plant with its exact Jacobian."""

    def _setup(self, x0, P0):
        self.f = _PlantEKFCore(dim_x=2, dim_z=1)
        self.reset(x0, P0)
        self._H = None

    def predict(self, dt: float, inputs: PlantInputs) -> None:
        self.f.Q = self.q_continuous * dt
        self.f.predict(u=(self.plant, dt, inputs))
        _symmetrise(self.f.P)

    def update(self, z, H, R) -> None:
        self._H = H
        self.f.update(z, self._jacobian, self._measure, R=R)
        _symmetrise(self.f.P)

    def _jacobian(self, x):
        return self._H

    def _measure(self, x):
        return self._H @ x


class PlantUKF(PressureFilter):
    """``ukf``: the plant on Merwe scaled sigma points (alpha 1, beta 2, kappa 1: all weights
    positive for n = 2, so the predicted covariance cannot lose definiteness)."""

    def _setup(self, x0, P0):
        points = MerweScaledSigmaPoints(2, alpha=1.0, beta=2.0, kappa=1.0,
                                        sqrt_method=_upper_cholesky_2x2)
        self.f = UnscentedKalmanFilter(dim_x=2, dim_z=1, dt=1e-3, hx=self._measure,
                                       fx=self._transition, points=points)
        self.f.inv = _inverse_small
        self.reset(x0, P0)

    @property
    def x(self) -> np.ndarray:
        return self.f.x.reshape(2, 1)

    def reset(self, x0, P0) -> None:
        self.f.x = np.asarray(x0, dtype=float).reshape(2).copy()
        self.f.P = np.asarray(P0, dtype=float).copy()
        self._sigmas_stale = True

    def add_covariance(self, extra: np.ndarray) -> None:
        super().add_covariance(extra)
        self._sigmas_stale = True  # the last predict's sigma points no longer span P

    def _transition(self, x, dt, inputs=None):
        return plant_step(self.plant, x, dt, inputs) if dt > 0.0 else np.array(x, dtype=float)

    def _measure(self, x, H=None):
        return H @ x

    def predict(self, dt: float, inputs: PlantInputs) -> None:
        self.f.Q = self.q_continuous * dt
        self.f.predict(dt=dt, inputs=inputs)
        self.f.P = _symmetric(self.f.P)
        self._sigmas_stale = False

    def update(self, z, H, R) -> None:
        if self._sigmas_stale:  # filterpy's update reuses the last predict's sigma points
            self.predict(0.0, None)
        self._sigmas_stale = True
        P_prior = self.f.P.copy()
        self.f.update(np.asarray(z, dtype=float).reshape(-1), R=R, H=H)
        self.f.P = _joseph(P_prior, self.f.K, H, R)


def make_filter(filter_type: str, plant: PneumaticPlant, x0, P0, q_continuous) -> PressureFilter:
    """The filter of ``filter_type`` (one of config.FILTER_TYPES); ValueError for another."""
    classes = dict(zip(FILTER_TYPES, (LinearFilter, PlantEKF, PlantUKF)))
    if filter_type not in classes:
        raise ValueError(f"filter_type must be one of {list(classes)}, got {filter_type!r}")
    return classes[filter_type](plant, x0, P0, q_continuous)

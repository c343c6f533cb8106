"""Fusing asynchronous pressure sensors into one chamber-pressure estimate, robustly.

:class:`PressureEstimator` owns one filter (:mod:`softgrip_ros.estimation.filters`) and adds what
a filter alone does not do:

- **Time.** Each sample is applied at its own stamp: the filter predicts to it (in sub-steps of
  at most ``max_step_s``) with the inputs then in force, then updates. A sample a little older
  than the filter's time (up to ``max_lag_s``, transport jitter) is applied at the filter's time;
  an older one is dropped and counted.
- **Gating.** Each sensor's sample is tested by its Mahalanobis distance, d^2 = y^2 / S, against
  that sensor's chi-square threshold (1 degree of freedom); a sample beyond it is rejected and
  counted. After ``max_consecutive_rejections`` in a row from every live sensor the filter is
  re-initialised from the measurements and the event is reported (a gate must not lock the
  filter out of the truth for ever).
- **Dropouts.** A sensor silent for ``sensor_timeout_s`` is not alive; the filter keeps
  predicting, its variance grows by Q, and it rejoins at its next sample.
- **Consistency.** The normalised innovation squared (NIS) of each sensor is averaged over a
  window of ``nis_window`` samples and compared with the two-sided chi-square interval of
  probability ``nis_confidence``: too large means the filter trusts its model or a sensor more
  than the data allow (R or Q too small, a biased sensor), too small means it is
  over-cautious. Either is reported.
"""
from __future__ import annotations

import collections
import dataclasses
import enum
import math

import numpy as np
from scipy.stats import chi2

from softgrip_ros.checks import require_positive
from softgrip_ros.estimation.filters import CHAMBER, FILTER_TYPES, make_filter
from softgrip_ros.model.pneumatics import PlantInputs, PneumaticPlant, Valve


class Health(enum.IntEnum):
    OK = 0
    WARN = 1
    ERROR = 2


@dataclasses.dataclass(frozen=True)
class SensorConfig:
    """name; noise_std_pa (1-sigma, Pa); rejection_threshold (chi-square on d^2, 1 dof;
    16 = 4 sigma)."""

    name: str
    noise_std_pa: float
    rejection_threshold: float = 16.0

    def __post_init__(self):
        if not self.name:
            raise ValueError("a sensor needs a name")
        if not (math.isfinite(self.noise_std_pa) and self.noise_std_pa > 0.0):
            raise ValueError(f"sensor {self.name}: noise_std_pa must be positive and finite, got {self.noise_std_pa}")
        if not (math.isfinite(self.rejection_threshold) and self.rejection_threshold > 0.0):
            raise ValueError(f"sensor {self.name}: rejection_threshold must be positive, got {self.rejection_threshold}")


def process_noise_matrix(values) -> np.ndarray:
    """Q (2, 2) from 2 values (its diagonal) or 4 (the full matrix, row-major); Pa^2/s.

    It must be symmetric and positive semi-definite."""
    values = [float(v) for v in values]
    if len(values) == 2:
        matrix = np.diag(values)
    elif len(values) == 4:
        matrix = np.array(values).reshape(2, 2)
    else:
        raise ValueError(f"process noise needs 2 values (diagonal) or 4 (full 2x2), got {len(values)}")
    if not np.all(np.isfinite(matrix)):
        raise ValueError("process noise must be finite")
    if not np.allclose(matrix, matrix.T):
        raise ValueError("process noise must be symmetric")
    if np.min(np.linalg.eigvalsh(matrix)) < 0.0:
        raise ValueError("process noise must be positive semi-definite")
    return matrix


@dataclasses.dataclass(frozen=True)
class EstimatorConfig:
    """Every setting of the estimator; pressures gauge Pa, times s.

    process_noise_pa2_per_s: Q's spectral density over [chamber, regulator], (2, 2).
    initial_regulator_std_pa: the regulator output's 1-sigma when the filter starts.
    """

    filter_type: str = "ekf"
    sensors: tuple = (SensorConfig("chamber_a", 300.0), SensorConfig("chamber_b", 150.0))
    sensor_timeout_s: float = 0.05
    process_noise_pa2_per_s: tuple = (2.0e5, 1.0e6)
    max_step_s: float = 0.005
    max_lag_s: float = 0.02
    nis_window: int = 200
    nis_confidence: float = 0.999
    max_consecutive_rejections: int = 25
    initial_regulator_std_pa: float = 20e3

    def __post_init__(self):
        if self.filter_type not in FILTER_TYPES:
            raise ValueError(f"filter_type must be one of {list(FILTER_TYPES)}, got {self.filter_type!r}")
        if not self.sensors:
            raise ValueError("the estimator needs at least one sensor")
        names = [s.name for s in self.sensors]
        if len(set(names)) != len(names):
            raise ValueError(f"sensor names must be unique, got {names}")
        process_noise_matrix(self.process_noise_pa2_per_s)
        require_positive(self, "sensor_timeout_s", "max_step_s", "max_lag_s", "initial_regulator_std_pa")
        if self.nis_window < 10:
            raise ValueError(f"nis_window must be at least 10 samples, got {self.nis_window}")
        if not 0.5 < self.nis_confidence < 1.0:
            raise ValueError(f"nis_confidence must lie in (0.5, 1), got {self.nis_confidence}")
        if self.max_consecutive_rejections < 1:
            raise ValueError("max_consecutive_rejections must be at least 1")


@dataclasses.dataclass
class SensorStats:
    accepted: int = 0
    rejected: int = 0
    late: int = 0
    invalid: int = 0
    consecutive_rejections: int = 0
    last_stamp_s: float = -math.inf
    nis: collections.deque = dataclasses.field(default_factory=collections.deque)

    def mean_nis(self) -> float:
        return float(np.mean(self.nis)) if self.nis else math.nan


@dataclasses.dataclass(frozen=True)
class Estimate:
    """The chamber's gauge pressure and its variance at ``stamp_s``."""

    stamp_s: float
    gauge_pa: float
    variance_pa2: float

    @property
    def std_pa(self) -> float:
        return math.sqrt(self.variance_pa2)


@dataclasses.dataclass(frozen=True)
class Report:
    """The estimator's health for diagnostics."""

    health: Health
    message: str
    values: dict


class PressureEstimator:
    """Sensor fusion around one filter; see the module docstring."""

    def __init__(self, config: EstimatorConfig | None = None, plant: PneumaticPlant | None = None):
        self.config = config or EstimatorConfig()
        self.plant = plant or PneumaticPlant()
        self.sensors = {s.name: s for s in self.config.sensors}
        self._variance = {s.name: s.noise_std_pa ** 2 for s in self.config.sensors}
        self.stats = {s.name: SensorStats(nis=collections.deque(maxlen=self.config.nis_window))
                      for s in self.config.sensors}
        self.q_continuous = process_noise_matrix(self.config.process_noise_pa2_per_s)
        window = self.config.nis_window
        tail = 0.5 * (1.0 - self.config.nis_confidence)
        self.nis_bounds = (chi2.ppf(tail, window) / window, chi2.ppf(1.0 - tail, window) / window)
        self.inputs = PlantInputs()
        self.filter = None
        self.time_s = math.nan
        self.reinitialisations = 0
        self._models = {}

    # ---- inputs and time ----------------------------------------------------------------------
    @property
    def initialised(self) -> bool:
        return self.filter is not None

    def set_inputs(self, regulator_command_gauge_pa: float, regulator_enabled: bool, valve: int, stamp_s: float) -> None:
        """The process model's inputs from ``stamp_s`` on (the controller's regulator command and valve)."""
        if not (math.isfinite(regulator_command_gauge_pa) and math.isfinite(stamp_s)):
            raise ValueError("inputs need a finite regulator command and stamp")
        if self.initialised and stamp_s > self.time_s:
            self.predict_to(stamp_s)
        self.inputs = PlantInputs(regulator_command_gauge_pa, bool(regulator_enabled), (Valve(valve),))

    def predict_to(self, stamp_s: float) -> None:
        """Advance the filter to ``stamp_s`` with the current inputs (no-op when not later)."""
        if not self.initialised or not stamp_s > self.time_s:
            return
        remaining = stamp_s - self.time_s
        steps = max(1, math.ceil(remaining / self.config.max_step_s - 1e-9))
        for _ in range(steps):
            self.filter.predict(remaining / steps, self.inputs)
        self.time_s = stamp_s

    # ---- measurements -------------------------------------------------------------------------
    def add_measurement(self, name: str, gauge_pa: float, stamp_s: float) -> bool:
        """Fuse one sample; True when it was used. Unknown sensors raise ValueError."""
        return self.add_measurements({name: gauge_pa}, stamp_s)[name]

    def add_measurements(self, samples: dict, stamp_s: float) -> dict:
        """Fuse samples of several sensors taken at one instant; {name: used}."""
        used = {}
        valid = {}
        for name, value in samples.items():
            if name not in self.sensors:
                raise ValueError(f"unknown sensor {name!r}; configured: {sorted(self.sensors)}")
            if not (math.isfinite(value) and math.isfinite(stamp_s)):
                self.stats[name].invalid += 1
                used[name] = False
            else:
                valid[name] = float(value)
        if not valid:
            return used
        if not self.initialised:
            self._initialise(valid, stamp_s)
            return {**used, **{name: True for name in valid}}
        if stamp_s < self.time_s - self.config.max_lag_s:
            for name in valid:
                self.stats[name].late += 1
            return {**used, **{name: False for name in valid}}
        self.predict_to(stamp_s)
        accepted = {}
        x, P = self.filter.x, self.filter.P
        for name, value in valid.items():
            stats = self.stats[name]
            if stamp_s > stats.last_stamp_s:
                stats.last_stamp_s = stamp_s
            d2 = (value - x[CHAMBER, 0]) ** 2 / (P[CHAMBER, CHAMBER] + self._variance[name])
            stats.nis.append(d2)
            if d2 > self.sensors[name].rejection_threshold:
                stats.rejected += 1
                stats.consecutive_rejections += 1
                used[name] = False
            else:
                stats.accepted += 1
                stats.consecutive_rejections = 0
                accepted[name] = value
                used[name] = True
        if accepted:
            H, R = self._measurement_model(tuple(accepted))
            self.filter.update(np.array(list(accepted.values())).reshape(-1, 1), H, R)
        elif self._locked_out(stamp_s):
            self._initialise(valid, stamp_s)
            self.reinitialisations += 1
        return used

    def _measurement_model(self, names: tuple) -> tuple[np.ndarray, np.ndarray]:
        """(H (m, 2), R (m, m)) for the sensors ``names``, cached: the subsets are few."""
        model = self._models.get(names)
        if model is None:
            H = np.zeros((len(names), 2))
            H[:, CHAMBER] = 1.0
            model = self._models[names] = (H, np.diag([self._variance[n] for n in names]))
        return model

    def _locked_out(self, now: float) -> bool:
        alive = self.alive_sensors(now)
        limit = self.config.max_consecutive_rejections
        return bool(alive) and all(self.stats[n].consecutive_rejections >= limit for n in alive)

    def _initialise(self, samples: dict, stamp_s: float) -> None:
        weights = {n: 1.0 / self.sensors[n].noise_std_pa ** 2 for n in samples}
        total = sum(weights.values())
        mean = sum(weights[n] * samples[n] for n in samples) / total
        x0 = np.array([mean, mean])
        P0 = np.diag([1.0 / total, self.config.initial_regulator_std_pa ** 2])
        if self.filter is None:
            self.filter = make_filter(self.config.filter_type, self.plant, x0, P0, self.q_continuous)
        else:
            self.filter.reset(x0, P0)
        for name in samples:
            self.stats[name].last_stamp_s = max(self.stats[name].last_stamp_s, stamp_s)
            self.stats[name].consecutive_rejections = 0
            self.stats[name].accepted += 1
        for stats in self.stats.values():
            stats.nis.clear()
        self.time_s = stamp_s

    # ---- outputs ------------------------------------------------------------------------------
    def alive_sensors(self, now: float) -> list:
        return [n for n, s in self.stats.items() if now - s.last_stamp_s <= self.config.sensor_timeout_s]

    def estimate(self, at_s: float | None = None) -> Estimate | None:
        """The estimate at the filter's time, or predicted to ``at_s`` without committing it."""
        if not self.initialised:
            return None
        if at_s is None or not at_s > self.time_s:
            return self._estimate_from(self.filter.x, self.filter.P, self.time_s)
        saved = (self.filter.x.copy(), self.filter.P.copy(), self.time_s)
        self.predict_to(at_s)
        result = self._estimate_from(self.filter.x, self.filter.P, self.time_s)
        self.filter.reset(saved[0], saved[1])
        self.time_s = saved[2]
        return result

    @staticmethod
    def _estimate_from(x, P, stamp) -> Estimate:
        return Estimate(stamp, float(x[CHAMBER, 0]), float(P[CHAMBER, CHAMBER]))

    def nis_verdict(self, name: str) -> str:
        """'' while the sensor's windowed NIS is consistent (or too few samples), else why not."""
        stats = self.stats[name]
        if len(stats.nis) < stats.nis.maxlen:
            return ""
        mean, (low, high) = stats.mean_nis(), self.nis_bounds
        if mean > high:
            return f"{name}: mean NIS {mean:.2f} above {high:.2f} (the filter is overconfident, or the sensor is biased)"
        if mean < low:
            return f"{name}: mean NIS {mean:.2f} below {low:.2f} (the filter is over-cautious: R or Q too large)"
        return ""

    def report(self, now: float) -> Report:
        alive = self.alive_sensors(now)
        problems = [v for v in (self.nis_verdict(n) for n in self.stats) if v]
        values = {"filter_type": self.config.filter_type, "sensors_alive": ",".join(alive) or "none",
                  "reinitialisations": self.reinitialisations}
        for name, stats in self.stats.items():
            values.update({f"{name}.accepted": stats.accepted, f"{name}.rejected": stats.rejected,
                           f"{name}.late": stats.late, f"{name}.invalid": stats.invalid,
                           f"{name}.mean_nis": round(stats.mean_nis(), 3)})
        estimate = self.estimate(now)
        if estimate is not None:
            values.update({"gauge_pa": round(estimate.gauge_pa, 1), "std_pa": round(estimate.std_pa, 1)})
        if not self.initialised:
            return Report(Health.WARN, "no sensor sample yet", values)
        if not alive:
            return Report(Health.WARN, "all sensors silent: predicting only, the variance grows", values)
        lost = [n for n in self.stats if n not in alive]
        if lost or problems:
            parts = ([f"sensors silent: {', '.join(lost)}"] if lost else []) + problems
            return Report(Health.WARN, "; ".join(parts), values)
        return Report(Health.OK, f"fusing {len(alive)} sensors", values)

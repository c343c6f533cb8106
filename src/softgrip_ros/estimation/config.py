"""The estimator's settings (:class:`EstimatorConfig`, :class:`SensorConfig`), apart from the
filters: a node that only declares or checks them imports neither filterpy nor scipy.stats."""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from softgrip_ros.checks import require_positive
from softgrip_ros.settings import check_settings, setting

FILTER_TYPES = ("kf", "ekf", "ukf")  # softgrip_ros.estimation.filters builds each


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
            raise ValueError(
                f"sensor {self.name}: noise_std_pa must be positive and finite, got "
                f"{self.noise_std_pa}"
            )
        if not (math.isfinite(self.rejection_threshold) and self.rejection_threshold > 0.0):
            raise ValueError(
                f"sensor {self.name}: rejection_threshold must be positive, got "
                f"{self.rejection_threshold}"
            )


def process_noise_matrix(values) -> np.ndarray:
    """Q (2, 2) from 2 values (its diagonal) or 4 (the full matrix, row-major); Pa^2/s.

    It must be symmetric and positive semi-definite."""
    values = [float(v) for v in values]
    if len(values) == 2:
        matrix = np.diag(values)
    elif len(values) == 4:
        matrix = np.array(values).reshape(2, 2)
    else:
        raise ValueError(
            f"process noise needs 2 values (diagonal) or 4 (full 2x2), got {len(values)}")
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

    filter_type: str = setting("ekf", "the filter", choices=FILTER_TYPES)
    sensors: tuple = (SensorConfig("chamber_a", 300.0), SensorConfig("chamber_b", 150.0))
    sensor_timeout_s: float = setting(0.05, "a sensor silent this long is dropped from fusion",
                                      "s", 0.001, 10.0)
    process_noise_pa2_per_s: tuple = (2.0e5, 1.0e6)
    max_step_s: float = 0.005
    max_lag_s: float = 0.02
    fusion_window_s: float = setting(
        0.0, "while the chamber rests, samples this close are fused in one filter step (0: each "
        "at once; 20 ms: one fusion every other bus batch while the controller rests)", "s", 0.0,
        0.02)
    max_fusion_shift_pa: float = setting(
        50.0, "the chamber rests (see fusion_window) while its modelled change over the window "
        "stays within this", "Pa", 1.0, 1000.0)
    input_timing_std_s: float = setting(
        0.01, "how far an input's effect at the device may lie from its stamp (1 sigma); P grows "
        "by the change in rate times this at each input change", "s", 0.0, 0.1)
    rewind_horizon_s: float = setting(
        0.25, "an input change stamped up to this long before the filter's time (a status held "
        "up on a loaded host) is applied at its stamp, the samples since taken again; 0: applied "
        "at the filter's time", "s", 0.0, 1.0)
    sample_timing_std_s: float = setting(
        0.0005, "how far a reading's stamp may lie from its sampling (1 sigma); the chamber's "
        "rate times this adds to each sensor's noise", "s", 0.0, 0.01)
    nis_input_settle_s: float = setting(
        0.1, "samples this soon after an input change, or after every sensor fell silent, stay "
        "out of the NIS window (still gated and fused): the inputs' timing is uncertain there",
        "s", 0.0, 1.0)
    nis_window: int = setting(200, "samples per sensor in the NIS consistency window", "", 10,
                              100000)
    nis_confidence: float = 0.999
    max_consecutive_rejections: int = setting(
        25, "rejections in a row from every live sensor before re-initialising", "", 1, 100000)
    initial_regulator_std_pa: float = 20e3

    def __post_init__(self):
        check_settings(self)
        if not self.sensors:
            raise ValueError("the estimator needs at least one sensor")
        names = [s.name for s in self.sensors]
        if len(set(names)) != len(names):
            raise ValueError(f"sensor names must be unique, got {names}")
        process_noise_matrix(self.process_noise_pa2_per_s)
        require_positive(self, "max_step_s", "max_lag_s", "initial_regulator_std_pa")
        # a waiting sample is no older than a taken one
        if self.fusion_window_s > self.max_lag_s:
            raise ValueError(f"fusion_window_s must lie in [0, max_lag_s = {self.max_lag_s:g}] s, "
                             f"got {self.fusion_window_s}")
        if not 0.5 < self.nis_confidence < 1.0:
            raise ValueError(f"nis_confidence must lie in (0.5, 1), got {self.nis_confidence}")

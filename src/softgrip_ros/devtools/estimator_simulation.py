"""Ground truth for judging the estimators: the pneumatic plant run through scripted inputs,
sampled by noisy, quantised sensors at their own rates (the simulated device's sensor model).

Used by the tests, ``scripts/bench_estimator.py`` and the speed-against-accuracy charts.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from scipy.stats import chi2

from softgrip_ros.canbus.sim_device import DEFAULT_SENSORS
from softgrip_ros.estimation.estimator import (EstimatorConfig, PressureEstimator, SensorConfig,
                                               process_noise_matrix)
from softgrip_ros.model.pneumatics import P_ATM_PA, PlantInputs, PneumaticPlant, Valve


def step_scenario() -> list:
    """(start time s, inputs): fill to 25 kPa, on to 40 kPa, hold, evacuate to -30 kPa, vent."""
    return [(0.0, PlantInputs(0.0, True, (Valve.CLOSED,))),
            (0.2, PlantInputs(25e3, True, (Valve.SUPPLY,))),
            (0.6, PlantInputs(40e3, True, (Valve.SUPPLY,))),
            (1.0, PlantInputs(40e3, True, (Valve.CLOSED,))),
            (1.3, PlantInputs(-30e3, True, (Valve.SUPPLY,))),
            (1.7, PlantInputs(0.0, True, (Valve.VENT,))),
            (2.0, PlantInputs(0.0, True, (Valve.CLOSED,)))]


@dataclasses.dataclass
class Trajectory:
    """truth_t (K,), truth (K, 2) gauge [chamber, regulator]; samples: [(t, name, gauge)] by time;
    input_changes: [(t, PlantInputs)]; sensor_std: {name: noise std incl. quantisation}."""

    truth_t: np.ndarray
    truth: np.ndarray
    samples: list
    input_changes: list
    sensor_std: dict

    def raw_rmse(self, name: str, windows=None) -> float:
        """RMSE of one sensor's raw samples against the truth (inside ``windows``, [(t0, t1)], if
        given)."""
        samples = np.array([(t, v) for t, n, v in self.samples if n == name])
        keep = np.ones(len(samples), bool) if windows is None else \
            np.any([(samples[:, 0] >= a) & (samples[:, 0] < b) for a, b in windows], axis=0)
        truth = np.interp(samples[keep, 0], self.truth_t, self.truth[:, 0])
        return float(np.sqrt(np.mean((samples[keep, 1] - truth)**2)))

    def truth_at(self, t: float) -> np.ndarray:
        """The truth at t, linear between the plant's steps (as the sensors sample it)."""
        return np.array([
            np.interp(t, self.truth_t, self.truth[:, 0]),
            np.interp(t, self.truth_t, self.truth[:, 1])
        ])


def simulate(duration_s: float = 2.2, scenario=None, sensors=DEFAULT_SENSORS, dt_s: float = 1e-3,
             process_noise_pa2_per_s=None, plant: PneumaticPlant | None = None, seed: int = 0,
             dropouts: dict | None = None, spikes: dict | None = None) -> Trajectory:
    """Run the plant at ``dt_s`` and sample every sensor at its rate with a random phase.

    process_noise_pa2_per_s: (2, 2) white noise added to [chamber, regulator] per step (for
    consistency tests, where the truth must obey the filter's own noise model).
    dropouts: {name: (t0, t1)} silences a sensor (or "all") over that interval.
    spikes: {name: [(t, added Pa)]} adds an outlier to the first sample at or after t.
    """
    rng = np.random.default_rng(seed)
    plant = plant or PneumaticPlant()
    scenario = list(scenario or step_scenario())
    steps = int(round(duration_s / dt_s))
    truth_t = np.arange(steps + 1) * dt_s
    truth = np.empty((steps + 1, 2))
    state = plant.initial_state()
    noise_cholesky = None if process_noise_pa2_per_s is None else np.linalg.cholesky(
        np.asarray(process_noise_pa2_per_s) * dt_s + 1e-12 * np.eye(2))
    change = 0
    inputs = scenario[0][1]
    for k in range(steps + 1):
        truth[k] = (state.chamber_pa[0] - P_ATM_PA, state.regulator_gauge_pa)
        if k == steps:
            break
        while change < len(scenario) and scenario[change][0] <= truth_t[k] + 1e-12:
            inputs = scenario[change][1]
            change += 1
        state = plant.step(state, inputs, dt_s)
        if noise_cholesky is not None:
            w = noise_cholesky @ rng.standard_normal(2)
            state.chamber_pa[0] += w[0]
            state.regulator_gauge_pa += w[1]
    samples = []
    dropouts = dropouts or {}
    spikes = {name: sorted(events) for name, events in (spikes or {}).items()}
    for sensor in sensors:
        period = 1.0 / sensor.rate_hz
        t = rng.uniform(0.0, period)
        pending = list(spikes.get(sensor.name, []))
        while t <= duration_s:
            silent = any(name in (sensor.name, "all") and t0 <= t < t1
                         for name, (t0, t1) in dropouts.items())
            if not silent:
                value = np.interp(t, truth_t, truth[:, 0]) + sensor.bias_pa
                value += rng.normal(0.0, sensor.noise_std_pa)
                if sensor.quantisation_pa > 0:
                    value = sensor.quantisation_pa * round(value / sensor.quantisation_pa)
                if pending and pending[0][0] <= t:
                    value += pending.pop(0)[1]
                samples.append((t, sensor.name, value))
            t += period
    samples.sort(key=lambda s: s[0])
    std = {s.name: math.sqrt(s.noise_std_pa**2 + s.quantisation_pa**2 / 12.0) for s in sensors}
    return Trajectory(truth_t, truth, samples, scenario, std)


def config_for(trajectory: Trajectory, filter_type: str, **changes) -> EstimatorConfig:
    """An estimator configuration whose sensor noise is the trajectory's."""
    sensors = tuple(SensorConfig(name, std) for name, std in trajectory.sensor_std.items())
    return EstimatorConfig(filter_type=filter_type, sensors=sensors, **changes)


@dataclasses.dataclass
class Run:
    """One estimator over one trajectory, evaluated after every sample: t (K,), sensor (K,) names,
    estimate (K,), variance (K,), truth (K,) at the filter's time (samples may wait for a fusion
    window), nees (K,) over the full state."""

    t: np.ndarray
    sensor: np.ndarray
    estimate: np.ndarray
    variance: np.ndarray
    truth: np.ndarray
    nees: np.ndarray
    estimator: PressureEstimator

    def rmse(self, mask=None) -> float:
        error = self.estimate - self.truth
        return float(np.sqrt(np.mean(error[mask]**2 if mask is not None else error**2)))


class InputFeed:
    """Hands a trajectory's input changes to an estimator as its samples' time passes."""

    def __init__(self, input_changes):
        self.changes, self.next = list(input_changes), 0

    def until(self, estimator: PressureEstimator, t: float) -> None:
        while self.next < len(self.changes) and self.changes[self.next][0] <= t:
            start, inputs = self.changes[self.next]
            estimator.set_inputs(inputs.regulator_setpoint_gauge_pa, inputs.regulator_enabled,
                                 inputs.valves[0], start)
            self.next += 1


def run(trajectory: Trajectory, config: EstimatorConfig, plant: PneumaticPlant | None = None,
        sensors: tuple | None = None, after_each=None) -> Run:
    """Feed ``trajectory`` (only ``sensors`` if given) and its inputs to a new estimator;
    ``after_each(estimator)`` runs after every sample."""
    estimator = PressureEstimator(config, plant)
    feed = InputFeed(trajectory.input_changes)
    t_out, names, est, var, tru, nees = [], [], [], [], [], []
    for t, name, value in trajectory.samples:
        if sensors is not None and name not in sensors:
            continue
        feed.until(estimator, t)
        estimator.add_measurement(name, value, t)
        if after_each is not None:
            after_each(estimator)
        # the filter's time: samples may wait (fusion window)
        truth = trajectory.truth_at(estimator.time_s)
        x, P = estimator.filter.x[:, 0], estimator.filter.P
        error = truth - x
        t_out.append(t)
        names.append(name)
        est.append(x[0])
        var.append(P[0, 0])
        tru.append(truth[0])
        nees.append(float(error @ np.linalg.solve(P, error)))
    return Run(np.array(t_out), np.array(names), np.array(est), np.array(var), np.array(tru),
               np.array(nees), estimator)


def anees(filter_type: str, runs: int = 50, grid=np.linspace(0.25, 2.15, 120),
          truth: PneumaticPlant | None = None, model: PneumaticPlant | None = None,
          **changes) -> tuple[np.ndarray, tuple]:
    """Average NEES over ``runs`` Monte Carlo runs at the times ``grid`` (truth with the filter's
    own process noise), and the two-sided 95 % interval chi2(2 runs)/runs for 2 states.
    ``truth``: the plant the trajectories run on, ``model``: the filter's (both default to the
    shipped assumptions). ``changes``: EstimatorConfig fields to set (``fusion_window_s``).

    The grid starts at 0.25 s: before the first fill the regulator is behind a closed valve,
    unobservable, and its prior (20 kPa) rightly exceeds its error."""
    q = process_noise_matrix(EstimatorConfig().process_noise_pa2_per_s)
    values = []
    for seed in range(runs):
        trajectory = simulate(seed=1000 + seed, process_noise_pa2_per_s=q, plant=truth)
        result = run(trajectory, config_for(trajectory, filter_type, **changes), model)
        values.append(result.nees[np.minimum(np.searchsorted(result.t, grid), len(result.t) - 1)])
    return np.mean(values,
                   axis=0), (chi2.ppf(0.025, 2 * runs) / runs, chi2.ppf(0.975, 2 * runs) / runs)

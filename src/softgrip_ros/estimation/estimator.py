"""Fusing asynchronous pressure sensors into one chamber-pressure estimate, robustly.

:class:`PressureEstimator` owns one filter (:mod:`softgrip_ros.estimation.filters`) and adds what
a filter alone does not do:

- **Time.** Each sample is applied at its own stamp: the filter predicts to it (in sub-steps of
  at most ``max_step_s``) with the inputs then in force, then updates. A sample a little older
  than the filter's time (up to ``max_lag_s``, transport jitter) is applied at the filter's time;
  an older one is dropped and counted.
- **Fusion window.** With ``fusion_window_s`` > 0, while the chamber rests (its modelled change
  over the window within ``max_fusion_shift_pa``) samples wait and are fused together, each
  moved to the fusion instant along the model's prediction across the window
  (:meth:`PressureEstimator.fuse_pending`); repeated inputs change nothing; a fill or
  an evacuation, or a sample 3 sigma off the estimate, is fused sample by sample and ends the
  rest (``resting``). Asking for the estimate, new inputs or a prediction fuses what waits first.
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
  than the data allow (R or Q too small, a biased or stuck sensor): a warning, and the evidence
  the pressure controller's safety checks take (:meth:`PressureEstimator.nis_evidence`); too
  small means it is over-cautious, which is reported but is no warning: Q is sized for fills
  and evacuations, so a resting chamber moves less than the filter allows, by design. Samples
  taken within ``nis_input_settle_s`` of an input change that matters (its timing, through the
  rate it changes, moves the state by more than the quietest sensor's noise: a valve switch, a
  boost, not the trim's small steps) stay out of the window (they are gated and fused as any
  other). The device acts on a valve a few ms before the controller's next status tells the
  filter; samples taken in between are fused under the old inputs, and once the widened P has
  collapsed the filter still carries about 1 kPa of that, which decays over some 80 ms (traced
  in the clamp's evacuation: innovations of 3-6 sigma for 50 ms). Fault-free grasps warned 5-7
  times each before. The samples fused before the change reached the filter but taken after its
  stamp leave the window too: on a loaded host the status comes tens of ms late. So do the
  samples within ``nis_input_settle_s`` of the first after every sensor fell silent (for
  ``sensor_timeout_s``): the filter predicted across that gap on inputs whose timing no reading
  checked, and a host that held up the readings held up the control loop too (traced beside
  three busy processes: no reading for 83 ms while the chamber overshot 8 kPa past the closed
  valves the filter had been told of; innovations of 20-35 sigma after the gap, mean NIS 14-24
  over the window). A faulty sensor shows outside those instants too.
- **Late inputs.** An input change that arrives stamped before the filter's time is applied at
  its stamp: the filter goes back to its state then and takes the samples since again
  (:meth:`PressureEstimator.set_inputs`).
- **Sample timing.** A reading's stamp may lie ``sample_timing_std_s`` (1 sigma) from the
  instant it was sampled (a device that samples on its tick and stamps at the send: the simulated
  one's send lags its plant by up to 1 ms): while the chamber moves at rate r that is a noise of
  r times it, added to the sensor's own in the gate, the fusion and the NIS. At the 300 kPa/s of
  a boost it doubles chamber_b's 150 Pa; at rest it is nothing. (Without it, fault-free grasps
  raised NIS warnings on both sensors at once, mean NIS ~2.3 against a bound of 1.36: 4 in 20 in
  one run of bench_faults.)
- **Time.** A prediction spans at most ``MAX_PREDICTION_STEPS`` sub-steps, whatever the gap: a
  stamp far ahead costs one bounded prediction, never a stalled caller.
"""
from __future__ import annotations

import collections
import dataclasses
import itertools
import math

import numpy as np
from scipy.stats import chi2

from softgrip_ros.estimation.config import (EstimatorConfig, SensorConfig,  # noqa: F401
                                            process_noise_matrix)
from softgrip_ros.estimation.filters import (CHAMBER, REGULATOR, chamber_rate, make_filter,
                                             plant_step)
from softgrip_ros.health import Health, Report
from softgrip_ros.model.pneumatics import PlantInputs, PneumaticPlant, Valve

_H_CHAMBER = np.array([[1.0, 0.0]])  # every sensor measures the chamber
# the recent NIS the safety checks judge (see nis_evidence)
NIS_EVIDENCE_SAMPLES = 25
# a longer gap is predicted in larger steps (backward Euler is stable)
MAX_PREDICTION_STEPS = 200
SILENCE_REPORTED_S = 0.1  # a sensor silent this long is named in the report
# 3 sigma: a sample this far from the estimate ends a rest
REST_GATE_D2 = 9.0
_SAMPLES_EVENT, _PREDICT_EVENT = 0, 1


@dataclasses.dataclass
class SensorStats:
    accepted: int = 0
    rejected: int = 0
    late: int = 0
    invalid: int = 0
    consecutive_rejections: int = 0
    last_stamp_s: float = -math.inf
    nis: collections.deque = dataclasses.field(default_factory=collections.deque)
    # the stamps of the samples in ``nis``
    nis_stamps: collections.deque = dataclasses.field(default_factory=collections.deque)
    # samples kept out of the NIS window, just after an input change
    nis_settling: int = 0

    def settle_from(self, stamp_s: float) -> None:
        """The samples taken from ``stamp_s`` on leave the NIS window: an input change stamped
        then reached the filter after they were fused under the inputs before it."""
        while self.nis_stamps and self.nis_stamps[-1] >= stamp_s:
            self.nis_stamps.pop()
            self.nis.pop()
            self.nis_settling += 1

    def clear_nis(self) -> None:
        """An empty NIS window (the filter started again)."""
        self.nis.clear()
        self.nis_stamps.clear()

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


def _shared_walk_variance(walks: list, total_weight: float) -> float:
    """The variance of a weighted mean of samples from the random walk each shares with the
    younger ones: q times the integral of A(t)^2, A(t) the weight of the samples taken before t.
    ``walks``: [(walk variance, weight)] of the samples with a walk (sorted here, in place)."""
    walks.sort(reverse=True)  # the oldest (longest walk) first
    variance, earlier_weight = 0.0, 0.0
    for k, (walk, weight) in enumerate(walks):
        earlier_weight += weight / total_weight
        walk_after = walks[k + 1][0] if k + 1 < len(walks) else 0.0
        variance += earlier_weight**2 * (walk - walk_after)
    return variance


class PressureEstimator:
    """Sensor fusion around one filter; see the module docstring."""

    def __init__(self, config: EstimatorConfig | None = None, plant: PneumaticPlant | None = None):
        self.config = config or EstimatorConfig()
        self.plant = plant or PneumaticPlant()
        self.sensors = {s.name: s for s in self.config.sensors}
        self._variance = {s.name: s.noise_std_pa**2 for s in self.config.sensors}
        self.stats = {
            s.name: SensorStats(nis=collections.deque(maxlen=self.config.nis_window),
                                nis_stamps=collections.deque(maxlen=self.config.nis_window))
            for s in self.config.sensors
        }
        self.q_continuous = process_noise_matrix(self.config.process_noise_pa2_per_s)
        window = self.config.nis_window
        tail = 0.5 * (1.0 - self.config.nis_confidence)
        self.nis_bounds = (chi2.ppf(tail, window) / window, chi2.ppf(1.0 - tail, window) / window)
        self.inputs = PlantInputs()
        # the stamp of the last input change, and of the first sample after every sensor fell
        # silent (see nis_input_settle_s)
        self._inputs_changed_s = self._sight_regained_s = -math.inf
        self.filter = None
        self.time_s = math.nan
        self.reinitialisations = 0
        self._pending = []  # [(name, gauge, stamp)] taken, not yet fused
        # samples wait for a fusion window (see add_measurement)
        self.resting = False
        # ... and the window is predicted in one step (see fuse_pending)
        self._one_step = False
        # since the last input change: [(state before, kind, args)] of each sample and committed
        # prediction taken, within rewind_horizon_s (see set_inputs)
        self._since_inputs = collections.deque()
        # taking them again (the counts and the NIS are the first pass's), and before the change
        self._rewinding = self._replaying_before_change = False
        self.rewinds = 0
        # input changes stamped before the filter's time that no rewind could reach: applied
        # at the filter's time
        self.inputs_applied_late = 0

    # ---- inputs and time ----------------------------------------------------------------------
    @property
    def initialised(self) -> bool:
        return self.filter is not None

    def set_inputs(self, regulator_command_gauge_pa: float, regulator_enabled: bool, valve: int,
                   stamp_s: float) -> None:
        """The process model's inputs from ``stamp_s`` on (the controller's regulator command and
        valve).

        A change stamped before the filter's time (its status held up behind a loaded host: up
        to tens of ms) is applied at its stamp: the filter goes back to its state before it
        passed the stamp, within ``rewind_horizon_s`` and never before the last change, and takes
        the samples and predictions since again, in order, the change among them. Applied at
        the filter's time instead, a boost's start 25 ms late left the estimate 6 kPa behind
        the chamber with a tight P, and the gate rejected every sample until the lockout
        re-initialised the filter (mean NIS 2-27 in fault-free grasps beside busy processes).
        The samples' counts and NIS are their first pass's."""
        if not (math.isfinite(regulator_command_gauge_pa) and math.isfinite(stamp_s)):
            raise ValueError("inputs need a finite regulator command and stamp")
        inputs = PlantInputs(regulator_command_gauge_pa, bool(regulator_enabled), (Valve(valve),))
        if inputs == self.inputs:
            return  # the model runs on as it was: nothing to fuse early, nothing to predict to
        self.fuse_pending()  # under the inputs they were taken with
        events, self._since_inputs = list(self._since_inputs), collections.deque()
        late = self.initialised and stamp_s < self.time_s
        if not (late and self._rewind(inputs, stamp_s, events)):
            self.inputs_applied_late += late
            self._switch_inputs(inputs, stamp_s)

    def _switch_inputs(self, inputs: PlantInputs, stamp_s: float) -> None:
        if self.initialised and stamp_s > self.time_s:
            self._predict_to(stamp_s)
        if self.initialised and self.config.input_timing_std_s > 0.0:
            d = self._widen_for_input_timing(inputs)
            # a change whose timing matters against the sensors' noise opens a NIS settle window;
            # the trim's small regulator steps (a status every 20 ms while regulating) do not
            quietest = min(s.noise_std_pa for s in self.config.sensors)
            if abs(d[CHAMBER]) > quietest or abs(d[REGULATOR]) > 10.0 * quietest:
                self._inputs_changed_s = stamp_s
                for stats in self.stats.values():
                    stats.settle_from(stamp_s)
        self.inputs = inputs

    def _record(self, kind: int, *args) -> None:
        """A sample or a committed prediction about to be taken, with the state before it (what
        :meth:`_rewind` goes back to)."""
        if self._replaying_before_change or not self.initialised:
            return
        events = self._since_inputs
        events.append(((self.time_s, self.filter.x.copy(), self.filter.P.copy(),
                        {n: (s.consecutive_rejections, s.last_stamp_s)
                         for n, s in self.stats.items()}), kind, args))
        while len(events) > 1 and events[1][0][0] < self.time_s - self.config.rewind_horizon_s:
            events.popleft()

    def _rewind(self, inputs: PlantInputs, stamp_s: float, events: list) -> bool:
        """Apply ``inputs`` at ``stamp_s``, before the filter's time, taking ``events`` (those
        recorded since the last change) again (see :meth:`set_inputs`); False when none of them
        starts before it within the horizon. The events after the change are recorded again: a
        second late change can go back to them."""
        base = None
        for k, ((time_s, _, _, _), _, _) in enumerate(events):
            if time_s > stamp_s:
                break
            base = k
        if base is None or self.time_s - stamp_s > self.config.rewind_horizon_s:
            return False
        (time_s, x, P, sensors), _, _ = events[base]
        self.filter.reset(x, P)
        self.time_s = time_s
        for name, (rejections, last_stamp_s) in sensors.items():
            self.stats[name].consecutive_rejections = rejections
            self.stats[name].last_stamp_s = last_stamp_s
        self._rewinding = self._replaying_before_change = True
        try:
            for _, kind, args in events[base:]:
                if self._replaying_before_change and args[-1] > stamp_s:
                    self._switch_inputs(inputs, stamp_s)
                    self._replaying_before_change = False
                self._record(kind, *args)
                if kind == _SAMPLES_EVENT:
                    self._add_measurements(*args)
                else:
                    self._predict_to(*args)
            if self._replaying_before_change:
                self._switch_inputs(inputs, stamp_s)
        finally:
            self._rewinding = self._replaying_before_change = False
        self.rewinds += 1
        return True

    def _widen_for_input_timing(self, inputs: PlantInputs) -> np.ndarray:
        """An input reaches the device within about ``input_timing_std_s`` of its stamp (a control
        period, the bus, a stalled thread on either side), so the state is uncertain by the change
        in its rate times that: P grows by d d' with d = (rate after - rate before) * sigma_t.
        Without it, a boosted fill starting a few ms off its stamp put the estimate kilopascals
        behind with a tight P, and the gate rejected every sample until the lockout reset the
        filter."""
        d = (self._state_rate(inputs) - self._state_rate(self.inputs)) * \
            self.config.input_timing_std_s
        self.filter.add_covariance(np.outer(d, d))
        return d

    def _state_rate(self, inputs: PlantInputs) -> np.ndarray:
        """d(state)/dt at the filter's state under ``inputs`` (Pa/s, over 1 ms)."""
        x, step_s = self.filter.x[:, 0], 1e-3
        return (plant_step(self.plant, x, step_s, inputs) - x) / step_s

    def predict_to(self, stamp_s: float) -> None:
        """Advance the filter to ``stamp_s`` with the current inputs (no-op when not later), after
        fusing the samples pending."""
        self.fuse_pending()
        if self.initialised and stamp_s > self.time_s:
            self._record(_PREDICT_EVENT, stamp_s)
        self._predict_to(stamp_s)

    def _predict_to(self, stamp_s: float, max_step_s: float | None = None) -> None:
        if not self.initialised or not stamp_s > self.time_s:
            return
        remaining = stamp_s - self.time_s
        steps = min(max(1, math.ceil(remaining / (max_step_s or self.config.max_step_s) - 1e-9)),
                    MAX_PREDICTION_STEPS)
        for _ in range(steps):
            self.filter.predict(remaining / steps, self.inputs)
        self.time_s = stamp_s

    # ---- measurements -------------------------------------------------------------------------
    def add_measurement(self, name: str, gauge_pa: float, stamp_s: float) -> bool:
        """Take one sample; True when it was taken: fused now or, with a fusion window, pending
        until the next fusion (whose gate may still reject it). Unknown sensors raise
        ValueError."""
        if self.config.fusion_window_s <= 0.0 or not self.initialised:
            return self.add_measurements({name: gauge_pa}, stamp_s)[name]
        if not self._screen(name, gauge_pa, stamp_s):
            return False
        self._record(_SAMPLES_EVENT, {name: float(gauge_pa)}, stamp_s)
        if not self._pending:
            self.resting, self._one_step = self._window_rests()
        if not self.resting or self._surprising(name, gauge_pa):
            self.resting = False
            self.fuse_pending()
            return self._add_measurements({name: gauge_pa}, stamp_s)[name]
        if self._late([name], stamp_s):
            return False
        self._pending.append((name, float(gauge_pa), stamp_s))
        if stamp_s - self._pending[0][2] >= self.config.fusion_window_s:
            self.fuse_pending()
        return True

    def add_measurements(self, samples: dict, stamp_s: float) -> dict:
        """Fuse samples of several sensors taken at one instant, now; {name: used}."""
        self.fuse_pending()
        self._record(_SAMPLES_EVENT, dict(samples), stamp_s)
        return self._add_measurements(samples, stamp_s)

    def _add_measurements(self, samples: dict, stamp_s: float) -> dict:
        valid = {
            name: float(value)
            for name, value in samples.items() if self._screen(name, value, stamp_s)
        }
        used = dict.fromkeys(samples, False)
        if not valid:
            return used
        if not self.initialised:
            self._initialise(valid, stamp_s)
            used.update(dict.fromkeys(valid, True))
            return used
        if self._late(valid, stamp_s):
            return used
        self._predict_to(stamp_s)
        used.update(self._fuse([(name, value, 0.0) for name, value in valid.items()], stamp_s))
        return used

    def fuse_pending(self) -> None:
        """Fuse the samples taken since the last fusion in one filter step, at the newest one's
        stamp.

        Each sample is moved to that instant by the model's change of the chamber between its
        stamp and the fusion's, and its variance grows by the chamber's process noise over the gap.
        That noise is one random walk, which the samples share where their gaps overlap: the
        fused measurement's variance counts it once (see :meth:`_fuse`); counted per sample, as
        if independent, it made the filter overconfident (ANEES 2.67 for the ekf with a 20 ms
        window, above the 95 % bound of 2.59).
        The change is read off the straight line between the chamber's prediction at the window's
        two ends: samples wait only while that change stays within ``max_fusion_shift_pa``, so
        the line's departure from the model's curve is smaller still, and one plant step per
        sample would cost more than the rest of its fusion. The filter's cost is per call, not per
        sample: 700 samples a second each fused at once cost a fifth of a core. For the same
        reason, when the model moves the regulator too by no more than ``max_fusion_shift_pa``
        across the window, the filter predicts across it in one step instead of steps of
        ``max_step_s``. One backward-Euler step is off from fine steps by up to ~30 % of that
        change (under 20 Pa, the sensors' noise is 150-300 Pa). Over 30 simulated trajectories
        with a 20 ms window it moved the RMSE by under 0.4 % and the ANEES after each fusion by
        under 0.15 (towards 2), and the node's window keeps the NEES consistent
        (tests/test_estimation.py)."""
        pending, self._pending = self._pending, []
        if not pending:
            return
        stamp_s = max(stamp for _, _, stamp in pending)
        start_s, start_gauge = self.time_s, float(self.filter.x[CHAMBER, 0])
        self._predict_to(
            stamp_s,
            max(self.config.max_step_s, self.config.fusion_window_s) if self._one_step else None)
        change_pa, span_s = float(self.filter.x[CHAMBER, 0]) - start_gauge, stamp_s - start_s
        q_chamber = self.q_continuous[CHAMBER, CHAMBER]
        moved = []
        for name, value, stamp in pending:
            still_to_come = min(max((stamp_s - stamp) / span_s, 0.0), 1.0) if span_s > 0.0 else 0.0
            moved.append((name, value + still_to_come * change_pa,
                          q_chamber * (stamp_s - max(stamp, start_s))))
        self._fuse(moved, stamp_s)

    def _window_rests(self) -> tuple[bool, bool]:
        """(chamber, whole state): whether the model's change over a fusion window stays within
        ``max_fusion_shift_pa`` for the chamber, and for the regulator too. The first lets samples
        wait for one fusion together; the second lets that window be predicted in one step (see
        :meth:`fuse_pending`). In a fill or an evacuation each sample is fused at once: the
        regulator's and the chamber's estimates move with every sample there, which a batch's
        shift, modelled before its update, misses (RMSE 38 -> 68 Pa in the fills of the step
        scenario with 5 ms batches and no such rule)."""
        x = self.filter.x[:, 0]
        change = np.abs(plant_step(self.plant, x, self.config.fusion_window_s, self.inputs) - x)
        limit = self.config.max_fusion_shift_pa
        return bool(change[CHAMBER] <= limit), bool(change.max() <= limit)

    def _surprising(self, name: str, value: float) -> bool:
        """A sample beyond REST_GATE_D2 of the estimate: the chamber moves without the model
        knowing (a leak, a squeeze). It ends the rest and is fused at once."""
        x, P = self.filter.x, self.filter.P
        return (value -
                x[CHAMBER, 0])**2 > REST_GATE_D2 * (P[CHAMBER, CHAMBER] + self._variance[name])

    def _screen(self, name: str, value: float, stamp_s: float) -> bool:
        """Whether a sample is a number (counted as invalid if not); ValueError for an unknown
        sensor."""
        if name not in self.sensors:
            raise ValueError(f"unknown sensor {name!r}; configured: {sorted(self.sensors)}")
        if math.isfinite(value) and math.isfinite(stamp_s):
            return True
        self.stats[name].invalid += 1
        return False

    def _late(self, names, stamp_s: float) -> bool:
        """Samples older than the filter by more than max_lag_s are counted and dropped; the others
        mark their sensors alive."""
        late = stamp_s < self.time_s - self.config.max_lag_s
        if not (late or self._rewinding) and self.initialised and not self.alive_sensors(stamp_s):
            self._sight_regained_s = stamp_s
        for name in names:
            stats = self.stats[name]
            if late:
                stats.late += 0 if self._rewinding else 1
            elif stamp_s > stats.last_stamp_s:
                stats.last_stamp_s = stamp_s
        return late

    def _fuse(self, samples: list, stamp_s: float) -> dict:
        """Gate [(name, value, walk variance)], measurements of the chamber now (the filter
        predicted to ``stamp_s``), each on its own; {name: used} (the last sample of each).
        A sample's walk variance is the chamber's process noise between its stamp and now
        (0 for a sample taken now), a random walk whose later part every younger sample shares.

        The accepted ones enter as one measurement, their weighted mean with weights a_i
        proportional to 1 / (r_i + walk_i). Its variance is exact for those weights: the sensor
        noise, sum a_i^2 r_i, plus the walk, q times the integral over the window of
        A(t)^2, where A(t) is the weight of the samples taken before t. For samples taken at one
        instant that is 1 / sum(1 / r_i), and the update is the stacked one exactly, with h
        linear and the noises independent. The innovation covariance stays 1x1 (a larger one
        sent scipy's inverse into OpenBLAS's threads, which spin)."""
        used, total, weighted_sum, noise_part, walks = {}, 0.0, 0.0, 0.0, []
        x_chamber, p_chamber = float(self.filter.x[CHAMBER, 0]), float(self.filter.P[CHAMBER,
                                                                                     CHAMBER])
        timing_variance = 0.0
        if self.config.sample_timing_std_s > 0.0:
            rate = chamber_rate(self.plant, self.filter.x[:, 0], self.inputs)
            timing_variance = (rate * self.config.sample_timing_std_s)**2
        first_pass = not self._rewinding  # a rewind's samples were counted already
        settled = stamp_s - max(self._inputs_changed_s,
                                self._sight_regained_s) >= self.config.nis_input_settle_s
        variances, sensors = self._variance, self.sensors
        for name, value, walk_variance in samples:
            stats = self.stats[name]
            noise_variance = variances[name] + timing_variance
            d2 = (value - x_chamber)**2 / (p_chamber + noise_variance + walk_variance)
            if not first_pass:
                pass
            elif settled:
                stats.nis.append(d2)
                stats.nis_stamps.append(stamp_s)
            else:
                stats.nis_settling += 1
            if d2 > sensors[name].rejection_threshold:
                stats.rejected += first_pass
                stats.consecutive_rejections += 1
                used[name] = False
            else:
                stats.accepted += first_pass
                stats.consecutive_rejections = 0
                weight = 1.0 / (noise_variance + walk_variance)
                total += weight
                weighted_sum += weight * value
                noise_part += weight * weight * noise_variance
                if walk_variance > 0.0:
                    walks.append((walk_variance, weight))
                used[name] = True
        if total > 0.0:
            mean = weighted_sum / total
            variance = noise_part / total**2 + _shared_walk_variance(walks, total)
            self.filter.update(np.array([[mean]]), _H_CHAMBER, np.array([[variance]]))
        elif self._locked_out(stamp_s):
            self._initialise({name: value for name, value, _ in samples}, stamp_s)
            self.reinitialisations += 1
        return used

    def _locked_out(self, now: float) -> bool:
        alive = self.alive_sensors(now)
        limit = self.config.max_consecutive_rejections
        return bool(alive) and all(self.stats[n].consecutive_rejections >= limit for n in alive)

    def _initialise(self, samples: dict, stamp_s: float) -> None:
        weights = {n: 1.0 / self.sensors[n].noise_std_pa**2 for n in samples}
        total = sum(weights.values())
        mean = sum(weights[n] * samples[n] for n in samples) / total
        x0 = np.array([mean, mean])
        P0 = np.diag([1.0 / total, self.config.initial_regulator_std_pa**2])
        if self.filter is None:
            self.filter = make_filter(self.config.filter_type, self.plant, x0, P0,
                                      self.q_continuous)
        else:
            self.filter.reset(x0, P0)
        for name in samples:
            self.stats[name].last_stamp_s = max(self.stats[name].last_stamp_s, stamp_s)
            self.stats[name].consecutive_rejections = 0
            self.stats[name].accepted += 1
        for stats in self.stats.values():
            stats.clear_nis()
        self.time_s = stamp_s

    # ---- outputs ------------------------------------------------------------------------------
    def alive_sensors(self, now: float) -> list:
        return [
            n for n, s in self.stats.items()
            if now - s.last_stamp_s <= self.config.sensor_timeout_s
        ]

    def estimate(self, at_s: float | None = None, fuse_pending: bool = True) -> Estimate | None:
        """The estimate at the filter's time (after fusing the samples pending), or predicted to
        ``at_s`` without committing it. ``fuse_pending=False`` leaves the pending samples for
        their own fusion: a look that changes nothing (a report's; fusing them at the moment it is
        asked made the estimates depend on when diagnostics ran, and a replay of the estimator's
        events diverged at each report)."""
        if not self.initialised:
            return None
        if fuse_pending:
            self.fuse_pending()
        if at_s is None or not at_s > self.time_s:
            return self._estimate_from(self.filter.x, self.filter.P, self.time_s)
        saved = (self.filter.x.copy(), self.filter.P.copy(), self.time_s)
        self._predict_to(at_s)
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
            return (f"{name}: mean NIS {mean:.2f} above {high:.2f} (the filter is overconfident, "
                    "or the sensor is biased)")
        if mean < low:
            return (f"{name}: mean NIS {mean:.2f} below {low:.2f} (the filter is over-cautious: R "
                    "or Q too large)")
        return ""

    def nis_evidence(self) -> dict:
        """{sensor: the median of its last NIS_EVIDENCE_SAMPLES NIS values}, for the pressure
        controller's safety checks (compared there with a multiple of ``nis_bounds[1]``). Not the
        window's mean: that outlives a sensor's recovery by the window's length (a second for the
        200 Hz sensor), and one transient moves it; the recent median does neither (a stuck
        sensor's is in the tens of thousands, a healthy one's near 0.45, the median of chi-square
        1)."""
        evidence = {}
        for name, stats in self.stats.items():
            if len(stats.nis) >= NIS_EVIDENCE_SAMPLES:
                recent = list(itertools.islice(reversed(stats.nis), NIS_EVIDENCE_SAMPLES))
                evidence[name] = float(np.median(recent))
        return evidence

    def report(self, now: float) -> Report:
        # silent for the report: SILENCE_REPORTED_S at least, not one fusion timeout (a loaded
        # host holds the reading thread up 50 ms now and then: a WARN in 1 of 40 fault-free
        # grasps of bench_faults); the fusion still drops a sensor after sensor_timeout_s
        silence_s = max(self.config.sensor_timeout_s, SILENCE_REPORTED_S)
        alive = [n for n, s in self.stats.items() if now - s.last_stamp_s <= silence_s]
        verdicts = {n: self.nis_verdict(n) for n in self.stats}
        problems = [
            v for n, v in verdicts.items() if v and self.stats[n].mean_nis() > self.nis_bounds[1]
        ]
        # over-cautious: no warning
        notes = [v for n, v in verdicts.items() if v and v not in problems]
        values = {
            "filter_type": self.config.filter_type, "sensors_alive": ",".join(alive) or "none",
            "reinitialisations": self.reinitialisations, "rewinds": self.rewinds,
            "inputs_applied_late": self.inputs_applied_late,
            "nis_upper_bound": round(self.nis_bounds[1], 4)
        }
        for name, stats in self.stats.items():
            values.update({
                f"{name}.accepted": stats.accepted, f"{name}.rejected": stats.rejected,
                f"{name}.late": stats.late, f"{name}.invalid": stats.invalid,
                f"{name}.nis_settling": stats.nis_settling,
                f"{name}.mean_nis": round(stats.mean_nis(), 3)
            })
        values.update(
            {f"{name}.recent_nis": round(nis, 3)
             for name, nis in self.nis_evidence().items()})
        estimate = self.estimate(now, fuse_pending=False)
        if estimate is not None:
            values.update(
                {"gauge_pa": round(estimate.gauge_pa, 1), "std_pa": round(estimate.std_pa, 1)})
        if not self.initialised:
            return Report(Health.WARN, "no sensor sample yet", values)
        if not alive:
            return Report(Health.WARN, "all sensors silent: predicting only, the variance grows",
                          values)
        lost = [n for n in self.stats if n not in alive]
        if lost or problems:
            parts = ([f"sensors silent: {', '.join(lost)}"] if lost else []) + problems + notes
            return Report(Health.WARN, "; ".join(parts), values)
        return Report(Health.OK, "; ".join([f"fusing {len(alive)} sensors"] + notes), values)

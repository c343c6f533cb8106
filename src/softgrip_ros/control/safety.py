"""Single-fault safety of the pressure controller (no ROS, no CAN).

One sensor stuck, one biased reading, one valve that does not move or one regulator that
overshoots must never take the chamber past its limits. :class:`SafetyMonitor` watches every
independent source of the chamber pressure: each chamber sensor, the regulator's reported
output and the plant model driven by what the controller commanded. Its findings latch a named
fault; the controller then goes to its safe state (valves VENT, regulator setpoint 0 and
disabled: the device cuts both sources, so even a valve stuck open cannot pump).

The checks, each with the fault flag it raises:

- **Limits, before they are crossed** (``OVERPRESSURE``). The trip takes the highest credible
  reading (every fresh sensor; the regulator's output too once the supply valve has stood open
  long enough to equalise), not their mean, and extrapolates it over ``reaction_time_s`` (a
  control period, the bus and the valve) at the fastest rate any source shows: a sensor's own
  rate, or the plant's rate from that pressure through the commanded valve to the regulator's
  reported output. It trips when that would pass the limit plus margin.
- **Sensors against each other** (``SENSOR_DISAGREE``): two sensors, low-passed and aligned in
  time, further apart than ``disagreement_pa`` for ``disagreement_time_s``.
- **A frozen sensor** (``SENSOR_STUCK``): a sensor whose reading has not changed for
  ``stuck_time_s``, over at least STUCK_MIN_REPEATS repeated readings (a sender that stalled
  leaves one long gap instead), while another sensor, or the plant through the commanded valves,
  moved the pressure by ``stuck_motion_pa`` or more. A sensor frozen while nothing moves is
  harmless and cannot be told from a quiet one; it is caught once the pressure moves.
- **A jump no plant can make** (``SENSOR_IMPLAUSIBLE``): every sensor stepping the same way
  within one sample by more than the plant's fastest rate allows (a common bias, a shifted
  reference), or a reading beyond any pressure the sources can make.
- **A noisy sensor** (``SENSOR_NOISE``): its noise, from the median of its readings' second
  differences (blind to ramps and to single spikes), above ``noise_ratio`` times its rated
  noise for ``noise_time_s``.
- **The chamber's response to the valves** (``RESPONSE``): over ``response_window_s`` with one
  valve state commanded, the measured change against the plant's prediction from the same
  start through that valve to the regulator's reported output. Off by more than
  ``response_tolerance`` of the prediction in every check for ``response_time_s`` (or moving
  with the valves closed, for half that): a valve that does not move, or sensors that are biased
  (with the supply valve open, a chamber that reads away from the regulator's output and stays
  there is one of the two, and no measurement here can say which).
- **The regulator against its model** (``REGULATOR``): its reported output away from the
  output its lag and rate limit predict for what it was told, by ``regulator_deviation_pa``
  for ``regulator_deviation_time_s``.
- **The estimator's evidence** (``SENSOR_INCONSISTENT``): the median of a sensor's recent NIS
  above ``nis_ratio`` times the estimator's consistency bound for ``nis_time_s``
  (:meth:`SafetyMonitor.update_consistency`).

While the plant model is being measured (``trust_model`` false: the pressure controller's
identification mode) the checks against it are suspended: the jump bound, the plant's part of
the frozen-sensor evidence, the regulator's model, the response and the estimator's NIS. The
limits (on the measured rates, never slower than the model's), the sensors against each other,
a frozen sensor against another, and the noise stay.

A latched fault clears on a new command once none of its evidence has been seen for
``clear_time_s``. The plant model must resemble the hardware within a factor of about two in
its rates (``response_tolerance``); ``softgrip_identify`` fits it.
"""
from __future__ import annotations

import collections
import dataclasses
import math
import statistics

import numpy as np

from softgrip_ros.checks import require_positive
from softgrip_ros.control.faults import Fault
from softgrip_ros.model.pneumatics import P_ATM_PA, PlantInputs, PneumaticPlant, Valve
from softgrip_ros.settings import check_settings, setting


@dataclasses.dataclass(frozen=True)
class SafetyConfig:
    """Thresholds of every check (see the module docstring). Pressures gauge Pa, times s."""

    max_gauge_pa: float = 50e3
    min_gauge_pa: float = -60e3
    margin_pa: float = 5e3
    reaction_time_s: float = setting(
        0.01, "the limit trip extrapolates each pressure over this: a control period, the bus "
        "and the valve's response", "s", 0.001, 0.2)
    disagreement_pa: float = setting(5e3, "two sensors further apart than this ...", "Pa", 500.0,
                                     50e3)
    disagreement_time_s: float = setting(0.05, "... for this long: SENSOR_DISAGREE", "s", 0.005,
                                         5.0)
    stuck_time_s: float = setting(0.1, "a reading unchanged this long ...", "s", 0.01, 10.0)
    stuck_motion_pa: float = setting(
        2e3, "... while another sensor or the plant moved the pressure by this: SENSOR_STUCK",
        "Pa", 100.0, 50e3)
    noise_ratio: float = setting(
        4.0, "a sensor's noise above this times its rated noise ...", "", 1.5, 1000.0)
    noise_time_s: float = setting(0.2, "... for this long: SENSOR_NOISE", "s", 0.01, 10.0)
    jump_sigmas: float = setting(
        6.0, "every sensor stepping, in one sample, by more than the plant's fastest rate allows "
        "plus this many noise sigmas: SENSOR_IMPLAUSIBLE", "", 3.0, 1000.0)
    response_window_s: float = setting(
        0.05, "the chamber's response to a valve state is judged over this ...", "s", 0.01, 1.0)
    response_settle_s: float = setting(
        0.02, "... from this long after the valve state was commanded", "s", 0.0, 1.0)
    response_min_change_pa: float = setting(
        2e3, "a change judged against the plant must be predicted this large; a chamber moving "
        "this much with the valves closed is a fault", "Pa", 100.0, 50e3)
    response_tolerance: float = setting(
        0.75, "the measured change may differ from the plant's by this fraction of it (the "
        "model's rates within about 2x of the hardware's)", "", 0.05, 0.95)
    response_time_s: float = setting(
        0.06, "a response off the plant in every check this long: RESPONSE", "s", 0.005, 5.0)
    regulator_deviation_pa: float = setting(
        10e3, "the regulator's output further from its model than this ...", "Pa", 1e3, 200e3)
    regulator_deviation_time_s: float = setting(0.03, "... for this long: REGULATOR", "s", 0.005,
                                                5.0)
    nis_ratio: float = setting(
        50.0, "the estimator's windowed NIS of a sensor above this times its bound ...", "", 1.0,
        1e6)
    nis_time_s: float = setting(0.5, "... for this long: SENSOR_INCONSISTENT", "s", 0.01, 60.0)
    clear_time_s: float = setting(
        0.5, "a safety fault clears on a new command once its evidence has been gone this long",
        "s", 0.05, 60.0)

    def __post_init__(self):
        for name in ("max_gauge_pa", "min_gauge_pa", "margin_pa"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"safety {name} must be finite, got {getattr(self, name)}")
        check_settings(self)
        require_positive(self, "margin_pa")
        if not self.min_gauge_pa < 0.0 < self.max_gauge_pa:
            raise ValueError("need min_gauge_pa < 0 < max_gauge_pa")

EMA_TIME_S = 0.01  # low-pass time constant of each sensor's value and rate
HISTORY_S = 0.5  # how far back the per-sensor and command histories reach
# jumps of every sensor within this count as one (sensors sample apart)
JUMP_WINDOW_S = 0.012
# a frozen sensor repeats its reading: a stalled sender leaves one long gap
STUCK_MIN_REPEATS = 5
STAMP_JITTER_S = 0.002  # a frame's stamp may lag its sample by this (a late send): the jump
# check judges a step over at least the sensor's usual period plus this
NOISE_SAMPLES = 64  # second differences in the noise median
_MAD_TO_SIGMA = 1.0 / (0.6745 * math.sqrt(6.0))  # |second difference| median -> sigma (Gaussian)


# how long a command may take from the control step that decided it to the regulator's report
# of it: the bus, the device, and a thread preempted between the step and its send on a loaded
# host (CI: the regulator reported 23.2 kPa where the model, 20 ms back, gave 2.6 kPa after a
# vent's 0 kPa: the command reached the device over 60 ms after its step; a false REGULATOR
# fault ended a fault-free RELEASE)
REGULATOR_REPORT_LATENCY_S = 0.1


def _UNBOUNDED(gauge_pa: float, rising: bool) -> float:
    """No rate bound: the jump check's bound while the model is being measured."""
    return math.inf


class _Sensor:
    """One sensor's recent behaviour."""

    def __init__(self, name: str, rated_noise_pa: float):
        self.name, self.rated_noise_pa = name, rated_noise_pa
        self.value = self.stamp = math.nan
        # the reading before ``value`` (its second difference)
        self.previous = math.nan
        self.lowpass = math.nan
        self.rate = 0.0  # low-passed dp/dt of the readings, Pa/s
        self.changed_at = math.nan  # when the reading last changed
        self.repeats = 0  # readings equal to the one before, in a row
        self.history = collections.deque()  # (stamp, low-passed value), HISTORY_S back
        self.second_differences = collections.deque(maxlen=NOISE_SAMPLES)
        self.noise_pa = math.nan  # the robust noise estimate
        self.last_jump = (-math.inf, 0.0)  # (stamp, size Pa) of the last step beyond the plant
        self.samples = 0
        # recent sample intervals: the usual one is their median
        self.periods = collections.deque(maxlen=15)

    def add(self, value: float, stamp: float, max_rate, jump_sigmas: float) -> None:
        """``max_rate(pressure, rising)``: the fastest the plant can move from there, that way
        (Pa/s)."""
        if math.isfinite(self.stamp) and stamp <= self.stamp:
            return  # out of order or repeated: nothing new
        if math.isnan(self.value):
            self.lowpass, self.changed_at = value, stamp
        else:
            dt = stamp - self.stamp
            if value != self.value:
                self.changed_at, self.repeats = stamp, 0
            else:
                self.repeats += 1
            if not math.isnan(self.previous):
                self.second_differences.append(abs(value - 2.0 * self.value + self.previous))
            step = value - self.value
            self.periods.append(dt)
            span = max(dt, sorted(self.periods)[len(self.periods) // 2]) + STAMP_JITTER_S
            if (abs(step) > max_rate(self.value, step > 0.0) * span +
                    jump_sigmas * math.sqrt(2.0) * self.rated_noise_pa):
                self.last_jump = (stamp, step)
            alpha = dt / (EMA_TIME_S + dt)
            old = self.lowpass
            self.lowpass += alpha * (value - self.lowpass)
            self.rate += alpha * ((self.lowpass - old) / dt - self.rate) if dt > 0.0 else 0.0
        self.previous, self.value, self.stamp = self.value, value, stamp
        self.samples += 1
        self.history.append((stamp, self.lowpass))
        while self.history and self.history[0][0] < stamp - HISTORY_S:
            self.history.popleft()
        # a median costs ~10 us
        if len(self.second_differences) == NOISE_SAMPLES and self.samples % 16 == 0:
            self.noise_pa = statistics.median(self.second_differences) * _MAD_TO_SIGMA

    def lowpass_at(self, when: float) -> float:
        """The low-passed value at ``when`` (linear between the samples kept; NaN outside them)."""
        history = self.history
        if not history or when < history[0][0] or when > history[-1][0] + EMA_TIME_S:
            return math.nan
        previous = history[0]
        for sample in history:
            if sample[0] >= when:
                span = sample[0] - previous[0]
                if span <= 0.0:
                    return sample[1]
                return previous[1] + (sample[1] - previous[1]) * (when - previous[0]) / span
            previous = sample
        return previous[1]

    def aligned(self, when: float) -> float:
        """The low-passed value carried to ``when`` at its rate (a sample's age times the
        slope)."""
        return self.lowpass + self.rate * (when - self.stamp)


class _Persistence:
    """Whether a condition has held, without a break, for a time."""

    def __init__(self):
        self.since = None

    def __call__(self, condition: bool, now: float, duration_s: float) -> bool:
        if not condition:
            self.since = None
            return False
        if self.since is None:
            self.since = now
        return now - self.since >= duration_s


@dataclasses.dataclass(frozen=True)
class Finding:
    flag: Fault
    message: str


class SafetyMonitor:
    """The checks of the module docstring over the readings (:meth:`add_reading`), the regulator's
    reports (:meth:`add_regulator`) and the controller's outputs (:meth:`record_output`).
    :meth:`check` runs every check once, at a control step, and returns its findings;
    :meth:`trip` is the limit check alone (every step, and at once on a reading beyond a limit).

    sensors: {name: rated 1-sigma noise, Pa}; a sensor not listed is rated at 300 Pa."""

    def __init__(self, config: SafetyConfig | None = None, plant: PneumaticPlant | None = None,
                 sensors: dict | None = None):
        self.config = config or SafetyConfig()
        self.plant = plant or PneumaticPlant()
        self._rated = dict(sensors or {})
        self.sensors: dict[str, _Sensor] = {}
        # False while the model is being measured: the checks against it are suspended
        self.trust_model = True
        par = self.plant.parameters
        # The jump check's physical bound: the fastest the chamber can move from a pressure, each
        # way (up: through the supply path from the regulator at its highest; down: to the vacuum
        # source or to atmosphere), tabulated on a 1 kPa grid; twice that, for a plant faster than
        # modelled. A sensor stepping beyond it is not measuring the chamber.
        lowest, highest = P_ATM_PA + par.vacuum_source_gauge_pa, P_ATM_PA + par.supply_gauge_pa
        self._rate_grid_pa = np.arange(par.vacuum_source_gauge_pa - 1e3, par.supply_gauge_pa + 2e3,
                                       1e3)
        self._max_rise = (2.0 * np.array([
            self.plant.rate_and_slopes(P_ATM_PA + p, highest, *par.path(Valve.SUPPLY))[0]
            for p in self._rate_grid_pa
        ]))
        self._max_fall = (2.0 * np.array([
            max(-self.plant.rate_and_slopes(P_ATM_PA + p, lowest, *par.path(Valve.VACUUM))[0],
                -self.plant.rate_and_slopes(P_ATM_PA + p, P_ATM_PA, *par.path(Valve.VENT))[0])
            for p in self._rate_grid_pa
        ]))
        self._max_rise, self._max_fall = np.maximum(self._max_rise,
                                                    0.0), np.maximum(self._max_fall, 0.0)
        self.max_rate_pa_per_s = float(max(self._max_rise.max(), self._max_fall.max()))
        # plain lists: a lookup per reading and per step, where numpy's slices cost ~5 us
        self._rise_table, self._fall_table = self._max_rise.tolist(), self._max_fall.tolist()
        self._grid_start_pa = float(self._rate_grid_pa[0])
        self._grid_size = len(self._rate_grid_pa)
        self.credible_range_pa = (par.vacuum_source_gauge_pa - self.config.margin_pa,
                                  par.supply_gauge_pa + self.config.margin_pa)
        self._regulator = (math.nan, -math.inf)  # (reported output, stamp)
        self._regulator_history = collections.deque()  # (stamp, reported output)
        self._model_regulator = math.nan  # synchronised to the first report
        # (time, modelled regulator output, the PlantInputs sent from then on)
        self._model_history = collections.deque()
        self._sent = None  # the PlantInputs of the last output (None before any)
        self._valve_since = (None, math.inf)  # (valve, since)
        self._last_step = None
        self._persist = collections.defaultdict(_Persistence)
        # name -> (mean NIS, bound, since when above)
        self._nis = {}
        self._last_response_check = -math.inf
        self._response_result = None
        self._response_text = ""
        # flag -> last time its evidence was seen
        self.last_seen: dict[Fault, float] = {}
        self.supply_equalised = False

    # ---- inputs ---------------------------------------------------------------------------------
    def add_reading(self, name: str, gauge_pa: float, stamp_s: float) -> None:
        sensor = self.sensors.get(name)
        if sensor is None:
            sensor = self.sensors[name] = _Sensor(name, float(self._rated.get(name, 300.0)))
        sensor.add(float(gauge_pa), float(stamp_s),
                   self.max_rate if self.trust_model else _UNBOUNDED, self.config.jump_sigmas)

    def max_rate(self, gauge_pa: float, rising: bool) -> float:
        """The fastest the plant can move the chamber from ``gauge_pa``, up or down (Pa/s, with 2x
        headroom)."""
        index = min(max(int(round((gauge_pa - self._grid_start_pa) / 1e3)), 0),
                    self._grid_size - 1)
        # the grid's neighbours too: a pressure between two points takes the faster
        table = self._rise_table if rising else self._fall_table
        return max(table[max(index - 1, 0):index + 2])

    def add_regulator(self, actual_gauge_pa: float, stamp_s: float) -> None:
        self._regulator = (float(actual_gauge_pa), float(stamp_s))
        if math.isnan(self._model_regulator):
            # the model starts where the regulator is
            self._model_regulator = float(actual_gauge_pa)
        self._regulator_history.append(self._regulator)
        while len(self._regulator_history
                  ) > 1 and self._regulator_history[0][1] < stamp_s - HISTORY_S:
            self._regulator_history.popleft()

    def update_consistency(self, name: str, mean_nis: float, bound: float, now: float) -> None:
        """The estimator's recent NIS of sensor ``name`` (the median of its last samples) and its
        upper consistency bound."""
        if not (math.isfinite(mean_nis) and math.isfinite(bound) and bound > 0.0):
            return
        above = mean_nis > self.config.nis_ratio * bound
        since = self._nis.get(name, (0.0, 0.0, None))[2] if above else None
        self._nis[name] = (mean_nis, bound,
                           (since if since is not None else now) if above else None)

    def record_output(self, now: float, valve: Valve, regulator_command_gauge_pa: float,
                      enabled: bool) -> None:
        """What the controller sent in this step (the plant model's inputs from now on)."""
        valve = Valve(valve)
        if self._last_step is not None and now > self._last_step and self._sent is not None \
                and math.isfinite(self._model_regulator):
            self._model_regulator = self.plant.regulator_step(self._model_regulator, self._sent,
                                                              now - self._last_step)[0]
        self._last_step = now
        self._sent = PlantInputs(float(regulator_command_gauge_pa), bool(enabled), (valve,))
        if math.isfinite(self._model_regulator):
            self._model_history.append((now, self._model_regulator, self._sent))
        while len(self._model_history) > 1 and self._model_history[0][0] < now - HISTORY_S:
            self._model_history.popleft()
        if valve != self._valve_since[0]:
            self._valve_since = (valve, now)

    def valves_sent(self, when: float) -> None:
        """The valve state recorded last went out at ``when``, after the step that decided it: the
        response check's settle counts from then. A thread held up between the two (21.7 ms,
        traced on a loaded host) let the check judge a chamber still filling through a valve not
        yet closed (a false RESPONSE fault, +4.9 kPa "with the valves closed")."""
        valve, since = self._valve_since
        if valve is not None and when > since:
            self._valve_since = (valve, when)

    def regulator_sent(self, when: float) -> None:
        """The regulator command recorded last went out at ``when``, after the step that decided
        it: until then the regulator followed the command before, and so does its model. A step
        that ended a boost, held up before its send on a loaded host, had the model falling
        towards the target while the regulator still stood at the boost's level (CI: 'reports
        60.2 kPa where its model gives 30.3 kPa', a false REGULATOR fault before a fault's
        injection)."""
        history = self._model_history
        # the last entry is that step's (it is not when the model had no value yet)
        if len(history) < 2 or history[-1][0] != self._last_step or when <= self._last_step:
            return
        (before, value, inputs_before), (_, _, inputs) = history[-2], history[-1]
        if inputs == inputs_before:
            return
        value = self.plant.regulator_step(value, inputs_before, when - before)[0]
        history[-1] = (when, value, inputs)
        self._model_regulator, self._last_step = value, when

    # ---- what the checks see --------------------------------------------------------------------
    def fresh(self, now: float, timeout_s: float) -> list:
        return [s for s in self.sensors.values() if now - s.stamp <= timeout_s]

    def credible_extremes(self, now: float, timeout_s: float) -> tuple[float, float]:
        """(lowest, highest) credible chamber pressure: every fresh sensor, and the regulator's
        output while the supply valve has stood open long enough to equalise (NaN, NaN: none)."""
        values = [s.value for s in self.fresh(now, timeout_s)]
        regulator, stamp = self._regulator
        if self.supply_equalised and now - stamp <= timeout_s and math.isfinite(regulator):
            values.append(regulator)
        return (min(values), max(values)) if values else (math.nan, math.nan)

    def commanded(self) -> tuple:
        """(valve, regulator command, enabled) last sent; CLOSED and disabled before any."""
        if self._sent is None:
            return Valve.CLOSED, 0.0, False
        return (self._sent.valves[0], self._sent.regulator_setpoint_gauge_pa,
                self._sent.regulator_enabled)

    def _regulator_known(self, now: float, timeout_s: float) -> bool:
        """Whether a fresh report of the regulator's output is at hand (without one, nothing says
        what the supply valve leads to: the checks that need it wait)."""
        regulator, stamp = self._regulator
        return math.isfinite(regulator) and now - stamp <= max(timeout_s, 0.05)

    def _regulator_output(self, now: float, timeout_s: float, at: float | None = None) -> float:
        """The regulator's reported output (at ``at``: the report then) while fresh, else its
        model's (0 before anything is known)."""
        regulator, stamp = self._regulator
        if not (now - stamp <= max(timeout_s, 0.05) and math.isfinite(regulator)):
            return self._model_regulator if math.isfinite(self._model_regulator) else 0.0
        if at is not None:
            for report, when in reversed(self._regulator_history):
                if when <= at:
                    return report
        return regulator

    # ---- the limit trip -------------------------------------------------------------------------
    def trip(self, now: float, timeout_s: float) -> Finding | None:
        """The limits, extrapolated over the reaction time from where the chamber is now; a finding
        when one would be crossed. Now is not when the newest reading was taken: on a loaded host
        readings reach the controller tens of ms after their stamps, so the credible extremes are
        carried over that age through the plant (:meth:`_carried`). From the readings as they
        were, a regulator settling 100 kPa high tripped at 51.2 kPa (rising 441 kPa/s, the reading
        late) and the chamber peaked at 55.4 kPa (the quick fault matrix)."""
        c = self.config
        fresh = self.fresh(now, timeout_s)
        low, high = self.credible_extremes(now, timeout_s)
        if math.isnan(high):
            return None
        upper, lower = c.max_gauge_pa + c.margin_pa, c.min_gauge_pa - c.margin_pa
        newest = max((s.stamp for s in fresh), default=now)
        # carried only where the plant's fastest motion could reach a limit by then (a trip that
        # carries took 16-19 us here, one that does not 11-12 us; at 30 kPa and a reading 2 ms
        # old, a rise reaches 16 kPa further)
        horizon_s = max(now - newest, 0.0) + c.reaction_time_s
        near = (high + self.max_rate(high, True) * horizon_s > upper or
                low - self.max_rate(low, False) * horizon_s < lower)
        segments = self._sent_since(newest, now) if near else []
        carried = f", {1e3 * (now - newest):.0f} ms after its reading" if segments else ""
        if segments:
            high = max(high, self._carried(high, segments, now, timeout_s))
            low = min(low, self._carried(low, segments, now, timeout_s))
        valve, _, enabled = self.commanded()
        regulator = self._regulator_output(now, timeout_s)
        rising = max([0.0] + [s.rate for s in fresh] +
                     [self.plant.chamber_rate(P_ATM_PA + high, valve, regulator, enabled)])
        falling = min([0.0] + [s.rate for s in fresh] +
                      [self.plant.chamber_rate(P_ATM_PA + low, valve, regulator, enabled)])
        ahead_high = high + rising * c.reaction_time_s
        ahead_low = low + falling * c.reaction_time_s
        if ahead_high > upper or high > upper:
            return Finding(
                Fault.OVERPRESSURE,
                f"pressure {high / 1e3:.1f} kPa{carried}, rising {rising / 1e3:.0f} kPa/s, "
                f"would pass the limit {upper / 1e3:.0f} kPa within "
                f"{1e3 * c.reaction_time_s:.0f} ms: venting")
        if ahead_low < lower or low < lower:
            return Finding(
                Fault.OVERPRESSURE,
                f"pressure {low / 1e3:.1f} kPa{carried}, falling {-falling / 1e3:.0f} kPa/s, "
                f"would pass the limit {lower / 1e3:.0f} kPa within "
                f"{1e3 * c.reaction_time_s:.0f} ms: venting")
        return None

    def _sent_since(self, since: float, now: float) -> list:
        """[(from, to, PlantInputs)]: what the steps sent over (``since``, ``now``), in order."""
        segments, end = [], now
        for when, _, inputs in reversed(self._model_history):
            if when < end:
                segments.append((max(when, since), end, inputs))
                end = when
            if when <= since:
                break
        if end > since and self._sent is not None and not segments:
            segments.append((since, end, self._sent))
        return segments[::-1]

    def _carried(self, gauge_pa: float, segments: list, now: float, timeout_s: float) -> float:
        """The chamber read at ``gauge_pa`` when ``segments`` begin, carried to their end through
        the plant under what was sent (:meth:`_sent_since`), fed by the regulator's reported
        output (its model's while no report is fresh), in steps of at most 5 ms. The plant's
        path, not the reading's rate: a fill nears its source and a settle closes the valve,
        where a straight line from a reading 30 ms late tripped a sound 45 kPa boost at
        34.5 kPa."""
        if not math.isfinite(gauge_pa):
            return gauge_pa
        for start, end, inputs in segments:
            gauge_pa = self._through_plant(gauge_pa, start, end, inputs.valves[0],
                                           inputs.regulator_enabled,
                                           max(1, math.ceil((end - start) / 0.005)), now,
                                           timeout_s)
        return gauge_pa

    def _through_plant(self, gauge_pa: float, start: float, end: float, valve: Valve,
                       enabled: bool, steps: int, now: float, timeout_s: float) -> float:
        """The chamber at ``gauge_pa`` at ``start``, at ``end`` through ``valve``: ``steps``
        backward-Euler steps, each fed by the regulator's reported output at its middle."""
        pressure, dt = P_ATM_PA + gauge_pa, (end - start) / steps
        for k in range(steps):
            regulator = self._regulator_output(now, timeout_s, at=start + (k + 0.5) * dt)
            pressure = self.plant.chamber_step(pressure, valve, regulator, dt, enabled)[0]
        return pressure - P_ATM_PA

    # ---- every check ----------------------------------------------------------------------------
    def check(self, now: float, timeout_s: float, regulating_in_track: bool = True) -> list:
        """Every check at ``now``; [Finding] of those that fire. ``regulating_in_track``: the
        controller regulates with the supply valve and no boost (the regulator may equalise)."""
        valve, _, _ = self.commanded()
        self.supply_equalised = (regulating_in_track and valve == Valve.SUPPLY and
                                 now - self._valve_since[1]
                                 >= self.config.response_settle_s + self.config.response_window_s)
        modelled = (self._regulator_finding(now, timeout_s), self._response_finding(
            now, timeout_s), self._consistency_finding(now)) if self.trust_model else ()
        findings = [
            f for f in (self.trip(now, timeout_s), *self._sensor_findings(now, timeout_s),
                        *modelled)
            if f is not None
        ]
        for finding in findings:
            self.last_seen[finding.flag] = now
        return findings

    def clearable(self, flags: Fault, now: float) -> Fault:
        """The subset of ``flags`` whose evidence has not been seen for ``clear_time_s``."""
        stale = Fault.NONE
        for flag in Fault:
            if flag and flag in flags and now - self.last_seen.get(
                    flag, -math.inf) >= self.config.clear_time_s:
                stale |= flag
        return stale

    def _sensor_findings(self, now: float, timeout_s: float) -> list:
        c, fresh, findings = self.config, self.fresh(now, timeout_s), []
        valve, _, enabled = self.commanded()
        regulator = self._regulator_output(now, timeout_s)
        # a reading no source can make
        for sensor in fresh:
            low, high = self.credible_range_pa
            if not low <= sensor.value <= high:
                findings.append(
                    Finding(
                        Fault.SENSOR_IMPLAUSIBLE,
                        f"{sensor.name} reads {sensor.value / 1e3:.1f} kPa, "
                        f"beyond what the sources can make"))
        # every sensor jumping the same way at once, beyond the plant's fastest rate
        jumps = [s.last_jump for s in fresh]
        stamps = [stamp for stamp, _ in jumps]
        if fresh and now - max(stamps) <= 0.05 and max(stamps) - min(stamps) <= JUMP_WINDOW_S \
                and (all(size > 0 for _, size in jumps) or all(size < 0 for _, size in jumps)):
            sizes = ", ".join(f"{s.name} {size / 1e3:+.1f} kPa"
                              for s, (_, size) in zip(fresh, jumps))
            findings.append(
                Finding(
                    Fault.SENSOR_IMPLAUSIBLE,
                    f"sensors jumped together ({sizes}) faster than the plant can "
                    f"move them: a sensor fault such as a bias"))
        # pairs that disagree
        for i, a in enumerate(fresh):
            for b in fresh[i + 1:]:
                gap = a.aligned(now) - b.aligned(now)
                key = ("disagree", a.name, b.name)
                if self._persist[key](abs(gap) > c.disagreement_pa, now, c.disagreement_time_s):
                    findings.append(
                        Finding(
                            Fault.SENSOR_DISAGREE, f"{a.name} disagrees with {b.name} by "
                            f"{abs(gap) / 1e3:.1f} kPa"))
        # frozen while the pressure moves
        for sensor in fresh:
            frozen_for = now - sensor.changed_at
            if frozen_for < c.stuck_time_s or sensor.repeats < STUCK_MIN_REPEATS:
                continue
            # as far back as the others' histories go
            since = max(sensor.changed_at, now - 0.9 * HISTORY_S)
            moved = [(other.name, abs(other.lowpass - other.lowpass_at(since))) for other in fresh
                     if other is not sensor and math.isfinite(other.lowpass_at(since))]
            predicted = abs(
                self.plant.chamber_rate(P_ATM_PA + sensor.value, valve, regulator,
                                        enabled)) * frozen_for if self.trust_model else 0.0
            evidence = [
                f"{name} moved {change / 1e3:.1f} kPa" for name, change in moved
                if change >= c.stuck_motion_pa
            ]
            judged = valve != Valve.CLOSED and (valve != Valve.SUPPLY or
                                                self._regulator_known(now, timeout_s))
            if predicted >= 5.0 * c.stuck_motion_pa and judged:
                evidence.append(
                    f"the plant, through the {valve.name} valve, moves it {predicted / 1e3:.0f} "
                    "kPa")
            if evidence:
                findings.append(
                    Finding(
                        Fault.SENSOR_STUCK,
                        f"{sensor.name} frozen at {sensor.value / 1e3:.1f} kPa for "
                        f"{frozen_for:.2f} s while {' and '.join(evidence)}"))
        # noisier than rated
        for sensor in fresh:
            noisy = math.isfinite(
                sensor.noise_pa) and sensor.noise_pa > c.noise_ratio * sensor.rated_noise_pa
            if self._persist[("noise", sensor.name)](noisy, now, c.noise_time_s):
                findings.append(
                    Finding(
                        Fault.SENSOR_NOISE,
                        f"{sensor.name} noisy: {sensor.noise_pa / 1e3:.2f} kPa rms, "
                        f"{sensor.noise_pa / sensor.rated_noise_pa:.0f}x its rated "
                        f"{sensor.rated_noise_pa / 1e3:.2f} kPa"))
        return findings

    def _model_at(self, when: float) -> float:
        """The modelled regulator output at ``when``: from the last step at or before it, under
        what that step sent (NaN before the model's first step)."""
        for time_s, value, inputs in reversed(self._model_history):
            if time_s <= when:
                return self.plant.regulator_step(value, inputs, when - time_s)[0]
        return math.nan

    def _regulator_finding(self, now: float, timeout_s: float) -> Finding | None:
        c = self.config
        actual, stamp = self._regulator
        deviation, expected = 0.0, math.nan
        if math.isfinite(actual) and now - stamp <= max(timeout_s, 0.05) and self._model_history:
            # the model over the report's latency (the command's path to the device and back);
            # below it only while it rests: a regulator slower than modelled lags a ramp, which is
            # no danger
            begin, end = stamp - REGULATOR_REPORT_LATENCY_S, stamp + 0.002
            # the model between two steps moves monotonically: its range over the window is that
            # of the steps inside it and of its two ends, taken exactly (steps come late on a
            # loaded host, and a boost slews 10 kPa in 5 ms: the last step before the report is
            # not the model at the report; bench_faults: 'reports 50.2 kPa where its model gives
            # 40.0 kPa' in fault-free grasps)
            window = [self._model_at(begin), self._model_at(end)] + [
                value for when, value, _ in self._model_history if begin <= when <= end
            ]
            window = [value for value in window if math.isfinite(value)]
            if window:
                low, high = min(window), max(window)
                resting = high - low <= 0.5 * c.regulator_deviation_pa
                deviation = actual - high if actual > high else (
                    low - actual if resting and actual < low else 0.0)
                expected = high if actual > high else low
        if self._persist["regulator"](deviation > c.regulator_deviation_pa, now,
                                      c.regulator_deviation_time_s):
            return Finding(
                Fault.REGULATOR,
                f"the regulator reports {actual / 1e3:.1f} kPa where its model gives "
                f"{expected / 1e3:.1f} kPa for what it was told")
        return None

    def _response_finding(self, now: float, timeout_s: float) -> Finding | None:
        """The chamber's response to the valve state commanded since ``response_settle_s`` after it
        was: over the last ``response_window_s`` of that (or all of it, when shorter) up to the
        newest instant every fresh sensor has reported, the measured change against the plant's
        over the same span. With the valves closed, moving
        by ``response_min_change_pa`` in every check for half ``response_time_s`` is the evidence;
        otherwise a change off the prediction by more than ``response_tolerance`` of it, in every
        check for ``response_time_s``."""
        c = self.config
        if now - self._last_response_check < 0.2 * c.response_window_s:
            return self._response_result
        self._last_response_check = now
        self._response_result = None
        valve, since = self._valve_since
        fresh = self.fresh(now, timeout_s)
        # up to the newest instant every fresh sensor has reported: readings reach a starved
        # process tens of ms after their stamps, and carried to ``now`` at their low-passed rate
        # (still high while the low-pass settles after a close), they moved a chamber closed 37 ms
        # earlier by kPa (fault-free grasps of the quick fault matrix, a 2-core host with 14-24 %
        # steal: a false RESPONSE fault)
        end = min((s.stamp for s in fresh), default=now)
        start = max(since + c.response_settle_s, end - c.response_window_s)
        judged = (valve is not None and fresh and end - start >= 0.2 * c.response_window_s and
                  (valve != Valve.SUPPLY or self._regulator_known(now, timeout_s)))
        wrong = False
        if judged:
            begins = [s.lowpass_at(start) for s in fresh]
            ends = [s.lowpass_at(end) for s in fresh]
            judged = all(math.isfinite(v) for v in begins + ends)
        if judged:
            p0, p1 = sum(begins) / len(begins), sum(ends) / len(ends)
            _, _, enabled = self.commanded()
            span = end - start
            measured = p1 - p0
            predicted = self._through_plant(p0, start, end, valve, enabled, 5, now,
                                            timeout_s) - p0
            if valve == Valve.CLOSED:
                wrong = abs(measured) > c.response_min_change_pa
            elif abs(predicted) >= c.response_min_change_pa and span >= 0.8 * c.response_window_s:
                wrong = abs(measured - predicted) > c.response_tolerance * abs(predicted)
            if wrong:
                self._response_text = (
                    f"the chamber does not respond to the {valve.name} valve as the plant "
                    "predicts: "
                    f"{measured / 1e3:+.1f} kPa in {1e3 * span:.0f} ms where "
                    f"{predicted / 1e3:+.1f} kPa was due" +
                    ("" if valve != Valve.SUPPLY else
                     f" (the regulator at "
                     f"{self._regulator_output(now, timeout_s, at=end) / 1e3:.1f} kPa)") +
                    ": a valve that does not move, or biased sensors")
        # closed valves: motion that lasts half as long is evidence enough (no leak moves a chamber
        # kPa in ms); a close that reached the device late moves it only in the first window
        persist = 0.5 * c.response_time_s if valve == Valve.CLOSED else c.response_time_s
        if self._persist["response"](wrong, now, persist):
            self._response_result = Finding(Fault.RESPONSE, self._response_text)
        return self._response_result

    def _consistency_finding(self, now: float) -> Finding | None:
        for name, (mean_nis, bound, since) in self._nis.items():
            if since is not None and now - since >= self.config.nis_time_s:
                return Finding(
                    Fault.SENSOR_INCONSISTENT,
                    f"{name} inconsistent with the plant model: the estimator's recent "
                    f"NIS {mean_nis:.0f}, {mean_nis / bound:.0f}x its bound "
                    f"{bound:.2f}")
        return None

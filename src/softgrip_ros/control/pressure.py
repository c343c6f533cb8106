"""Pressure control law and safety logic of the pressure controller (no ROS, no CAN).

Each control period :meth:`PressureController.step` turns the latest command, sensor
readings and regulator status into a regulator setpoint and a valve state per channel.

Control law (source SUPPLY or VACUUM, target r* in Pa gauge):

- the setpoint r slews towards r* at the command's max rate (the configured default when
  the command gives none), after clamping r* to [min_gauge_pa, max_gauge_pa];
- **boost**: on a rise of more than ``boost_min_step_pa``, while the chamber is more than
  ``boost_band_pa`` below r, the
  regulator is driven towards its maximum (capped at the target + ``boost_headroom_pa``, and
  at the **boost ceiling**: the highest output with which even a valve stuck open keeps the
  chamber within the limit plus margin, found for the target, see :func:`boost_ceiling_pa`)
  with the valve open (the time-optimal rise is the valve fully open to supply);
  ``boost_lead_s`` before the chamber would reach r at its current rate the valve closes
  (**settle**) until the regulator's reported output has come down to the regulated value, so
  its lag cannot overshoot the chamber; meanwhile the valve opens for single periods while the
  model says one cannot pass r (:meth:`PressureController._top_up`). The crossing is judged on
  the feedback carried to the step's time at its rate over the readings' stamps: a reading is as
  old as its stamp, and on a loaded host it reaches the controller tens of ms late;
- **regulation**: regulator setpoint = r (feed-forward) + PI trim on the feedback
  (the estimate when fresh, else the mean of the fresh sensors), the trim clamped to
  +-``trim_limit_pa``; the integral runs only within ``integral_band_pa`` of the setpoint
  and while the trim is not clamped (anti-windup);
- **valves** (hysteresis ``valve_band_pa``, so they do not chatter): SUPPLY (the regulated
  line) normally; VACUUM (the raw pump) while the chamber is far above a negative target;
  VENT for a VENT command; CLOSED for HOLD, with the regulator at atmosphere (so that a valve
  stuck open shows itself; in identification mode where it was).

Safety (design.md), independent of the grasp manager:

- setpoints beyond the hard limits are clamped, and flagged until a valid command;
- :class:`~softgrip_ros.control.safety.SafetyMonitor` checks every source of the chamber
  pressure against the limits (before they are crossed, on the highest credible reading),
  against each other and against the plant; a finding latches its named fault and the
  **safe state**: valves VENT, the regulator setpoint 0 and disabled (the device then cuts both
  sources, so a valve stuck open cannot pump either). A new command clears it once the
  evidence has been gone for ``safety.clear_time_s``;
- no valid sensor reading for ``sensor_timeout_s``: valves closed (hold), flagged, and
  regulation resumes by itself when readings return. An explicit VENT is still obeyed then,
  and said to be unconfirmed;
- no command for ``command_timeout_s`` while regulating: the configured safe action
  (``hold`` or ``vent``).
- **identification mode** (:attr:`PressureController.identification`, for
  ``softgrip_identify``): no control law. A SUPPLY command's target is the regulator setpoint,
  with the valve open to it; a VACUUM command opens the valve to the pump until the chamber
  would reach its target within ``boost_lead_s`` at its rate (as the closed loop's evacuation
  hands back), then closes it; a HOLD command with a finite target sets the regulator
  there with the valves closed (its own response, alone); VENT as always. Targets are clamped
  to the limits, and the limit trip, the sensor cross-checks and the safe state stay: it is
  open-loop access, not a way around them. The monitor's checks against the plant model are
  suspended, since that model is what is being measured;
- at a steady target, ``hold_cycles`` boosts or evacuations within ``hold_cycle_window_s``
  (the first one, which reaches the target, not counted): the regulated line cannot hold the
  chamber where the sensors say (biased sensors, a leak, a regulator offset), and the valves
  toggling defeat the monitor's single-valve response check; a RESPONSE fault.
"""
from __future__ import annotations

import collections
import contextlib
import dataclasses
import enum
import functools
import math
import sys

from softgrip_ros import cache
from softgrip_ros.control.faults import SAFETY_FAULTS, Fault, fault_names
from softgrip_ros.control.safety import SafetyConfig, SafetyMonitor
from softgrip_ros.model.pneumatics import P_ATM_PA, PlantInputs, PneumaticPlant, Valve
from softgrip_ros.settings import check_settings, setting


class RegulationPhase(enum.Enum):
    """The regulated line's sub-phase towards a target; its value is the output's message (none
    while tracking)."""

    TRACK = "track"  # the PI loop on the setpoint
    BOOST = "boost"  # the regulator above the target with the valve open: a fast fill
    SETTLE = "settle"  # the air held in (topped up by single-period pulses) while the
    # regulator comes down to the setpoint


class Source(enum.IntEnum):
    """PressureCommand.source (and the RegulatorSetpoint Source signal)."""

    SUPPLY = 0
    VACUUM = 1
    VENT = 2
    HOLD = 3


class PressureMode(enum.IntEnum):
    """ControllerStatus.mode."""

    INACTIVE = 0
    REGULATE = 1
    HOLD = 2
    VENT = 3
    FAULT = 4
    IDENTIFY = 5


@dataclasses.dataclass(frozen=True)
class PressureControlConfig:
    """Parameters of the control law and the safety rules. Pressures gauge, Pa; times s."""

    max_gauge_pa: float = setting(50e3, "hard upper limit of the setpoint", "Pa", 1e3, 100e3)
    min_gauge_pa: float = setting(-60e3, "hard lower limit of the setpoint", "Pa", -100e3, -1e3)
    overpressure_margin_pa: float = setting(5e3, "measured excess beyond a limit that vents",
                                            "Pa", 100.0, 50e3)
    sensor_timeout_s: float = setting(0.05, "no valid reading for this long: hold and report",
                                      "s", 0.005, 10.0)
    command_timeout_s: float = setting(
        2.0, "no command for this long while regulating: safe action", "s", 0.1, 3600.0)
    command_timeout_action: str = setting("hold", "safe action on a command timeout",
                                          choices=("hold", "vent"))
    default_rate_pa_per_s: float = setting(1.0e6, "setpoint slew when a command gives none",
                                           "Pa/s", 1e3, 1e8)
    regulator_max_gauge_pa: float = 150e3
    regulator_min_gauge_pa: float = -80e3
    kp: float = setting(0.3, "proportional gain of the trim", "Pa/Pa", 0.0, 10.0)
    ki_per_s: float = setting(30.0, "integral gain of the trim", "1/s", 0.0, 1000.0)
    trim_limit_pa: float = setting(5e3, "largest trim of the regulator setpoint", "Pa", 0.0, 50e3)
    integral_band_pa: float = 1.5e3
    boost_band_pa: float = 1e3
    boost_min_step_pa: float = 5e3
    boost_headroom_pa: float = 90e3
    boost_lead_s: float = 0.005
    rate_filter_s: float = 0.01
    settle_timeout_s: float = 0.2
    valve_band_pa: float = 5e3
    channels: int = 1
    boost_ceiling_pa: float = math.nan  # NaN: per target, from the plant (boost_ceilings)
    hold_cycles: int = 3
    hold_cycle_window_s: float = 1.0
    safety: SafetyConfig = SafetyConfig()  # its limits are replaced by the ones above

    def __post_init__(self):
        object.__setattr__(
            self, "safety",
            dataclasses.replace(self.safety, max_gauge_pa=self.max_gauge_pa,
                                min_gauge_pa=self.min_gauge_pa,
                                margin_pa=self.overpressure_margin_pa))
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if field.name == "boost_ceiling_pa" and math.isnan(value):
                continue
            if isinstance(value, float) and not math.isfinite(value):
                raise ValueError(f"{field.name} must be finite, got {value}")
        check_settings(self)
        checks = [
            (self.regulator_min_gauge_pa < 0.0 < self.regulator_max_gauge_pa,
             "the regulator range must span 0"),
            (0.0 < self.integral_band_pa <= 50e3, "integral_band_pa must lie in (0, 50000] Pa"),
            (0.0 < self.boost_band_pa and
             0.0 <= self.boost_lead_s <= 1.0, "boost_band_pa > 0, boost_lead_s in [0, 1]"),
            (self.boost_min_step_pa
             >= self.boost_band_pa, "boost_min_step_pa must be >= boost_band_pa"),
            (0.0 < self.boost_headroom_pa <= 500e3,
             "boost_headroom_pa must lie in (0, 500000] Pa"),
            (0.0 <= self.rate_filter_s <= 1.0, "rate_filter_s must lie in [0, 1] s"),
            (0.0 < self.valve_band_pa, "valve_band_pa must be > 0"),
            (1 <= self.channels <= 4, "channels must lie in 1..4"),
            (1 <= self.hold_cycles <= 1000 and 0.0 < self.hold_cycle_window_s <= 60.0,
             "hold_cycles must lie in 1..1000 and hold_cycle_window_s in (0, 60] s"),
        ]
        for ok, message in checks:
            if not ok:
                raise ValueError(message)


@dataclasses.dataclass(frozen=True)
class ControlOutput:
    regulator_setpoint_gauge_pa: float
    regulator_enabled: bool
    regulator_source: Source
    valves: tuple
    mode: PressureMode
    fault_flags: Fault
    setpoint_gauge_pa: float  # after limits and slew
    feedback_gauge_pa: float  # what the law used (NaN when none)
    message: str


class PressureController:
    """The control core; feed it readings and commands, call :meth:`step` every period.

    plant: the plant model the safety checks compare the chamber with (default: the defaults').
    sensor_noise_pa: {sensor name: rated 1-sigma noise, Pa}, for the noise check."""

    def __init__(self, config: PressureControlConfig | None = None,
                 plant: PneumaticPlant | None = None, sensor_noise_pa: dict | None = None):
        self.plant = plant or PneumaticPlant()
        self._config = config or PressureControlConfig()
        self._ceilings = boost_ceilings(self.plant.parameters, self._config)
        self.monitor = SafetyMonitor(self._config.safety, self.plant, sensor_noise_pa)
        self._sensors: dict = {}  # name -> (gauge_pa, time)
        self._estimate = (math.nan, -math.inf)
        self._target = 0.0
        self._source = Source.VENT
        self._rate = self.config.default_rate_pa_per_s
        self._command_time = None
        self._setpoint = 0.0
        self._integral = 0.0
        self._last_step = None
        self._period_s = 0.0
        self._phase = RegulationPhase.TRACK
        self._settle_started = 0.0
        self._regulator_actual = 0.0
        self._previous_feedback = None
        self._rate_estimate = 0.0
        self._evacuating = False
        self._latched = Fault.NONE
        self._fault_message = ""  # the finding that latched the safe state
        self._steady_target = math.nan
        self._rejection = ""  # why the last refused command was refused
        # a refusal no step has reported yet; whether a command applied since
        self._rejection_unreported = self._applied_after_rejection = False
        self._regulator_faults = 0
        # boosts and evacuations since the target last changed
        self._corrections = collections.deque()
        self._hold_regulator = False
        self.active = False
        self.last_output: ControlOutput | None = None

    @property
    def identification(self) -> bool:
        """Open loop for identification (see the module docstring); the monitor's checks against
        the plant model are suspended meanwhile, since that model is what is being measured. The
        node changes it only while inactive."""
        return not self.monitor.trust_model

    @identification.setter
    def identification(self, on: bool) -> None:
        self.monitor.trust_model = not on

    @property
    def regulation_phase(self) -> RegulationPhase:
        """The REGULATE mode's sub-phase (back to TRACK when no valid reading or a safe state
        interrupts it)."""
        return self._phase

    @property
    def config(self) -> PressureControlConfig:
        return self._config

    @config.setter
    def config(self, config: PressureControlConfig) -> None:
        """A new configuration (live parameters): the monitor's thresholds follow it."""
        self._ceilings = boost_ceilings(self.plant.parameters, config)
        self._config = config
        self.monitor.config = config.safety

    # ---- inputs -----------------------------------------------------------------------------
    def command(self, target_gauge_pa: float, source: Source, max_rate_pa_per_s: float,
                now: float) -> str:
        """Accept a PressureCommand. Returns a note for the user ('' when nothing to say)."""
        source = Source(source)
        if source in (Source.SUPPLY, Source.VACUUM) and not math.isfinite(target_gauge_pa):
            raise ValueError(
                f"target pressure must be finite for {source.name}, got {target_gauge_pa}")
        note = ""
        cleared = Fault.SETPOINT_CLAMPED | Fault.COMMAND_TIMEOUT
        # a refusal is reported by a step even when a command applies before any step ran
        if self._rejection_unreported:
            self._applied_after_rejection = True
        else:
            cleared |= Fault.COMMAND_REJECTED
        self._latched &= ~cleared
        # identification: a HOLD may set the regulator, with the valves closed
        self._hold_regulator = (self.identification and source == Source.HOLD and
                                math.isfinite(target_gauge_pa))
        if source in (Source.SUPPLY, Source.VACUUM) or self._hold_regulator:
            clamped = min(max(target_gauge_pa, self.config.min_gauge_pa), self.config.max_gauge_pa)
            if clamped != target_gauge_pa:
                self._latched |= Fault.SETPOINT_CLAMPED
                note = (
                    f"setpoint {target_gauge_pa:.0f} Pa clamped to {clamped:.0f} Pa "
                    f"(limits {self.config.min_gauge_pa:.0f}..{self.config.max_gauge_pa:.0f} Pa)")
            self._target = clamped
        rate = max_rate_pa_per_s
        self._rate = rate if (math.isfinite(rate) and
                              rate > 0.0) else self.config.default_rate_pa_per_s
        if source != self._source or (source in (Source.SUPPLY, Source.VACUUM) and
                                      self._target != self._steady_target):
            # a new target: its first boost or evacuation is the way there
            self._corrections.clear()
        self._steady_target = self._target if source in (Source.SUPPLY,
                                                         Source.VACUUM) else math.nan
        if source != self._source:
            self._integral = 0.0
        self._source = source
        self._command_time = now
        cleared = self.monitor.clearable(self._latched & SAFETY_FAULTS, now)
        if cleared:
            self._latched &= ~cleared
            if not self._latched & SAFETY_FAULTS:
                self._fault_message = ""
        still = fault_names(self._latched & SAFETY_FAULTS)
        if still:
            note = f"{note}; " if note else ""
            note += f"still in the safe state: {still} ({self._fault_message})"
        return note

    def reject_command(self, reason: str) -> None:
        """A command the caller refused (a stamp in the future): flagged until the next one
        applies, and in the next step's output at least."""
        self._latched |= Fault.COMMAND_REJECTED
        self._rejection = reason
        self._rejection_unreported, self._applied_after_rejection = True, False

    def _report_rejection(self) -> Fault:
        """The faults latched for this step's output; a refusal is reported once here, and
        cleared after it when a command has applied since."""
        faults = self._latched
        if self._rejection_unreported:
            self._rejection_unreported = False
            if self._applied_after_rejection:
                self._latched &= ~Fault.COMMAND_REJECTED
        return faults

    def update_sensor(self, name: str, gauge_pa: float, now: float) -> bool:
        """Take a reading taken at ``now``; True when it lies beyond the limits plus margin and the
        controller is not yet in its safe state (step now)."""
        if math.isfinite(gauge_pa):
            self._sensors[name] = (gauge_pa, now)
            self.monitor.add_reading(name, gauge_pa, now)
            return not self._within_limits(gauge_pa) and not self._latched & SAFETY_FAULTS
        return False

    def update_estimate(self, gauge_pa: float, now: float) -> None:
        if math.isfinite(gauge_pa):
            self._estimate = (gauge_pa, now)

    def update_regulator_status(self, actual_gauge_pa: float, fault_bits: int,
                                now: float | None = None) -> None:
        """The regulator's report (taken at ``now``; default: the last step's time)."""
        if math.isfinite(actual_gauge_pa):
            self._regulator_actual = actual_gauge_pa
            self.monitor.add_regulator(actual_gauge_pa, now if now is not None else
                                       (self._last_step or 0.0))
        self._regulator_faults = int(fault_bits)

    def valves_sent(self, now: float) -> None:
        """The valve state of the last step went out at ``now`` (see SafetyMonitor.valves_sent)."""
        self.monitor.valves_sent(now)

    def regulator_sent(self, now: float) -> None:
        """The regulator command of the last step went out at ``now`` (see
        SafetyMonitor.regulator_sent)."""
        self.monitor.regulator_sent(now)

    def update_consistency(self, name: str, mean_nis: float, bound: float, now: float) -> None:
        """The estimator's windowed NIS of a sensor and its upper bound (see SafetyMonitor)."""
        self.monitor.update_consistency(name, mean_nis, bound, now)

    def vent(self, now: float) -> None:
        """Vent now (service call, shutdown, deactivate)."""
        self._source = Source.VENT
        self._target = 0.0
        self._command_time = now
        self._integral = 0.0

    # ---- feedback ---------------------------------------------------------------------------
    def fresh_sensors(self, now: float) -> dict:
        return {name: value for name, (value, _) in self._fresh_readings(now).items()}

    def _fresh_readings(self, now: float) -> dict:
        """{name: (gauge Pa, stamp)} of the sensors read within ``sensor_timeout_s``."""
        return {
            name: (value, stamp)
            for name, (value, stamp) in self._sensors.items()
            if now - stamp <= self.config.sensor_timeout_s
        }

    def measured(self, now: float) -> float:
        """Mean of the fresh sensor readings, NaN when none is fresh."""
        fresh = self.fresh_sensors(now)
        return sum(fresh.values()) / len(fresh) if fresh else math.nan

    def feedback(self, now: float) -> float:
        return self._feedback(now)[0]

    def _feedback(self, now: float) -> tuple:
        """(the feedback, when it was measured): the estimate while fresh (dated when it came),
        else the mean of the fresh sensors at the mean of their stamps (NaN, NaN: none)."""
        value, stamp = self._estimate
        fresh = list(self._fresh_readings(now).values())
        if now - stamp <= self.config.sensor_timeout_s and fresh:
            return value, stamp
        if not fresh:
            return math.nan, math.nan
        return (sum(g for g, _ in fresh) / len(fresh), sum(w for _, w in fresh) / len(fresh))

    def estimate_gauge_pa(self, now: float) -> float:
        """The latest estimate while fresh, else NaN."""
        value, stamp = self._estimate
        return value if now - stamp <= self.config.sensor_timeout_s else math.nan

    def last_sensor_age(self, now: float) -> float:
        return min((now - stamp for _, stamp in self._sensors.values()), default=math.inf)

    def _within_limits(self, pressure: float) -> bool:
        c = self.config
        return (math.isfinite(pressure) and c.min_gauge_pa - c.overpressure_margin_pa <= pressure
                <= c.max_gauge_pa + c.overpressure_margin_pa)

    # ---- the law ------------------------------------------------------------------------------
    def step(self, now: float) -> ControlOutput:
        c = self.config
        dt = 0.0 if self._last_step is None else max(0.0, now - self._last_step)
        self._last_step = now
        # the period the valve state now sent will likely stand for: an extra step (a command,
        # a reading beyond a limit) does not shorten the next one
        self._period_s = max(dt, 0.9 * self._period_s)
        if not self.active:
            return self._output(0.0, False, Source.VENT, Valve.CLOSED, PressureMode.INACTIVE,
                                self._report_rejection(), self.feedback(now), "inactive")
        regulating = self._source in (Source.SUPPLY, Source.VACUUM)
        for finding in self.monitor.check(now, c.sensor_timeout_s, regulating and
                                          self._phase == RegulationPhase.TRACK):
            if finding.flag in SAFETY_FAULTS and not self._latched & SAFETY_FAULTS:
                self._fault_message = finding.message  # the first evidence names the fault
            self._latched |= finding.flag & SAFETY_FAULTS
        faults = self._report_rejection()
        if self._regulator_faults:
            faults |= Fault.REGULATOR
        measured = self.measured(now)
        feedback, measured_at = self._feedback(now)
        if self._latched & SAFETY_FAULTS:
            return self._safe_state(now, faults, feedback)
        if math.isnan(measured):
            self._integral = 0.0
            self._phase = RegulationPhase.TRACK
            # the first reading after recovery starts a new rate estimate
            self._previous_feedback = None
            # asked for explicitly: obeyed, but nothing can confirm it
            if self._source == Source.VENT:
                return self._output(0.0, True, Source.VENT, Valve.VENT, PressureMode.VENT,
                                    faults | Fault.SENSOR_TIMEOUT, feedback,
                                    "venting, unconfirmed: no valid pressure reading")
            return self._output(self._setpoint, True, self._regulator_source(), Valve.CLOSED,
                                PressureMode.HOLD, faults | Fault.SENSOR_TIMEOUT, feedback,
                                "no valid pressure reading: valves held closed")
        regulating = self._source in (Source.SUPPLY, Source.VACUUM)
        if (regulating and self._command_time is not None and
                now - self._command_time > c.command_timeout_s):
            self._latched |= Fault.COMMAND_TIMEOUT
            faults |= Fault.COMMAND_TIMEOUT
            if c.command_timeout_action == "vent":
                self.vent(now)
            else:
                self._source = Source.HOLD
            regulating = False
        if self._source == Source.VENT:
            self._setpoint = 0.0
            return self._output(0.0, True, Source.VENT, Valve.VENT, PressureMode.VENT, faults,
                                feedback, "venting")
        if self._source == Source.HOLD and self._hold_regulator:
            self._setpoint = self._target
            return self._output(self._target, True, self._regulator_source(), Valve.CLOSED,
                                PressureMode.IDENTIFY, faults, feedback,
                                "identification: valves closed, the regulator set")
        if self._source == Source.HOLD or not regulating:
            # the regulator at atmosphere: closed valves do not feel it, and a valve stuck open
            # then moves the chamber towards atmosphere, where the response check names it. At
            # the held pressure it kept the chamber there, unseen (a valve stuck open to SUPPLY
            # through a release, into the HOLD after it: the fault matrix). Identification keeps
            # it where its excitation put it (its holds end in refills that measure the valve,
            # not the regulator's lag; and the response check is suspended there anyway)
            regulator = self._setpoint if self.identification else 0.0
            return self._output(regulator, True, Source.HOLD, Valve.CLOSED, PressureMode.HOLD,
                                faults, feedback, "holding: valves closed")
        if self.identification:
            return self._open_loop(faults, feedback, measured_at, now)

        # slew the setpoint towards the target
        step_limit = self._rate * dt if dt > 0 else math.inf
        self._setpoint += min(max(self._target - self._setpoint, -step_limit), step_limit)
        error = self._setpoint - feedback
        rate = self._update_rate(feedback, measured_at)
        # the error now, at the feedback's rate since it was measured: the crossing predictions
        # and the settle's top-up judge this (the boost, by a feedback 20 ms old, overshot a
        # 25 kPa step by 8.7 kPa; see test_control_pressure)
        error_now = error - rate * max(now - measured_at, 0.0)
        valve = self._arbitrate(error_now, rate)
        regulator, valve_override = self._regulation(error, error_now, feedback, dt, now)
        # the pump needs no settled regulator
        if valve_override is not None and valve != Valve.VACUUM:
            valve = valve_override  # (Valve.CLOSED is 0: no "or")
        return self._output(regulator, True, self._regulator_source(), valve,
                            PressureMode.REGULATE, faults, feedback,
                            "" if self._phase == RegulationPhase.TRACK else self._phase.value)

    def _open_loop(self, faults: Fault, feedback: float, measured_at: float,
                   now: float) -> ControlOutput:
        """Identification: the regulator at the target with the valve open to it (SUPPLY), or
        the valve open to the pump until the chamber would reach the target within
        ``boost_lead_s`` (VACUUM; then HOLD).

        The crossing is predicted, as the closed loop's is: the pump's raw flow near the bottom
        of a small chamber is some 550 kPa/s, and closing on the first reading past the target
        ended evacuations 2-4 kPa below it, live (one, under load, 8.7 kPa below, into the
        limit trip: bench_identify, drawn_2)."""
        rate = self._update_rate(feedback, measured_at)
        error_now = self._target - feedback - rate * max(now - measured_at, 0.0)
        if self._source == Source.VACUUM and (
                feedback <= self._target or _falls_to(error_now, rate, self.config.boost_lead_s)):
            self._source = Source.HOLD
            return self._output(self._setpoint, True, Source.HOLD, Valve.CLOSED,
                                PressureMode.IDENTIFY, faults, feedback,
                                f"identification: evacuated to {self._target:.0f} Pa, held")
        if self._source == Source.SUPPLY:
            self._setpoint = self._target
            return self._output(self._target, True, self._regulator_source(), Valve.SUPPLY,
                                PressureMode.IDENTIFY, faults, feedback,
                                "identification: valve open to the regulator")
        return self._output(self._setpoint, True, self._regulator_source(), Valve.VACUUM,
                            PressureMode.IDENTIFY, faults, feedback,
                            f"identification: evacuating to {self._target:.0f} Pa")

    def _safe_state(self, now: float, faults: Fault, feedback: float) -> ControlOutput:
        """Valves VENT and the regulator disabled at 0 (the device cuts both sources), until a new
        command clears the fault."""
        self.vent(now)
        self._phase = RegulationPhase.TRACK
        return self._output(
            0.0, False, Source.VENT, Valve.VENT, PressureMode.FAULT, faults, feedback,
            f"fault: {fault_names(self._latched & SAFETY_FAULTS)}: {self._fault_message}; "
            f"venting with the regulator disabled")

    def boost_ceiling_gauge_pa(self, target_gauge_pa: float) -> float:
        """The boost's ceiling on the way to ``target_gauge_pa`` (see :func:`boost_ceiling_pa`)."""
        for up_to, ceiling in self._ceilings:
            if target_gauge_pa <= up_to:
                return ceiling
        return self._ceilings[-1][1]  # a NaN target: the lowest

    def _regulation(self, error: float, error_now: float, feedback: float, dt: float,
                    now: float) -> tuple:
        """(regulator setpoint, valve override or None) for one REGULATE period: ``error`` of the
        feedback, ``error_now`` carried to ``now`` at the feedback's rate."""
        c = self.config
        rate = self._rate_estimate
        if (self._phase == RegulationPhase.TRACK and self._setpoint > 0.0 and
                error > c.boost_band_pa and self._target - feedback > c.boost_min_step_pa):
            self._phase = RegulationPhase.BOOST
            self._count_correction(now, "boosts")
        if self._phase == RegulationPhase.BOOST:
            time_to_setpoint = error_now / rate if rate > 0.0 else math.inf
            if error_now > 0.0 and time_to_setpoint > c.boost_lead_s:
                # fill hard, but no harder than the headroom and the ceiling: a late or stuck
                # valve then stays bounded
                return min(c.regulator_max_gauge_pa, self._target + c.boost_headroom_pa,
                           self.boost_ceiling_gauge_pa(self._target)), Valve.SUPPLY
            self._phase, self._settle_started = RegulationPhase.SETTLE, now
        command = self._trimmed(error, dt, integrate=self._phase == RegulationPhase.TRACK)
        if self._phase == RegulationPhase.SETTLE:
            # hold the air in while the regulator comes down from its maximum to the setpoint
            regulator_close = abs(self._regulator_actual - command) <= c.boost_band_pa
            if regulator_close or now - self._settle_started > c.settle_timeout_s:
                self._phase = RegulationPhase.TRACK
            else:
                return command, self._top_up(error_now, feedback)
        return command, None

    def _top_up(self, error: float, feedback: float) -> Valve:
        """The settle's valve: CLOSED, or SUPPLY for one period while the model's rate from the
        regulator's reported output (stale, so high while it falls) through the open valve, over
        two periods, stays below the error.

        The boost stops ``boost_lead_s`` short of the setpoint (12 % of a 25 kPa step at a hard
        boost), and a regulator falling from a hard boost takes several lags to come within
        ``boost_band_pa``: waiting for it held the chamber short for up to ``settle_timeout_s``.
        A pulse one period long cannot pass the setpoint on a plant up to twice the model's
        rate, or a period stretched to twice its length."""
        if error <= self.config.boost_band_pa:
            return Valve.CLOSED
        rate = self.plant.chamber_rate(P_ATM_PA + feedback, Valve.SUPPLY, self._regulator_actual)
        return Valve.SUPPLY if rate * 2.0 * self._period_s < error else Valve.CLOSED

    def _count_correction(self, now: float, what: str) -> None:
        """A boost or an evacuation at the steady target; too many of them latch RESPONSE."""
        c, corrections = self.config, self._corrections
        corrections.append(now)
        while corrections and corrections[0] < now - c.hold_cycle_window_s:
            corrections.popleft()
        # the first one reaches the target
        if len(corrections) > c.hold_cycles and not self._latched & SAFETY_FAULTS:
            self._latched |= Fault.RESPONSE
            self._fault_message = (
                "the regulated line cannot hold the chamber where the sensors say: "
                f"{len(corrections)} "
                f"{what} within {c.hold_cycle_window_s:g} s at a steady {self._target / 1e3:.1f} "
                "kPa "
                f"(biased sensors, a leak or a regulator offset)")

    def _update_rate(self, feedback: float, measured_at: float) -> float:
        """dp/dt of the feedback over the times it was measured, low-passed (time constant
        rate_filter_s): raw differences of noisy readings would make the boost's crossing
        prediction jitter. Over the steps' times instead, readings held up by a stall read as a
        standstill (the rate decayed, and the boost went on blind) and then as a jump."""
        previous = self._previous_feedback
        if previous is None or measured_at > previous[1]:
            self._previous_feedback = (feedback, measured_at)
        if previous is not None and measured_at > previous[1]:
            span = measured_at - previous[1]
            raw = (feedback - previous[0]) / span
            self._rate_estimate += span / (self.config.rate_filter_s + span) * (
                raw - self._rate_estimate)
        return self._rate_estimate

    def _trimmed(self, error: float, dt: float, integrate: bool) -> float:
        c = self.config
        # integrator separation: no wind-up on the approach
        near = abs(error) < c.integral_band_pa
        if integrate and near and abs(c.kp * error + c.ki_per_s *
                                      (self._integral + error * dt)) < c.trim_limit_pa:
            # conditional integration: no wind-up at the clamp
            self._integral += error * dt
        trim = min(max(c.kp * error + c.ki_per_s * self._integral, -c.trim_limit_pa),
                   c.trim_limit_pa)
        return min(max(self._setpoint + trim, c.regulator_min_gauge_pa), c.regulator_max_gauge_pa)

    def _arbitrate(self, error: float, rate: float) -> Valve:
        """SUPPLY (the regulated line) normally; the raw vacuum pump while far above a negative
        target, handing back ``boost_lead_s`` before the predicted crossing (as the boost does).

        "Far above" is judged where the slewing setpoint will be ``boost_lead_s`` ahead: a clamp
        at the default 1 MPa/s then opens the pump at once instead of after the 5 kPa band's
        5 ms of slew, while a slow ramp (10 kPa/s: 50 Pa ahead) is followed as before."""
        c = self.config
        if self._target < 0.0:
            setpoint_ahead = max(self._target, self._setpoint - self._rate * c.boost_lead_s)
            error_ahead = min(error, error + setpoint_ahead - self._setpoint)
            if error_ahead < -c.valve_band_pa:
                if not self._evacuating:
                    self._count_correction(self._last_step, "evacuations")
                self._evacuating = True
            if error_ahead > -0.5 * c.valve_band_pa or _falls_to(error, rate, c.boost_lead_s):
                self._evacuating = False
        else:
            self._evacuating = False
        return Valve.VACUUM if self._evacuating else Valve.SUPPLY

    def _regulator_source(self) -> Source:
        return Source.VACUUM if self._setpoint < 0.0 else Source.SUPPLY

    def _output(self, regulator, enabled, source, valve, mode, faults, feedback,
                message) -> ControlOutput:
        if Fault.COMMAND_REJECTED in faults and self._rejection:
            message = f"{message}; {self._rejection}" if message else self._rejection
        self.monitor.record_output(self._last_step if self._last_step is not None else 0.0, valve,
                                   regulator, enabled)
        self.last_output = ControlOutput(regulator_setpoint_gauge_pa=float(regulator),
                                         regulator_enabled=enabled, regulator_source=source,
                                         valves=(valve,) * self.config.channels, mode=mode,
                                         fault_flags=Fault(faults),
                                         setpoint_gauge_pa=self._setpoint,
                                         feedback_gauge_pa=feedback, message=message)
        return self.last_output


def _falls_to(error_pa: float, rate_pa_per_s: float, within_s: float) -> bool:
    """Whether a chamber falling at ``rate_pa_per_s`` passes a target ``error_pa`` (target minus
    chamber) away within ``within_s``, or has passed it."""
    return rate_pa_per_s < 0.0 and error_pa / rate_pa_per_s <= within_s


BOOST_CEILING_TARGETS = 10  # the targets a ceiling is computed for: the upper limit's tenths


BOOST_CEILINGS_CACHE = "boost_ceilings"  # softgrip_ros.cache's directory of them
# whose code the ceilings' simulation runs: a change to any makes a new cache key
_SIMULATING_MODULES = tuple(sys.modules[name] for name in (
    __name__, SafetyMonitor.__module__, Fault.__module__, PneumaticPlant.__module__))


def boost_ceilings(plant_parameters, config: PressureControlConfig) -> tuple:
    """((target, ceiling), ...) in Pa gauge, targets rising: the boost's ceiling for any target up
    to each one. A finite ``config.boost_ceiling_pa`` is the ceiling for every target.

    Kept in :mod:`softgrip_ros.cache`, keyed by the plant, the configuration and the source of the
    code that simulates them, so a controller computes them (a fifth of a second of CPU) once per
    plant and configuration, not at every start; a cached file that is unreadable or holds a
    ceiling outside [``max_gauge_pa``, ``regulator_max_gauge_pa``] is recomputed. A cache that
    cannot be written costs the time, nothing else."""
    if math.isfinite(config.boost_ceiling_pa):
        return ((math.inf, config.boost_ceiling_pa),)
    key = cache.key_of({"plant": dataclasses.asdict(plant_parameters),
                        "config": dataclasses.asdict(config),
                        "code": _simulating_code()})
    ceilings = cache.read_cache(BOOST_CEILINGS_CACHE, key,
                                lambda document: _parse_ceilings(document, config))
    if ceilings is None:
        ceilings = _computed_ceilings(plant_parameters, config)
        with contextlib.suppress(OSError):
            cache.write_cache(BOOST_CEILINGS_CACHE, key, {
                "ceilings": [[None if math.isinf(t) else t, c] for t, c in ceilings]})
    return ceilings


@functools.lru_cache(maxsize=1)
def _simulating_code() -> str:
    return cache.source_digest(*_SIMULATING_MODULES)


def _targets(config: PressureControlConfig) -> list:
    """The targets a ceiling holds up to, rising; the last one inf (any target)."""
    return [config.max_gauge_pa * k / BOOST_CEILING_TARGETS
            for k in range(1, BOOST_CEILING_TARGETS)] + [math.inf]


def _parse_ceilings(document: dict, config: PressureControlConfig) -> tuple:
    """The ceilings of a cached ``document``; ValueError unless they are for this configuration's
    targets and each lies within [the limit, the regulator's maximum]."""
    pairs = tuple((math.inf if target is None else float(target), float(ceiling))
                  for target, ceiling in document["ceilings"])
    if [target for target, _ in pairs] != _targets(config) or not all(
            config.max_gauge_pa <= ceiling <= config.regulator_max_gauge_pa
            for _, ceiling in pairs):
        raise ValueError("cached boost ceilings that do not fit this configuration")
    return pairs


def _computed_ceilings(plant_parameters, config: PressureControlConfig) -> tuple:
    ceilings = []
    # from the highest target down: the ceiling does not fall as the target does, so once one
    # is the regulator's maximum, so is every one below it
    for target in reversed(_targets(config)):
        if ceilings and ceilings[-1][1] >= config.regulator_max_gauge_pa:
            ceiling = config.regulator_max_gauge_pa
        else:
            ceiling = boost_ceiling_pa(plant_parameters, config,
                                       None if math.isinf(target) else target)
        ceilings.append((target, ceiling))
    return tuple(reversed(ceilings))


@functools.lru_cache(maxsize=256)
def boost_ceiling_pa(plant_parameters, config: PressureControlConfig,
                     target_gauge_pa: float | None = None, guard_pa: float = 1e3) -> float:
    """The highest regulator output a boost towards ``target_gauge_pa`` (default: the upper limit)
    may ask for, on this plant: with it, even a valve stuck open to the supply keeps the chamber
    ``guard_pa`` (sensor noise) inside the limit plus margin.

    Simulated, not assumed: this controller, on the plant, fills towards the target with its
    valve stuck open. Its settle then cannot close the valve; the regulator, told the target,
    falls at its lag and rate limit, and the monitor or the limit trip (the regulator disabled)
    stops the chamber. The peak rises with the target, so a low target may boost harder: a
    25 kPa step may use the regulator's whole range where a step to the limit may not. The
    ceiling is bisected between the limit and the regulator's maximum (0.05-0.3 s of computing,
    once per plant, configuration and target)."""
    plant = PneumaticPlant(plant_parameters)
    limit = config.max_gauge_pa + config.overpressure_margin_pa - guard_pa
    target = config.max_gauge_pa if target_gauge_pa is None else target_gauge_pa

    def within_limit(ceiling_pa: float) -> bool:
        """Whether the chamber's peak stays at or below ``limit`` (stops at the first step past
        it: the peak's height beyond does not matter)."""
        controller = PressureController(dataclasses.replace(config, boost_ceiling_pa=ceiling_pa),
                                        plant)
        controller.active = True
        state = plant.initial_state()
        controller.command(target, Source.SUPPLY, math.nan, 0.0)
        inputs = PlantInputs(valves=(Valve.SUPPLY,))
        # 1.5 s at 1 kHz: the fill, the settle against the stuck valve, the trip, the fall
        for tick in range(1, 1500):
            now, gauge = tick * 1e-3, float(state.chamber_pa[0] - P_ATM_PA)
            # sensors at 500 Hz, the regulator's report at 100 Hz
            if tick % 2 == 0:
                controller.update_sensor("sensor", gauge, now)
                if tick % 10 == 0:
                    controller.update_regulator_status(state.regulator_gauge_pa, 0, now)
                out = controller.step(now)
                inputs = PlantInputs(out.regulator_setpoint_gauge_pa, out.regulator_enabled,
                                     (Valve.SUPPLY,))
            state = plant.step(state, inputs, 1e-3)
            if float(state.chamber_pa[0] - P_ATM_PA) > limit:
                return False
            if (controller.last_output is not None and
                    controller.last_output.mode == PressureMode.FAULT and
                    state.regulator_gauge_pa < gauge):
                # the regulator is below the chamber: it falls from here
                break
        return True

    low, high = config.max_gauge_pa, config.regulator_max_gauge_pa
    if within_limit(high):
        return high
    while high - low > 1e3:
        middle = 0.5 * (low + high)
        low, high = (middle, high) if within_limit(middle) else (low, middle)
    return low

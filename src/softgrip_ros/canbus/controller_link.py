"""The pressure controller's side of the bus: frames in, control core, frames out (no ROS).

Sensor and regulator frames are decoded (invalid ones are counted and dropped by the codec) and
fed to the control core, a batch at a time. While a control loop runs (:func:`make_control_loop`)
its thread takes them, every frame queued before each step, so that readings and the step that
uses them are ordered by one thread; otherwise a :class:`~softgrip_ros.canbus.reader.BatchReader`
thread takes each as it comes. While the controller rests (venting, holding, inactive or
faulted: the valves stay as they are) the frames are taken every ``rest_receive_period_s``
instead, which saves a thread wake per frame; a reading beyond the limits is then acted on within
that period. A step that starts regulating (a command's) ends the wait. The
owner calls :meth:`ControllerLink.step` once per control period; it runs the core and
sends RegulatorSetpoint and ValveCommand in that period when their content changed, and else
every ``command_frame_period_s`` (they are cyclic frames: the device's watchdog expects them),
and ControllerHeartbeat at 10 Hz. Unchanged frames every 2 ms would only load the bus and the CPU.

Every ValveCommand carries ``valve_lifetime_s`` (the DBC's OpenLifetime): the device closes a
channel left in SUPPLY or VACUUM that long without a newer frame. The link re-sends well within
it, so in normal running nothing expires; when this process stalls (a GIL hog, a paused VM), the
chamber is held instead of running on towards the vacuum pump or the boosted regulator. A frame
sent after such a lapse reopens them; the status reports the lapse (see
:meth:`ControllerLink.status_outputs`).
"""
from __future__ import annotations

import dataclasses
import math
import threading
import time

import can

from softgrip_ros.canbus.codec import FrameCodec, frame_sent_at
from softgrip_ros.checks import future_stamp_reason
from softgrip_ros.canbus.reader import BatchReader
from softgrip_ros.control.faults import Fault
from softgrip_ros.control.pressure import ControlOutput, PressureMode, PressureController, Source
from softgrip_ros.control.reports import LinkStats
from softgrip_ros.model.pneumatics import SOURCE_VALVES, Valve
from softgrip_ros.realtime import PeriodicThread

HEARTBEAT_PERIOD_S = 0.1
CONTROLLER_STATE = {PressureMode.INACTIVE: 0, PressureMode.FAULT: 2}
# FRAMES_REJECTED is reported this long after the last rejected frame
FRAMES_REJECTED_HOLD_S = 1.0
IGNORED_IN_IDENTIFICATION = "pressure command ignored: identification mode"


def acting(output) -> bool:
    """Whether ``output`` needs every reading at once and its frames at the control rate (the
    rest batch the readings and step at the rest rate: see make_control_loop): regulating, or a
    valve open to a source in identification (its OpenLifetime needs the frames; an evacuation
    stops at its target)."""
    return output.mode == PressureMode.REGULATE or (
        output.mode == PressureMode.IDENTIFY and
        any(v in (Valve.SUPPLY, Valve.VACUUM) for v in output.valves))


@dataclasses.dataclass(frozen=True)
class SensorBinding:
    """A pressure sensor: its name (topic pressure/sensor/<name>), its DBC message and its bias
    (Pa, taken off every reading: the plant file's, identified at rest)."""

    name: str
    message: str
    bias_pa: float = 0.0


class ControllerLink:
    """Owns the controller's bus traffic. ``on_readings(readings)`` is called (from the thread
    that takes the frames) with each batch's valid sensor readings, [(name, gauge_pa, stamp)]
    oldest first; ``stamp`` is when the frame was sent, on ``clock`` (see
    :func:`frame_sent_at`)."""

    def __init__(self, bus: can.BusABC, controller: PressureController, sensors: list,
                 codec: FrameCodec | None = None, bus_silent_timeout_s: float = 0.25,
                 on_readings=None, clock=time.monotonic, command_frame_period_s: float = 0.01,
                 valve_lifetime_s: float = 0.025, control_period_s: float = 0.002,
                 rest_receive_period_s: float = 0.0):
        self.bus = bus
        self.controller = controller
        self.codec = codec or FrameCodec()
        self.sensors = {binding.message: binding.name for binding in sensors}
        self._bias_pa = {binding.message: binding.bias_pa for binding in sensors}
        unknown = set(self.sensors) - set(self.codec.message_names)
        if unknown:
            raise ValueError(f"sensor messages {sorted(unknown)} are not in the DBC")
        self.bus_silent_timeout_s = bus_silent_timeout_s
        self.on_readings = on_readings
        self.clock = clock
        self._lock = threading.Lock()
        self._step_lock = threading.Lock()
        self.frames_rx = 0
        self.frames_tx = 0
        self.send_errors = 0
        self.listener_errors = 0
        self.last_listener_error = ""
        self.regulator_actual_gauge_pa = math.nan
        self.regulator_report_time = -math.inf  # when the device sent it, on ``clock``
        self.last_frame_time = -math.inf
        self._last_heartbeat = -math.inf
        self._rejected_total, self._rejected_at = 0, -math.inf
        if not 0.0 <= command_frame_period_s <= 0.1:
            raise ValueError(
                f"command_frame_period_s must lie in [0, 0.1] s, got {command_frame_period_s}")
        self.command_frame_period_s = command_frame_period_s
        lifetime_max = self.codec.signal_range("ValveCommand", "OpenLifetime")[1]
        resend_s = max(command_frame_period_s, control_period_s)
        if not 2.0 * resend_s <= valve_lifetime_s <= lifetime_max:
            raise ValueError(
                f"valve_lifetime_s must lie in [{2.0 * resend_s:g}, {lifetime_max:g}] s, twice "
                "the "
                f"re-send period at least (else the device closes the valves between two frames), "
                f"got {valve_lifetime_s:g}")
        self.valve_lifetime_s = valve_lifetime_s
        self._last_command_frames = {}  # message -> (signals, time sent)
        # when the valves or the regulator's command last changed (their frames went out then)
        self.output_changed_time = -math.inf
        # ... and the valves alone; whether no status has carried that yet (see status_outputs)
        self.valves_changed_time, self._valve_change_unreported = -math.inf, False
        # the last ValveCommand: when it went out and the valves it set
        self._valves_sent_at, self._valves_sent = -math.inf, ()
        # a lapse of the valves' lifetime that no status has carried: (from when, the valves then)
        self._lapse = None
        # the regulator's command of a step that then switched the valves, which went out first:
        # (when, the output with the valves the device still held); see status_outputs
        self._regulator_ahead = None
        self.lapses = 0  # lapses of the valves' lifetime (see _valves_went_out)
        self.last_output = None  # the last step's
        # the control loop's wake(): a command or a reading beyond a limit
        self.wake = None
        # the last step left the valves as they are (not regulating)
        self.resting = False
        self.rest_receive_period_s = rest_receive_period_s
        self._reader = BatchReader(bus, self._on_frames, rest_receive_period_s,
                                   lambda: self.resting, name="softgrip-can-rx")

    @property
    def frames_bad(self) -> int:
        return self.codec.rejected_total

    @property
    def receive_errors(self) -> tuple:
        """(count, the last one's text) of failed reads from the bus."""
        return self._reader.errors, self._reader.last_error

    def close(self) -> None:
        self._reader.stop(timeout_s=1.0)

    def receive_queued(self) -> int:
        """Take every frame queued on the bus now, in the calling thread (a control loop's, with
        :meth:`reception_thread` off); how many."""
        return self._reader.take_queued()

    def reception_thread(self, on: bool) -> None:
        """Whether the link's own thread takes the frames (on, from construction) or a caller
        of :meth:`receive_queued` does."""
        if on:
            self._reader.start()
        else:
            self._reader.stop(timeout_s=1.0)

    # ---- reception
    # --------------------------------------------------------------------------------
    def _on_frames(self, frames: list) -> None:
        # each frame dated from its own stamp: one ``now`` for the batch minus ages put a frame
        # decoded later that much earlier (a regulator report 2.9 ms before the plant time of its
        # value, behind a burst of readings on a loaded host: a false REGULATOR fault, its report
        # 16.7 kPa above the model during a boost)
        valid = [(decoded, frame_sent_at(frame, self.clock)) for frame in frames
                 if (decoded := self.codec.decode(frame)) is not None]
        if not valid:
            return
        readings, urgent = [], False
        with self._lock:
            self.frames_rx += len(valid)
            for decoded, sent_at in valid:
                self.last_frame_time = max(self.last_frame_time, sent_at)
                signals = decoded.signals
                if decoded.name in self.sensors:
                    if signals["SensorStatus"] == 0:
                        name = self.sensors[decoded.name]
                        gauge_pa = signals["GaugePressure"] - self._bias_pa[decoded.name]
                        urgent = self.controller.update_sensor(name, gauge_pa, sent_at) or urgent
                        readings.append((name, gauge_pa, sent_at))
                elif decoded.name == "RegulatorStatus":
                    self.regulator_actual_gauge_pa = signals["ActualGaugePressure"]
                    self.regulator_report_time = sent_at
                    self.controller.update_regulator_status(signals["ActualGaugePressure"],
                                                            int(signals["FaultBits"]), sent_at)
        if urgent and self.wake is not None:
            self.wake()
        if readings and self.on_readings is not None:
            try:
                self.on_readings(readings)
            except Exception as error:  # a failing listener must not stop reception
                self.listener_errors += 1
                self.last_listener_error = f"{type(error).__name__}: {error}"

    # ---- the control period ---------------------------------------------------------------------
    def command(self, target_gauge_pa: float, source: Source, max_rate_pa_per_s: float,
                on_applied=None) -> str:
        """Apply a command, in the order commands arrive: no stamp can lock out the ones after it
        (a stamp in the future is for the caller to refuse, see :meth:`reject_command`). What
        the controller says of it ('' for nothing); ``on_applied(note)`` runs once it has
        applied, before any step reports on it (so that a status can carry the note)."""
        with self._lock:
            note = self.controller.command(target_gauge_pa, source, max_rate_pa_per_s,
                                           self.clock())
            active = self.controller.active
            if on_applied is not None:
                on_applied(note)
        if self.wake is not None:  # a control loop runs this link
            if active:
                # Step here, in the caller's thread: handing the step to the woken loop thread
                # cost ~1 ms more (a thread wake and the GIL) in the composed controller. The loop
                # still ticks at once, for the status and a schedule that starts from the command.
                self.step()
            self.wake()
        return note

    def take(self, target_gauge_pa: float, source: Source, max_rate_pa_per_s: float,
             stamp_s: float, now_s: float, tolerance_s: float, identification_topic: bool = False,
             on_applied=None) -> str:
        """A command as it arrives (the topic's, or the composed grasp manager's): what to tell
        the user ('' for nothing). ``identification_topic``: it came on
        ~/identification_command, which alone applies in identification mode, and only there.
        One stamped more than ``tolerance_s`` ahead of ``now_s`` is refused, and the status
        carries why until a command applies; an invalid one is refused with its reason."""
        if identification_topic != self.controller.identification:
            return ("identification command ignored: identification_mode is off"
                    if identification_topic else IGNORED_IN_IDENTIFICATION)
        refused = future_stamp_reason(stamp_s, now_s, tolerance_s)
        if refused:
            self.reject_command(f"pressure command {refused}")
            return f"pressure command {refused}"
        try:
            return self.command(target_gauge_pa, source, max_rate_pa_per_s,
                                on_applied=on_applied)
        except ValueError as error:
            note = f"command rejected: {error}"
            if on_applied is not None:
                on_applied(note)
            return note

    def reject_command(self, reason: str) -> None:
        """A command the caller refused: flagged in the next outputs, with ``reason``, until one
        applies."""
        with self._lock:
            self.controller.reject_command(reason)
        if self.wake is not None:
            self.wake()

    def update_consistency(self, name: str, mean_nis: float, bound: float) -> None:
        with self._lock:
            self.controller.update_consistency(name, mean_nis, bound, self.clock())

    def update_estimate(self, gauge_pa: float) -> None:
        with self._lock:
            self.controller.update_estimate(gauge_pa, self.clock())

    def step(self) -> ControlOutput:
        """One control period: the controller's step and its frames. Steps from two threads (the
        loop's, and a command's) run one at a time, so that frames leave in the order computed."""
        with self._step_lock:
            with self._lock:
                # read once the lock is held: a step that waited for it behind a batch of
                # readings would otherwise be dated before them, and its outputs too
                now = self.clock()
                output = self.controller.step(now)
            resting = not acting(output)
            if self.resting and not resting:
                self._reader.wake()  # regulating: the readings matter at once from here on
            self.resting = resting
            extra = Fault.NONE
            if now - self.last_frame_time > self.bus_silent_timeout_s:
                extra |= Fault.BUS_SILENT
            rejected = self.codec.rejected_total
            if rejected != self._rejected_total:
                self._rejected_total, self._rejected_at = rejected, now
            message = output.message
            if now - self._rejected_at < FRAMES_REJECTED_HOLD_S:
                extra |= Fault.FRAMES_REJECTED
                message = "; ".join(
                    m for m in (message, f"frames rejected by the E2E checks ({rejected} so far)")
                    if m)
            if extra:
                output = dataclasses.replace(output, fault_flags=output.fault_flags | extra,
                                             message=message)
            self._send_output(output, now)
            self.last_output = output
            if now - self._last_heartbeat >= HEARTBEAT_PERIOD_S:
                self._last_heartbeat = now
                self._send("ControllerHeartbeat",
                           {"ControllerState": CONTROLLER_STATE.get(output.mode, 1)})
            return output

    def status_outputs(self) -> list:
        """What the next statuses report, in order: [(output, when its outputs changed, a note)];
        none before the first step. The last is the last step's output, its outputs changed
        when the valves did, if they have since the last call, else when the valves or the
        regulator command last did. A lapse since the last call comes first: the same output
        with the valves the device held, from when their lifetime ran out, and a note that says
        so.

        Dated from the last change of either, a valve switch came out as late as a regulator step
        after it that no status had carried in between (a command's step switched the valves, the
        loop's step woken after it moved the regulator: up to 50 ms late on a loaded host, and the
        estimator predicted the chamber closed while it filled, NIS outliers in the hundreds). A
        regulator step taken after the switch is dated with it, early by the wait for the loop,
        where the switch matters more: a valve moves the chamber at up to 1000 kPa/s, a regulator
        step through its 30 ms lag. A lapse: the loop was held up past ``valve_lifetime_s`` with
        a source valve open, so the device closed it until the next frame (on a 2-core host
        beside one busy process, some 7 times a grasp); the reopening counts as a valve change.
        A step that changed the regulator's command and then the valves sent the regulator's
        frame first: that command comes before, from when its frame went out, with the valves
        the device still held. Its frame goes out a median 0.1 ms before the switch's, at times
        2-5 ms (a GIL wait; live identification, two runs). Dated with the switch, the regulator
        ran ahead of a live identification's log at every fill (its reports up to 0.8 kPa above
        the model's, just after); the chamber fit took the faster fills for its compliances
        (+2 to +8 %), and through them put the vent path's critical ratio up to +24 % off."""
        with self._step_lock:
            valves_changed, self._valve_change_unreported = self._valve_change_unreported, False
            lapse, self._lapse = self._lapse, None
            ahead, self._regulator_ahead = self._regulator_ahead, None
            output = self.last_output
            changed = self.valves_changed_time if valves_changed else self.output_changed_time
        if output is None:
            return []
        statuses = [(output, changed, "")]
        if ahead is not None and valves_changed:
            statuses.insert(0, (ahead[1], ahead[0], ""))
        if lapse is not None:
            lapsed_at, valves = lapse
            statuses.insert(0, (dataclasses.replace(output, valves=valves), lapsed_at, (
                f"the device closed the valves at the end of their lifetime, "
                f"{(changed - lapsed_at) * 1e3:.0f} ms before this loop sent the next "
                "ValveCommand (the loop was held up)")))
        return sorted(statuses, key=lambda status: status[1])

    def _valves_went_out(self, valves: tuple, sent: float) -> None:
        """A ValveCommand setting ``valves`` went out at ``sent``: a lapse ends here if the last
        one left a source valve open for longer than its lifetime."""
        expired_at = self._valves_sent_at + self.valve_lifetime_s
        if sent > expired_at and any(v in SOURCE_VALVES for v in self._valves_sent):
            self.lapses += 1
            self._lapse = (expired_at, tuple(Valve.CLOSED if v in SOURCE_VALVES else v
                                             for v in self._valves_sent))
            self.valves_changed_time, self._valve_change_unreported = sent, True
        self._valves_sent_at, self._valves_sent = sent, valves

    def send_vent(self, repeats: int = 3) -> None:
        """Vent frames now (shutdown, deactivate, the ~/vent service), a few times for
        robustness."""
        with self._lock:
            self.controller.vent(self.clock())
        with self._step_lock:  # a step's frames and these do not interleave
            for _ in range(repeats):
                self._send("RegulatorSetpoint",
                           {"SetpointGaugePressure": 0.0, "Enable": 0, "Source": int(Source.VENT)})
                sent = self._send("ValveCommand", self._valve_signals([Valve.VENT] * 4))
                # the supply and vacuum closed here: a later frame ends no lapse of them
                self._valves_went_out((Valve.VENT,), sent)

    def vent_and_say(self) -> str:
        """:meth:`send_vent`, then what to tell the caller: "venting" when a fresh reading can
        confirm it; blind, that the VENT frames went out but nothing says the chamber follows."""
        self.send_vent()
        age_s = self.last_sensor_age_s()
        if age_s <= self.controller.config.sensor_timeout_s:
            return "venting"
        return f"VENT sent, but it cannot be confirmed: no valid sensor reading for {age_s:.2f} s"

    def _send_output(self, output: ControlOutput, now: float) -> None:
        low, high = self.codec.signal_range("RegulatorSetpoint", "SetpointGaugePressure")
        valves = list(output.valves) + [Valve.CLOSED] * (4 - len(output.valves))
        regulator_changed_at, valves_before = None, self._valves_sent
        for message, signals in (("RegulatorSetpoint", {
                "SetpointGaugePressure": min(max(output.regulator_setpoint_gauge_pa, low), high),
                "Enable": int(output.regulator_enabled), "Source": int(output.regulator_source)
        }), ("ValveCommand", self._valve_signals(valves))):
            last = self._last_command_frames.get(message)
            changed = last is None or last[0] != signals
            if changed or now - last[1] >= self.command_frame_period_s - 1e-9:
                self._last_command_frames[message] = (signals, now)
                sent = self._send(message, signals)
                if message == "ValveCommand":
                    self._valves_went_out(tuple(output.valves), sent)
                if changed:
                    self.output_changed_time = sent
                    if message == "ValveCommand":
                        self.valves_changed_time, self._valve_change_unreported = sent, True
                        ahead = regulator_changed_at is not None and regulator_changed_at < sent
                        self._regulator_ahead = (regulator_changed_at, dataclasses.replace(
                            output, valves=valves_before or output.valves)) if ahead else None
                    else:
                        regulator_changed_at = sent
                    with self._lock:
                        if message == "ValveCommand":
                            # once the send has returned, not ``sent``: a safety check's settle
                            # may start late, never before the device can have acted
                            self.controller.valves_sent(self.clock())
                        else:
                            # when the device takes it: the regulator's model must not run ahead
                            self.controller.regulator_sent(sent)

    def _valve_signals(self, valves) -> dict:
        signals = {f"Channel{i}": int(v) for i, v in enumerate(valves)}
        signals["OpenLifetime"] = self.valve_lifetime_s
        return signals

    def _send(self, message: str, signals: dict) -> float:
        """Send; when the frame went out, on ``clock``: the stamp the bus gave it, where it gives
        one (softgrip_ipc: the kernel's, when it sent the frame, microseconds from when it
        reached the device), else the time just before the send. This thread may wait for the
        GIL or the CPU on either side of the socket call. Dated after the send returns, one valve
        change in a live identification came out 4 ms late; dated before it, evacuations started
        5 ms after their logged times: either way the chamber fit bent its critical ratios to
        match."""
        frame = self.codec.encode(message, signals)
        before = self.clock()
        try:
            self.bus.send(frame)
            self.frames_tx += 1
        except can.CanError:
            self.send_errors += 1
        if not frame.timestamp:
            return before
        return frame_sent_at(frame, self.clock)

    def last_sensor_age_s(self) -> float:
        with self._lock:
            return self.controller.last_sensor_age(self.clock())

    def stats(self, sensor_names, loop: PeriodicThread | None = None) -> LinkStats:
        """What this link (and the control ``loop`` that steps it) has counted, for the report."""
        with self._lock:
            fresh = self.controller.fresh_sensors(self.clock())
        receive_errors, last_receive_error = self.receive_errors  # one read: count and text agree
        return LinkStats(frames_rx=self.frames_rx, frames_tx=self.frames_tx,
                         frames_bad=self.frames_bad, rejected=dict(self.codec.rejected),
                         last_sensor_age_s=self.last_sensor_age_s(), silent_sensors=tuple(
                             n for n in sensor_names
                             if n not in fresh), listener_errors=self.listener_errors,
                         last_listener_error=self.last_listener_error,
                         status_errors=loop.errors if loop is not None else 0,
                         last_status_error=loop.last_error if loop is not None else "",
                         receive_errors=receive_errors, last_receive_error=last_receive_error,
                         valve_lapses=self.lapses)


class ControlLoop(PeriodicThread):
    """The pressure controller's one thread (see :func:`make_control_loop`): while it runs it
    takes the link's frames too, before each step and every ``rest_receive_period_s`` at rest;
    stopped, it hands them back to the link's reception thread."""

    def __init__(self, link: ControllerLink, rate_hz: float, on_output=None,
                 rest_rate_hz: float | None = None):
        super().__init__(link.step, rate_hz, "softgrip-control-loop", on_output=on_output,
                         rest_rate_hz=rest_rate_hz, resting=lambda output: not acting(output),
                         receive=link.receive_queued,
                         receive_period_s=link.rest_receive_period_s or None)
        self.link = link

    def start(self) -> None:
        if self.running:
            return
        self.link.reception_thread(False)
        try:
            super().start()
        except BaseException:
            self.link.reception_thread(True)
            raise

    def stop(self) -> None:
        running = self.running
        super().stop()
        if running:
            self.link.reception_thread(True)


def make_control_loop(link: ControllerLink, rate_hz: float, status_rate_hz: float, on_status=None,
                      rest_rate_hz: float | None = None) -> ControlLoop:
    """The pressure controller's loop: ``link.step`` at ``rate_hz`` while regulating, and at
    ``rest_rate_hz`` (default: the same) while venting, holding, inactive or faulted, when the
    valves stay as they are; a command, or a reading beyond the limits, runs a step at once.
    Its thread takes the bus's frames too (:class:`ControlLoop`). ``on_status`` at about
    ``status_rate_hz`` and at once on a change (see :class:`StatusOnChange`)."""
    on_output = None if on_status is None else StatusOnChange(on_status, 1.0 / status_rate_hz)
    loop = ControlLoop(link, rate_hz, on_output=on_output, rest_rate_hz=rest_rate_hz)
    link.wake = loop.wake
    return loop


class StatusOnChange:
    """Pass a ControlOutput on when ``period_s`` has passed since the last one passed, and at once
    when the valves, the mode, the regulator enable, the fault flags or (by more than
    ``regulator_band_pa``) the regulator command change: a flag that lasts less than a period
    (a refused command, cleared by the next one) must still reach controller/status."""

    def __init__(self, callback, period_s: float, regulator_band_pa: float = 1e3,
                 clock=time.monotonic):
        self.callback, self.period_s, self.clock = callback, period_s, clock
        self.regulator_band_pa = regulator_band_pa
        self._sent_at, self._last = -math.inf, None

    def __call__(self, output) -> None:
        last, now = self._last, self.clock()
        changed = (last is None or
                   (output.valves, output.mode, output.regulator_enabled, output.fault_flags)
                   != (last.valves, last.mode, last.regulator_enabled, last.fault_flags) or
                   abs(output.regulator_setpoint_gauge_pa - last.regulator_setpoint_gauge_pa)
                   > self.regulator_band_pa)
        if changed or now - self._sent_at >= self.period_s - 1e-4:
            self._sent_at, self._last = now, output
            self.callback(output)

"""Conformance of a device's firmware to the CAN protocol of ``config/softgrip.dbc``.

:class:`DeviceChecker` plays the controller on any python-can bus: it sends the controller's
heartbeat, RegulatorSetpoint and ValveCommand frames (with their alive counters and CRCs), records
every frame the device sends, and judges each requirement of the protocol as one :class:`Row`:

- each cyclic device frame at its rate (the DBC's ``GenMsgCycleTime``, or an override), within
  ``rate_tolerance``, measured from the median spacing of its frames; the DeviceHeartbeat on its
  own row, with its state RUNNING and its uptime counting;
- every device frame 8 bytes long, its CRC-8 right, its alive counter stepping by one (mod 16)
  between consecutive frames with a right CRC, its signals within their DBC ranges;
- the regulator's reported output following a RegulatorSetpoint;
- each valve channel answering a ValveCommand (SUPPLY fills, CLOSED holds, VENT empties, VACUUM
  draws), seen on the pressure sensors;
- an open channel closed when its OpenLifetime runs out without a new ValveCommand: the watchdog
  that keeps a stalled controller from pumping on;
- no fault bit set in RegulatorStatus or a sensor's SensorStatus.

It never asks for more than ``test_pressure_pa`` and vents (regulator disabled, every channel
VENT) when any reading passes ``pressure_limit_pa``, at the end, on a failure and on an
interruption. This module knows no ROS; ``softgrip_check_device`` is its command line.
"""
from __future__ import annotations

import dataclasses
import math
import statistics
import threading
import time

import can

from softgrip_ros.canbus.codec import (COUNTER_MODULO, COUNTER_SIGNAL, CRC_BYTE, CRC_SIGNAL,
                                       FrameCodec, frame_crc)

VALVE_CHANNELS = 4  # ValveCommand's Channel0..3
CLOSED, SUPPLY, VACUUM, VENT = 0, 1, 2, 3  # the DBC's VAL_ of ValveCommand ChannelN
DEVICE_RUNNING = 1  # the DBC's VAL_ of DeviceState
SENSOR_PREFIX = "PressureSensor"
FAULT_BIT_NAMES = ("supply low", "vacuum low", "output deviation", "over-temperature")


@dataclasses.dataclass
class Row:
    """One requirement: PASS or FAIL, what was measured, and why it failed."""

    check: str
    passed: bool
    measured: str
    reason: str = ""

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


# CheckConfig's ranges, which softgrip_check_device's options take too
CHECK_RANGES = {
    "listen_s": (0.5, 60.0), "rate_tolerance": (0.01, 0.5),
    "test_pressure_pa": (1000.0, 50000.0), "pressure_limit_pa": (2000.0, 100000.0),
    "lifetime_s": (0.001, 0.255), "response_timeout_s": (0.1, 10.0),
    "control_period_s": (0.002, 0.05)
}
MAX_RATE_HZ = 100e3  # a frame rate beyond any CAN bus's


@dataclasses.dataclass
class CheckConfig:
    """listen_s: how long the passive checks (rates, counters, CRC, ranges) listen.
    rates_hz: {message: expected Hz} overriding the DBC's cycle times.
    rate_tolerance: a rate within this fraction of the expected one passes.
    channels: the valve channels to exercise (each must be seen by the pressure sensors).
    test_pressure_pa: the regulator setpoint the active checks use (gauge).
    pressure_limit_pa: any reading beyond +-this vents and ends the check.
    lifetime_s: the OpenLifetime of the single ValveCommand of the watchdog check.
    response_timeout_s: how long the regulator and the chamber get to answer a command.
    control_period_s: the controller frames' period while commanding."""

    listen_s: float = 2.0
    rates_hz: dict = dataclasses.field(default_factory=dict)
    rate_tolerance: float = 0.10
    channels: tuple = (0,)
    test_pressure_pa: float = 8000.0
    pressure_limit_pa: float = 10000.0
    lifetime_s: float = 0.01
    response_timeout_s: float = 1.0
    control_period_s: float = 0.01

    def __post_init__(self):
        for name, (low, high) in CHECK_RANGES.items():
            value = getattr(self, name)
            if not (math.isfinite(value) and low <= value <= high):
                raise ValueError(f"{name} must lie in [{low:g}, {high:g}], got {value!r}")
        if self.test_pressure_pa >= 0.9 * self.pressure_limit_pa:
            raise ValueError(f"test_pressure_pa ({self.test_pressure_pa:g}) must stay below 90 % "
                             f"of pressure_limit_pa ({self.pressure_limit_pa:g})")
        for name, hz in self.rates_hz.items():
            if not (math.isfinite(hz) and 0.0 < hz <= MAX_RATE_HZ):
                raise ValueError(f"the rate of {name} must lie in (0, {MAX_RATE_HZ:g}] Hz, got "
                                 f"{hz!r}")
        if not self.channels or any(not 0 <= c < VALVE_CHANNELS for c in self.channels):
            raise ValueError(f"channels must be among 0..{VALVE_CHANNELS - 1}, got "
                             f"{self.channels!r}")


# a row without the readings it is judged on fails: a check that saw nothing passes nothing
NO_READING = "no chamber pressure reading arrived to judge it by"


def _only(channel: int, state: int) -> tuple:
    """Every valve channel's state: ``state`` on ``channel``, the others CLOSED."""
    return tuple(state if i == channel else CLOSED for i in range(VALVE_CHANNELS))


def _pressure_signal(message: str) -> str | None:
    """The pressure a device message carries: a sensor's reading, the regulator's output (None:
    no pressure)."""
    if message == "RegulatorStatus":
        return "ActualGaugePressure"
    return "GaugePressure" if message.startswith(SENSOR_PREFIX) else None


class CheckAborted(RuntimeError):
    """A reading passed the pressure limit: the device was vented."""


@dataclasses.dataclass
class _Received:
    arrival: float  # time.monotonic() when taken off the bus
    stamp: float  # the interface's timestamp (the arrival when it gives none)
    name: str
    dlc: int
    crc_ok: bool
    counter: int
    signals: dict | None  # None: undecodable


class DeviceChecker:
    """Check the device on ``bus`` against ``codec``'s DBC (see the module docstring).

    ``progress(text)`` is told what each step does. :meth:`run` returns the rows; the device is
    vented when it returns or raises."""

    def __init__(self, bus: can.BusABC, codec: FrameCodec | None = None,
                 config: CheckConfig | None = None, progress=lambda text: None):
        self.bus, self.codec = bus, codec or FrameCodec()
        self.config = config or CheckConfig()
        self.progress = progress
        messages = {m.name: m for m in self.codec.database.messages}
        self._device_messages = {
            name: m for name, m in messages.items() if "DEVICE" in (m.senders or [])
        }
        self._names_by_id = {self.codec.frame_ids[name]: name for name in self._device_messages}
        self._sensor_messages = sorted(n for n in self._device_messages
                                       if n.startswith(SENSOR_PREFIX))
        for name in self.config.rates_hz:
            if name not in self._device_messages:
                raise ValueError(f"rate of {name!r}: not a device message of the DBC; device "
                                 f"messages: {sorted(self._device_messages)}")
        self._lock = threading.Lock()
        self._frames: list[_Received] = []
        self._latest: dict = {}  # message name -> (arrival, signals) of its last CRC-valid frame
        self._command = (0.0, False, (VENT,) * VALVE_CHANNELS, True)  # setpoint, enable, valves,
        # valves sent
        self._aborted = ""
        self._stop = threading.Event()
        self._threads = []

    # ---- the run ------------------------------------------------------------------------------
    def run(self) -> list[Row]:
        self._start()
        rows = []
        try:
            self._command_safe()
            steps = [self._listen_rows, lambda: [self._regulator_row()]]
            steps += [lambda c=c: [self._valve_row(c)] for c in self.config.channels]
            steps.append(lambda: [self._lifetime_row()])
            for step in steps:
                try:
                    rows += step()
                except CheckAborted as aborted:
                    rows.append(Row("safety", False, "", str(aborted)))
                    break
            rows.append(self._fault_bits_row(self._frames_snapshot()))
        finally:
            self.close()
        return rows

    def _listen_rows(self) -> list[Row]:
        self.progress(f"listening to the device for {self.config.listen_s:.1f} s")
        started = len(self._frames_snapshot())
        self._wait(self.config.listen_s)
        return self.passive_rows(self._frames_snapshot()[started:])

    def close(self) -> None:
        """Vent, then stop sending and listening (idempotent)."""
        if not self._threads:
            return
        self._command_safe()
        time.sleep(5 * self.config.control_period_s)  # a few VENT frames go out
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=2.0)
        self._threads = []

    # ---- judged from what the device sent alone -------------------------------------------------
    def passive_rows(self, frames: list) -> list[Row]:
        """Rates, the heartbeat, DLCs, CRCs, counters and signal ranges of ``frames``."""
        rows = []
        by_name = {name: [f for f in frames if f.name == name] for name in self._device_messages}
        for name in sorted(by_name):
            if name == "DeviceHeartbeat":
                rows.append(self._heartbeat_row(by_name[name]))
            elif self._expected_hz(name):
                rows.append(self._rate_row(name, by_name[name]))
        nothing = "" if frames else "no device frame"
        short = [f for f in frames if f.dlc != 8]
        rows.append(Row("DLC 8 on every frame", bool(frames) and not short,
                        f"{len(frames) - len(short)} of {len(frames)}",
                        f"{short[0].name} with DLC {short[0].dlc}" if short else nothing))
        bad_crc = [f for f in frames if not f.crc_ok]
        rows.append(Row("CRC-8 (SAE J1850 over data ID and payload)", bool(frames) and
                        not bad_crc, f"{len(frames) - len(bad_crc)} of {len(frames)} right",
                        f"{len(bad_crc)} frames with a wrong CRC (first: {bad_crc[0].name})"
                        if bad_crc else nothing))
        rows.append(self._counter_row(by_name))
        rows.append(self._range_row(frames))
        return rows

    def _expected_hz(self, name: str) -> float:
        if name in self.config.rates_hz:
            return float(self.config.rates_hz[name])
        cycle_ms = self._device_messages[name].cycle_time
        return 1000.0 / cycle_ms if cycle_ms else 0.0

    @staticmethod
    def _spacings_s(frames: list) -> list:
        """The gaps between the frames' stamps, in time order (s)."""
        stamps = sorted(f.stamp for f in frames)
        return [b - a for a, b in zip(stamps, stamps[1:])]

    @classmethod
    def _measured_hz(cls, frames: list) -> float:
        """The frames' rate from their median cycle (their stamps' median spacing), 0.0 with fewer
        than 3. A median, not the count over the span: a host that stalls the thread reading (or
        a simulated device's sending) loses frames in a few long gaps, which say nothing of the
        cycle the firmware keeps; a wrong cycle moves every spacing, and so the median."""
        spacings = cls._spacings_s(frames)
        span = sum(spacings)
        if len(spacings) < 2 or span <= 0.0:
            return 0.0
        cycle = statistics.median(spacings)
        return 1.0 / cycle if cycle > 0.0 else len(spacings) / span

    @classmethod
    def _longest_gap_ms(cls, frames: list) -> float:
        return 1e3 * max(cls._spacings_s(frames), default=0.0)

    def _rate_row(self, name: str, frames: list) -> Row:
        expected, measured = self._expected_hz(name), self._measured_hz(frames)
        ok = abs(measured - expected) <= self.config.rate_tolerance * expected
        reason = "" if ok else (f"no {name} frame" if not frames else
                                f"{measured:.1f} Hz is off the expected {expected:g} Hz by more "
                                f"than {100 * self.config.rate_tolerance:.0f} %")
        return Row(f"{name} rate", ok, f"{measured:.1f} Hz (expected {expected:g}; longest gap "
                   f"{self._longest_gap_ms(frames):.0f} ms)", reason)

    def _heartbeat_row(self, frames: list) -> Row:
        expected, measured = self._expected_hz("DeviceHeartbeat"), self._measured_hz(frames)
        decoded = [f.signals for f in frames if f.crc_ok and f.signals is not None]
        states = {int(s["DeviceState"]) for s in decoded}
        uptimes = [s["Uptime"] for s in decoded]
        problems = []
        if not frames:
            problems.append("no DeviceHeartbeat frame")
        elif abs(measured - expected) > self.config.rate_tolerance * expected:
            problems.append(f"{measured:.1f} Hz where {expected:g} Hz is expected")
        if decoded and states != {DEVICE_RUNNING}:
            problems.append(f"DeviceState {sorted(states)}, not RUNNING ({DEVICE_RUNNING})")
        if len(uptimes) > 1 and any(b <= a for a, b in zip(uptimes, uptimes[1:])):
            problems.append("Uptime does not count up")
        return Row("DeviceHeartbeat", not problems, f"{measured:.1f} Hz (expected {expected:g})",
                   "; ".join(problems))

    def _counter_row(self, by_name: dict) -> Row:
        steps = good = 0
        first_bad = ""
        for name, frames in by_name.items():
            # consecutive frames with a right CRC (a frame with a wrong one breaks the pair: its
            # counter is not to be believed)
            for a, b in zip(frames, frames[1:]):
                if not (a.crc_ok and b.crc_ok):
                    continue
                steps += 1
                if (b.counter - a.counter) % COUNTER_MODULO == 1:
                    good += 1
                elif not first_bad:
                    first_bad = f"{name}: {a.counter} then {b.counter}"
        ok = steps > 0 and good == steps
        return Row("alive counters step by 1 (mod 16)", ok, f"{good} of {steps} steps",
                   "" if ok else (f"{steps - good} steps not +1 (first: {first_bad})"
                                  if steps else "no pair of frames to judge"))

    def _range_row(self, frames: list) -> Row:
        judged = [f for f in frames if f.crc_ok]
        outside = []
        for f in judged:
            if f.signals is None:
                outside.append(f"{f.name} undecodable")
                continue
            for signal, value in f.signals.items():
                low, high = self.codec.signal_range(f.name, signal)
                if (low is not None and value < low) or (high is not None and value > high):
                    outside.append(f"{f.name}.{signal} = {value:g} outside [{low:g}, {high:g}]")
        return Row("signals within their DBC ranges", not outside and bool(judged),
                   f"{len(judged)} frames", outside[0] if outside else
                   "" if judged else "no frame with a right CRC")

    def _fault_bits_row(self, frames: list) -> Row:
        judged = [f for f in frames if f.crc_ok and f.signals is not None and (
            f.name == "RegulatorStatus" or f.name.startswith(SENSOR_PREFIX))]
        if not judged:
            return Row("no fault bits set", False, "no status frame",
                       "no valid RegulatorStatus or sensor frame arrived to judge it by")
        seen = set()
        for f in judged:
            if not f.crc_ok or f.signals is None:
                continue
            if f.name == "RegulatorStatus":
                bits = int(f.signals["FaultBits"])
                seen |= {f"RegulatorStatus {FAULT_BIT_NAMES[b]}" if b < len(FAULT_BIT_NAMES)
                         else f"RegulatorStatus bit {b}" for b in range(8) if bits >> b & 1}
            elif f.name.startswith(SENSOR_PREFIX) and int(f.signals["SensorStatus"]):
                seen.add(f"{f.name} SensorStatus {int(f.signals['SensorStatus'])}")
        return Row("no fault bits set", not seen, "none" if not seen else ", ".join(sorted(seen)),
                   "" if not seen else f"the device reports {', '.join(sorted(seen))}")

    # ---- judged from the device's answers to commands ----------------------------------------
    def _regulator_row(self) -> Row:
        target = self.config.test_pressure_pa
        self.progress(f"regulator: setpoint {target / 1e3:.1f} kPa, valves closed")
        results, tolerance = [], max(1000.0, 0.1 * abs(target))
        for setpoint in (target, 0.0):
            self._set_command(setpoint, True, (CLOSED,) * VALVE_CHANNELS)
            reached = self._wait_for(
                lambda s=setpoint: abs(self._latest_value("RegulatorStatus") - s) <= tolerance,
                self.config.response_timeout_s, samples=3)
            results.append((setpoint, reached, self._latest_value("RegulatorStatus")))
        ok = all(reached is not None for _, reached, _ in results)
        measured = ", ".join(
            f"{setpoint / 1e3:g} kPa -> {value / 1e3:.1f} kPa" +
            (f" in {reached:.2f} s" if reached is not None else "")
            for setpoint, reached, value in results)
        reason = "" if ok else "; ".join(
            f"ActualGaugePressure {value / 1e3:.1f} kPa, not within {tolerance / 1e3:g} kPa of "
            "the setpoint "
            f"{setpoint / 1e3:g} kPa after {self.config.response_timeout_s:g} s"
            for setpoint, reached, value in results if reached is None)
        return Row("regulator follows RegulatorSetpoint", ok, measured, reason)

    def _valve_row(self, channel: int) -> Row:
        c = self.config
        self.progress(f"valve channel {channel}: SUPPLY, CLOSED, VENT, VACUUM")
        target = c.test_pressure_pa
        problems, measured = [], []

        start = self._chamber()
        self._set_command(target, True, _only(channel, SUPPLY))
        rose = self._wait_for(lambda: self._chamber() - start >= 0.5 * (target - start),
                              c.response_timeout_s)
        measured.append(f"SUPPLY {self._chamber() / 1e3:+.1f} kPa")
        if rose is None:
            problems.append(f"SUPPLY: the chamber went from {start / 1e3:+.1f} to "
                            f"{self._chamber() / 1e3:+.1f} kPa, toward a "
                            f"{target / 1e3:.1f} kPa regulator")
        self._set_command(target, True, _only(channel, CLOSED))
        self._wait(0.1)
        held = self._chamber_mean(0.2)
        drift = abs(self._chamber_mean(0.2) - held)
        measured.append(f"CLOSED {drift / 1e3:.2f} kPa drift")
        if not math.isfinite(drift):
            problems.append(f"CLOSED: {NO_READING}")
        elif drift > max(500.0, 0.1 * abs(held)):
            problems.append(f"CLOSED: the chamber moved {drift / 1e3:.1f} kPa in 0.2 s")
        self._set_command(0.0, True, _only(channel, VENT))
        vented = self._wait_for(lambda: abs(self._chamber()) <= 1000.0, c.response_timeout_s)
        measured.append(f"VENT {self._chamber() / 1e3:+.1f} kPa")
        if vented is None:
            problems.append(f"VENT: the chamber still at {self._chamber() / 1e3:+.1f} kPa")
        start = self._chamber()
        drew = self._vacuum_pulses(channel, start - 0.25 * target)
        measured.append(f"VACUUM {self._chamber() / 1e3:+.1f} kPa")
        if not drew:
            problems.append(f"VACUUM: the chamber went from {start / 1e3:+.1f} to "
                            f"{self._chamber() / 1e3:+.1f} kPa")
        self._set_command(0.0, True, _only(channel, VENT))
        self._wait_for(lambda: abs(self._chamber()) <= 1000.0, c.response_timeout_s)
        return Row(f"valve channel {channel} answers ValveCommand", not problems,
                   ", ".join(measured), "; ".join(problems))

    def _vacuum_pulses(self, channel: int, stop_pa: float) -> bool:
        """Draw the chamber toward ``stop_pa`` with VACUUM pulses, each one ValveCommand whose
        OpenLifetime ends it, followed by CLOSED; True once a reading is at or below ``stop_pa``.

        The vacuum source is not regulated. Opening the channel until a reading shows the drop
        lets the chamber go on falling for as long as the sensor period, the check's polling and
        the next frame take together (30 ms and more on a loaded host, ~10 kPa). A pulse's depth
        is set by its lifetime instead. A pulse that moved the chamber less than a quarter of what
        is left is followed by one twice as long (a slow valve), up to the DBC's 255 ms."""
        c = self.config
        closed, vacuum = (CLOSED,) * VALVE_CHANNELS, _only(channel, VACUUM)
        self._set_command(0.0, True, closed, send_valves=False)
        self._wait(2.0 * c.control_period_s)  # no periodic CLOSED in flight to cut a pulse short
        pulse_s, before = c.lifetime_s, self._chamber()
        deadline = time.monotonic() + c.response_timeout_s
        try:
            while time.monotonic() < deadline:
                self._send("ValveCommand", self._valve_signals(vacuum, pulse_s))
                # a device that ignores its lifetime is closed by the check as well
                self._wait(pulse_s)
                self._send("ValveCommand", self._valve_signals(closed, pulse_s))
                now = self._chamber_mean(0.05)
                if now <= stop_pa:
                    return True
                if before - now < 0.25 * (before - stop_pa):
                    pulse_s = min(2.0 * pulse_s, 0.255)
                before = now
            return False
        finally:
            self._set_command(0.0, True, closed)

    def _lifetime_row(self) -> Row:
        """One SUPPLY command with a short OpenLifetime, then none: the chamber must stop filling
        when the lifetime runs out, well short of the regulator's output."""
        c = self.config
        channel = c.channels[0]
        self.progress(f"OpenLifetime: one SUPPLY command with {1e3 * c.lifetime_s:.0f} ms, then "
                      "none")
        target = c.test_pressure_pa
        self._set_command(target, True, (CLOSED,) * VALVE_CHANNELS)
        self._wait_for(lambda: abs(self._latest_value("RegulatorStatus") - target) <= 1000.0,
                       c.response_timeout_s, samples=3)
        start = self._chamber_mean(0.05)
        valves = _only(channel, SUPPLY)
        self._set_command(target, True, valves, send_valves=False)
        # no periodic ValveCommand in flight any more, then the one
        self._wait(2.0 * c.control_period_s)
        self._send("ValveCommand", self._valve_signals(valves, c.lifetime_s))
        self._wait(c.lifetime_s + 0.05)
        early = self._chamber_mean(0.05)
        self._wait(0.2)
        late = self._chamber_mean(0.05)
        self._set_command(0.0, True, (VENT,) * VALVE_CHANNELS)
        self._wait_for(lambda: abs(self._chamber()) <= 1000.0, c.response_timeout_s)
        if not all(math.isfinite(v) for v in (start, early, late)):
            return Row("OpenLifetime closes an open channel", False, "no chamber reading",
                       NO_READING)
        gap = target - start
        still_rising = late - early > max(500.0, 0.1 * gap)
        at_regulator = late - start >= 0.8 * gap
        ok = not (still_rising or at_regulator)
        measured = (f"{(early - start) / 1e3:+.1f} kPa at {1e3 * c.lifetime_s + 50:.0f} ms, "
                    f"{(late - start) / 1e3:+.1f} kPa at {1e3 * c.lifetime_s + 300:.0f} ms "
                    f"(regulator {gap / 1e3:+.1f} kPa above the start)")
        reason = "" if ok else (
            f"channel {channel} stayed open past its OpenLifetime of {1e3 * c.lifetime_s:.0f} ms: "
            "the chamber " + ("went on filling" if still_rising else
                              "reached the regulator's output") +
            " with no ValveCommand (a chamber that fills within the lifetime cannot tell: "
            "lower --test-pressure-kpa)")
        return Row("OpenLifetime closes an open channel", ok, measured, reason)

    # ---- the controller's side ----------------------------------------------------------------
    def _start(self) -> None:
        self._stop.clear()
        self._threads = [
            threading.Thread(target=self._listen, name="check-device-rx", daemon=True),
            threading.Thread(target=self._transmit, name="check-device-tx", daemon=True)
        ]
        for thread in self._threads:
            thread.start()

    def _command_safe(self) -> None:
        with self._lock:
            self._command = (0.0, False, (VENT,) * VALVE_CHANNELS, True)

    def _set_command(self, setpoint_pa: float, enable: bool, valves: tuple,
                     send_valves: bool = True) -> None:
        if self._aborted:
            setpoint_pa, enable, valves, send_valves = 0.0, False, (VENT,) * VALVE_CHANNELS, True
        with self._lock:
            self._command = (setpoint_pa, enable, valves, send_valves)
        if self._aborted:
            raise CheckAborted(self._aborted)

    def _valve_signals(self, valves: tuple, lifetime_s: float) -> dict:
        signals = {f"Channel{i}": int(v) for i, v in enumerate(valves)}
        signals["OpenLifetime"] = lifetime_s
        return signals

    def _send(self, name: str, signals: dict) -> None:
        try:
            self.bus.send(self.codec.encode(name, signals))
        except can.CanError as error:
            self.progress(f"send {name} failed: {error}")

    def _transmit(self) -> None:
        period = self.config.control_period_s
        # every command may keep a channel open two periods, and no more: a stalled check leaves
        # the chamber held
        lifetime = min(max(2.0 * period, 0.01), 0.255)
        next_heartbeat = 0.0
        while not self._stop.is_set():
            with self._lock:
                setpoint, enable, valves, send_valves = self._command
            self._send("RegulatorSetpoint", {"SetpointGaugePressure": setpoint,
                                             "Enable": int(enable), "Source": 0})
            if send_valves:
                self._send("ValveCommand", self._valve_signals(valves, lifetime))
            now = time.monotonic()
            if now >= next_heartbeat:
                next_heartbeat = now + 0.1
                self._send("ControllerHeartbeat", {"ControllerState": 1})
            self._stop.wait(period)

    def _listen(self) -> None:
        limit = self.config.pressure_limit_pa
        while not self._stop.is_set():
            try:
                frame = self.bus.recv(timeout=0.05)
            except can.CanError as error:
                self.progress(f"receive failed: {error}")
                continue
            received = self.received(frame) if frame is not None else None
            if received is None:
                continue
            name, signals = received.name, received.signals
            usable = received.crc_ok and signals is not None
            with self._lock:
                self._frames.append(received)
                if usable:
                    self._latest[name] = (received.arrival, signals)
            # a chamber reading beyond the limit, or a regulator output beyond it that a SUPPLY
            # channel would pass on
            signal = _pressure_signal(name)
            if (usable and signal and abs(signals[signal]) > limit and not self._aborted):
                self._aborted = (f"{name} {signal} {signals[signal] / 1e3:+.1f} kPa, beyond the "
                                 f"check's limit of +-{limit / 1e3:g} kPa: vented")
                self._command_safe()

    def received(self, frame: can.Message) -> _Received | None:
        """What a device frame carried, judged raw (no E2E state: a checker sees every frame);
        None for a frame that is not the device's."""
        name = self._names_by_id.get(frame.arbitration_id)
        if name is None or frame.is_error_frame or frame.is_remote_frame:
            return None
        data = bytes(frame.data)
        crc_ok = len(data) == 8 and data[CRC_BYTE] == frame_crc(frame.arbitration_id, data)
        try:
            signals = self._device_messages[name].decode(data, decode_choices=False, scaling=True)
            counter = int(signals.pop(COUNTER_SIGNAL))
            signals.pop(CRC_SIGNAL)
        except Exception:  # cantools raises several types for a malformed payload
            signals, counter = None, -1
        return _Received(time.monotonic(), frame.timestamp or time.time(), name, frame.dlc,
                         crc_ok, counter, signals)

    # ---- what the device says ------------------------------------------------------------------
    def _frames_snapshot(self) -> list:
        with self._lock:
            return list(self._frames)

    def _latest_value(self, name: str) -> float:
        signal = _pressure_signal(name)
        with self._lock:
            latest = self._latest.get(name)
        return float(latest[1][signal]) if latest else math.nan

    def _chamber(self) -> float:
        """The mean of the sensors' latest readings (NaN: none yet)."""
        values = [self._latest_value(n) for n in self._sensor_messages]
        values = [v for v in values if math.isfinite(v)]
        return statistics.fmean(values) if values else math.nan

    def _chamber_mean(self, seconds: float) -> float:
        """The mean of every sensor reading over the next ``seconds``."""
        since = time.monotonic()
        self._wait(seconds)
        with self._lock:
            values = [f.signals["GaugePressure"] for f in self._frames
                      if f.arrival >= since and f.crc_ok and f.signals is not None and
                      f.name.startswith(SENSOR_PREFIX)]
        return statistics.fmean(values) if values else self._chamber()

    def _wait(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            if self._aborted:
                raise CheckAborted(self._aborted)
            time.sleep(min(0.01, max(deadline - time.monotonic(), 0.0)))

    def _wait_for(self, condition, timeout_s: float, samples: int = 1) -> float | None:
        """Seconds until ``condition`` held ``samples`` polls in a row (None: not within
        ``timeout_s``)."""
        start = time.monotonic()
        run = 0
        while time.monotonic() - start < timeout_s:
            run = run + 1 if condition() else 0
            if run >= samples:
                return time.monotonic() - start
            self._wait(0.01)
        return None


def format_table(rows: list) -> str:
    """The rows as a Markdown table."""
    lines = ["| check | result | measured | reason |", "|---|---|---|---|"]
    for row in rows:
        lines.append(f"| {row.check} | {'PASS' if row.passed else 'FAIL'} | {row.measured} | "
                     f"{row.reason} |")
    return "\n".join(lines)

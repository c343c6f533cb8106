"""A simulated valve, regulator and sensor device on any python-can bus.

It obeys RegulatorSetpoint and ValveCommand frames, runs the pneumatic plant in real time,
and sends PressureSensorN, RegulatorStatus and DeviceHeartbeat frames at their rates,
with sensor noise, quantisation and bias. Faults can be injected at any time
(:meth:`SimulatedDevice.set_fault`), which the ``sim_device`` node maps to ROS parameters.

Each sensor samples the plant on its own period in the plant's time (see BACKFILL_S), and every
frame carries the instant it describes as its timestamp. On a bus that keeps a sender's stamps
(``preserve_timestamps``: python-can's virtual bus, softgrip_ipc; the ``sim_device`` node opens
its bus so) a receiver sees when a reading was taken, as a real device's frames arrive within
microseconds of their sampling, however late this host runs the thread that sends them.

Like a real device it has a watchdog: without a valid ValveCommand for
``command_watchdog_s`` it closes its valves and drives the regulator to 0. Before that, a
channel in SUPPLY or VACUUM closes when the OpenLifetime of the last ValveCommand runs out
(within a plant step: the step is split at that instant). A RegulatorSetpoint with Enable = 0
cuts both sources (see :mod:`softgrip_ros.model.pneumatics`): the second path to safety, which
holds even when a valve is stuck open.

The plant runs on real elapsed time: each tick integrates exactly the time since the last one
(a tick late by a few ms integrates those; the quick catch-up ticks after it integrate
almost nothing), so that the simulated chamber keeps real time, as a real device's does while
the controller's host stalls (up to MAX_STALL_S: a plant that dropped the time of a stall lagged
the controller's model of it, and the regulator check, the response check and the estimator
took the lag for a fault on a loaded host). The tick reads the frames
that have arrived itself, and splits its step at each one's arrival: a command takes effect
when it reached the device, however late the thread ran. (A separate reception thread, held up
for tens of ms by the GIL on a loaded host, once let the plant integrate past a ValveCommand
CLOSED with the valve still open: the chamber rose kPa "with the valve closed".)

:meth:`SimulatedDevice.true_extremes` gives the lowest and highest true chamber pressure since
the last :meth:`SimulatedDevice.reset_true_extremes`, over every plant step: what a fault test
judges, rather than what any sensor said.

With a physics world (:class:`~softgrip_ros.model.world.world.GripperWorld`), the plant and the
world step together in the plant's time: after each span of the plant the world is stepped to it
(never more than half a world step ahead or behind) with channel 0's pressure, which drives both
fingers, and channel 0's air volume then follows the fingers' bending in the world at a fixed mass
of air (:meth:`~softgrip_ros.model.pneumatics.PneumaticPlant.with_volume_offset`): a finger held
back by the object holds less air than a free one at the same pressure.
"""
from __future__ import annotations

import collections
import dataclasses
import logging
import math
import random
import threading
import time

import can
import numpy as np

from softgrip_ros.canbus.codec import CRC_BYTE, FrameCodec, frame_sent_at
from softgrip_ros.model.pneumatics import (P_ATM_PA, SOURCE_VALVES, PlantInputs,
                                           PneumaticParameters, PneumaticPlant, Valve)
from softgrip_ros.realtime import PeriodicThread, clock_offset_s

LOG = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class SensorSpec:
    """One simulated chamber pressure sensor."""

    name: str
    message: str
    rate_hz: float
    noise_std_pa: float
    quantisation_pa: float = 10.0
    bias_pa: float = 0.0
    channel: int = 0


DEFAULT_SENSORS = (
    SensorSpec("chamber_a", "PressureSensor1", rate_hz=500.0, noise_std_pa=300.0,
               quantisation_pa=10.0),
    SensorSpec("chamber_b", "PressureSensor2", rate_hz=200.0, noise_std_pa=150.0,
               quantisation_pa=5.0),
)


@dataclasses.dataclass(frozen=True)
class SimDeviceConfig:
    plant: PneumaticParameters = PneumaticParameters()
    sensors: tuple = DEFAULT_SENSORS
    plant_rate_hz: float = 1000.0
    regulator_status_hz: float = 100.0
    heartbeat_hz: float = 10.0
    command_watchdog_s: float = 0.5
    seed: int | None = None

    def __post_init__(self):
        if not 50.0 <= self.plant_rate_hz <= 5000.0:
            raise ValueError(f"plant_rate_hz must lie in [50, 5000], got {self.plant_rate_hz}")
        for sensor in self.sensors:
            if not 0.0 < sensor.rate_hz <= self.plant_rate_hz:
                raise ValueError(f"sensor {sensor.name}: rate_hz must lie in (0, plant_rate_hz]")
            if sensor.noise_std_pa < 0.0 or sensor.quantisation_pa < 0.0:
                raise ValueError(f"sensor {sensor.name}: noise and quantisation must be >= 0")
            if not 0 <= sensor.channel < self.plant.channels:
                raise ValueError(f"sensor {sensor.name}: channel {sensor.channel} does not exist")


# What a stuck sensor reads (fault sensor_stuck_at): "present" freezes its last reading; "low"
# and "high" are fixed readings inside the pressure limits, so that only a plausibility check,
# not the limits, can catch them.
STUCK_READINGS_PA = {"low": -40e3, "high": 40e3}
# a replay burst: this many old frames of a sensor, in their old order
REPLAY_BURST_FRAMES = 3
# ... sent this many frames ago (their counters jump from the live ones)
REPLAY_AGE_FRAMES = 8

FAULTS = {
    "sensor_dropout": "",  # a sensor name, or "all": those sensors fall silent
    "sensor_stuck": "",  # a sensor name, or "all": those sensors read sensor_stuck_at
    # "present" (the last reading, frozen), "low" or "high" (STUCK_READINGS_PA)
    "sensor_stuck_at": "present",
    "sensor_bias_pa": 0.0,  # added to every sensor reading
    "sensor_noise_scale": 1.0,  # multiplies every sensor's noise
    "regulator_overshoot_pa": 0.0,  # the regulator settles this far above its setpoint
    "valve_stuck": False,  # the valves ignore commands and keep their state
    "valve_stuck_open": False,  # the valves ignore commands and stay open to SUPPLY
    "bus_silent": False,  # the device sends nothing at all
    "corrupt_rate": 0.0,  # fraction of sent frames with a bad CRC or a repeated counter
    # bursts per second of replayed old frames (see SimulatedDevice.replay_burst)
    "replay_rate_hz": 0.0,
    # firmware defects, for the conformance checker (softgrip_check_device):
    "crc_corrupt": 0.0,  # fraction of sent frames whose CRC byte is wrong (nothing else is)
    "counter_stuck": False,  # every sent frame carries alive counter 0
    "heartbeat_off": False,  # no DeviceHeartbeat
    "ignore_valve_lifetime": False,  # an open channel stays open past its OpenLifetime
    "sensor_rate_hz": 0.0,  # every sensor sends at this rate (0: each at its own)
}
FAULT_CHOICES = {"sensor_stuck_at": ("present", *STUCK_READINGS_PA)}
FAULT_RANGES = {
    "corrupt_rate": (0.0, 1.0), "sensor_noise_scale": (0.0, 100.0), "replay_rate_hz": (0.0, 100.0),
    "crc_corrupt": (0.0, 1.0), "sensor_rate_hz": (0.0, 1000.0)
}


# a status frame sent later than this after the plant's time: catch up first (it reports the
# regulator as the plant has it when it goes out)
SEND_LAG_S = 0.0002
# a device keeps real time through a stall of its host thread up to this long (beyond it, a
# suspended process say, the plant resumes from where it stopped) ...
MAX_STALL_S = 1.0
# ... in spans no longer than this, each sub-stepped by PneumaticPlant.advance, a stall's catch-up
# too: one backward-Euler step per span strays from the law, so the truth would move with the
# host's load (and an identification or the grasp sensing would fit that)
MAX_PLANT_STEP_S = 0.005
# a sensor samples on its own period in the plant's time, however the thread that simulates it is
# held up, and its frame carries the sampling instant, as a device with its own processor does:
# read when its tick came and stamped when it went out, a reading held up between the two by this
# host (a GIL wait, a stalled virtual CPU: up to 35 ms in a fault-free grasp on a 2-core host with
# 14-24 % steal) was older than its stamp by that, and the response check and the estimator took
# a chamber closed 36 ms earlier for one still moving (a false RESPONSE fault, NIS 4-10). A
# stall's catch-up sends no readings older than this (a longer stall looks like the silence it
# is; the controller drops readings that old anyway)
BACKFILL_S = 0.1


class SimulatedDevice:
    """The device on ``bus``. Call :meth:`start`, then :meth:`stop` (it does not close the bus)."""

    def __init__(self, bus: can.BusABC, config: SimDeviceConfig | None = None,
                 codec: FrameCodec | None = None, clock=time.monotonic, wall_clock=time.time,
                 world=None):
        self.bus = bus
        self.world = world
        # frames carry wall-clock stamps (python-can's); the plant runs on ``clock``
        self.clock, self.wall_clock = clock, wall_clock
        self.config = config or SimDeviceConfig()
        self.codec = codec or FrameCodec()
        self.plant = PneumaticPlant(self.config.plant)
        self._state = self.plant.initial_state()
        self._inputs = PlantInputs(regulator_enabled=False,
                                   valves=(Valve.CLOSED,) * self.config.plant.channels)
        self._faults = dict(FAULTS)
        self._lock = threading.Lock()
        self._rng = np.random.default_rng(self.config.seed)
        self._corrupt_rng = random.Random(self.config.seed)
        self._stuck_values: dict = {}
        self._last_valve_command = -math.inf
        self._valves_open_until = math.inf
        self._sent_history = {
            s.message: collections.deque(maxlen=REPLAY_AGE_FRAMES + REPLAY_BURST_FRAMES)
            for s in self.config.sensors
        }
        self._received_valve_frames = collections.deque(maxlen=REPLAY_AGE_FRAMES + 1)
        self._next_replay = math.inf
        self._true_low = self._true_high = 0.0
        self._loop = PeriodicThread(self._tick, self.config.plant_rate_hz, "softgrip-sim-device")
        self._started_at = 0.0
        self.frames_sent = 0
        self.frames_received = 0

    # ---- lifecycle ----------------------------------------------------------------------------
    def start(self) -> None:
        if self._loop.running:
            return
        self._started_at = self._last_tick = self.clock()
        self._last_valve_command = self._started_at
        self._next_sensor = {s.name: 0.0 for s in self.config.sensors}
        self._next_status = self._next_heartbeat = 0.0
        self._loop.start()

    def stop(self) -> None:
        self._loop.stop()

    # ---- faults and observation -----------------------------------------------------------------
    def set_fault(self, name: str, value) -> None:
        """Inject (or clear) a fault; raises ValueError naming the problem."""
        if name not in FAULTS:
            raise ValueError(f"unknown fault {name!r}; known: {sorted(FAULTS)}")
        kind = type(FAULTS[name])
        if kind is float:
            value = float(value)
            if not math.isfinite(value):
                raise ValueError(f"fault {name} must be finite")
            low, high = FAULT_RANGES.get(name, (-math.inf, math.inf))
            if not low <= value <= high:
                raise ValueError(f"fault {name} must lie in [{low:g}, {high:g}], got {value:g}")
        elif kind is bool:
            value = bool(value)
        elif name in FAULT_CHOICES:
            value = str(value)
            if value not in FAULT_CHOICES[name]:
                raise ValueError(
                    f"fault {name} must be one of {list(FAULT_CHOICES[name])}, got {value!r}")
        else:
            value = str(value)
            known = {s.name for s in self.config.sensors} | {"all", ""}
            if value not in known:
                raise ValueError(
                    f"fault {name}: unknown sensor {value!r}; known: {sorted(known - {''})}")
        with self._lock:
            self._faults[name] = value
            if name in ("sensor_stuck", "sensor_stuck_at"):
                self._stuck_values.clear()
            if name == "replay_rate_hz":
                self._next_replay = self.clock() if value > 0.0 else math.inf

    @property
    def faults(self) -> dict:
        with self._lock:
            return dict(self._faults)

    def chamber_gauge_pa(self, channel: int = 0) -> float:
        with self._lock:
            return float(self._state.chamber_pa[channel] - P_ATM_PA)

    def valves(self) -> tuple:
        with self._lock:
            return tuple(self._inputs.valves)

    def regulator_enabled(self) -> bool:
        with self._lock:
            return bool(self._inputs.regulator_enabled)

    def true_extremes(self) -> tuple[float, float]:
        """(lowest, highest) true gauge pressure of any channel since :meth:`reset_true_extremes`,
        Pa."""
        with self._lock:
            return self._true_low, self._true_high

    def reset_true_extremes(self) -> None:
        with self._lock:
            gauge = self._state.chamber_pa - P_ATM_PA
            self._true_low, self._true_high = float(gauge.min()), float(gauge.max())

    # ---- reception (in the tick) ----------------------------------------------------------------
    def _receive(self, now: float) -> None:
        """Every frame that has arrived, in order: the plant advanced to each one's arrival, then
        the frame taken (see the module docstring)."""
        while True:
            try:
                frame = self.bus.recv(timeout=0.0)
            except can.CanError as error:
                LOG.warning("sim device: CAN receive failed: %s", error)
                return
            if frame is None:
                return
            # when it was sent, on this clock, from its own stamp (softgrip_ipc: the kernel's, as
            # it reached this bus; the tick's start minus an age read later put a frame taken
            # after a GIL wait, or after the plant was advanced for the frames before it, that
            # long before it was sent)
            sent = frame_sent_at(frame, self.clock, self.wall_clock)
            arrived = min(max(sent, self._last_tick), now)
            self._advance_to(arrived)
            self._on_frame(frame)

    def _on_frame(self, frame: can.Message) -> None:
        if self.codec.frame_ids.get("ValveCommand") == frame.arbitration_id:
            with self._lock:
                self._received_valve_frames.append(frame)
        decoded = self.codec.decode(frame)
        if decoded is None:
            return
        self.frames_received += 1
        with self._lock:
            if decoded.name == "RegulatorSetpoint":
                self._inputs = dataclasses.replace(
                    self._inputs,
                    regulator_setpoint_gauge_pa=decoded.signals["SetpointGaugePressure"],
                    regulator_enabled=bool(decoded.signals["Enable"]))
            elif decoded.name == "ValveCommand":
                # from its arrival on the bus
                self._last_valve_command = frame_sent_at(frame, self.clock, self.wall_clock)
                if not (self._faults["valve_stuck"] or self._faults["valve_stuck_open"]):
                    self._valves_open_until = (self._last_valve_command +
                                               decoded.signals["OpenLifetime"])
                    channels = self.config.plant.channels
                    self._inputs = dataclasses.replace(
                        self._inputs, valves=tuple(
                            Valve(int(decoded.signals[f"Channel{i}"])) for i in range(channels)))

    # ---- the real-time loop
    # ----------------------------------------------------------------------
    @property
    def ticks(self) -> int:
        return self._loop.ticks

    def _tick(self) -> None:
        """One plant step of exactly the real time elapsed since the last tick (bounded after a
        stall), then the frames due."""
        now = self.clock()
        sim_time = now - self._started_at
        try:
            self._bring_to(now)
            if now >= self._next_replay:
                with self._lock:
                    rate_hz = self._faults["replay_rate_hz"]
                self._next_replay = now + 1.0 / rate_hz if rate_hz > 0.0 else math.inf
                self.replay_burst()
            with self._lock:
                heartbeat_off = self._faults["heartbeat_off"]
            if sim_time >= self._next_status:
                self._next_status += 1.0 / self.config.regulator_status_hz
                self._send_status()
            if sim_time >= self._next_heartbeat:
                period = 1.0 / self.config.heartbeat_hz
                self._next_heartbeat += period
                if self._next_heartbeat <= sim_time:
                    # after a stall one heartbeat, not the ones it missed: those would go out in
                    # one tick with one Uptime, which check_device rightly calls a clock that does
                    # not count up (seen once in CI, a loaded host, with no defect injected)
                    self._next_heartbeat = sim_time + period
                if not heartbeat_off:
                    self._send("DeviceHeartbeat",
                               {"DeviceState": 1, "Uptime": min(sim_time, 167772.15)}, now)
        except can.CanError as error:  # a closed or failing bus: keep simulating, report it
            LOG.warning("sim device: CAN send failed: %s", error)

    def _bring_to(self, now: float) -> None:
        """The plant to ``now`` (from at most MAX_STALL_S back), split at each frame's arrival."""
        self._last_tick = max(self._last_tick, now - MAX_STALL_S)
        self._receive(now)
        self._advance_to(now)

    def _advance_to(self, when: float) -> None:
        """The plant from the last tick's time to ``when``, in spans of at most MAX_PLANT_STEP_S,
        each sub-stepped (:meth:`PneumaticPlant.advance`); after each span, the sensors due by
        its end read (see :meth:`_sample_due`)."""
        while when > self._last_tick:
            step_end = min(when, self._last_tick + MAX_PLANT_STEP_S)
            self._advance(step_end - self._last_tick, step_end)
            self._last_tick = step_end
            self._sample_due(step_end, oldest=when - BACKFILL_S)

    def _sample_due(self, now: float, oldest: float) -> None:
        """Each sensor due by ``now`` (the plant's time) read and sent, stamped ``now``, once (the
        samples due earlier within the span are not taken: a tick's span is one period of the
        plant, a stall's catch-up spans MAX_PLANT_STEP_S); not sent when ``now`` is before
        ``oldest``. Splitting the spans at each sample instead cost the device 44 % more CPU, and
        its thread then fell further behind on a loaded host."""
        for sensor in self.config.sensors:
            due = self._started_at + self._next_sensor[sensor.name]
            if due > now + 1e-9:
                continue
            with self._lock:
                period = 1.0 / (self._faults["sensor_rate_hz"] or sensor.rate_hz)
            self._next_sensor[sensor.name] += period * (1 + math.floor((now - due) / period))
            if now >= oldest:
                self._send_sensor(sensor, now)

    def _advance(self, dt: float, now: float) -> None:
        with self._lock:
            inputs = self._inputs
            if now - self._last_valve_command > self.config.command_watchdog_s:
                inputs = PlantInputs(regulator_enabled=False,
                                     valves=(Valve.CLOSED,) * self.config.plant.channels)
            stuck = self._faults["valve_stuck"] or self._faults["valve_stuck_open"]
            if stuck:  # a stuck valve obeys neither the commands nor the watchdog
                stuck_valves = ((Valve.SUPPLY,) * self.config.plant.channels
                                if self._faults["valve_stuck_open"] else self._inputs.valves)
                inputs = dataclasses.replace(inputs, valves=stuck_valves)
            inputs = dataclasses.replace(
                inputs, regulator_overshoot_pa=self._faults["regulator_overshoot_pa"])
            open_for = self._valves_open_until - (now - dt)
            expires = open_for < dt and not stuck and not self._faults["ignore_valve_lifetime"]
            if expires and any(v in SOURCE_VALVES for v in inputs.valves):
                if open_for > 0.0:
                    self._state = self.plant.advance(self._state, inputs, open_for)
                    dt -= open_for
                valves = tuple(Valve.CLOSED if v in SOURCE_VALVES else v for v in inputs.valves)
                inputs = dataclasses.replace(inputs, valves=valves)
                self._inputs = dataclasses.replace(self._inputs, valves=valves)
            self._state = self.plant.advance(self._state, inputs, dt)
            if stuck:
                # what the valves really do
                self._inputs = dataclasses.replace(self._inputs, valves=inputs.valves)
            if self.world is not None:
                self._step_world(now)
            gauge = self._state.chamber_pa - P_ATM_PA
            self._true_low, self._true_high = min(self._true_low, float(gauge.min())), max(
                self._true_high, float(gauge.max()))

    def _step_world(self, now: float) -> None:
        """The world to the plant's time ``now`` with channel 0's pressure, then the plant's volume
        to the world's bending (under the lock)."""
        world = self.world
        world.set_pressure(float(self._state.chamber_pa[0] - P_ATM_PA))
        if world.advance_to(now - self._started_at - world.time_offset_s):
            offsets = np.zeros(self.config.plant.channels)
            offsets[0] = world.volume_offset_m3()
            if self._state.volume_offset_m3 is None or not np.array_equal(
                    offsets, self._state.volume_offset_m3):
                self._state = self.plant.with_volume_offset(self._state, offsets)

    # ---- the physics world ------------------------------------------------------------------
    def world_truth(self):
        """The world's :class:`~softgrip_ros.model.world.world.WorldTruth` now; None without a
        world."""
        if self.world is None:
            return None
        with self._lock:
            return self.world.truth()

    def play_arm_move(self, move: str) -> None:
        """Queue the scene's arm move ``move``; ValueError when there is no world or no such
        move."""
        if self.world is None:
            raise ValueError("no physics world: the device was started without a scene")
        with self._lock:
            self.world.play(move)

    def replace_world(self, world) -> None:
        """Simulate ``world`` from now on (its clock starts at the device's present time); the
        chamber's air keeps its mass, its volume offset back to the new world's."""
        with self._lock:
            now = self._last_tick - self._started_at
            world.time_s = world.steps = 0
            world.time_offset_s = now
            self.world = world
            offsets = np.zeros(self.config.plant.channels)
            self._state = self.plant.with_volume_offset(self._state, offsets)

    def world_load(self) -> tuple[float, float]:
        """(CPU seconds spent stepping the world, world seconds simulated); zeros without one."""
        if self.world is None:
            return 0.0, 0.0
        with self._lock:
            return self.world.cpu_s, self.world.time_s

    def _catch_up(self) -> None:
        """The plant brought to the present (frames that arrived meanwhile taken at their
        arrival, the samples due meanwhile taken), when this thread was held up since its tick."""
        now = self.clock()
        if now - self._last_tick > SEND_LAG_S:
            self._bring_to(now)

    def _send_sensor(self, sensor: SensorSpec, sampled_at: float) -> None:
        """The reading of the plant at ``sampled_at`` (its time now), its frame stamped then."""
        with self._lock:
            faults = self._faults
            if faults["sensor_dropout"] in (sensor.name, "all"):
                return
            true_gauge = self._state.chamber_pa[sensor.channel] - P_ATM_PA
            stuck = faults["sensor_stuck"] in (sensor.name, "all")
            stuck_at = STUCK_READINGS_PA.get(faults["sensor_stuck_at"])
            bias, noise_scale = faults["sensor_bias_pa"], faults["sensor_noise_scale"]
        if stuck and stuck_at is not None:
            reading = stuck_at
        elif stuck and sensor.name in self._stuck_values:
            reading = self._stuck_values[sensor.name]
        else:
            reading = (true_gauge + sensor.bias_pa + bias +
                       noise_scale * sensor.noise_std_pa * self._rng.standard_normal())
            if sensor.quantisation_pa > 0.0:
                reading = round(reading / sensor.quantisation_pa) * sensor.quantisation_pa
            low, high = self.codec.signal_range(sensor.message, "GaugePressure")
            reading = min(max(reading, low), high)
            self._stuck_values[sensor.name] = reading
        frame = self._send(sensor.message, {"GaugePressure": reading, "SensorStatus": 0},
                           sampled_at)
        if frame is not None:
            with self._lock:
                self._sent_history[sensor.message].append(frame)

    def replay_burst(self) -> None:
        """Replay old frames, as a faulty gateway or an adversary on the bus would: the first
        sensor's REPLAY_BURST_FRAMES frames of REPLAY_AGE_FRAMES ago, in their old order (in
        sequence among themselves, their counters jump from the live stream), and the
        ValveCommand received REPLAY_AGE_FRAMES ago, into this device's own receiver. The E2E
        checks must keep both from being acted on."""
        message = self.config.sensors[0].message
        with self._lock:
            history = list(self._sent_history[message])
            valve_frames = list(self._received_valve_frames)
        if len(history) == REPLAY_AGE_FRAMES + REPLAY_BURST_FRAMES:
            for frame in history[:REPLAY_BURST_FRAMES]:
                self._send_frame(frame)
        if len(valve_frames) > REPLAY_AGE_FRAMES:
            old = valve_frames[0]
            self._on_frame(
                can.Message(arbitration_id=old.arbitration_id, data=old.data, is_extended_id=False,
                            timestamp=self.wall_clock()))

    def _send_status(self) -> None:
        self._catch_up()
        with self._lock:
            actual = self._state.regulator_gauge_pa
        low, high = self.codec.signal_range("RegulatorStatus", "ActualGaugePressure")
        self._send("RegulatorStatus",
                   {"ActualGaugePressure": min(max(actual, low), high), "FaultBits": 0},
                   self._last_tick)

    def _wall_time(self, when: float) -> float:
        """``when`` on this device's clock as a python-can timestamp (wall-clock seconds), through
        the clocks' offset read at one instant (see :func:`frame_sent_at`)."""
        return when + clock_offset_s(self.clock, self.wall_clock)

    def _send(self, message: str, signals: dict, when: float) -> can.Message | None:
        """Encode and send, stamped with ``when`` (this clock: the instant the frame describes);
        the frame as encoded (before any corruption), None when the bus is silent."""
        with self._lock:
            silent, corrupt_rate = self._faults["bus_silent"], self._faults["corrupt_rate"]
            crc_corrupt, counter_stuck = self._faults["crc_corrupt"], self._faults["counter_stuck"]
        if silent:
            return None
        frame = sent = self.codec.encode(message, signals, counter=0 if counter_stuck else None)
        frame.timestamp = self._wall_time(when)
        if crc_corrupt > 0.0 and self._corrupt_rng.random() < crc_corrupt:
            data = bytearray(frame.data)
            data[CRC_BYTE] ^= 0xFF
            sent = can.Message(arbitration_id=frame.arbitration_id, data=bytes(data),
                               is_extended_id=False, timestamp=frame.timestamp)
        if corrupt_rate > 0.0 and self._corrupt_rng.random() < corrupt_rate:
            data = bytearray(frame.data)
            if self._corrupt_rng.random() < 0.5:
                # bad CRC
                data[self._corrupt_rng.randrange(7)] ^= 1 << self._corrupt_rng.randrange(8)
                sent = can.Message(arbitration_id=frame.arbitration_id, data=bytes(data),
                                   is_extended_id=False, timestamp=frame.timestamp)
            else:
                # repeated counter
                self.bus.send(frame)
        self.bus.send(sent)
        self.frames_sent += 1
        return frame

    def _send_frame(self, frame: can.Message) -> None:
        with self._lock:
            silent = self._faults["bus_silent"]
        if not silent:
            self.bus.send(
                can.Message(arbitration_id=frame.arbitration_id, data=frame.data,
                            is_extended_id=False, timestamp=self.wall_clock()))
            self.frames_sent += 1

"""The simulated device on its own: its clock, its faults and its safe state, ticked by hand."""
import uuid

import can
import numpy as np
import pytest

from softgrip_ros.canbus.codec import FrameCodec
from softgrip_ros.canbus.sim_device import (MAX_PLANT_STEP_S, REPLAY_AGE_FRAMES,
                                            REPLAY_BURST_FRAMES, STUCK_READINGS_PA,
                                            SimDeviceConfig, SimulatedDevice)
from softgrip_ros.model.pneumatics import P_ATM_PA, PlantInputs, PneumaticPlant, Valve
from tests.helpers.clocks import SwitchingClocks


class FakeClock:

    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


@pytest.fixture
def bench():
    """A device on a private virtual channel with a hand-driven clock, a listener bus and a codec
    for both directions; the device is never started (its ticks are called here)."""
    channel = f"simdev-{uuid.uuid4().hex[:8]}"
    # the device's bus keeps its frames' stamps, as the sim_device node opens it
    device_bus = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    peer_bus = can.Bus(interface="virtual", channel=channel)
    clock = FakeClock()
    # a receiver that trusts at once: these tests hand it frames one by one (E2E:
    # test_canbus_codec)
    device = SimulatedDevice(device_bus, SimDeviceConfig(seed=4), codec=FrameCodec(sync_frames=0),
                             clock=clock)
    device._started_at = device._last_tick = clock.now
    device._last_valve_command = clock.now
    device._next_sensor = {s.name: 0.0 for s in device.config.sensors}
    device._next_status = device._next_heartbeat = 0.0
    try:
        yield device, clock, peer_bus, FrameCodec(max_counter_delta=15, sync_frames=0)
    finally:
        peer_bus.shutdown()
        device_bus.shutdown()


def command(device, codec, valve, setpoint_pa=0.0, enable=True, lifetime_s=0.2):
    """Hand the device a RegulatorSetpoint and a ValveCommand, as if received."""
    device._on_frame(
        codec.encode("RegulatorSetpoint",
                     {"SetpointGaugePressure": setpoint_pa, "Enable": int(enable), "Source": 0}))
    device._on_frame(
        codec.encode(
            "ValveCommand", {
                "Channel0": int(valve), "Channel1": 0, "Channel2": 0, "Channel3": 0,
                "OpenLifetime": lifetime_s
            }))


def tick_for(device, clock, seconds, period_s=1e-3, burst=1):
    """Tick the device as its thread would: every ``period_s``, or in bursts of ``burst`` ticks at
    one instant after a late wake (what a deadline scheduler does to catch up)."""
    end = clock.now + seconds
    while clock.now < end - 1e-12:
        clock.now += period_s * burst
        for _ in range(burst):
            device._tick()


def readings(peer_bus, codec, message="PressureSensor1"):
    """Drain the bus; the readings of ``message`` (a str) or {message: readings} (a tuple of
    names)."""
    names = (message,) if isinstance(message, str) else message
    values = {name: [] for name in names}
    while (frame := peer_bus.recv(0.0)) is not None:
        decoded = codec.decode(frame)
        if decoded is not None and decoded.name in values:
            values[decoded.name].append(decoded.signals["GaugePressure"])
    return values[message] if isinstance(message, str) else values


def test_the_plant_integrates_exactly_the_real_elapsed_time_even_when_ticks_come_in_bursts(bench):
    """A late tick followed by catch-up ticks at the same instant used to integrate a full plant
    period each, so the simulated chamber ran ahead of real time during transients (it filled
    about 20 % faster than the estimator's model of the same plant, whose innovations then
    raised false NIS alarms). The reference is the plant stepped over the same real time."""
    device, clock, _, codec = bench
    command(device, codec, Valve.SUPPLY, setpoint_pa=40e3, lifetime_s=0.25)
    # 60 ms of real time, ticks in threes
    tick_for(device, clock, 0.06, period_s=1e-3, burst=3)
    plant = PneumaticPlant()
    state = plant.initial_state()
    inputs = PlantInputs(40e3, True, (Valve.SUPPLY,))
    for _ in range(20):
        state = plant.advance(state, inputs, 3e-3)
    assert device.chamber_gauge_pa() == pytest.approx(state.chamber_pa[0] - P_ATM_PA, rel=1e-6)


def test_after_a_stall_one_heartbeat_goes_out_and_its_uptime_counts_up(bench):
    device, clock, peer_bus, codec = bench
    tick_for(device, clock, 0.25, period_s=1e-3)
    clock.now += 0.5  # the thread held up for five heartbeat periods
    device._tick()
    tick_for(device, clock, 0.25, period_s=1e-3)
    uptimes = []
    while (frame := peer_bus.recv(0.0)) is not None:
        decoded = codec.decode(frame)
        if decoded is not None and decoded.name == "DeviceHeartbeat":
            uptimes.append(decoded.signals["Uptime"])
    assert len(uptimes) >= 3
    assert all(b > a for a, b in zip(uptimes, uptimes[1:])), uptimes
    # none of the missed ones was sent late: the gap spans the stall
    assert max(b - a for a, b in zip(uptimes, uptimes[1:])) >= 0.5


def test_a_disabled_regulator_cuts_both_sources_even_through_valves_stuck_open(bench):
    device, clock, _, codec = bench
    device.set_fault("valve_stuck_open", True)
    command(device, codec, Valve.VENT, setpoint_pa=30e3)
    tick_for(device, clock, 0.5)
    assert device.valves() == (Valve.SUPPLY,)
    # pumped through the stuck valve
    assert device.chamber_gauge_pa() == pytest.approx(30e3, abs=500.0)
    # the second path: Enable = 0
    command(device, codec, Valve.VENT, setpoint_pa=30e3, enable=False)
    tick_for(device, clock, 0.5)
    assert abs(device.chamber_gauge_pa()) < 300.0
    device.set_fault("valve_stuck_open", False)
    command(device, codec, Valve.VACUUM, enable=True)
    tick_for(device, clock, 0.05)
    # stuck open to the vacuum pump
    device.set_fault("valve_stuck", True)
    command(device, codec, Valve.CLOSED, enable=True)
    tick_for(device, clock, 0.1)
    assert device.valves() == (Valve.VACUUM,) and device.chamber_gauge_pa() < -20e3
    command(device, codec, Valve.VENT, enable=False)
    tick_for(device, clock, 1.0)
    # the isolated vacuum line vents
    assert abs(device.chamber_gauge_pa()) < 300.0


def test_true_extremes_cover_every_plant_step_since_the_reset(bench):
    device, clock, _, codec = bench
    command(device, codec, Valve.SUPPLY, setpoint_pa=30e3)
    tick_for(device, clock, 0.3)
    command(device, codec, Valve.VENT)
    tick_for(device, clock, 0.5)
    low, high = device.true_extremes()
    assert high == pytest.approx(30e3, abs=600.0) and low == pytest.approx(0.0, abs=50.0)
    device.reset_true_extremes()
    assert device.true_extremes()[1] < 300.0


@pytest.mark.parametrize("stuck_at", ["present", "low", "high"])
def test_a_stuck_sensor_reads_its_last_value_or_a_fixed_one_while_the_other_moves(bench, stuck_at):
    device, clock, peer, codec = bench
    command(device, codec, Valve.SUPPLY, setpoint_pa=10e3)
    tick_for(device, clock, 0.3)
    readings(peer, codec)
    device.set_fault("sensor_stuck_at", stuck_at)
    device.set_fault("sensor_stuck", "chamber_a")
    command(device, codec, Valve.SUPPLY, setpoint_pa=30e3)
    tick_for(device, clock, 0.3)
    both = readings(peer, codec, ("PressureSensor1", "PressureSensor2"))
    stuck, live = both["PressureSensor1"], both["PressureSensor2"]
    assert len(set(stuck)) == 1, "a stuck sensor repeats one value"
    expected = STUCK_READINGS_PA.get(stuck_at, 10e3)
    assert stuck[0] == pytest.approx(expected, abs=1.5e3)
    assert max(live) == pytest.approx(30e3, abs=1e3)
    with pytest.raises(ValueError, match="must be one of"):
        device.set_fault("sensor_stuck_at", "sideways")


def test_the_noise_scale_multiplies_the_sensor_noise(bench):
    device, clock, peer, codec = bench
    command(device, codec, Valve.CLOSED)
    tick_for(device, clock, 0.5)
    quiet = np.std(readings(peer, codec))
    device.set_fault("sensor_noise_scale", 10.0)
    tick_for(device, clock, 0.5)
    loud = np.std(readings(peer, codec))
    # 250 samples each: the sample standard deviation is within ~10 % of the true one
    assert quiet == pytest.approx(300.0, rel=0.2) and loud == pytest.approx(3000.0, rel=0.2)


def test_a_replay_burst_sends_old_frames_with_jumping_counters_and_feeds_an_old_valve_command(
        bench):
    device, clock, peer, _ = bench
    sync_codec = FrameCodec(max_counter_delta=15, sync_frames=0)
    for valve in (Valve.VENT, *[Valve.CLOSED] * REPLAY_AGE_FRAMES):  # the oldest one kept: VENT
        command(device, sync_codec, valve)
        tick_for(device, clock, 0.005)
    while peer.recv(0.0) is not None:
        pass
    before = device.valves()
    device.replay_burst()
    frames = []
    while (frame := peer.recv(0.0)) is not None:
        frames.append(frame)
    counters = [frame.data[6] & 0x0F for frame in frames]
    assert len(frames) == REPLAY_BURST_FRAMES
    # in sequence among themselves
    assert all((b - a) % 16 == 1 for a, b in zip(counters, counters[1:]))
    # ... and old: the device's own codec saw the old ValveCommand's counter jump and ignored it
    assert device.codec.rejected["counter_jump"] >= 1 and device.valves() == before


def test_a_valve_command_takes_effect_when_it_arrived_even_when_the_tick_comes_late(bench):
    """The tick reads the bus itself and splits its plant step at each frame's arrival. A CLOSED
    that arrived about 20 ms into a late tick stops the fill there: applied at the tick (the old
    reception thread's order when the GIL held it up) the chamber rose on, or applied to the
    whole step, it stopped too early; either is kPa away. The tick's span is the frame's age plus
    20 ms, however long the sleep took (a fixed 30 ms span left a loaded host's late wake almost
    no fill to tell the orders apart: 3 failures in 6 runs beside a test suite)."""
    import time
    device, clock, peer_bus, codec = bench
    command(device, codec, Valve.SUPPLY, setpoint_pa=40e3, lifetime_s=0.25)
    tick_for(device, clock, 0.02)
    peer_bus.send(codec.encode("ValveCommand", {"Channel0": int(Valve.CLOSED), "Channel1": 0,
                                                "Channel2": 0, "Channel3": 0,
                                                "OpenLifetime": 0.2}))
    sent = time.time()
    time.sleep(0.02)
    span = time.time() - sent + 0.02
    clock.now += span
    before = time.time() - sent
    device._tick()
    after = time.time() - sent  # the frame's age at the tick lies between these
    plant = PneumaticPlant()
    state = plant.initial_state()
    inputs = PlantInputs(40e3, True, (Valve.SUPPLY,))
    for _ in range(20):
        state = plant.step(state, inputs, 1e-3)

    def filled_for(seconds):
        """The chamber after ``seconds`` more of the fill, in 1 ms steps (gauge Pa)."""
        p = state
        steps = max(int(seconds / 1e-3), 1)
        for _ in range(steps):
            p = plant.step(p, inputs, seconds / steps)
        return p.chamber_pa[0] - P_ATM_PA

    assert device.valves() == (Valve.CLOSED,)
    gauge = device.chamber_gauge_pa()
    # the device's 5 ms steps against the 1 ms reference: within 0.3 kPa, and 1 ms either way
    assert filled_for(span - after - 1e-3) - 300.0 <= gauge <= filled_for(span - before +
                                                                          1e-3) + 300.0
    # and far from either wrong order
    closed_at_start, closed_at_end = filled_for(1e-9), filled_for(span)
    assert gauge - closed_at_start > 2e3 and closed_at_end - gauge > 2e3


def test_a_frame_taken_late_in_a_tick_acts_when_it_was_sent(bench, monkeypatch):
    """A tick takes its frames one after the other; one may be taken ms after the tick began
    (a GIL wait, or the plant advanced for the frames before it). It acts when it was sent, as
    its stamp says. Against the tick's start it acted that long
    before it was sent (here 4 ms; live, up to the ms a loaded host's tick spent before taking
    it), and the switches an identification dates from its log were off by as much."""
    import softgrip_ros.canbus.sim_device as sim_device
    device, clock, _, codec = bench
    command(device, codec, Valve.SUPPLY, setpoint_pa=40e3, lifetime_s=0.25)
    tick_for(device, clock, 0.02)
    start, state = clock.now, device._state
    # stamped on the fake clock; a tick 15 ms late, the CLOSED sent 8 ms before it and taken
    # after a 4 ms wait behind the setpoint frame
    monkeypatch.setattr(sim_device, "frame_sent_at", lambda frame, *clocks: frame.timestamp)
    queued = [codec.encode("RegulatorSetpoint", {"SetpointGaugePressure": 40e3, "Enable": 1,
                                                 "Source": 0}),
              codec.encode("ValveCommand", {"Channel0": int(Valve.CLOSED), "Channel1": 0,
                                            "Channel2": 0, "Channel3": 0, "OpenLifetime": 0.2})]
    queued[0].timestamp, queued[1].timestamp = start + 0.002, start + 0.007

    def recv(timeout=None):
        if not queued:
            return None
        if len(queued) == 1:
            clock.now += 0.004
        return queued.pop(0)

    monkeypatch.setattr(device.bus, "recv", recv)
    clock.now = start + 0.015
    device._tick()
    assert device.valves() == (Valve.CLOSED,)
    plant = PneumaticPlant()
    inputs = PlantInputs(40e3, True, (Valve.SUPPLY,))

    def closed_after(seconds):
        return plant.advance(state, inputs, seconds).chamber_pa[0] - P_ATM_PA

    # the fill for the 7 ms until the CLOSED was sent, within 20 Pa (4 ms less: 0.9 kPa less)
    assert device.chamber_gauge_pa() == pytest.approx(closed_after(0.007), abs=20.0)
    assert closed_after(0.007) - closed_after(0.003) > 500.0


def test_frames_are_stamped_and_dated_across_a_thread_switch_between_the_clocks():
    """The device's two clock conversions, a reading's wall-clock stamp and a command's sending
    instant, read the clocks' offset at one instant: a thread switch of 8 ms between the two reads
    moves neither. (Read one after the other, it put the reading's stamp and the command's action
    8 ms early: the chamber then moved before the status's stamp said the valve did.)"""
    clocks = SwitchingClocks(now=100.0, switch_s=0.008)
    bus = can.Bus(interface="virtual", channel=f"simdev-{uuid.uuid4().hex[:8]}")
    try:
        device = SimulatedDevice(bus, SimDeviceConfig(seed=4), codec=FrameCodec(sync_frames=0),
                                 clock=clocks.monotonic, wall_clock=clocks.wall)
        assert device._wall_time(99.995) == pytest.approx(999.995, abs=1e-9)
        command = FrameCodec().encode("ValveCommand", {
            "Channel0": int(Valve.SUPPLY), "Channel1": 0, "Channel2": 0, "Channel3": 0,
            "OpenLifetime": 0.2})
        command.timestamp = 1000.010  # sent at 100.010 on the device's clock
        clocks.now, clocks.switches = 100.020, 1
        device._on_frame(command)
        assert device.valves() == (Valve.SUPPLY,)
        assert device._last_valve_command == pytest.approx(100.010, abs=1e-9)
    finally:
        bus.shutdown()


def test_the_plant_keeps_real_time_through_a_stall_of_its_thread(bench):
    """A tick 200 ms late integrates all 200 ms, as a real device's chamber goes on filling while
    the host that simulates it stalls (it integrated 50 ms of them: the plant then lagged the
    controller's model of it, and on a loaded host the regulator and response checks took the lag
    for a fault). The regulator status sent then reports the caught-up output."""
    device, clock, peer_bus, codec = bench
    command(device, codec, Valve.SUPPLY, setpoint_pa=30e3, lifetime_s=0.25)
    device._tick()
    while peer_bus.recv(0.0) is not None:
        pass
    clock.now += 0.2
    device._tick()
    plant = PneumaticPlant()
    state, inputs = plant.initial_state(), PlantInputs(30e3, True, (Valve.SUPPLY,))
    for _ in range(200):
        state = plant.step(state, inputs, 1e-3)
    # the 1 ms reference after 0.2 s (the regulator's 30 ms lag long settled): within 0.3 kPa
    assert device.chamber_gauge_pa() == pytest.approx(state.chamber_pa[0] - P_ATM_PA, abs=300.0)
    assert device.chamber_gauge_pa() > 20e3
    statuses = [codec.decode(frame) for frame in iter(lambda: peer_bus.recv(0.0), None)]
    actual = [s.signals["ActualGaugePressure"] for s in statuses
              if s is not None and s.name == "RegulatorStatus"]
    assert actual and actual[-1] == pytest.approx(30e3, abs=100.0)


def test_a_reading_is_the_plant_at_its_stamp_however_late_it_goes_out(bench, monkeypatch):
    """A reading is stamped with the instant it samples (the end of the plant step that reached
    its due time), none missed, and its value is the plant then. Each send here takes 0.5 ms of
    the clock (a GIL wait on a loaded host):
    stamped when it went out, a reading was as much older than its stamp as the sends before it
    took (at a 1 ms catch-up threshold, 0.5-1 ms, and the live identification fitted its critical
    ratios to that lag; 35 ms in a stalled fault-free grasp, a false RESPONSE fault)."""
    device, clock, _, codec = bench
    monkeypatch.setattr(device, "_wall_time", lambda when: when)  # stamps on the device clock
    sensor1 = codec.frame_ids["PressureSensor1"]
    sent = []  # (stamp, plant time, clock) of each PressureSensor1 frame as it goes out
    send = device.bus.send

    def slow_send(frame, timeout=None):
        clock.now += 0.0005  # held up before it goes out
        if frame.arbitration_id == sensor1:
            sent.append((frame.timestamp, device._last_tick, clock.now))
        send(frame, timeout)

    device.bus.send = slow_send
    command(device, codec, Valve.SUPPLY, setpoint_pa=40e3, lifetime_s=0.25)
    tick_for(device, clock, 0.1, period_s=1e-3)
    stamps = np.array([stamp for stamp, _, _ in sent])
    # the plant read is the plant at the stamp
    assert max(abs(stamp - plant) for stamp, plant, _ in sent) < 1e-9
    # one reading per 2 ms period of the plant's time, none missed, each within a tick's span
    # (here up to 1 + 3 x 0.5 ms) of its due instant
    elapsed = device._last_tick - device._started_at
    assert abs(len(sent) - elapsed / 2e-3) <= 1.0
    late = (stamps - device._started_at) % 2e-3
    assert np.all((late < 2.5e-3 + 1e-9) | (late > 2e-3 - 1e-9))
    assert np.all(np.diff(stamps) > 0.0) and np.diff(stamps).max() <= 2e-3 + 2.5e-3
    # while each went out 0.5 ms or more after its stamp
    assert min(now - stamp for stamp, _, now in sent) >= 0.5e-3 - 1e-9


def test_a_stall_of_the_device_thread_leaves_no_gap_in_the_readings(bench, monkeypatch):
    """A tick 30 ms late sends readings of chamber_a from across the stall, one per catch-up span
    (MAX_PLANT_STEP_S), each stamped at its span's end and reading the plant then (within 5 sigma
    of the sensor noise and its quantisation), as a real device's samples reach a receiver that
    was held up; beyond BACKFILL_S, none."""
    from softgrip_ros.canbus.sim_device import BACKFILL_S
    device, clock, peer_bus, codec = bench
    monkeypatch.setattr(device, "_wall_time", lambda when: when)
    truth = []
    advance = device._advance
    monkeypatch.setattr(device, "_advance", lambda dt, now: (
        advance(dt, now), truth.append((now, device.chamber_gauge_pa()))))
    command(device, codec, Valve.SUPPLY, setpoint_pa=40e3, lifetime_s=0.25)
    tick_for(device, clock, 0.01)
    while peer_bus.recv(0.0) is not None:
        pass
    stall_from = clock.now
    clock.now += 0.03
    device._tick()
    frames = [f for f in iter(lambda: peer_bus.recv(0.0), None)
              if f.arbitration_id == codec.frame_ids["PressureSensor1"]]
    stamps = [f.timestamp for f in frames]
    assert len(frames) == 6 and stamps[0] > stall_from and stamps[-1] == pytest.approx(clock.now)
    np.testing.assert_allclose(np.diff(stamps), MAX_PLANT_STEP_S, atol=1e-9)
    at = dict(truth)
    noise = device.config.sensors[0].noise_std_pa
    for frame in frames:
        reading = codec.decode(frame).signals["GaugePressure"]
        assert reading == pytest.approx(at[frame.timestamp], abs=5 * noise + 10.0)
    # the chamber moved kPa over the stall: the readings follow it, not the tick's end
    assert at[stamps[-1]] - at[stamps[0]] > 3e3
    clock.now += 2 * BACKFILL_S
    device._tick()
    later = [f.timestamp for f in iter(lambda: peer_bus.recv(0.0), None)
             if f.arbitration_id == codec.frame_ids["PressureSensor1"]]
    assert later and min(later) >= clock.now - BACKFILL_S - 1e-9


@pytest.mark.parametrize("period_s", [1e-3, 5e-3])
def test_the_truth_does_not_depend_on_how_the_ticks_fall(bench, period_s):
    """Each tick integrates the time since the last. In one backward-Euler step each, ticks 1 ms
    and 5 ms apart (a loaded host) put the fill 76 and 332 Pa ahead of the law, and the live
    identification fitted the host's load. Sub-stepped (PneumaticPlant.advance), both stay within
    30 Pa of a 10 us reference."""
    device, clock, _, codec = bench
    command(device, codec, Valve.SUPPLY, setpoint_pa=40e3, lifetime_s=0.25)
    tick_for(device, clock, 0.06, period_s=period_s)
    plant = PneumaticPlant()
    reference = plant.advance(plant.initial_state(), PlantInputs(40e3, True, (Valve.SUPPLY,)),
                              0.06, max_step_s=1e-5)
    assert device.chamber_gauge_pa() == pytest.approx(reference.chamber_pa[0] - P_ATM_PA,
                                                      abs=30.0)


def test_a_stalls_catch_up_follows_the_law_too(bench):
    """A stall of 60 ms caught up in one tick lands where the law puts the chamber, as 1 ms ticks
    do (one backward-Euler step per 5 ms span put a fill hundreds of Pa ahead: the grasp sensing
    read that as a finger held back)."""
    device, clock, _, codec = bench
    command(device, codec, Valve.SUPPLY, setpoint_pa=40e3, lifetime_s=0.25)
    tick_for(device, clock, 0.06, period_s=0.06)
    plant = PneumaticPlant()
    reference = plant.advance(plant.initial_state(), PlantInputs(40e3, True, (Valve.SUPPLY,)),
                              0.06, max_step_s=1e-5)
    assert device.chamber_gauge_pa() == pytest.approx(reference.chamber_pa[0] - P_ATM_PA,
                                                      abs=30.0)

"""The CAN codec: round trips, CRC and counter protection, range checks, and random bytes."""
import can
import pytest
from hypothesis import given, settings, strategies as st

from softgrip_ros.canbus.codec import FrameCodec, crc8_sae_j1850

pytestmark = pytest.mark.cpu  # computation only: scripts/test.sh runs it beside another


def test_crc_check_value():
    assert crc8_sae_j1850(b"123456789") == 0x4B  # the published check value of CRC-8/SAE-J1850


def sensor(codec, pressure=-12_345.6, status=0, counter=None):
    return codec.encode("PressureSensor1", {"GaugePressure": pressure, "SensorStatus": status},
                        counter=counter)


@settings(max_examples=200, deadline=None)
@given(pressure=st.floats(-101_325, 700_000), status=st.integers(0, 15))
def test_sensor_frame_round_trip(pressure, status):
    tx, rx = FrameCodec(), FrameCodec(sync_frames=0)
    decoded = rx.decode(sensor(tx, pressure, status))
    assert decoded.name == "PressureSensor1"
    # 0.1 Pa resolution
    assert decoded.signals["GaugePressure"] == pytest.approx(pressure, abs=0.05 + 1e-9)
    assert decoded.signals["SensorStatus"] == status


@settings(max_examples=100, deadline=None)
@given(setpoint=st.floats(-101_325, 600_000), enable=st.integers(0, 1), source=st.integers(0, 3),
       valves=st.lists(st.integers(0, 3), min_size=4, max_size=4), lifetime_ms=st.integers(0, 255))
def test_command_frames_round_trip(setpoint, enable, source, valves, lifetime_ms):
    tx, rx = FrameCodec(), FrameCodec(sync_frames=0)
    decoded = rx.decode(
        tx.encode("RegulatorSetpoint",
                  {"SetpointGaugePressure": setpoint, "Enable": enable, "Source": source}))
    assert decoded.signals["SetpointGaugePressure"] == pytest.approx(setpoint, abs=0.05 + 1e-9)
    assert (decoded.signals["Enable"], decoded.signals["Source"]) == (enable, source)
    decoded = rx.decode(
        tx.encode("ValveCommand", {
            **{f"Channel{i}": v
               for i, v in enumerate(valves)}, "OpenLifetime": lifetime_ms / 1000.0
        }))
    assert [decoded.signals[f"Channel{i}"] for i in range(4)] == valves
    # whole ms
    assert decoded.signals["OpenLifetime"] == pytest.approx(lifetime_ms / 1000.0, abs=1e-9)


@settings(max_examples=500, deadline=None)
@given(arbitration_id=st.integers(0, 0x7FF), data=st.binary(min_size=0, max_size=8))
def test_random_bytes_never_crash_the_decoder(arbitration_id, data):
    codec = FrameCodec(sync_frames=0)
    codec.decode(can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False))
    assert codec.accepted + codec.rejected_total == 1


def test_every_bit_flip_is_caught():
    tx = FrameCodec()
    frame = sensor(tx)
    for bit in range(64):
        rx = FrameCodec()
        data = bytearray(frame.data)
        data[bit // 8] ^= 1 << (bit % 8)
        assert rx.decode(
            can.Message(arbitration_id=frame.arbitration_id, data=bytes(data),
                        is_extended_id=False)) is None
        assert rx.rejected["bad_crc"] == 1


def test_counter_rules():
    tx, rx = FrameCodec(), FrameCodec(max_counter_delta=3, sync_frames=2)
    # start-up: the first frame is the reference ...
    assert rx.decode(sensor(tx, counter=5)) is None
    assert rx.decode(sensor(tx, counter=6)) is None
    # ... trusted after 2 frames in sequence
    assert rx.decode(sensor(tx, counter=7))
    assert rx.synchronising == 2 and rx.rejected_total == 0  # not yet trusted is not bad
    assert rx.decode(sensor(tx, counter=7)) is None  # repeated
    assert rx.rejected["repeated_counter"] == 1
    assert rx.decode(sensor(tx, counter=9))  # one lost frame is tolerated
    # stale (a jump of 10): distrusted from here
    assert rx.decode(sensor(tx, counter=3)) is None
    assert rx.rejected["counter_jump"] == 1 and rx.receiver_states() == {
        "PressureSensor1": "INVALID"
    }
    # the live sequence jumps from the stale frame too
    assert rx.decode(sensor(tx, counter=10)) is None
    assert rx.decode(sensor(tx, counter=11)) is None
    assert rx.decode(sensor(tx, counter=12))  # two in sequence again: trusted
    assert rx.receiver_states() == {"PressureSensor1": "VALID"}
    assert rx.accepted == 3


def test_a_replayed_burst_of_old_frames_is_never_acted_on():
    """The adversary of #20: three old frames in their old order (in sequence among themselves,
    jumping from the live stream) between two live frames. A receiver that resynchronised on a
    jump accepted the third; with the E2E state machine none of them, and the live stream only
    after sync_frames frames in sequence."""
    tx, rx = FrameCodec(), FrameCodec()
    # frame i reads 20000 + i Pa
    stream = [sensor(tx, pressure=20_000.0 + i) for i in range(30)]
    # frames 8-10 replayed after 15
    arrivals = stream[:16] + stream[8:11] + stream[16:]
    taken = [rx.decode(frame) for frame in arrivals]
    values = [round(d.signals["GaugePressure"] - 20_000.0) for d in taken if d is not None]
    # start-up: frames 0-3 synchronise; the burst (8-10 again) and the live 16-19 after it are
    # distrusted
    assert values == list(range(4, 16)) + list(range(16 + rx.sync_frames, 30))
    assert rx.rejected["counter_jump"] == 2  # into the burst, and out of it


@pytest.mark.parametrize("bad", [-1, 65])
def test_sync_frames_out_of_range_is_refused(bad):
    with pytest.raises(ValueError, match="sync_frames"):
        FrameCodec(sync_frames=bad)


def test_counter_wraps_and_is_per_message():
    tx, rx = FrameCodec(), FrameCodec(max_counter_delta=1, sync_frames=0)
    for _ in range(40):
        assert rx.decode(sensor(tx))
        assert rx.decode(tx.encode("RegulatorStatus",
                                   {"ActualGaugePressure": 1.0, "FaultBits": 0}))
    assert rx.rejected_total == 0


def test_wrong_dlc_unknown_id_and_out_of_range_are_counted():
    tx, rx = FrameCodec(), FrameCodec()
    frame = sensor(tx)
    assert rx.decode(
        can.Message(arbitration_id=frame.arbitration_id, data=frame.data[:6],
                    is_extended_id=False)) is None
    assert rx.rejected["bad_dlc"] == 1
    assert rx.decode(can.Message(arbitration_id=0x7AB, data=frame.data,
                                 is_extended_id=False)) is None
    assert rx.decode(
        can.Message(arbitration_id=frame.arbitration_id, data=frame.data,
                    is_extended_id=True)) is None
    assert rx.rejected["unknown_id"] == 2
    # a raw value the signal can carry but the DBC range forbids: -0.2 MPa gauge is below vacuum
    raw = bytearray(frame.data)
    value = int(-200_000 / 0.1) & 0xFFFFFF
    raw[0:3] = value.to_bytes(3, "little")
    from softgrip_ros.canbus.codec import frame_crc
    raw[7] = frame_crc(frame.arbitration_id, bytes(raw))
    assert rx.decode(
        can.Message(arbitration_id=frame.arbitration_id, data=bytes(raw),
                    is_extended_id=False)) is None
    assert rx.rejected["out_of_range"] == 1
    assert rx.accepted == 0


def test_encode_refuses_bad_values():
    codec = FrameCodec()
    with pytest.raises(ValueError, match="cannot encode PressureSensor1"):
        sensor(codec, pressure=1e7)
    with pytest.raises(ValueError, match="unknown message"):
        codec.encode("Nope", {})


def test_a_repeated_frame_is_taken_from_the_cache_and_equals_a_fresh_encode():
    """At rest the controller re-sends the same signals every 10 ms: after one pass of the alive
    counter every frame is a cached payload, bit for bit what cantools gives."""
    cached = FrameCodec()
    signals = {"Channel0": 3, "Channel1": 0, "Channel2": 0, "Channel3": 0, "OpenLifetime": 0.025}
    for k in range(40):
        frame = cached.encode("ValveCommand", signals)
        assert frame.data == FrameCodec().encode("ValveCommand", signals, counter=k).data
    assert len(cached._encoded) == 16
    changed = cached.encode("ValveCommand", {**signals, "Channel0": 1})
    assert changed.data[0] == 1 and len(cached._encoded) == 17
    with pytest.raises(ValueError, match="cannot encode ValveCommand"):
        cached.encode("ValveCommand", {**signals, "OpenLifetime": 1.0})
    with pytest.raises(ValueError, match="cannot encode ValveCommand"):
        # unhashable: not cached, refused
        cached.encode("ValveCommand", {**signals, "Channel0": [1]})


def test_frame_ids_are_configurable():
    tx = FrameCodec(frame_ids={"PressureSensor1": 0x300})
    rx = FrameCodec(frame_ids={"PressureSensor1": 0x300}, sync_frames=0)
    frame = sensor(tx)
    assert frame.arbitration_id == 0x300
    assert rx.decode(frame).name == "PressureSensor1"
    assert FrameCodec().decode(frame) is None  # a receiver on the default IDs does not know 0x300
    with pytest.raises(ValueError, match="share an arbitration ID"):
        FrameCodec(frame_ids={"PressureSensor1": 0x211})
    with pytest.raises(ValueError, match="unknown message"):
        FrameCodec(frame_ids={"Sensor9": 0x400})

"""The batch reception thread, alone and under the controller link, over python-can's virtual
bus."""
import threading
import time
import uuid

import can
import pytest

from softgrip_ros.canbus.codec import FrameCodec
from softgrip_ros.canbus.controller_link import ControllerLink, SensorBinding
from softgrip_ros.canbus.reader import BatchReader
from softgrip_ros.control.pressure import PressureControlConfig, PressureController, Source

from tests.helpers.ros import wait_for

SENSORS = [
    SensorBinding("chamber_a", "PressureSensor1"),
    SensorBinding("chamber_b", "PressureSensor2")
]


@pytest.fixture
def buses():
    channel = f"softgrip-reader-{uuid.uuid4().hex[:8]}"
    sender, receiver = can.Bus(interface="virtual",
                               channel=channel), can.Bus(interface="virtual", channel=channel)
    yield sender, receiver
    sender.shutdown()
    receiver.shutdown()


def frame(k: int) -> can.Message:
    return can.Message(arbitration_id=0x100 + k, data=bytes(8), is_extended_id=False)


class Batches:

    def __init__(self):
        self.calls, self.lock = [], threading.Lock()

    def __call__(self, frames):
        with self.lock:
            self.calls.append([f.arbitration_id - 0x100 for f in frames])

    def ids(self):
        with self.lock:
            return [k for call in self.calls for k in call]


def test_frames_queued_behind_the_first_come_in_one_call_in_order(buses):
    sender, receiver = buses
    for k in range(40):
        sender.send(frame(k))
    batches = Batches()
    reader = BatchReader(receiver, batches, max_batch=16)
    try:
        wait_for(lambda: len(batches.ids()) == 40, timeout=2.0, message="all 40 frames")
    finally:
        reader.stop()
    assert batches.ids() == list(range(40))
    assert [len(call) for call in batches.calls] == [16, 16, 8]
    assert (reader.batches, reader.frames, reader.errors) == (3, 40, 0)


def test_while_resting_frames_wait_for_the_period_and_a_wake_ends_the_wait(buses):
    sender, receiver = buses
    batches = Batches()
    resting = threading.Event()
    resting.set()
    reader = BatchReader(receiver, batches, rest_period_s=1.0, resting=resting.is_set)
    try:
        sender.send(frame(0))
        wait_for(lambda: batches.ids() == [0], timeout=2.0, message="the first frame at once")
        sent = time.monotonic()
        for k in range(1, 6):  # arrive during the rest wait
            sender.send(frame(k))
            time.sleep(0.01)
        time.sleep(0.1)
        assert batches.ids() == [0], "read during the rest wait"
        resting.clear()
        reader.wake()
        wait_for(lambda: len(batches.ids()) == 6, timeout=2.0,
                 message="the waiting frames once woken")
        assert time.monotonic() - sent < 0.8  # woken (~0.16 s), not the end of the 1 s period
        assert batches.calls[1] == [1, 2, 3, 4, 5]
        sender.send(frame(6))  # not resting: at once
        wait_for(lambda: batches.ids()[-1:] == [6], timeout=0.2,
                 message="a frame at once after the rest")
    finally:
        reader.stop()


class FailingOnce:
    """A bus whose first read fails, then delivers one frame."""

    def __init__(self):
        self.reads = 0

    def recv(self, timeout=None):
        self.reads += 1
        if self.reads == 1:
            raise can.CanOperationError("adapter unplugged")
        if self.reads == 2:
            return frame(7)
        time.sleep(min(timeout or 0.0, 0.01))
        return None


def test_a_failing_read_is_counted_and_reading_goes_on():
    batches = Batches()
    reader = BatchReader(FailingOnce(), batches, timeout_s=0.01)
    try:
        wait_for(lambda: batches.ids() == [7], timeout=2.0, message="the frame after the failure")
    finally:
        reader.stop()
    assert reader.errors == 1 and "adapter unplugged" in reader.last_error


def test_a_stopped_reader_hands_the_queued_frames_to_its_caller_and_starts_again(buses):
    """Stopped, the reader's thread takes nothing: the frames queue until take_queued() hands
    them over in the calling thread (max_batch a call, in order); started again, it reads on."""
    sender, receiver = buses
    batches = Batches()
    threads = []
    reader = BatchReader(receiver, lambda frames: (threads.append(threading.current_thread()),
                                                   batches(frames)), max_batch=16)
    try:
        reader.stop()
        assert not reader.running
        for k in range(40):
            sender.send(frame(k))
        threading.Event().wait(0.1)
        assert batches.ids() == []
        assert reader.take_queued() == 40 and reader.take_queued() == 0
        assert batches.ids() == list(range(40))
        assert [len(call) for call in batches.calls] == [16, 16, 8]
        assert set(threads) == {threading.current_thread()}
        reader.start()
        sender.send(frame(40))
        wait_for(lambda: batches.ids()[-1:] == [40], timeout=2.0, message="read on its thread")
        assert threads[-1] is not threading.current_thread()
    finally:
        reader.stop()


def test_a_failing_take_is_counted_not_raised():
    reader = BatchReader(FailingOnce(), Batches(), timeout_s=0.01)
    reader.stop()
    reader.bus.reads, errors = 0, reader.errors  # its thread may have read already
    assert reader.take_queued() == 0
    assert reader.errors == errors + 1 and "adapter unplugged" in reader.last_error


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="rest_period_s"):
        BatchReader(None, print, rest_period_s=-0.1)
    with pytest.raises(ValueError, match="max_batch"):
        BatchReader(None, print, max_batch=0)


def test_the_link_takes_readings_in_batches_while_resting_and_at_once_after_a_command(buses):
    """A vented controller rests: its readings wait for the 1 s rest period and come together (in
    at most two batches: the first may find the reader in a read). The step that starts regulating
    wakes the reader from that wait, and each reading is taken as it comes from then on (well
    within the rest period, so that a loaded machine cannot blur the two). The sensor timeout is
    long here only so that readings held for a 1 s rest still count as fresh."""
    sender, receiver = buses
    codec = FrameCodec()
    batches = []
    link = ControllerLink(
        receiver,
        PressureController(PressureControlConfig(sensor_timeout_s=5.0)),
        SENSORS,
        on_readings=batches.append,
        rest_receive_period_s=1.0,
        # hand-made frames: trusted at once (E2E: test_canbus_codec)
        codec=FrameCodec(sync_frames=0))
    link.controller.active = True

    def reading(value):
        sender.send(codec.encode("PressureSensor1", {"GaugePressure": value, "SensorStatus": 0}))

    try:
        link.command(0.0, Source.VENT, float("nan"))
        link.step()  # no control loop here: step by hand
        assert link.resting
        for k in range(5):
            reading(float(k))
            time.sleep(0.005)
        wait_for(lambda: sum(map(len, batches)) == 5, timeout=3.0, message="the resting readings")
        assert [value for batch in batches for _, value, _ in batch] == [0.0, 1.0, 2.0, 3.0, 4.0]
        assert len(batches) <= 2 and len(batches[-1]) >= 4, [len(batch) for batch in batches]
        link.command(20e3, Source.SUPPLY, float("nan"))
        # the reader is in its 1 s rest wait: this ends it
        link.step()
        assert not link.resting
        count = len(batches)
        for k in range(5, 8):
            reading(float(k))
            wait_for(lambda: len(batches) > count, timeout=0.5, message="a reading taken at once")
            count = len(batches)
        assert [len(batch) for batch in batches[-3:]] == [1, 1, 1]
    finally:
        link.close()

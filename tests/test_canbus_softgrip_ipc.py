"""softgrip_ipc, the inter-process bus: frames reach every other bus on the channel, in order,
also when a receiver reads late; buses that are gone are forgotten."""
import subprocess
import sys
import time

import can
import pytest

from softgrip_ros.canbus import softgrip_ipc

from tests.helpers.ros import unique


@pytest.fixture
def channel():
    return unique("ipc")


def drain(bus) -> list:
    frames = []
    while (frame := bus.recv(0.0)) is not None:
        frames.append(frame)
    return frames


def test_a_receiver_that_reads_late_still_gets_every_frame_in_order(channel):
    """On Unix datagram sockets (before) the kernel queued 11 frames and dropped the rest."""
    sender, receiver = (can.Bus(interface="softgrip_ipc", channel=channel) for _ in range(2))
    try:
        for i in range(300):
            sender.send(
                can.Message(arbitration_id=i, data=bytes([i % 256, 1, 2]), is_extended_id=False))
        frames = drain(receiver)
        assert [f.arbitration_id for f in frames] == list(range(300))
        assert frames[7].data == bytearray([7, 1, 2]) and frames[7].dlc == 3
        assert sender.frames_dropped == 0
        assert receiver.recv(0.05) is None  # nothing else, and a timed wait ends
    finally:
        sender.shutdown()
        receiver.shutdown()


def test_every_other_bus_gets_each_frame_and_a_closed_one_is_forgotten(channel):
    a, b, c = (can.Bus(interface="softgrip_ipc", channel=channel) for _ in range(3))
    try:
        a.send(can.Message(arbitration_id=0x10, data=b"\x01", is_extended_id=False))
        assert [f.arbitration_id for f in drain(b)] == [0x10]
        assert [f.arbitration_id for f in drain(c)] == [0x10]
        assert drain(a) == []  # not its own frames
        c.shutdown()
        assert len(list(softgrip_ipc.channel_directory(channel).glob("*.port"))) == 2
        a._peers_read = -1.0  # look at the channel again now
        a.send(can.Message(arbitration_id=0x11, data=b"", is_extended_id=False))
        assert len(a._peers) == 1 and [f.arbitration_id for f in drain(b)] == [0x11]
    finally:
        for bus in (a, b, c):
            bus.shutdown()


def test_the_channel_s_last_bus_leaves_no_directory_behind(channel):
    """Each test and benchmark run opens channels of its own; their empty directories piled up
    under $TMPDIR (180 after a day of runs)."""
    directory = softgrip_ipc.channel_directory(channel)
    a = can.Bus(interface="softgrip_ipc", channel=channel)
    b = can.Bus(interface="softgrip_ipc", channel=channel)
    a.shutdown()
    assert directory.is_dir()  # b is still on it
    b.send(can.Message(arbitration_id=0x12, data=b"", is_extended_id=False))
    b.shutdown()
    assert not directory.exists()
    c = can.Bus(interface="softgrip_ipc", channel=channel)  # and the channel opens again
    try:
        assert len(list(directory.glob("*.port"))) == 1
    finally:
        c.shutdown()
    assert not directory.exists()


def test_the_announcement_of_a_process_that_died_is_removed(channel):
    finished = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                              capture_output=True, text=True)
    directory = softgrip_ipc.channel_directory(channel)
    directory.mkdir(parents=True, exist_ok=True)
    stale = directory / f"{int(finished.stdout)}-9.port"
    stale.touch()
    bus = can.Bus(interface="softgrip_ipc", channel=channel)
    try:
        bus.send(can.Message(arbitration_id=1, data=b"", is_extended_id=False))
        assert not stale.exists() and bus._peers == []
    finally:
        bus.shutdown()
    assert list(directory.glob("*.port")) == []  # its own announcement goes at shutdown


def test_a_datagram_that_is_not_a_frame_is_ignored(channel):
    import socket
    sender, receiver = (can.Bus(interface="softgrip_ipc", channel=channel) for _ in range(2))
    stray = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        stray.sendto(b"not a frame", receiver._socket.getsockname())
        assert receiver.recv(0.2) is None
        sender.send(can.Message(arbitration_id=0x21, data=b"\x05", is_extended_id=False))
        assert receiver.recv(1.0).arbitration_id == 0x21
    finally:
        stray.close()
        sender.shutdown()
        receiver.shutdown()


def test_the_interface_is_named_as_python_can_names_its_own_and_a_failed_send_is_a_can_error(
        channel):
    """python-can's convention: interface ``virtual``, class ``VirtualBus``; its buses raise
    CanOperationError, never a bare OSError."""
    bus = can.Bus(interface="softgrip_ipc", channel=channel)
    peer = can.Bus(interface="softgrip_ipc", channel=channel)
    try:
        assert type(bus) is softgrip_ipc.SoftgripIpcBus
        # the peer is known now
        bus.send(can.Message(arbitration_id=1, data=b"\x01", is_extended_id=False))
        # a send then fails
        bus._sender.close()
        with pytest.raises(can.CanOperationError, match="softgrip_ipc send failed"):
            bus.send(can.Message(arbitration_id=1, data=b"\x01", is_extended_id=False))
    finally:
        peer.shutdown()
        bus._path.unlink(missing_ok=True)


def test_a_frame_is_stamped_when_it_went_out_not_when_its_send_began(channel):
    """A receiver acts on a frame's stamp (the simulated device switches a valve at it), and the
    sender dates what it sent by its copy's. A wait between the send's start and the socket call
    (the look-up of the peers, or any wait for the GIL or the CPU: live, up to 1.8 ms) must not
    come between the stamp and the sending: here the look-up and each socket call are held up
    20 ms first, and every frame, the receiver's and the sender's copy, carries a time within
    the socket call."""
    import time
    sender, receiver = (can.Bus(interface="softgrip_ipc", channel=channel) for _ in range(2))
    look_up = sender._refresh_peers

    def slow_look_up():
        look_up()
        time.sleep(0.02)

    sender._refresh_peers = slow_look_up
    calls = []

    class HeldUpSocket:
        def __init__(self, inner):
            self.inner = inner

        def sendto(self, *args):
            time.sleep(0.02)
            before = time.time()
            result = self.inner.sendto(*args)
            calls.append((before, time.time()))
            return result

        def __getattr__(self, name):
            return getattr(self.inner, name)

    sender._sender = HeldUpSocket(sender._sender)
    try:
        sent = [can.Message(arbitration_id=i, data=bytes([i]), is_extended_id=False)
                for i in (1, 2)]
        sender.send(sent[0])
        sender._peers_read = time.monotonic() - 1.0  # known, and due for a look-up again
        sender.send(sent[1])
        frames = drain(receiver)
        assert [f.arbitration_id for f in frames] == [1, 2]
        assert len(calls) == 2
        for frame, copy, (before, after) in zip(frames, sent, calls):
            assert before <= frame.timestamp <= after, (frame.timestamp - before, after - before)
            assert before <= copy.timestamp <= after, (copy.timestamp - before, after - before)
    finally:
        sender.shutdown()
        receiver.shutdown()


def test_the_sender_s_frame_carries_the_stamp_its_receiver_gets(channel):
    """The sender dates what it sent by the stamp a receiver acts on (the controller dates its
    valve changes so, and the simulated device switches at it), to the microseconds between the
    kernel's stamps at each end; a stamp the sender set stays."""
    sender, receiver = (can.Bus(interface="softgrip_ipc", channel=channel) for _ in range(2))
    try:
        sender._refresh_peers()
        frame = can.Message(arbitration_id=0x101, data=b"\x01", is_extended_id=False)
        sender.send(frame)
        received = receiver.recv(2.0)
        assert received is not None and frame.timestamp > 0.0
        assert abs(received.timestamp - frame.timestamp) < 1e-3
        preset = can.Message(arbitration_id=0x102, data=b"\x02", is_extended_id=False,
                             timestamp=123.5)
        sender.send(preset)
        assert preset.timestamp == 123.5
        assert receiver.recv(2.0).timestamp != 123.5
    finally:
        sender.shutdown()
        receiver.shutdown()


def _assert_dated_as_it_went(sender, receiver) -> None:
    """A frame sent without a stamp reaches ``receiver`` dated between its send and its receipt."""
    before = time.time()
    sender.send(can.Message(arbitration_id=0x103, data=b"\x03", is_extended_id=False))
    assert before <= receiver.recv(2.0).timestamp <= time.time()


def test_without_kernel_stamps_a_frame_carries_the_senders_stamp_to_its_receiver(channel):
    """A kernel that takes neither timestamping option: the sender stamps each frame in Python
    as it goes to the socket, and its receiver gets that very stamp; a receiver without kernel
    stamps dates a frame sent without one by when it read it."""
    sender, receiver = (can.Bus(interface="softgrip_ipc", channel=channel) for _ in range(2))
    try:
        sender._kernel_send_stamps = receiver._kernel_receive_stamps = False
        sender._refresh_peers()
        before = time.time()
        frame = can.Message(arbitration_id=0x101, data=b"\x01", is_extended_id=False)
        sender.send(frame)
        received = receiver.recv(2.0)
        assert received is not None and received.timestamp == frame.timestamp
        assert before <= frame.timestamp <= time.time()
        sender._kernel_send_stamps = True  # a frame sent with a stamp of 0
        _assert_dated_as_it_went(sender, receiver)
    finally:
        sender.shutdown()
        receiver.shutdown()


def test_a_bus_that_preserves_timestamps_delivers_the_senders_stamp(channel):
    """As python-can's virtual bus with ``preserve_timestamps``: the simulated device stamps a
    reading when it samples it, and its receivers must see that instant, not when a held-up thread
    got to send it; a frame without a stamp still gets the time it went out."""
    sender = can.Bus(interface="softgrip_ipc", channel=channel, preserve_timestamps=True,
                     receive_own_messages=True)
    receiver = can.Bus(interface="softgrip_ipc", channel=channel)
    try:
        sender._refresh_peers()
        sender.send(can.Message(arbitration_id=0x102, data=b"\x02", is_extended_id=False,
                                timestamp=123.5))
        assert receiver.recv(2.0).timestamp == 123.5
        assert sender.recv(2.0).timestamp == 123.5  # its own copy too
        _assert_dated_as_it_went(sender, receiver)
    finally:
        sender.shutdown()
        receiver.shutdown()

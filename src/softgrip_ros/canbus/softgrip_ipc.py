"""``softgrip_ipc``: a python-can interface that joins processes on this machine into one CAN bus.

Like a kernel vcan, which the build machines lack, but in user space: every bus on a channel
binds a UDP socket on 127.0.0.1 (loopback only: nothing leaves the machine), announces it by a
file ``<pid>-<port>.port`` in ``$TMPDIR/softgrip-can-<uid>/<channel>/``, and sends each frame to
every other bus announced there. It exists so that tests (and users without SocketCAN) can run
the controller, the simulated device and a bus monitor as separate processes::

    can.Bus(interface="softgrip_ipc", channel="softgrip")      # a SoftgripIpcBus

Why UDP and not Unix datagram sockets, which it used before: Linux queues at most
``net.unix.max_dgram_qlen`` datagrams (10 by default) on a Unix socket, so a receiver that reads
its frames in batches (the pressure controller at rest takes ~8 every 10 ms) lost frames,
silently, whenever it ran a few milliseconds late. A UDP socket's queue is bounded by bytes
(``SO_RCVBUF``): a few hundred frames at the kernel's default limit, as a SocketCAN socket holds.
A frame that finds a receiver's queue full is dropped and counted (``frames_dropped``), as a real
receiver's overflowing queue would drop it.

Each end stamps a frame with the kernel's time, as SocketCAN does: a receiver gets when the frame
reached its socket (``SO_TIMESTAMPNS``), and the sender's copy says when the kernel sent it (a
software transmit timestamp, ``SO_TIMESTAMPING``); on loopback the two are microseconds apart.
A stamp read in Python before the socket call was as early as a wait for the GIL or the CPU
between the two lasted: in a live identification the simulated device took 10 of 4,671 valve
frames 0.5-1.8 ms after their stamps (none of them a change there; one that was would have
switched the valves later than the controller logged). A bus with ``preserve_timestamps`` still
sends the sender's own stamp (a sampling instant).
"""
from __future__ import annotations

import os
import pathlib
import select
import socket
import struct
import tempfile
import threading
import time

import can

FRAME = struct.Struct("<dIB??8s")  # timestamp, arbitration id, dlc, extended, remote, data
# (a timestamp of 0: the receiver dates the frame by its arrival)
# Linux's socket options and flags for kernel timestamps (asm-generic/socket.h,
# linux/net_tstamp.h), which Python's socket module does not name
SO_TIMESTAMPNS = 35
SO_TIMESTAMPING = 37
SOF_TIMESTAMPING_TX_SOFTWARE = 1 << 1
SOF_TIMESTAMPING_SOFTWARE = 1 << 4
SOF_TIMESTAMPING_OPT_TSONLY = 1 << 11
TIMESPEC = struct.Struct("@ll")  # the kernel's struct timespec: seconds, nanoseconds
ANCILLARY_BYTES = socket.CMSG_SPACE(3 * TIMESPEC.size)
PEER_REFRESH_S = 0.05
LOOPBACK = "127.0.0.1"
RECEIVE_BUFFER_BYTES = 4 * 1024 * 1024  # asked for; the kernel caps it at net.core.rmem_max


def channel_directory(channel: str) -> pathlib.Path:
    if not channel or "/" in channel or channel.startswith("."):
        raise ValueError(f"softgrip_ipc: invalid channel name {channel!r}")
    return pathlib.Path(tempfile.gettempdir()) / f"softgrip-can-{os.getuid()}" / channel


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        return True
    return True


class SoftgripIpcBus(can.BusABC):
    """A bus on ``channel`` shared by every process of this user on this machine.
    ``preserve_timestamps``: a frame sent with a timestamp reaches the receivers with it, as on
    python-can's virtual bus (a simulated device's sampling instants); otherwise, and for a frame
    without one, the stamp is the time it went out."""

    def __init__(self, channel: str = "softgrip", receive_own_messages: bool = False,
                 preserve_timestamps: bool = False, **kwargs):
        self._directory = channel_directory(str(channel))
        self._preserve_timestamps = preserve_timestamps
        self._directory.mkdir(parents=True, exist_ok=True)
        self._socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._socket.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER_BYTES)
        self._socket.bind((LOOPBACK, 0))
        self._kernel_receive_stamps = _set_option(self._socket, SO_TIMESTAMPNS, 1)
        # frames go out of a socket of their own: the transmit timestamps queue on its error
        # queue, which would wake a select on the receiving socket
        self._sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sender.bind((LOOPBACK, 0))
        self._kernel_send_stamps = _set_option(
            self._sender, SO_TIMESTAMPING, SOF_TIMESTAMPING_TX_SOFTWARE |
            SOF_TIMESTAMPING_SOFTWARE | SOF_TIMESTAMPING_OPT_TSONLY)
        self._path = self._directory / f"{os.getpid()}-{self._socket.getsockname()[1]}.port"
        for attempt in range(3):
            try:
                self._path.touch()
                break
            except FileNotFoundError:  # the last bus before this one removed the directory
                if attempt == 2:
                    raise
                self._directory.mkdir(parents=True, exist_ok=True)
        self._receive_own = receive_own_messages
        self._own: list = []
        self._peers: list = []
        self._peers_read = -1.0
        self.frames_dropped = 0
        self._send_lock = threading.Lock()
        self.channel_info = f"softgrip_ipc {channel}"
        super().__init__(channel=channel, **kwargs)

    def _refresh_peers(self) -> None:
        now = time.monotonic()
        if now - self._peers_read < PEER_REFRESH_S:
            return
        self._peers_read = now
        peers = []
        try:
            entries = [
                entry for entry in os.scandir(self._directory)
                if entry.name.endswith(".port") and entry.path != str(self._path)
            ]
        except FileNotFoundError:
            entries = []
        for entry in entries:
            try:
                pid, port = (int(part) for part in entry.name[:-len(".port")].split("-"))
            except ValueError:
                continue  # not one of ours
            if _alive(pid):
                peers.append((LOOPBACK, port))
            else:
                self._unlink(entry.path)  # a process that died without cleaning up
        self._peers = peers

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Send to every other bus on the channel. A frame without a timestamp gets when the
        kernel sent it (to the first peer), as a frame's stamp says when it was received: the
        sender dates what it sent by it (the controller its valve changes, which the simulated
        device makes when the frame reaches it)."""
        data = bytes(msg.data)
        if len(data) > 8:
            raise can.CanOperationError(
                "softgrip_ipc carries classic CAN frames of at most 8 bytes")
        fields = (msg.arbitration_id, len(data), msg.is_extended_id, msg.is_remote_frame,
                  data.ljust(8, b"\0"))
        preserved = msg.timestamp if self._preserve_timestamps and msg.timestamp else 0.0
        with self._send_lock:
            if self._peers_read < 0.0:
                self._refresh_peers()
            went_out = None
            for peer in self._peers:
                # without kernel stamps, stamped in Python as it goes to this peer
                stamp = preserved or (0.0 if self._kernel_send_stamps else time.time())
                try:
                    self._sender.sendto(FRAME.pack(stamp, *fields), socket.MSG_DONTWAIT, peer)
                except BlockingIOError:  # its queue is full
                    self.frames_dropped += 1
                    continue
                # a closed socket, a vanished peer: python-can's error
                except OSError as error:
                    raise can.CanOperationError(f"softgrip_ipc send failed: {error}") from error
                sent = self._kernel_send_stamp() or stamp
                went_out = sent if went_out is None else went_out
            if not msg.timestamp:
                msg.timestamp = went_out or time.time()
            if self._receive_own:
                self._own.append(FRAME.pack(msg.timestamp, *fields))
            # after the frame, not between its stamp and its sending (the directory's system
            # calls); a peer that joins gets frames from the next send after the refresh
            self._refresh_peers()

    def _kernel_send_stamp(self) -> float | None:
        """When the kernel sent the last datagram (its transmit timestamp, from the sending
        socket's error queue, which this empties), or None without one."""
        stamp = None
        while self._kernel_send_stamps:
            try:
                _, ancillary, _, _ = self._sender.recvmsg(
                    1, ANCILLARY_BYTES, socket.MSG_ERRQUEUE | socket.MSG_DONTWAIT)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                self._kernel_send_stamps = False  # not on this kernel: stamped in Python
                break
            stamp = _kernel_stamp(ancillary, SO_TIMESTAMPING) or stamp
        return stamp

    @staticmethod
    def _unlink(path) -> None:
        try:
            os.unlink(path)
        except OSError:
            pass

    def _recv_internal(self, timeout: float | None):
        if self._own:
            return self._decode(self._own.pop(0)), False
        try:
            # a drain (timeout 0) makes one system call per frame, not a select and a recv: each
            # lets another thread take the GIL, which can take a switch interval to come back
            if timeout is None or timeout > 0.0:
                readable, _, _ = select.select([self._socket], [], [], timeout)
                if not readable:
                    return None, False
            payload, ancillary, flags, _ = self._socket.recvmsg(
                FRAME.size, ANCILLARY_BYTES, socket.MSG_DONTWAIT)
        except BlockingIOError:
            return None, False
        except OSError as error:
            raise can.CanOperationError(f"softgrip_ipc receive failed: {error}") from error
        if len(payload) != FRAME.size or flags & socket.MSG_TRUNC:
            return None, False  # not a softgrip_ipc frame
        arrived = _kernel_stamp(ancillary, SO_TIMESTAMPNS) if self._kernel_receive_stamps else None
        return self._decode(payload, arrived or time.time()), False

    def _decode(self, payload: bytes, arrived: float = 0.0) -> can.Message:
        """The frame in ``payload``, stamped as its sender stamped it, else ``arrived``."""
        timestamp, arbitration_id, dlc, extended, remote, data = FRAME.unpack(payload)
        return can.Message(timestamp=timestamp or arrived, arbitration_id=arbitration_id,
                           is_extended_id=extended, is_remote_frame=remote, dlc=dlc,
                           data=data[:dlc], channel=self.channel_info)

    def fileno(self) -> int:
        return self._socket.fileno()

    def shutdown(self) -> None:
        super().shutdown()
        self._unlink(self._path)
        try:
            self._directory.rmdir()  # the channel's last bus leaves nothing behind
        except OSError:
            pass  # another bus is still on the channel
        self._socket.close()
        self._sender.close()


def _set_option(sock: socket.socket, option: int, value: int) -> bool:
    """Whether this kernel took the socket option (Linux's kernel timestamps)."""
    try:
        sock.setsockopt(socket.SOL_SOCKET, option, value)
    except OSError:
        return False
    return True


def _kernel_stamp(ancillary: list, kind: int) -> float | None:
    """The first kernel time (wall clock, s) in a message's ancillary data of ``kind``
    (SO_TIMESTAMPNS: one timespec; SO_TIMESTAMPING: three, the software one first)."""
    for level, message_type, data in ancillary:
        if level == socket.SOL_SOCKET and message_type == kind and len(data) >= TIMESPEC.size:
            seconds, nanoseconds = TIMESPEC.unpack_from(data)
            if seconds or nanoseconds:
                return seconds + 1e-9 * nanoseconds
    return None

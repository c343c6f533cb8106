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
        self._path = self._directory / f"{os.getpid()}-{self._socket.getsockname()[1]}.port"
        self._path.touch()
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

    def _stamp(self, msg: can.Message) -> float:
        """The stamp a receiver gets: the sender's, where this bus preserves it, else now."""
        return msg.timestamp if self._preserve_timestamps and msg.timestamp else time.time()

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        data = bytes(msg.data)
        if len(data) > 8:
            raise can.CanOperationError(
                "softgrip_ipc carries classic CAN frames of at most 8 bytes")
        fields = (msg.arbitration_id, len(data), msg.is_extended_id, msg.is_remote_frame,
                  data.ljust(8, b"\0"))
        with self._send_lock:
            if self._peers_read < 0.0:
                self._refresh_peers()
            for peer in self._peers:
                # stamped as it goes to this peer: each system call lets another thread take the
                # GIL (up to a switch interval, 5 ms), and a receiver acts on the stamp (the
                # simulated device switches a valve at it: a stamp taken before such a wait let a
                # live identification see valve pulses ~1 ms longer than the device made them)
                stamp = self._stamp(msg)
                if not msg.timestamp:
                    # the sender's copy says when it went out (to the first peer), as a frame's
                    # stamp says when it was received: the sender dates what it sent by it
                    msg.timestamp = stamp
                payload = FRAME.pack(stamp, *fields)
                try:
                    self._socket.sendto(payload, socket.MSG_DONTWAIT, peer)
                except BlockingIOError:  # its queue is full
                    self.frames_dropped += 1
                # a closed socket, a vanished peer: python-can's error
                except OSError as error:
                    raise can.CanOperationError(f"softgrip_ipc send failed: {error}") from error
            if self._receive_own:
                self._own.append(FRAME.pack(self._stamp(msg), *fields))
            # after the frame, not between its stamp and its sending (the directory's system
            # calls); a peer that joins gets frames from the next send after the refresh
            self._refresh_peers()

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
            payload = self._socket.recv(FRAME.size, socket.MSG_DONTWAIT)
        except BlockingIOError:
            return None, False
        except OSError as error:
            raise can.CanOperationError(f"softgrip_ipc receive failed: {error}") from error
        if len(payload) != FRAME.size:
            return None, False  # not a softgrip_ipc frame
        return self._decode(payload), False

    def _decode(self, payload: bytes) -> can.Message:
        timestamp, arbitration_id, dlc, extended, remote, data = FRAME.unpack(payload)
        return can.Message(timestamp=timestamp, arbitration_id=arbitration_id,
                           is_extended_id=extended, is_remote_frame=remote, dlc=dlc,
                           data=data[:dlc], channel=self.channel_info)

    def fileno(self) -> int:
        return self._socket.fileno()

    def shutdown(self) -> None:
        super().shutdown()
        self._unlink(self._path)
        self._socket.close()

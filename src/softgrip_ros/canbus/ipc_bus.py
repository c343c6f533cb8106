"""``softgrip_ipc``: a python-can interface that joins processes on this machine into one CAN bus.

Like a kernel vcan, which the build machines lack, but in user space: every bus on a
channel binds a Unix datagram socket in ``$TMPDIR/softgrip-can-<uid>/<channel>/`` and
sends each frame to every other socket there. Nothing touches the network. It exists
so that tests (and users without SocketCAN) can run the controller, the simulated device
and a bus monitor as separate processes::

    can.Bus(interface="softgrip_ipc", channel="softgrip")
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

FRAME = struct.Struct("<dIB??8s")   # timestamp, arbitration id, dlc, extended, remote, data
PEER_REFRESH_S = 0.05


def channel_directory(channel: str) -> pathlib.Path:
    if not channel or "/" in channel or channel.startswith("."):
        raise ValueError(f"softgrip_ipc: invalid channel name {channel!r}")
    return pathlib.Path(tempfile.gettempdir()) / f"softgrip-can-{os.getuid()}" / channel


class LocalSocketBus(can.BusABC):
    """A bus on ``channel`` shared by every process of this user on this machine."""

    def __init__(self, channel: str = "softgrip", receive_own_messages: bool = False, **kwargs):
        self._directory = channel_directory(str(channel))
        self._directory.mkdir(parents=True, exist_ok=True)
        self._path = self._directory / f"{os.getpid()}-{id(self):x}.sock"
        self._socket = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self._socket.bind(str(self._path))
        self._socket.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
        self._receive_own = receive_own_messages
        self._own: list = []
        self._peers: list = []
        self._peers_read = -1.0
        self._send_lock = threading.Lock()
        self.channel_info = f"softgrip_ipc {channel}"
        super().__init__(channel=channel, **kwargs)

    def _refresh_peers(self) -> None:
        now = time.monotonic()
        if now - self._peers_read < PEER_REFRESH_S:
            return
        self._peers_read = now
        try:
            self._peers = [entry.path for entry in os.scandir(self._directory)
                           if entry.name.endswith(".sock") and entry.path != str(self._path)]
        except FileNotFoundError:
            self._peers = []

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        data = bytes(msg.data)
        if len(data) > 8:
            raise can.CanOperationError("softgrip_ipc carries classic CAN frames of at most 8 bytes")
        payload = FRAME.pack(time.time(), msg.arbitration_id, len(data), msg.is_extended_id,
                             msg.is_remote_frame, data.ljust(8, b"\0"))
        with self._send_lock:
            self._refresh_peers()
            for peer in list(self._peers):
                try:
                    self._socket.sendto(payload, socket.MSG_DONTWAIT, peer)
                except (ConnectionRefusedError, FileNotFoundError):
                    self._forget(peer)            # a peer that died without cleaning up
                except BlockingIOError:
                    pass                          # a full receiver drops the frame, as a real bus would
            if self._receive_own:
                self._own.append(payload)

    def _forget(self, peer: str) -> None:
        try:
            os.unlink(peer)
        except OSError:
            pass
        if peer in self._peers:
            self._peers.remove(peer)

    def _recv_internal(self, timeout: float | None):
        if self._own:
            return self._decode(self._own.pop(0)), False
        readable, _, _ = select.select([self._socket], [], [], timeout)
        if not readable:
            return None, False
        try:
            payload = self._socket.recv(FRAME.size)
        except OSError as error:
            raise can.CanOperationError(f"softgrip_ipc receive failed: {error}") from error
        return self._decode(payload), False

    def _decode(self, payload: bytes) -> can.Message:
        timestamp, arbitration_id, dlc, extended, remote, data = FRAME.unpack(payload)
        return can.Message(timestamp=timestamp, arbitration_id=arbitration_id, is_extended_id=extended,
                           is_remote_frame=remote, dlc=dlc, data=data[:dlc], channel=self.channel_info)

    def fileno(self) -> int:
        return self._socket.fileno()

    def shutdown(self) -> None:
        super().shutdown()
        self._socket.close()
        try:
            self._path.unlink()
        except FileNotFoundError:
            pass

"""softgrip_ros.canbus: the CAN side, free of ROS."""
from __future__ import annotations

import can


def open_bus(interface: str, channel: str, bitrate: int) -> can.BusABC:
    """A python-can bus; the virtual and softgrip_ipc interfaces take no bitrate."""
    kwargs = {} if interface in ("virtual", "softgrip_ipc") else {"bitrate": bitrate}
    return can.Bus(interface=interface, channel=channel, **kwargs)

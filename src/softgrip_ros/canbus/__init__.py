"""softgrip_ros.canbus: the CAN side, free of ROS."""
from __future__ import annotations

import can


SIMULATED_INTERFACES = ("virtual", "softgrip_ipc")


def open_bus(interface: str, channel: str, bitrate: int,
             preserve_timestamps: bool = False) -> can.BusABC:
    """A python-can bus; the simulated interfaces take no bitrate. ``preserve_timestamps``: on
    those, a frame sent with a timestamp reaches its receivers with it (a simulated device's
    sampling instants); a hardware interface stamps frames as they arrive, and ignores it."""
    if interface in SIMULATED_INTERFACES:
        kwargs = {"preserve_timestamps": True} if preserve_timestamps else {}
    else:
        kwargs = {"bitrate": bitrate}
    return can.Bus(interface=interface, channel=channel, **kwargs)

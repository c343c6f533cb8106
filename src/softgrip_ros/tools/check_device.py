"""softgrip_check_device: does a device's firmware speak the softgrip CAN protocol?

    softgrip_check_device --interface socketcan --channel can0
    softgrip_check_device --interface softgrip_ipc --channel softgrip --json

It plays the controller on the bus (heartbeat, RegulatorSetpoint, ValveCommand, each with its
alive counter and CRC-8), listens to the device, and prints one PASS/FAIL row per requirement of
config/softgrip.dbc with what it measured: each cyclic frame at its rate (the DBC's
GenMsgCycleTime, within 10 %), the DeviceHeartbeat, DLCs, CRCs, alive counters, signal ranges,
the regulator following a setpoint, each valve channel answering a ValveCommand, an open channel
closing when its OpenLifetime runs out, and no fault bits (softgrip_ros.canbus.conformance says
how each is judged). Run it before anything else on new hardware (docs/hardware.md).

The gauge pressure stays within --limit-kpa: the regulator is never set above --test-pressure-kpa,
and a reading beyond the limit vents at once and ends the check. It vents (regulator disabled,
every channel VENT) at the end, on a failure and on Ctrl-C. Stop anything else that commands the
device first (the controller): two controllers on one bus fight.

Exit status: 0 every row passed; 1 a row failed (or the check was interrupted); 2 bad arguments
or no bus.
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys

from softgrip_ros.argtypes import Assignment, Number
from softgrip_ros.canbus import open_bus
from softgrip_ros.canbus.codec import FrameCodec
from softgrip_ros.canbus.conformance import (CHECK_RANGES, MAX_RATE_HZ, VALVE_CHANNELS,
                                             CheckConfig, DeviceChecker, format_table)


def _option(name: str, scale: float, unit: str) -> Number:
    """CheckConfig's range of ``name``, in the option's unit (``scale`` per config unit)."""
    low, high = CHECK_RANGES[name]
    return Number(low * scale, high * scale, unit)


def parser() -> argparse.ArgumentParser:
    top = argparse.ArgumentParser(prog="softgrip_check_device", description=__doc__,
                                  formatter_class=argparse.RawDescriptionHelpFormatter)
    top.add_argument("--interface", default="socketcan", help="python-can interface: "
                     "socketcan, softgrip_ipc, pcan, ... (default: socketcan)")
    top.add_argument("--channel", default="can0", help="python-can channel (default: can0)")
    top.add_argument("--bitrate", type=Number(10_000, 1_000_000, "bit/s", integer=True),
                     default=500000, help="bit/s (default: 500000; "
                     "ignored by virtual and softgrip_ipc)")
    top.add_argument("--dbc", type=pathlib.Path, help="the DBC (default: the packaged "
                     "config/softgrip.dbc)")
    top.add_argument("--frame-id", type=Assignment(Number(0, 0x1FFFFFFF, integer=True)),
                     action="append",
                     default=[], metavar="MESSAGE=ID", help="an arbitration ID other than the "
                     "DBC's, as the nodes' can.frame_ids.* parameters (e.g. "
                     "PressureSensor1=0x220); repeatable")
    top.add_argument("--rate", type=Assignment(Number(0.0, MAX_RATE_HZ, "Hz", low_open=True)),
                     action="append", default=[],
                     metavar="MESSAGE=HZ", help="a device frame's expected rate other than the "
                     "DBC's cycle time (e.g. PressureSensor1=250); repeatable")
    top.add_argument("--channels", type=Number(0, VALVE_CHANNELS - 1, integer=True), nargs="+",
                     default=[0], metavar="N",
                     help="the valve channels to exercise; each must be seen by the pressure "
                     "sensors (default: 0)")
    top.add_argument("--listen", type=_option("listen_s", 1.0, "s"), default=2.0, metavar="S",
                     help="seconds of listening for the rates, counters and CRCs (default: 2)")
    top.add_argument("--test-pressure-kpa", type=_option("test_pressure_pa", 1e-3, "kPa"),
                     default=8.0,
                     help="the regulator setpoint of the active checks (default: 8)")
    top.add_argument("--limit-kpa", type=_option("pressure_limit_pa", 1e-3, "kPa"),
                     default=10.0,
                     help="any reading beyond +-this vents and ends the check (default: 10)")
    top.add_argument("--lifetime-ms", type=_option("lifetime_s", 1e3, "ms"), default=10.0,
                     help="the OpenLifetime of the watchdog check's one command (default: 10)")
    top.add_argument("--json", action="store_true", help="print the rows as JSON, not a table")
    return top


def main(argv=None) -> int:
    args = parser().parse_args(argv)

    def fail(text: str) -> int:
        print(f"softgrip_check_device: {text}", file=sys.stderr)
        return 2

    try:
        config = CheckConfig(listen_s=args.listen, rates_hz=dict(args.rate),
                             channels=tuple(args.channels),
                             test_pressure_pa=1e3 * args.test_pressure_kpa,
                             pressure_limit_pa=1e3 * args.limit_kpa,
                             lifetime_s=1e-3 * args.lifetime_ms)
    except ValueError as error:
        return fail(str(error))
    try:
        codec = FrameCodec(args.dbc, frame_ids=dict(args.frame_id))
    except Exception as error:  # cantools raises its own types for a malformed DBC
        return fail(f"the DBC {args.dbc or '(packaged)'}: {error}")
    try:
        bus = open_bus(args.interface, args.channel, args.bitrate)
    except Exception as error:  # python-can raises many types for a missing interface or device
        return fail(f"cannot open {args.interface} channel {args.channel!r}: {error}")

    def progress(text: str) -> None:
        print(f"[check] {text}", file=sys.stderr, flush=True)

    try:
        checker = DeviceChecker(bus, codec, config, progress)
        try:
            rows = checker.run()
        except KeyboardInterrupt:
            checker.close()
            print("softgrip_check_device: interrupted; the device was told to vent",
                  file=sys.stderr)
            return 1
    except ValueError as error:
        return fail(str(error))
    finally:
        bus.shutdown()
    if args.json:
        print(json.dumps({"passed": all(r.passed for r in rows),
                          "rows": [r.as_dict() for r in rows]}, indent=1))
    else:
        print(format_table(rows))
        failed = [r.check for r in rows if not r.passed]
        print(f"\n{len(rows) - len(failed)} of {len(rows)} checks passed" +
              (f"; FAILED: {', '.join(failed)}" if failed else ""))
    return 0 if all(r.passed for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())

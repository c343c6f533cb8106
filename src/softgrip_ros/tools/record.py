"""softgrip_record: record a trial as a rosbag2 (MCAP storage, each message definition embedded).

    softgrip_record trial1                      # until Ctrl-C
    softgrip_record trial2 --duration 30 --namespace /g1 --can trial2.blf \\
        --can-interface socketcan --can-channel can0

By default it records, relative to --namespace: grasp_command, grasp_state, controller/status,
pressure/* (the sensors, the estimate, the commands and the estimator's journal,
pressure/estimator_input), tip_pose/*, joint_states, and /diagnostics; each as soon as it
appears. --topics replaces that list (shell-style patterns). A topic that never appears is a
warning at the end, not a failure. The estimator's parameters go into the bag's custom_data, for
softgrip_replay. ``ros2 bag info``, Foxglove and the rosbags library read the result.

An exact replay needs the estimator's journal from its first event: start the recorder before the
controller (the estimator keeps its first JOURNAL_HISTORY events for a recorder that joins within
JOURNAL_STARTUP_S of its start).

--can FILE also logs the raw CAN traffic through python-can's Logger (.blf, .asc or .log), which
its player and viewer replay. The recording stops, keeping the bag readable, when the disk has
less than --min-free-mb left.

Exit status: 0 recorded (until --duration, Ctrl-C or SIGTERM); 1 stopped early (disk full, a
write failed, the CAN log failed); 2 bad arguments (OUTDIR exists, a bad CAN interface).
"""
from __future__ import annotations

import argparse
import fnmatch
import math
import pathlib
import shutil
import signal
import struct
import sys
import threading
import time

from softgrip_ros.argtypes import Number
from softgrip_ros.client import add_namespace_argument

DEFAULT_TOPICS = ("grasp_command", "grasp_state", "controller/status", "pressure/*", "tip_pose/*",
                  "joint_states", "/diagnostics")
DISCOVERY_PERIOD_S = 0.5
FLUSH_PERIOD_S = 0.1
PROGRESS_PERIOD_S = 5.0
DRAIN_QUIET_S = 0.5
DRAIN_MAX_S = 15.0


class OneChannelLog:
    """A python-can listener: every frame into ``logger`` on channel 1, the one bus logged, until
    the first error (the writer's or the bus's), kept in ``error`` for the recording to stop on.

    A frame's channel is its bus's name, and python-can's writers take the name's trailing digits
    as the channel number: a softgrip_ipc channel such as ``trial-20261203`` would number beyond
    BLF's 16 bits, and the writer would fail on every frame.
    """

    def __init__(self, logger):
        self.logger = logger
        self.error: Exception | None = None
        self.frames = 0

    def __call__(self, frame) -> None:
        if self.error is not None:
            return
        frame.channel = 1
        try:
            self.logger(frame)
        except Exception as error:  # the writers raise OSError, struct.error, ValueError, ...
            self.error = error
        else:
            self.frames += 1

    def on_error(self, error: Exception) -> None:
        """The bus failed; the notifier carries on (and the recording stops on ``error``)."""
        self.error = self.error or error

    def stop(self) -> None:
        self.logger.stop()


def parser() -> argparse.ArgumentParser:
    top = argparse.ArgumentParser(prog="softgrip_record", description=__doc__,
                                  formatter_class=argparse.RawDescriptionHelpFormatter)
    top.add_argument("outdir", type=pathlib.Path, help="the bag directory to create (must not "
                     "exist)")
    top.add_argument("--topics", nargs="+", help="topics or patterns, relative to --namespace "
                     "unless they start with / (default: " + " ".join(DEFAULT_TOPICS) + ")")
    top.add_argument("--duration", type=Number(0.0, 1e6, "s", low_open=True),
                     help="stop after this many seconds (default: until Ctrl-C)")
    add_namespace_argument(top)
    top.add_argument("--can", type=pathlib.Path, metavar="FILE", help="also log the raw CAN "
                     "traffic to FILE (.blf, .asc or .log)")
    top.add_argument("--can-interface", default="socketcan", help="python-can interface for "
                     "--can (default: socketcan)")
    top.add_argument("--can-channel", default="can0", help="python-can channel for --can "
                     "(default: can0)")
    top.add_argument("--min-free-mb", type=Number(0.0, 1e12, "MB"), default=100.0,
                     help="stop when the disk has less than this left (default: 100)")
    return top


def resolve(patterns, namespace: str) -> list:
    """Absolute topic patterns: relative ones under ``namespace``."""
    prefix = namespace.rstrip("/")
    if prefix and not prefix.startswith("/"):
        prefix = "/" + prefix
    return [p if p.startswith("/") else f"{prefix}/{p}" for p in patterns]


class Recorder:
    """Subscribes (serialised) to every topic matching ``patterns`` as it appears, and queues
    (topic, msgtype, receive time ns, CDR bytes) for the writer."""

    def __init__(self, node, patterns: list, knows, namespace: str, stamped=lambda _: False):
        self.node, self.patterns, self.knows = node, patterns, knows
        self.stamped = stamped  # msgtype -> whether its first field is a std_msgs/Header
        self.newest_stamp_s = -math.inf  # the header stamp of the last stamped message taken
        self.namespace = namespace
        self.lock = threading.Lock()
        self.queue = []
        self.subscribed = {}  # topic -> msgtype
        self.skipped = {}  # topic -> msgtype with no known definition
        self.counts = {}
        self.last_received = time.monotonic()
        self.parameters = None  # the estimator's, once read

    def discover(self) -> None:
        from rclpy.qos import DurabilityPolicy, QoSProfile

        from softgrip_ros.estimation.runner import JOURNAL_HISTORY, JOURNAL_TOPIC
        for topic, types in self.node.get_topic_names_and_types():
            if topic in self.subscribed or topic in self.skipped or not any(
                    fnmatch.fnmatchcase(topic, p) for p in self.patterns):
                continue
            msgtype = types[0]
            message_class = _message_class(msgtype)
            if message_class is None or not self.knows(msgtype):
                self.skipped[topic] = msgtype
                print(f"[record] {topic}: type {msgtype} has no definition here; not recorded",
                      file=sys.stderr)
                continue
            # the journal is kept for a late subscriber (transient local): take its history
            qos = (QoSProfile(depth=JOURNAL_HISTORY, durability=DurabilityPolicy.TRANSIENT_LOCAL)
                   if topic.endswith("/" + JOURNAL_TOPIC) else QoSProfile(depth=1000))
            self.node.create_subscription(
                message_class, topic,
                lambda data, t=topic, m=msgtype: self._keep(t, m, data), qos, raw=True)
            self.subscribed[topic] = msgtype

    def _keep(self, topic: str, msgtype: str, data: bytes) -> None:
        data = bytes(data)
        with self.lock:
            self.queue.append((topic, msgtype, time.time_ns(), data))
            self.last_received = time.monotonic()
            # little-endian CDR: the encapsulation (4 bytes), then the header's sec, nanosec
            if self.stamped(msgtype) and len(data) >= 12 and data[1] == 1:
                sec, nanosec = struct.unpack_from("<iI", data, 4)
                self.newest_stamp_s = sec + 1e-9 * nanosec

    def take(self) -> list:
        """The messages received since the last take, to be written (``counts`` counts them)."""
        with self.lock:
            queued, self.queue = self.queue, []
        for topic, *_ in queued:
            self.counts[topic] = self.counts.get(topic, 0) + 1
        return queued


def _drain(recorder: Recorder, bag, stopped_at_s: float) -> None:
    """Write what was published before the stop (``stopped_at_s``, wall clock) and is still
    arriving: on a loaded host the subscriptions run seconds behind the publishers (3.3 s in a
    12 s recording of the composed controller), and what DDS still held at the stop was lost.
    Until a message stamped after the stop comes, or nothing for DRAIN_QUIET_S; at most
    DRAIN_MAX_S."""
    started = time.monotonic()
    told = False
    while time.monotonic() - started < DRAIN_MAX_S:
        for message in recorder.take():
            bag.write(*message)
        if (recorder.newest_stamp_s >= stopped_at_s or
                time.monotonic() - recorder.last_received >= DRAIN_QUIET_S):
            break
        if not told and time.monotonic() - started > 1.0:
            print("[record] writing what is still arriving ...", file=sys.stderr, flush=True)
            told = True
        time.sleep(FLUSH_PERIOD_S)
    for message in recorder.take():
        bag.write(*message)


def _message_class(msgtype: str):
    """The Python class of ``package/msg/Name`` (None when it is not installed here)."""
    import importlib
    package, _, name = msgtype.partition("/msg/")
    try:
        return getattr(importlib.import_module(f"{package}.msg"), name)
    except (ImportError, AttributeError, ValueError):
        return None


def _estimator_parameters(node, namespace: str, timeout_s: float = 2.0) -> dict | None:
    """The estimator's parameter values ({name: value}), or None when it does not answer."""
    from rcl_interfaces.srv import GetParameters
    from rclpy.parameter import parameter_value_to_python
    from softgrip_ros.nodes.specs import ESTIMATOR_SPECS
    service = f"{namespace.rstrip('/')}/estimator/get_parameters"
    client = node.create_client(GetParameters, service)
    try:
        if not client.wait_for_service(timeout_sec=timeout_s):
            return None
        names = [spec.name for spec in ESTIMATOR_SPECS]
        future = client.call_async(GetParameters.Request(names=names))
        deadline = time.monotonic() + timeout_s
        while not future.done() and time.monotonic() < deadline:
            time.sleep(0.01)
        if not future.done() or future.result() is None:
            return None
        values = {}
        for name, value in zip(names, future.result().values):
            value = parameter_value_to_python(value)
            # arrays come as array.array: YAML wants lists
            values[name] = value if isinstance(value, (str, bool, int, float)) else list(value)
        return values
    finally:
        node.destroy_client(client)


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    if args.outdir.exists():
        print(f"softgrip_record: {args.outdir} exists; give a new directory", file=sys.stderr)
        return 2
    if not args.outdir.parent.resolve().is_dir():
        print(f"softgrip_record: {args.outdir.parent} is not a directory", file=sys.stderr)
        return 2
    from softgrip_ros.fileio import OutputError, check_writable_directory
    try:
        check_writable_directory(args.outdir.parent)
    except OutputError as error:
        print(f"softgrip_record: {error}", file=sys.stderr)
        return 2
    can_log, can_listener = None, None
    if args.can is not None:
        import can
        from softgrip_ros.canbus import open_bus
        try:
            bus = open_bus(args.can_interface, args.can_channel, 500000)
        except Exception as error:  # python-can raises many types for a missing interface
            print(f"softgrip_record: cannot open {args.can_interface} {args.can_channel!r}: "
                  f"{error}", file=sys.stderr)
            return 2
        try:
            logger = can.Logger(str(args.can))
        except ValueError as error:
            bus.shutdown()
            print(f"softgrip_record: --can {args.can}: {error}", file=sys.stderr)
            return 2
        can_listener = OneChannelLog(logger)
        can_log = (bus, can.Notifier(bus, [can_listener]))

    import rclpy
    import yaml
    from rclpy.signals import SignalHandlerOptions

    from softgrip_ros.nodes.common import spinning
    from softgrip_ros.tools.bag import BagWriter

    stop = threading.Event()
    for number in (signal.SIGINT, signal.SIGTERM):
        signal.signal(number, lambda *_: stop.set())
    context = rclpy.Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node(f"softgrip_record_{int(time.time() * 1e3) % 1000000}",
                             context=context)
    patterns = resolve(args.topics or DEFAULT_TOPICS, args.namespace)
    status, reason, recorder = 0, "", None
    started = time.monotonic()
    try:
        with BagWriter(args.outdir) as bag:
            recorder = Recorder(node, patterns, bag.knows, args.namespace, bag.stamped)
            print(f"[record] {args.outdir}: {' '.join(patterns)}", file=sys.stderr, flush=True)
            # one thread: its per-message cost is far below a multi-threaded executor's, and
            # hundreds of messages a second come in
            with spinning(node, context=context, threads=1):
                next_discovery = next_progress = next_space = 0.0
                while not stop.is_set():
                    now = time.monotonic()
                    if args.duration is not None and now - started >= args.duration:
                        break
                    if now >= next_discovery:
                        next_discovery = now + DISCOVERY_PERIOD_S
                        recorder.discover()
                        if recorder.parameters is None:
                            recorder.parameters = _estimator_parameters(node, args.namespace,
                                                                        timeout_s=0.2)
                    if now >= next_space:
                        next_space = now + 1.0
                        free_mb = shutil.disk_usage(args.outdir.parent.resolve()).free / 1e6
                        if free_mb < args.min_free_mb:
                            status, reason = 1, (f"the disk has {free_mb:.0f} MB left (below "
                                                 f"--min-free-mb {args.min_free_mb:g})")
                            break
                    if can_listener is not None and can_listener.error is not None:
                        status, reason = 1, f"the CAN log failed: {can_listener.error}"
                        break
                    try:
                        for message in recorder.take():
                            bag.write(*message)
                    except OSError as error:
                        status, reason = 1, f"writing failed: {error}"
                        break
                    if now >= next_progress:
                        next_progress = now + PROGRESS_PERIOD_S
                        total = sum(recorder.counts.values())
                        print(f"[record] {now - started:.0f} s: {total} messages on "
                              f"{len(recorder.counts)} topics", file=sys.stderr, flush=True)
                    stop.wait(FLUSH_PERIOD_S)
                if status == 0:
                    _drain(recorder, bag, time.time())
            if recorder.parameters is not None:
                bag.set_custom_data("softgrip.estimator_parameters",
                                    yaml.safe_dump(recorder.parameters))
    except OSError as error:
        done = "finished" if recorder is not None else "created"
        status, reason = 1, f"the bag could not be {done}: {error}"
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)
        if can_log is not None:
            bus, notifier = can_log
            try:
                notifier.stop()  # stops the logger too: the file is closed
            except OSError as error:  # its last block could not be written
                can_listener.on_error(error)
            bus.shutdown()
            if can_listener.error is not None and not reason:
                status, reason = 1, f"the CAN log failed: {can_listener.error}"
    if reason and recorder is None:  # the bag was never opened: nothing recorded
        print(f"softgrip_record: cannot record: {reason}", file=sys.stderr)
    elif reason:
        print(f"softgrip_record: recording stopped: {reason}; {args.outdir} holds everything "
              "recorded until then", file=sys.stderr)
    if recorder is None:
        return status
    missing = [p for p in patterns if "*" not in p and p not in recorder.subscribed]
    if missing:
        print(f"softgrip_record: warning: never appeared: {' '.join(missing)}", file=sys.stderr)
    counts = ", ".join(f"{t} {n}" for t, n in sorted(recorder.counts.items()))
    print(f"[record] {args.outdir}: {sum(recorder.counts.values())} messages in "
          f"{time.monotonic() - started:.1f} s ({counts or 'none'})", file=sys.stderr)
    if can_listener is not None:
        print(f"[record] {args.can}: {can_listener.frames} CAN frames", file=sys.stderr)
    return status


if __name__ == "__main__":
    sys.exit(main())

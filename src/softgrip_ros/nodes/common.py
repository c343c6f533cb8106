"""Small pieces every softgrip node uses: the spin-and-exit-cleanly main, CAN bus opening,
stamps."""
from __future__ import annotations

import contextlib
import faulthandler
import signal
import sys
import threading

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import (ExternalShutdownException, MultiThreadedExecutor,
                             SingleThreadedExecutor)
from rclpy.time import Time

from softgrip_ros.nodes.rclpy_compat import RCLError, SHUTDOWN_ERRORS, shutdown_executor
from softgrip_ros.realtime import TimerThread, freeze_start_up_heap

# longest wait for a SIGINT/SIGTERM whose wake the executor missed (see run_node)
SHUTDOWN_POLL_S = 0.5


def stamp_seconds(stamp) -> float:
    """A builtin_interfaces Time as seconds of ROS time (the inverse of :func:`stamp_msg`)."""
    return stamp.sec + 1e-9 * stamp.nanosec


def stamp_msg(seconds: float):
    """A builtin_interfaces Time for ``seconds`` of ROS time, to the nearest nanosecond (so that a
    stamp read back as sec + 1e-9 nanosec and written again is unchanged)."""
    return Time(nanoseconds=round(seconds * 1e9)).to_msg()


# requests to an action's goal, result and cancel services, and their responses, that may wait to
# be taken: rclpy's default keeps 10 and drops the older ones, so that in a storm of 100 goals
# a second some never got an answer
ACTION_QUEUE_DEPTH = 1000


def action_qos() -> dict:
    """Keyword arguments for an rclpy ActionServer or ActionClient: its goal, result and cancel
    services keep ACTION_QUEUE_DEPTH requests (and responses), reliably, as the default does
    10."""
    from rclpy.qos import QoSProfile, qos_profile_services_default as default

    deep = QoSProfile(history=default.history, depth=ACTION_QUEUE_DEPTH,
                      reliability=default.reliability, durability=default.durability)
    return {f"{kind}_service_qos_profile": deep for kind in ("goal", "result", "cancel")}


class _StampOrder:
    """One publisher's last header stamp (ns), and the lock that makes checking it and publishing
    one step: two threads that each decided to publish could otherwise send their messages in
    the other order, and a stream's stamps went back (by up to 133 ms on tip_pose)."""

    def __init__(self):
        self.lock = threading.Lock()
        self.last_ns = -1
        self.dropped = 0


def _stamp_ns(message) -> int | None:
    stamp = getattr(getattr(message, "header", None), "stamp", None)
    return None if stamp is None else int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def publish(node, publisher, message) -> bool:
    """``publisher.publish(message)``, unless the message's header stamp is older than the last
    one this publisher sent: every stamped stream goes forward in time, whichever threads
    publish on it (a message that lost that race is dropped, counted by :func:`dropped_stale`).
    Quietly dropped, too, once SIGINT/SIGTERM has shut ROS down: a callback or CAN thread still
    running then would raise ("publisher's context is invalid"), and no check beforehand can
    close that race. Whether it was published."""
    stamp_ns = _stamp_ns(message)
    order = None
    if stamp_ns is not None:
        order = getattr(publisher, "_softgrip_stamp_order", None)
        if order is None:
            with _ORDERS_LOCK:
                order = getattr(publisher, "_softgrip_stamp_order", None)
                if order is None:
                    order = publisher._softgrip_stamp_order = _StampOrder()
    with order.lock if order is not None else contextlib.nullcontext():
        if order is not None:
            if stamp_ns < order.last_ns:
                order.dropped += 1
                return False
            order.last_ns = stamp_ns
        try:
            publisher.publish(message)
        except RCLError:
            if node.context.ok():
                raise
            return False
    return True


_ORDERS_LOCK = threading.Lock()


def dropped_stale(publisher) -> int:
    """How many messages :func:`publish` dropped on ``publisher`` for a stamp older than one
    already sent."""
    order = getattr(publisher, "_softgrip_stamp_order", None)
    return 0 if order is None else order.dropped


def listened(node, publisher) -> bool:
    """Whether ``publisher`` has a subscriber. The high-rate topics (sensor readings, estimates,
    tip poses) are not built or serialised for nobody: in the composed controller their consumers
    take them by direct call, and a DDS publish holds the GIL for its serialisation and write."""
    try:
        return publisher.get_subscription_count() > 0
    except SHUTDOWN_ERRORS:
        if node.context.ok():
            raise
        return False


class NodeTimers:
    """A node's periodic callbacks: rclpy timers when the node runs on its own; for a node composed
    in one process (``in_process``), one :class:`TimerThread` (``thread``), which the node starts
    once its callbacks are added and stops in its ``close()``."""

    def __init__(self, node, in_process: bool):
        self.node = node
        logger = node.get_logger()
        self.thread = TimerThread(
            f"{node.get_name()}-timers", on_error=lambda name, error: logger.error(
                f"{name} failed: {type(error).__name__}: {error}", throttle_duration_sec=5.0)
        ) if in_process else None

    def every(self, period_s: float, callback) -> None:
        if self.thread is None:
            self.node.create_timer(period_s, callback)
        else:
            self.thread.add(period_s, callback)

    def start(self) -> None:
        if self.thread is not None:
            self.thread.start()

    def stop(self) -> None:
        if self.thread is not None:
            self.thread.stop()


def _try_shutdown() -> None:
    """rclpy.try_shutdown, while rclpy's signal handler may shut the context down at the same
    moment (it raised "rcl_shutdown already called" after a Ctrl-C during start-up)."""
    try:
        rclpy.try_shutdown()
    except Exception:
        if rclpy.ok():
            raise


def run_node(node_factory, args=None, executor_factory=None) -> int:
    """rclpy.init, build the node(s), spin until SIGINT/SIGTERM, then ``close()`` each (the
    pressure controller vents) in reverse order of creation, and exit 0.

    ``node_factory()`` returns a node or a list of nodes (a factory that fails part-way closes
    what it made before raising); ``executor_factory`` (default: a
    SingleThreadedExecutor) spins them. rclpy (Jazzy) handles SIGTERM as it does Ctrl-C, waking
    the executor, so close runs and no traceback is printed. A node that fails to start prints
    its reason and returns 1; a signal during start-up ends it with 0.

    rclpy's signal thread wakes the executor *before* it shuts the context down. An executor that
    wakes, still finds the context valid and waits again is not woken a second time; with no
    timer it would wait forever (seen under load, 1 SIGTERM in a few dozen). So the first node
    carries a do-nothing timer every ``SHUTDOWN_POLL_S``: such a missed shutdown ends within it.
    """
    # rclpy's own handlers turn SIGINT and SIGTERM into a shutdown that wakes spin
    rclpy.init(args=args)
    # kill -USR1 <pid>: where is every thread?
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    try:
        made = node_factory()
    # a bad parameter at start-up: say which, exit 1
    except (ValueError, ParameterException) as error:
        print(f"{sys.argv[0]}: {error}", file=sys.stderr)
        _try_shutdown()
        return 1
    except (KeyboardInterrupt, Exception) as error:
        # SIGINT/SIGTERM during start-up: Ctrl-C raises here, and rclpy shuts the context down
        # under the node being built, which fails on its next use of it
        if not isinstance(error, KeyboardInterrupt) and rclpy.ok():
            raise
        print(f"{sys.argv[0]}: stopped during start-up", file=sys.stderr)
        _try_shutdown()
        return 0
    nodes = made if isinstance(made, list) else [made]
    executor = None
    try:
        nodes[0].create_timer(SHUTDOWN_POLL_S, lambda: None)
        executor = executor_factory() if executor_factory is not None else SingleThreadedExecutor()
        for node in nodes:
            executor.add_node(node)
        freeze_start_up_heap()
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # A signal landing while spin builds its wait set surfaces as RCLError ("context is
        # not valid") instead of ExternalShutdownException: that is the same shutdown.
        if rclpy.ok():
            raise
    finally:
        # the executor first: a callback still running in its pool while its node is destroyed
        # fails ("destruction was requested") in a task whose exception nobody retrieves
        if executor is not None:
            shutdown_executor(executor, timeout_sec=1.0)
        close_all(nodes)
        _try_shutdown()
    return 0


def close_all(nodes) -> None:
    """close() and destroy each node, the last made first."""
    for node in reversed(nodes):
        node.close()
        node.destroy_node()


@contextlib.contextmanager
def closed_if_cut_short(node):
    """The rest of ``node``'s construction, from where it starts what must be stopped (a thread,
    a child, a bus): whatever ends it early, a bad value or a Ctrl-C, closes and destroys the
    node before passing on, as no caller is handed a node to close. ``node.close()`` must take a
    node built part-way."""
    try:
        yield
    except BaseException:
        close_all([node])
        raise


@contextlib.contextmanager
def spinning(*nodes, context=None, threads: int = 4):
    """Spin ``nodes`` in a background thread (a SingleThreadedExecutor for ``threads=1``, whose
    per-callback cost is far lower); stop and join on exit. For tools that drive nodes from their
    own thread: tests, benchmarks, the demo.
    """
    executor = ((SingleThreadedExecutor(context=context)
                 if threads == 1 else MultiThreadedExecutor(num_threads=threads, context=context)))
    for node in nodes:
        executor.add_node(node)
    stop = threading.Event()

    def spin():
        # spin_once until told: shutdown() while spin() waits races with its guard conditions
        # (Jazzy: "'NoneType' object has no attribute 'handle'" when actions are present)
        while not stop.is_set() and executor.context.ok():
            executor.spin_once(timeout_sec=0.05)

    thread = threading.Thread(target=spin, name="softgrip-spin", daemon=True)
    thread.start()
    try:
        yield executor
    finally:
        stop.set()
        thread.join(timeout=5.0)
        shutdown_executor(executor, timeout_sec=2.0)

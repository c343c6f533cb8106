"""Threads for the suite's periodic work, off the rclpy executor.

:class:`PeriodicThread` calls a function at a fixed rate on absolute deadlines: the pressure
controller's control loop and the simulated device's plant. An rclpy timer shares the executor
(and the GIL) with every callback of the process and loses ticks under load; these loops must
not. :class:`TimerThread` runs the composed nodes' slower periodic callbacks.
:func:`freeze_start_up_heap` keeps the garbage collector's full passes from stopping them.
"""
from __future__ import annotations

import collections
import gc
import math
import sys
import threading
import time

# CPython hands the GIL over every 5 ms by default, so a woken loop thread can wait several
# periods behind busy threads; 0.2 ms keeps a 500 Hz loop's period p99 near 2.5 ms.
GIL_SWITCH_INTERVAL_S = 2e-4


def freeze_start_up_heap() -> None:
    """What start-up built (rclpy, the models, the DBC) lives as long as the process: it is
    collected once and frozen out of the garbage collector's full passes, which scanned it all
    and stopped every thread (the composed controller at run time: 92 ms, against the 50 ms
    sensor timeout and the safety trip's 10 ms reaction time; frozen, 1.5 ms)."""
    gc.collect()
    gc.freeze()


def clock_offset_s(clock, other_clock, attempts: int = 4, bracket_s: float = 2e-4) -> float:
    """``other_clock() - clock()`` at one instant: ``other_clock`` read between two reads of
    ``clock``, the narrowest of ``attempts`` brackets kept (one within ``bracket_s`` ends it).
    Two clocks read one after the other are an instant apart only while this thread keeps the
    GIL. A switch between the reads (up to 89 ms in the composed controller on a 2-core host)
    dated a status's output change, or a batch of readings, that much early."""
    width, offset = math.inf, 0.0
    for _ in range(max(1, attempts)):
        before = clock()
        value = other_clock()
        after = clock()
        if after - before < width:
            width, offset = after - before, value - 0.5 * (before + after)
        if width <= bracket_s:
            break
    return offset


class PeriodicThread:
    """Calls ``step()`` at ``rate_hz``, and ``on_output(result)`` after each tick.

    With ``rest_rate_hz`` and ``resting``: after a tick whose result ``resting(result)`` calls
    at rest, the next tick comes at the slower ``rest_rate_hz``; :meth:`wake` (from any thread)
    runs a tick at once and restarts the schedule from there. ``periods_s`` and ``work_s`` keep
    the recent tick-to-tick periods and the time spent in ``step()``. After falling more than
    10 periods behind, the schedule re-anchors rather than bursting to catch up. Exceptions
    from ``on_output`` are counted, never raised.

    With ``receive``, the thread also takes its inputs itself: ``receive()`` runs before each
    tick and, while the ticks are further apart than ``receive_period_s``, every
    ``receive_period_s`` between them; a :meth:`wake` during ``receive()`` runs the tick at
    once. So the inputs and the step that uses them are ordered by one thread, and a wait costs
    one wake instead of one per thread (``receives`` counts the calls).
    """

    def __init__(self, step, rate_hz: float, name: str, on_output=None, history: int = 20000,
                 rest_rate_hz: float | None = None, resting=None, receive=None,
                 receive_period_s: float | None = None):
        if not 1.0 <= rate_hz <= 5000.0:
            raise ValueError(f"rate_hz must lie in [1, 5000], got {rate_hz}")
        if rest_rate_hz is not None and not 1.0 <= rest_rate_hz <= rate_hz:
            raise ValueError(
                f"rest_rate_hz must lie in [1, rate_hz = {rate_hz:g}], got {rest_rate_hz}")
        self.step_function = step
        self.period_s = 1.0 / rate_hz
        self.rest_period_s = self.period_s if rest_rate_hz is None else 1.0 / rest_rate_hz
        self.resting = resting
        self.receive = receive
        self.receive_period_s = self.period_s if receive_period_s is None else receive_period_s
        if not 0.0 < self.receive_period_s <= 1.0:
            raise ValueError(f"receive_period_s must lie in (0, 1] s, got {receive_period_s}")
        self.receives = 0
        self.name = name
        self.on_output = on_output
        self.periods_s = collections.deque(maxlen=history)
        self.work_s = collections.deque(maxlen=history)
        self.ticks = 0
        self.rest_ticks = 0
        self.errors = 0
        self.last_error = ""
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._thread = None

    @property
    def running(self) -> bool:
        return self._thread is not None

    def start(self) -> None:
        if self._thread is not None:
            return
        sys.setswitchinterval(min(sys.getswitchinterval(), GIL_SWITCH_INTERVAL_S))
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def wake(self) -> None:
        """Run a tick now instead of at the next deadline (a command, a reading beyond a limit)."""
        self._wake.set()

    def _run(self) -> None:
        deadline = previous = time.monotonic()
        period = self.period_s
        while not self._stop.is_set():
            deadline += period
            deadline = self._wait_for(deadline, period)
            self._wake.clear()
            if self._stop.is_set():
                return
            if self.receive is not None:
                self._receive()
            now = time.monotonic()
            self.periods_s.append(now - previous)
            previous = now
            output = self.step_function()
            self.work_s.append(time.monotonic() - now)
            self.ticks += 1
            period = self.period_s
            if self.resting is not None and self.resting(output):
                period = self.rest_period_s
                self.rest_ticks += 1
            if self.on_output is not None:
                try:
                    self.on_output(output)
                except Exception as error:  # publishing must never stop the loop
                    self.errors += 1
                    self.last_error = f"{type(error).__name__}: {error}"

    def _wait_for(self, deadline: float, period: float) -> float:
        """Wait until ``deadline`` or a wake, taking the inputs every receive period meanwhile;
        the deadline the tick then keeps (now after a wake, or after falling 10 periods
        behind)."""
        while True:
            delay = deadline - time.monotonic()
            if delay <= 0.0:
                return time.monotonic() if delay < -10 * period else deadline
            # not for a sliver of a period: that input comes with the tick
            receiving = self.receive is not None and delay > 1.5 * self.receive_period_s
            if self._wake.wait(self.receive_period_s if receiving else delay):
                return time.monotonic()
            if receiving:
                self._receive()
                if self._wake.is_set():  # an input that needs the step now
                    return time.monotonic()

    def _receive(self) -> None:
        self.receives += 1
        try:
            self.receive()
        except Exception as error:  # the inputs' own failures are counted by their owner
            self.errors += 1
            self.last_error = f"{type(error).__name__}: {error}"


class TimerThread:
    """Several periodic callbacks on one thread, for nodes composed in one process.

    An rclpy timer costs an executor wake per tick, and each wake rebuilds the wait set over
    every entity of every node (about a millisecond of Python for the composed controller's
    five nodes): the composed nodes' timers at 50, 20 and 10 Hz cost a fifth of a core that
    way. Here a tick costs its callback. A callback that falls behind is not burst to catch
    up; its exceptions go to ``on_error(name, error)`` and never stop the thread.
    """

    def __init__(self, name: str, on_error=None):
        self.name = name
        self.on_error = on_error
        self.errors = 0
        self._timers = []  # [next due (monotonic s), period s, callback]
        self._stop = threading.Event()
        self._thread = None

    def add(self, period_s: float, callback) -> None:
        if not period_s > 0.0:
            raise ValueError(f"period_s must be positive, got {period_s}")
        if self._thread is not None:
            raise RuntimeError("add timers before start()")
        self._timers.append([time.monotonic() + period_s, period_s, callback])

    def start(self) -> None:
        if self._thread is None and self._timers:
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
            self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            if self._thread is not threading.current_thread():
                self._thread.join(timeout=2.0)
            self._thread = None

    def _run(self) -> None:
        while not self._stop.is_set():
            due = min(timer[0] for timer in self._timers)
            delay = due - time.monotonic()
            if delay > 0.0 and self._stop.wait(delay):
                return
            now = time.monotonic()
            for timer in self._timers:
                if timer[0] <= now:
                    timer[0] += timer[1]
                    if timer[0] <= now:  # fell a period behind: skip, do not burst
                        timer[0] = now + timer[1]
                    try:
                        timer[2]()
                    except Exception as error:  # a failing callback must not stop the others
                        self.errors += 1
                        if self.on_error is not None:
                            self.on_error(getattr(timer[2], "__name__", repr(timer[2])), error)

"""CPU-heavy work of the composed controller in a child process of its own.

A few milliseconds to a few hundred of pure-Python CPU in a thread of the controller hold the GIL
that the 500 Hz pressure loop, the CAN threads and an in-process simulated device need: they
stall behind it. :class:`WorkerProcess` runs such work in a spawned child (never forked from a
threaded process) at a raised nice value, which ignores Ctrl-C (the parent ends it) and exits
within PARENT_POLL_S of its parent's death, even a SIGKILL.

This module imports nothing heavy, nor may a ``setup`` function's module at its top: the child
imports that module to unpickle ``setup``, before it starts watching its parent.
"""
from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import threading
import time
from concurrent.futures import Future, ProcessPoolExecutor

# The workers' matrices are small: OpenBLAS's worker threads gain nothing on them and spin
# between calls (see docs/benchmarks.md). A setting of the user's own is kept.
WORKER_PROCESS_ENVIRONMENT = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
# At the default nice value the scheduler shares a core evenly between the worker and the pressure
# loop, the CAN reception and the estimator, which wait behind it. Raised by 10, the child yields
# to them.
WORKER_NICE_INCREMENT = 10
PARENT_POLL_S = 0.2  # a child checks this often that its parent lives

_STATE = {}  # in the child: what its setup returned


@contextlib.contextmanager
def _sigint_blocked_for_children():
    """SIGINT blocked in this thread while it spawns a child, so that the child is born with it
    blocked (a signal mask survives fork and exec) and never sees a Ctrl-C before its initializer
    ignores it: Ctrl-C in a terminal reaches the whole process group, the child too, even while it
    is still importing. Blocked, not ignored: a Ctrl-C meanwhile stays pending for this process
    and is delivered as the block ends (another thread may take it even sooner)."""
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


@contextlib.contextmanager
def _environment_defaults(values: dict):
    """os.environ with ``values`` where unset, for a child started inside; restored after."""
    added = [name for name in values if name not in os.environ]
    os.environ.update({name: values[name] for name in added})
    try:
        yield
    finally:
        for name in added:
            os.environ.pop(name, None)


class WorkerProcess:
    """One spawned child that runs ``setup(*setup_args)`` once (its result: :func:`worker_state`
    there), then the functions given to :meth:`submit`, in turn. ``nice_increment`` (0..19):
    how far above this process's nice value it runs; ValueError outside. :meth:`close` it."""

    def __init__(self, setup, setup_args: tuple = (),
                 nice_increment: int = WORKER_NICE_INCREMENT, name: str = "softgrip-worker"):
        check_nice_increment(nice_increment)
        self._executor = ProcessPoolExecutor(
            1, mp_context=multiprocessing.get_context("spawn"), initializer=_start_worker,
            initargs=(os.getpid(), nice_increment, setup, tuple(setup_args)))
        spawned = threading.Event()
        self._children = []

        def spawn():
            try:
                with _environment_defaults(WORKER_PROCESS_ENVIRONMENT), \
                        _sigint_blocked_for_children():
                    # start the child now (its imports take about a second), not at first use
                    self._executor.submit(os.getpid)
                # the child as a Process, which close ends by its PID: its first result comes
                # only after its imports, which a loaded host and the nice value can stretch past
                # a stop's timeout
                self._children = list(getattr(self._executor, "_processes", {}).values())
            except RuntimeError:  # the interpreter is exiting (Ctrl-C): no child
                pass
            finally:
                spawned.set()

        # Spawned from a thread of its own: Python raises KeyboardInterrupt only in the main
        # thread, and one raised there between the child's spawn and the write of its start-up
        # data left the child to die on EOFError with a traceback (Ctrl-C during start-up, CI).
        # Not a daemon, so that an exit waits for it; and waited for on an Event, not by join: a
        # Ctrl-C during Thread.join marks a running thread stopped (CPython 3.11, bpo-45274's
        # fix), and the exit then no longer waits for it.
        threading.Thread(target=spawn, name=f"{name}-spawn").start()
        spawned.wait()

    def submit(self, function, *args) -> Future:
        """``function(*args)`` in the child (both picklable); RuntimeError once closed."""
        return self._executor.submit(function, *args)

    def close(self) -> None:
        """End the child now, work in it or not: niced work on a loaded host can take seconds,
        and waiting for it held a SIGTERM'd controller past its stop timeout. A future not yet
        done fails with BrokenProcessPool."""
        for child in self._children:
            if child.is_alive():  # still this process's child: its PID is not another's
                child.terminate()
        # the executor's manager thread sees its child gone, reaps it and ends; this joins it
        self._executor.shutdown(wait=True, cancel_futures=True)


def check_nice_increment(nice_increment: int) -> None:
    """ValueError unless ``nice_increment`` lies in 0..19 (os.nice's useful range)."""
    if not 0 <= nice_increment <= 19:
        raise ValueError(f"nice_increment must lie in [0, 19], got {nice_increment}")


def worker_state():
    """In the child: what its ``setup`` returned."""
    return _STATE["value"]


def _exit_with_parent(parent_pid: int) -> None:
    """End this process once its parent is gone (killed, even by SIGKILL: the child is then
    re-parented and ``getppid`` changes; the parent's PID comes from the parent itself, since it
    may be gone before this runs). A child that outlives the controller would hold a core's worth
    of work and a Python interpreter for nothing."""
    while os.getppid() == parent_pid:
        time.sleep(PARENT_POLL_S)
    os._exit(0)


def _start_worker(parent_pid: int, nice_increment: int, setup, setup_args: tuple) -> None:
    # Ctrl-C in a terminal reaches the whole process group: the parent decides when this child
    # ends (close()), and a KeyboardInterrupt here would only print a traceback. Born with SIGINT
    # blocked (see _sigint_blocked_for_children): ignored from here on, then unblocked.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    threading.Thread(target=_exit_with_parent, args=(parent_pid,),
                     name="softgrip-worker-parent-watch", daemon=True).start()
    if nice_increment:
        os.nice(nice_increment)
    _STATE["value"] = setup(*setup_args)  # the heavy imports, once watched

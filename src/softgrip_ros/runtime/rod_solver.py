"""The L2 rod solver in a child process of its own, and the thread that feeds it the latest
request.

This module imports nothing heavy at its top: the child imports it first, to run
:func:`_start_rod_worker`, which starts the parent watch before the model's imports (about a
second of numpy and scipy).
"""
from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import threading
import time
from concurrent.futures import ProcessPoolExecutor

# The solver's matrices are small: OpenBLAS's worker threads gain nothing on them and spin between
# calls, which in the controller's child took 40 % of a core during grasps (solves 26 -> 8.5 ms of
# CPU each with one thread; bench_e2e). A setting of the user's own is kept.
SOLVER_PROCESS_ENVIRONMENT = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
# A solve holds a core for ~8.5 ms; at the default nice value the scheduler shares that core
# evenly with the pressure loop, the CAN reception and the estimator, which wait behind it. Raised
# by 10, the child yields to them (bench_e2e: the sensor-to-pose p99 lower in each of 4
# comparisons, by 0.05-0.7 ms; see docs/benchmarks.md).
SOLVER_PROCESS_NICE_INCREMENT = 10


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


class RodSolverProcess:
    """L2 solves in a child process of their own. A solve is milliseconds of pure-Python CPU; in a
    thread of the composed controller it holds the GIL that the 500 Hz pressure loop and the CAN
    threads need, and they stall behind it (the demo's clamp overshot past the vacuum limit in 3
    of 14 runs that way, 0 of 14 before L2 ran there). Call it as SceneModel's ``rod_solver``;
    :meth:`close` it when done. The child is spawned (never forked from a threaded process) and
    runs ``nice_increment`` (0..19) above this process's nice value: the solves are a refinement
    that must not delay the control path. The child ignores Ctrl-C (the parent ends it) and exits
    within PARENT_POLL_S of its parent's death, even a SIGKILL: this module imports nothing heavy
    until the child has started watching.

    continuation_steps: the load steps of each solve (SceneModel's ROD_CONTINUATION_STEPS)."""

    def __init__(self, gripper_model: str = "type_II",
                 nice_increment: int = SOLVER_PROCESS_NICE_INCREMENT, continuation_steps: int = 4):
        if not 0 <= nice_increment <= 19:
            raise ValueError(f"nice_increment must lie in [0, 19], got {nice_increment}")
        self._executor = ProcessPoolExecutor(
            1, mp_context=multiprocessing.get_context("spawn"), initializer=_start_rod_worker,
            initargs=(gripper_model, nice_increment, os.getpid(), continuation_steps))
        spawned = threading.Event()
        self._children = []

        def spawn():
            try:
                with _environment_defaults(SOLVER_PROCESS_ENVIRONMENT), \
                        _sigint_blocked_for_children():
                    # start the child now (about a second), not at the first solve
                    self._executor.submit(os.getpid)
                # the child as a Process, which close ends by its PID: the submit spawned it, but
                # its first result comes only after its imports, which a loaded host and the nice
                # value stretch past a stop's timeout (CI: a SIGTERM 8 s after start-up waited
                # for them, and the controller was killed)
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
        threading.Thread(target=spawn, name="softgrip-l2-spawn").start()
        spawned.wait()

    def __call__(self, pressure_pa: float, obstacle, from_pressure_pa: float):
        return self._executor.submit(_solve_in_rod_worker, pressure_pa, obstacle,
                                     from_pressure_pa).result()

    def close(self) -> None:
        """End the child now, a solve in it or not: a niced solve on a loaded host can take
        seconds, and waiting for it held a SIGTERM'd controller past its stop timeout. A caller
        waiting in :meth:`__call__` gets BrokenProcessPool."""
        for child in self._children:
            if child.is_alive():  # still this process's child: its PID is not another's
                child.terminate()
        # the executor's manager thread sees its child gone, reaps it and ends; this joins it
        self._executor.shutdown(wait=True, cancel_futures=True)


class LatestSolveThread:
    """:meth:`~softgrip_ros.model.fidelity.SceneModel.solve_rod` on a thread of its own, for a
    caller that cannot wait milliseconds (the kinematics node answers each estimate at once, with
    the last solve). :meth:`request` replaces a request not yet started: the latest pressure is the
    one worth solving. A failed solve goes to ``on_error(pressure_pa, error)`` and the thread goes
    on."""

    def __init__(self, model, on_error=None, name: str = "softgrip-l2"):
        self.model, self.on_error = model, on_error
        self._wanted = threading.Condition()
        self._request = None  # (pressure, scene, stamp)
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def request(self, pressure_pa: float, scene, stamp_s: float | None = None) -> None:
        with self._wanted:
            self._request = (pressure_pa, scene, stamp_s)
            self._wanted.notify()

    def stop(self) -> None:
        """No solve after the running one; a failure from now on is not reported (closing the
        solver process fails the running one)."""
        with self._wanted:
            self._closed = True
            self._wanted.notify_all()

    def close(self) -> None:
        self.stop()
        self._thread.join(timeout=2.0)

    def _run(self) -> None:
        while True:
            with self._wanted:
                while self._request is None and not self._closed:
                    self._wanted.wait()
                if self._closed:
                    return
                (pressure, scene, stamp_s), self._request = self._request, None
            try:
                self.model.solve_rod(pressure, scene, stamp_s)
            except Exception as error:  # noqa: BLE001 - a failed solve must not end the thread
                if self.on_error is not None and not self._closed:
                    self.on_error(pressure, error)


_WORKER = {}  # the child's rod and continuation steps (set by _start_rod_worker)
PARENT_POLL_S = 0.2  # the L2 child checks this often that its parent lives


def _exit_with_parent(parent_pid: int) -> None:
    """End this process once its parent is gone (killed, even by SIGKILL: the child is then
    re-parented and ``getppid`` changes; the parent's PID comes from the parent itself, since it
    may be gone before this runs). A child that outlives the controller would hold a core's worth
    of solver and a Python interpreter for nothing."""
    while os.getppid() == parent_pid:
        time.sleep(PARENT_POLL_S)
    os._exit(0)


def _start_rod_worker(gripper_model: str, nice_increment: int, parent_pid: int,
                      continuation_steps: int) -> None:
    # Ctrl-C in a terminal reaches the whole process group: the parent decides when this child
    # ends (close()), and a KeyboardInterrupt here would only print a traceback. Born with SIGINT
    # blocked (see _sigint_blocked_for_children): ignored from here on, then unblocked.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    threading.Thread(target=_exit_with_parent, args=(parent_pid,), name="softgrip-l2-parent-watch",
                     daemon=True).start()
    if nice_increment:
        os.nice(nice_increment)
    # the heavy imports, once watched
    from softgrip_ros.model.calibration import build_kinematics
    from softgrip_ros.model.rod import RodFinger
    l1 = build_kinematics("l1", gripper_model)
    _WORKER.update(rod=RodFinger(l1.geometry, l1.calibration), steps=continuation_steps)


def _solve_in_rod_worker(pressure_pa, obstacle, from_pressure_pa):
    return _WORKER["rod"].solve(pressure_pa, obstacle=obstacle, from_pressure_pa=from_pressure_pa,
                                steps=_WORKER["steps"])

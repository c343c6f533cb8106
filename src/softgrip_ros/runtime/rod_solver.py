"""The L2 rod solver in a child process of its own, and the thread that feeds it the latest
request.

This module imports nothing heavy at its top: the child imports it to unpickle its setup, before
it watches its parent; the model's imports (about a second of numpy and scipy) come after.
"""
from __future__ import annotations

import threading

from softgrip_ros.runtime.worker_process import (WORKER_NICE_INCREMENT, WorkerProcess,
                                                 check_nice_increment, worker_state)


class RodSolverProcess:
    """L2 solves in a child process of their own (:class:`WorkerProcess`), spawned at the first
    solve: with ``fidelity`` auto most scenes never need L2, and the child's interpreter and model
    are a second of CPU and tens of MB for nothing then. A solve is milliseconds of pure-Python
    CPU; in a thread of the composed controller it holds the GIL that the 500 Hz pressure loop
    and the CAN threads need, and they stall behind it. Call it as SceneModel's ``rod_solver``
    (from a thread that may wait for the spawn: :class:`LatestSolveThread`); :meth:`close` it
    when done. ``nice_increment``: see WorkerProcess (ValueError outside 0..19).

    continuation_steps: the load steps of each solve (SceneModel's ROD_CONTINUATION_STEPS)."""

    def __init__(self, gripper_model: str = "type_II",
                 nice_increment: int = WORKER_NICE_INCREMENT, continuation_steps: int = 4):
        check_nice_increment(nice_increment)
        self._setup_args = (gripper_model, continuation_steps)
        self._nice_increment = nice_increment
        self._lock = threading.Lock()
        self._worker: WorkerProcess | None = None
        self._closed = False

    def worker(self) -> WorkerProcess:
        """The child, spawned now if it is not yet; RuntimeError once closed."""
        with self._lock:
            if self._closed:
                raise RuntimeError("the L2 solver process is closed")
            if self._worker is None:
                self._worker = WorkerProcess(_setup_rod, self._setup_args, self._nice_increment,
                                             "softgrip-l2")
            return self._worker

    @property
    def started(self) -> bool:
        """Whether the child has been spawned (and not closed)."""
        return self._worker is not None and not self._closed

    def __call__(self, pressure_pa: float, obstacle, from_pressure_pa: float):
        return self.worker().submit(_solve_in_rod_worker, pressure_pa, obstacle,
                                    from_pressure_pa).result()

    def close(self) -> None:
        """End the child now, a solve in it or not; a caller waiting in :meth:`__call__` gets
        BrokenProcessPool, and a later one RuntimeError."""
        with self._lock:
            self._closed = True
            worker = self._worker
        if worker is not None:
            worker.close()


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


def _setup_rod(gripper_model: str, continuation_steps: int) -> dict:
    from softgrip_ros.model.calibration import build_kinematics
    from softgrip_ros.model.rod import RodFinger
    l1 = build_kinematics("l1", gripper_model)
    return {"rod": RodFinger(l1.geometry, l1.calibration), "steps": continuation_steps}


def _solve_in_rod_worker(pressure_pa, obstacle, from_pressure_pa):
    state = worker_state()
    return state["rod"].solve(pressure_pa, obstacle=obstacle, from_pressure_pa=from_pressure_pa,
                              steps=state["steps"])

"""A bus's reception thread that hands the frames over in batches (no ROS).

python-can's ``Notifier`` calls its listeners once per frame, so each frame costs a thread
wake. On the build VMs a wake costs 45-80 us of CPU before any work, and the first Python
code after it runs several times slower than warm (docs/benchmarks.md, bench_e2e): at the
simulated device's ~700 frames a second that alone was a tenth of a core. :class:`BatchReader`
takes every frame already queued at each wake, and while its owner says nothing needs them at
once (``resting()``) it waits ``rest_period_s`` between batches, so a quiet stream costs one
wake per period. A thread that has other periodic work (the control loop) can take the frames
itself instead: :meth:`BatchReader.stop` the reader's thread and call
:meth:`BatchReader.take_queued` at each of its own wakes.
"""
from __future__ import annotations

import threading


class BatchReader:
    """Reads ``bus`` on its own thread; ``on_frames(frames)`` gets the frames in arrival order,
    up to ``max_batch`` per call: the one that woke the thread and every one queued behind it.

    After a batch, while ``resting()`` is true, the thread waits ``rest_period_s`` (or until
    :meth:`wake`) before reading again; the frames meanwhile queue in the bus. Exceptions from
    the bus or from ``on_frames`` are counted (``errors``, ``last_error``) and reading goes on
    after ``timeout_s``: a failing read must neither end reception nor spin. The thread starts
    with the reader; :meth:`stop` and :meth:`start` hand reception to another thread and back.
    """

    def __init__(self, bus, on_frames, rest_period_s: float = 0.0, resting=None,
                 name: str = "softgrip-can-rx", timeout_s: float = 0.05, max_batch: int = 256):
        if not 0.0 <= rest_period_s <= 1.0:
            raise ValueError(f"rest_period_s must lie in [0, 1] s, got {rest_period_s}")
        if max_batch < 1:
            raise ValueError(f"max_batch must be at least 1, got {max_batch}")
        self.bus, self.on_frames = bus, on_frames
        self.rest_period_s, self.resting = rest_period_s, resting
        self.timeout_s, self.max_batch = timeout_s, max_batch
        self.batches = self.frames = self.errors = 0
        self.last_error = ""
        self.name = name
        self._stop, self._wake = threading.Event(), threading.Event()
        self._thread = None
        self.start()

    @property
    def running(self) -> bool:
        """Whether the reader's own thread reads the bus."""
        return self._thread is not None

    def start(self) -> None:
        """Read on the reader's own thread (again, after :meth:`stop`)."""
        if self._thread is not None:
            return
        self._stop = threading.Event()  # each thread its own: one that outlives a join must end
        self._thread = threading.Thread(target=self._run, args=(self._stop,), name=self.name,
                                        daemon=True)
        self._thread.start()

    def wake(self) -> None:
        """End a rest wait now (a command: its readings matter from here on)."""
        self._wake.set()

    def stop(self, timeout_s: float = 1.0) -> None:
        """End the reader's thread; the frames queue in the bus until :meth:`take_queued` or
        :meth:`start`."""
        thread, self._thread = self._thread, None
        self._stop.set()
        self._wake.set()
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=timeout_s)

    def take_queued(self) -> int:
        """Hand every frame queued now to ``on_frames`` in the calling thread, ``max_batch`` at
        most per call, without waiting for one; how many. For a caller that reads instead of
        the reader's thread (stopped): errors are counted as the thread counts them."""
        taken = 0
        while True:
            try:
                frames = self._read_batch(0.0)
                if not frames:
                    return taken
                self.batches += 1
                self.frames += len(frames)
                taken += len(frames)
                self.on_frames(frames)
            except Exception as error:  # a closed or failing bus, a consumer's bug
                self.errors += 1
                self.last_error = f"{type(error).__name__}: {error}"
                return taken
            if len(frames) < self.max_batch:
                return taken

    def _read_batch(self, timeout_s: float) -> list:
        frame = self.bus.recv(timeout_s)
        if frame is None:
            return []
        frames = [frame]
        while len(frames) < self.max_batch:
            frame = self.bus.recv(0.0)
            if frame is None:
                break
            frames.append(frame)
        return frames

    def _run(self, stop: threading.Event) -> None:
        while not stop.is_set():
            self._wake.clear()  # a wake ends the wait after a batch taken from here on
            try:
                frames = self._read_batch(self.timeout_s)
                if frames:
                    self.batches += 1
                    self.frames += len(frames)
                    self.on_frames(frames)
            except Exception as error:  # a closed or failing bus, a consumer's bug
                if stop.is_set():
                    return
                self.errors += 1
                self.last_error = f"{type(error).__name__}: {error}"
                stop.wait(self.timeout_s)
                continue
            if self.rest_period_s > 0.0 and self.resting is not None and self.resting():
                self._wake.wait(self.rest_period_s)

"""Helpers for tests that run nodes: a background executor, waiting on conditions, unique names."""
import contextlib
import threading
import time
import uuid

from rclpy.executors import MultiThreadedExecutor


def unique(prefix: str) -> str:
    return f"{prefix}-{uuid.uuid4().hex[:8]}"


@contextlib.contextmanager
def spinning(context, *nodes, threads: int = 4):
    """Spin ``nodes`` on a MultiThreadedExecutor in a background thread; stop and join afterwards."""
    executor = MultiThreadedExecutor(num_threads=threads, context=context)
    for node in nodes:
        executor.add_node(node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        yield executor
    finally:
        executor.shutdown(timeout_sec=2.0)
        thread.join(timeout=5.0)
        pool = getattr(executor, "_executor", None)   # Jazzy's shutdown() leaves its thread pool running
        if pool is not None:
            pool.shutdown(wait=True)


def wait_for(condition, timeout: float = 10.0, period: float = 0.01, message: str = "condition"):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(period)
    raise AssertionError(f"timed out after {timeout} s waiting for {message}")

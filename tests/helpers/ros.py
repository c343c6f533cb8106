"""Helpers for tests that run nodes: a background executor, waiting on conditions, unique names."""
import time
import uuid


def unique(prefix: str) -> str:
    return f"{prefix}-{uuid.uuid4().hex[:8]}"


def spinning(context, *nodes, threads: int = 4):
    """The package's background spinner, on a test's own context."""
    from softgrip_ros.nodes.common import spinning as spin_in_background
    return spin_in_background(*nodes, context=context, threads=threads)


def wait_for(condition, timeout: float = 10.0, period: float = 0.01, message: str = "condition"):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(period)
    raise AssertionError(f"timed out after {timeout} s waiting for {message}")

"""The three places where softgrip relies on rclpy's private API, each for a reason that
public Jazzy rclpy (7.1.x) leaves no other way around. ``tests/test_rclpy_compat.py`` checks
every assumption against the pinned rclpy, so an upgrade that changes one fails there first.

- :data:`RCLError`: what ``publish`` and ``get_subscription_count`` raise once SIGINT/SIGTERM
  has shut the context down under a running callback or CAN thread. rclpy exports no public
  name for it (``rclpy.exceptions`` re-exports ``InvalidHandle`` only).
- ``MultiThreadedExecutor._executor``: its ``ThreadPoolExecutor``. ``Executor.shutdown()``
  does not shut that pool down, so its worker threads outlive the executor (a test or a node's
  exit would then wait on them at interpreter exit, or leak them between tests).
- ``MultiThreadedExecutor._futures``: the tasks it has started. A callback cut short by the
  shutdown fails on a destroyed handle; its task's error is never retrieved, and asyncio-style
  "exception never retrieved" noise follows. :func:`shutdown_executor` reads them.
"""
from __future__ import annotations

import sys

from rclpy._rclpy_pybind11 import RCLError  # noqa: F401  (re-exported: see the module docstring)
from rclpy.exceptions import InvalidHandle

#: the errors a handle raises once the shutdown has destroyed it, or its context
SHUTDOWN_ERRORS = (InvalidHandle, RCLError)


def shutdown_executor(executor, timeout_sec: float) -> None:
    """``executor.shutdown(timeout_sec)``, then its thread pool (if it has one) shut down and
    joined, then the errors of callbacks the shutdown cut short read: a shutdown error is
    expected there and dropped, any other is printed to stderr."""
    executor.shutdown(timeout_sec=timeout_sec)
    pool = getattr(executor, "_executor", None)
    if pool is not None:
        pool.shutdown(wait=True)
    read_errors_of_unfinished_callbacks(executor)


def read_errors_of_unfinished_callbacks(executor) -> None:
    """Retrieve each finished task's error from ``executor._futures`` (a SingleThreadedExecutor
    has none); report the ones that are not shutdown errors."""
    for future in list(getattr(executor, "_futures", [])):
        error = future.exception() if future.done() else None
        if error is not None and not isinstance(error, SHUTDOWN_ERRORS):
            print(
                f"{sys.argv[0]}: a callback failed during shutdown: "
                f"{type(error).__name__}: {error}", file=sys.stderr)

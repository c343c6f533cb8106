"""Helpers for tests that run nodes: a background executor, waiting on conditions, unique names."""
import time
import uuid


def unique(prefix: str) -> str:
    return f"{prefix}-{uuid.uuid4().hex[:8]}"


def spinning(context, *nodes, threads: int = 4):
    """The package's background spinner, on a test's own context."""
    from softgrip_ros.nodes.common import spinning as spin_in_background
    return spin_in_background(*nodes, context=context, threads=threads)


def wait_for(condition, timeout: float = 10.0, period: float = 0.01, message: str = "condition",
             detail=None):
    """Poll ``condition`` until it is truthy; on timeout fail, naming ``message`` and, when given,
    what ``detail()`` says of the state then (the controller's status message, say)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(period)
    seen = f" ({detail()})" if detail is not None else ""
    raise AssertionError(f"timed out after {timeout} s waiting for {message}{seen}")


def send_future_command(node, publisher, statuses, target_pa: float, source: int, ahead_s: float,
                        timeout: float = 10.0):
    """Publish a PressureCommand stamped ``ahead_s`` beyond ``node``'s clock; the first
    controller/status in ``statuses`` (a list a subscription fills) that flags it refused."""
    import math

    from softgrip_interfaces.msg import ControllerStatus, PressureCommand
    from softgrip_ros.nodes.common import stamp_msg
    ahead = PressureCommand(target_gauge_pressure_pa=target_pa, max_rate_pa_per_s=math.nan,
                            source=source)
    ahead.header.stamp = stamp_msg(node.get_clock().now().nanoseconds * 1e-9 + ahead_s)
    publisher.publish(ahead)
    rejected = ControllerStatus.FAULT_COMMAND_REJECTED
    return wait_for(lambda: next((s for s in reversed(statuses) if s.fault_flags & rejected),
                                 None), timeout=timeout, message="the command's refusal")

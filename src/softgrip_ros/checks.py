"""Checks the cores and nodes share (no ROS)."""
from __future__ import annotations

import math


def require_positive(owner, *names: str) -> None:
    """Raise ValueError naming the first of ``owner``'s fields ``names`` that is not positive and
    finite."""
    for name in names:
        value = getattr(owner, name)
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(
                f"{type(owner).__name__}.{name} must be positive and finite, got {value}")


def future_stamp_reason(stamp_s: float, now_s: float, tolerance_s: float) -> str:
    """'' for a stamp no further ahead of ``now_s`` than ``tolerance_s`` (or unstamped: 0), else
    why it is refused. A stamp far ahead would make a receiver that orders or predicts by stamps
    wait for it, or step the filter that far: no message may do that."""
    if stamp_s and stamp_s - now_s > tolerance_s:
        return (f"stamped {stamp_s - now_s:.3g} s in the future (tolerance {tolerance_s:g} s): "
                "refused")
    return ""

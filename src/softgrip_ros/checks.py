"""Checks the configuration dataclasses share (no ROS)."""
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

"""A configuration field's one source: its default, meaning, unit and range.

The cores' dataclasses (safety, pressure control, estimator, grasp state machine, force law)
declare their user-settable fields with :func:`setting`. Everything else follows from those
declarations: the dataclass's own check (:func:`check_settings`, from ``__post_init__``), the ROS
parameter that sets the field (``nodes.specs``, through ``nodes.parameters.field_spec``), its
descriptor, and its line in config/softgrip.yaml (``nodes.params_file``). ROS-free.
"""
from __future__ import annotations

import dataclasses
import math

SETTING_KEY = "softgrip_setting"


@dataclasses.dataclass(frozen=True)
class Setting:
    """What a field means, its unit, and the values it accepts: [low, high] for a number (both or
    neither), ``choices`` for a value from a list."""

    description: str
    unit: str = ""
    low: float | None = None
    high: float | None = None
    choices: tuple = ()

    def __post_init__(self):
        if (self.low is None) != (self.high is None):
            raise ValueError("a setting's range needs both ends or neither")
        if self.low is not None and not self.low <= self.high:
            raise ValueError(f"a setting's range [{self.low}, {self.high}] is empty")


def setting(default, description: str, unit: str = "", low: float | None = None,
            high: float | None = None, choices: tuple = ()):
    """A dataclass field with its :class:`Setting` in its metadata."""
    return dataclasses.field(
        default=default,
        metadata={SETTING_KEY: Setting(description, unit, low, high, tuple(choices))})


def setting_of(cls, field_name: str) -> tuple:
    """(default, Setting) of ``cls``'s field ``field_name``; KeyError when it has no setting."""
    for field in dataclasses.fields(cls):
        if field.name == field_name:
            return field.default, field.metadata[SETTING_KEY]
    raise KeyError(f"{cls.__name__} has no field {field_name!r}")


def value_problem(name: str, value, unit: str = "", low=None, high=None, choices=(),
                  allow_empty: bool = True) -> str:
    """'' when ``value`` is acceptable, else why not, naming ``name``: a float must be finite, a
    value with ``choices`` one of them, a number within [low, high], a string not empty unless
    ``allow_empty``. The one rule behind both the ROS parameters' and the dataclasses' checks."""
    if isinstance(value, float) and not math.isfinite(value):
        return f"{name} must be finite, got {value}"
    if choices and value not in choices:
        return f"{name} must be one of {list(choices)}, got {value!r}"
    if low is not None and isinstance(value, (int, float)) and not isinstance(value, bool):
        if not low <= value <= high:
            return f"{name} must lie in [{low}, {high}]{' ' + unit if unit else ''}, got {value}"
    if isinstance(value, str) and not value and not allow_empty:
        return f"{name} must not be empty"
    return ""


def check_settings(config) -> None:
    """ValueError naming the first field of the dataclass ``config`` whose value its setting
    refuses."""
    for field in dataclasses.fields(config):
        spec = field.metadata.get(SETTING_KEY)
        if spec is None:
            continue
        problem = value_problem(f"{type(config).__name__}.{field.name}",
                                getattr(config, field.name), spec.unit, spec.low, spec.high,
                                spec.choices)
        if problem:
            raise ValueError(problem)

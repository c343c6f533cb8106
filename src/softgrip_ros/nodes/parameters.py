"""Declaring node parameters with a description, a range and a unit, and checking them on set."""
from __future__ import annotations

import dataclasses

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)

from softgrip_ros.settings import setting_of, value_problem


@dataclasses.dataclass(frozen=True)
class ParamSpec:
    """One parameter: its default, what it means, its unit and its allowed range or choices."""

    name: str
    default: object
    description: str
    unit: str = ""
    low: float | None = None
    high: float | None = None
    choices: tuple = ()
    read_only: bool = False
    allow_empty: bool = False  # for strings: '' is a meaningful value (e.g. "no fault")
    # the core's configuration field it sets ("safety.x": a nested one)
    field: str = ""

    def descriptor(self) -> ParameterDescriptor:
        text = self.description + (f" [{self.unit}]" if self.unit else "")
        if self.choices:
            text += f" (one of: {', '.join(map(str, self.choices))})"
        descriptor = ParameterDescriptor(description=text, read_only=self.read_only)
        if self.low is not None and isinstance(self.default, float):
            descriptor.floating_point_range = [
                FloatingPointRange(from_value=float(self.low), to_value=float(self.high))
            ]
        elif self.low is not None and isinstance(self.default,
                                                 int) and not isinstance(self.default, bool):
            descriptor.integer_range = [
                IntegerRange(from_value=int(self.low), to_value=int(self.high))
            ]
        return descriptor

    def check(self, value) -> str:
        """'' when ``value`` is acceptable, else the reason."""
        return value_problem(self.name, value, self.unit, self.low, self.high, self.choices,
                             self.allow_empty)


def field_spec(name: str, config_class, field: str, default=None) -> ParamSpec:
    """The parameter ``name`` that sets ``field`` ("a.b": field b of the nested dataclass a) of
    ``config_class``: its meaning, unit, range and choices are the field's
    :func:`softgrip_ros.settings.setting`, and so is its default unless ``default`` is given (a
    node whose default differs from the library's, said where it is given)."""
    owner = config_class
    head, _, rest = field.partition(".")
    if rest:
        owner = type(getattr(config_class(), head))
    field_default, setting = setting_of(owner, rest or head)
    return ParamSpec(name, field_default if default is None else default, setting.description,
                     setting.unit, setting.low, setting.high, setting.choices, field=field)


def declare(node, specs) -> dict:
    """Declare every spec on ``node``; return {name: value} after overrides (--params-file, -p).

    A value given at start-up that fails its check raises ValueError naming it."""
    values = {}
    for spec in specs:
        values[spec.name] = node.declare_parameter(spec.name, spec.default,
                                                   spec.descriptor()).value
        problem = spec.check(values[spec.name])
        if problem:
            raise ValueError(f"parameter {problem}")
    return values


def replace_fields(config, specs, values: dict):
    """``config`` (a frozen dataclass) with the field of each spec that names one set to its value
    in ``values``; a field "a.b" sets b of the nested dataclass a. The dataclass's own checks
    (``__post_init__``) raise ValueError for a bad combination."""
    changes, nested = {}, {}
    for spec in specs:
        if spec.field:
            head, _, rest = spec.field.partition(".")
            if rest:
                nested.setdefault(head, {})[rest] = values[spec.name]
            else:
                changes[head] = values[spec.name]
    for head, fields in nested.items():
        changes[head] = dataclasses.replace(getattr(config, head), **fields)
    return dataclasses.replace(config, **changes)


def check_all(specs_by_name: dict, parameters, extra_check=None) -> SetParametersResult:
    """An on-set callback body: every parameter must pass its spec (and ``extra_check``)."""
    for parameter in parameters:
        spec = specs_by_name.get(parameter.name)
        if spec is not None:
            problem = spec.check(parameter.value)
            if problem:
                return SetParametersResult(successful=False, reason=problem)
    if extra_check is not None:
        problem = extra_check(parameters)
        if problem:
            return SetParametersResult(successful=False, reason=problem)
    return SetParametersResult(successful=True)


# The CAN bus parameters every node that opens a bus declares.
CAN_SPECS = [
    ParamSpec("can.interface", "virtual",
              "python-can interface (virtual, softgrip_ipc, socketcan, pcan, ...)"),
    ParamSpec("can.channel", "softgrip", "python-can channel (e.g. can0)"),
    ParamSpec("can.bitrate", 500_000, "CAN bit rate (ignored by virtual and softgrip_ipc)",
              "bit/s", 10_000, 1_000_000),
]

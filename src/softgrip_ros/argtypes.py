"""Command-line values with their ranges, for argparse's ``type=`` (no ROS).

Every numeric option of the tools is one of these, so that a value out of its range (or not a
number, or NaN) is a usage error at parsing: the tool's name, the option and the range on one
line, exit 2, before anything is opened, started or written. tests/test_tool_arguments.py
checks every tool's parser for it.
"""
from __future__ import annotations

import argparse
import dataclasses
import math


@dataclasses.dataclass(frozen=True)
class Number:
    """A number from ``low`` to ``high`` (either end excluded when ``low_open``/``high_open``),
    in ``unit``; an integer when ``integer``. NaN is never one; an infinite end is accepted only
    when it is a closed end of the range (e.g. a time budget of ``inf`` for none)."""

    low: float
    high: float
    unit: str = ""
    integer: bool = False
    low_open: bool = False
    high_open: bool = False

    def __post_init__(self):
        if not self.low <= self.high:
            raise ValueError(f"an empty range: [{self.low}, {self.high}]")

    def __call__(self, text: str):
        try:
            value = int(text, 0) if self.integer else float(text)
        except (TypeError, ValueError):
            kind = "an integer" if self.integer else "a number"
            raise argparse.ArgumentTypeError(f"{text!r} is not {kind}") from None
        if not self.contains(value):
            raise argparse.ArgumentTypeError(f"must lie in {self.describe()}, got {text}")
        return value

    def contains(self, value) -> bool:
        if math.isnan(value):
            return False
        above = value > self.low if self.low_open else value >= self.low
        below = value < self.high if self.high_open else value <= self.high
        return above and below

    def describe(self) -> str:
        def end(value):
            return f"{int(value)}" if self.integer and math.isfinite(value) else f"{value:g}"
        return (f"{'(' if self.low_open else '['}{end(self.low)}, {end(self.high)}"
                f"{')' if self.high_open else ']'}" + (f" {self.unit}" if self.unit else ""))


@dataclasses.dataclass(frozen=True)
class Assignment:
    """``NAME=VALUE``, the value a :class:`Number`: parsed to (name, value)."""

    value: Number

    def __call__(self, text: str):
        name, sep, raw = text.partition("=")
        if not sep or not name:
            raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
        try:
            return name, self.value(raw)
        except argparse.ArgumentTypeError as error:
            raise argparse.ArgumentTypeError(f"{name}: {error}") from None

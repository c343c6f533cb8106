"""Every numeric option of every tool, at random (hypothesis): a value in its declared range is
taken as given; NaN, an infinity, a value outside the range or text that is no number is a usage
error at parsing (exit 2, the last line naming the option and its range), before the tool opens,
starts or writes anything (#52). And no numeric option goes unranged."""
import argparse
import contextlib
import importlib
import io
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from softgrip_ros.argtypes import Assignment, Number

pytestmark = pytest.mark.cpu  # computation only: scripts/test.sh runs it beside another

TOOLS = {
    "softgrip": "softgrip_ros.cli",
    "softgrip_identify": "softgrip_ros.tools.identify",
    "softgrip_calibrate": "softgrip_ros.tools.calibrate",
    "softgrip_check_device": "softgrip_ros.tools.check_device",
    "softgrip_record": "softgrip_ros.tools.record",
    "softgrip_replay": "softgrip_ros.tools.replay",
}
EXAMPLES = settings(max_examples=20, deadline=None)


def _parsers(parser, path=()):
    """(the subcommand path, the parser) of ``parser`` and of each of its subcommands."""
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, path + (name,))


def _options():
    """(tool, subcommand path, the option's action) of every option that takes a value."""
    for tool, module in TOOLS.items():
        for path, parser in _parsers(importlib.import_module(module).parser()):
            for action in parser._actions:
                if action.option_strings and action.nargs != 0 and not isinstance(
                        action, (argparse._HelpAction, argparse._SubParsersAction)):
                    yield tool, path, action


OPTIONS = list(_options())
RANGED = [(tool, path, action) for tool, path, action in OPTIONS
          if isinstance(action.type, (Number, Assignment))]


def _inside(number: Number):
    """A strategy of values inside ``number``'s range."""
    if number.integer:
        return st.integers(int(number.low) + number.low_open,
                           int(number.high) - number.high_open)
    high = number.high if math.isfinite(number.high) else max(number.low, 0.0) + 1e6
    return st.floats(number.low, high, exclude_min=number.low_open,
                     exclude_max=number.high_open and math.isfinite(number.high))


def _outside(number: Number):
    """A strategy of texts that are not a value of ``number``."""
    below = [number.low] if number.low_open else []
    below += [number.low - max(1.0, abs(number.low)), -1e300] if math.isfinite(number.low) else []
    above = [number.high] if number.high_open else []
    above += [number.high + max(1.0, abs(number.high)), 1e300] if math.isfinite(
        number.high) else []
    hostile = [v for v in below + above + [math.nan, -math.inf, math.inf]
               if not number.contains(v)]
    texts = [repr(float(v)) if not number.integer or not math.isfinite(v) else str(int(v))
             for v in hostile]
    texts += ["", "12 mm", "1,5", "0x", "nan%"]
    if number.integer:
        texts += ["1.5", "1e3"]
    return st.sampled_from(texts)


def _parse(tool, path, argv):
    """(exit code or None, the parsed namespace or None, stderr) of ``tool`` parsing
    ``path`` + ``argv`` with the other required arguments given valid values."""
    parser = importlib.import_module(TOOLS[tool]).parser()
    full = list(path) + _required(parser, path) + list(argv)
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            return None, parser.parse_args(full), err.getvalue()
    except SystemExit as stop:
        return stop.code, None, err.getvalue()


def _required(parser, path) -> list:
    """Valid values for the positionals and required options of the subcommand at ``path``."""
    for name in path:
        parser = next(a for a in parser._actions
                      if isinstance(a, argparse._SubParsersAction)).choices[name]
    argv = []
    for action in parser._actions:
        if not action.option_strings and not isinstance(action, argparse._SubParsersAction) \
                and action.dest != "help":
            argv.append("x")
        elif action.required:
            argv += [action.option_strings[0], _valid_text(action.type)]
    return argv


def _valid_text(kind) -> str:
    if isinstance(kind, Assignment):
        return "PressureSensor1=" + _valid_text(kind.value)
    if isinstance(kind, Number):
        high = kind.high if math.isfinite(kind.high) else kind.low + 2.0
        middle = 0.5 * (kind.low + high)
        return str(int(middle)) if kind.integer else repr(middle)
    return "n"


def test_every_numeric_option_has_a_range():
    """No option is a bare int or float: each says its range (softgrip_ros.argtypes)."""
    bare = [f"{tool} {' '.join(path)} {action.option_strings[0]}"
            for tool, path, action in OPTIONS if action.type in (int, float)]
    assert not bare, bare
    assert len(RANGED) >= 25


@pytest.mark.parametrize("tool, path, action", RANGED,
                         ids=[f"{t}-{'-'.join(p)}{a.option_strings[0]}" for t, p, a in RANGED])
def test_a_value_out_of_range_is_a_usage_error_naming_the_option(tool, path, action):
    number = action.type.value if isinstance(action.type, Assignment) else action.type

    @EXAMPLES
    @given(text=_outside(number))
    def refused(text):
        value = f"PressureSensor1={text}" if isinstance(action.type, Assignment) else text
        code, _, stderr = _parse(tool, path, [f"{action.option_strings[0]}={value}"])
        assert code == 2, (value, stderr)
        last = stderr.strip().splitlines()[-1]
        assert last.startswith(tool) and f"argument {'/'.join(action.option_strings)}" in last
        assert "Traceback" not in stderr

    @EXAMPLES
    @given(value=_inside(number))
    def taken(value):
        text = str(value) if number.integer else repr(float(value))
        text = f"PressureSensor1={text}" if isinstance(action.type, Assignment) else text
        code, parsed, stderr = _parse(tool, path, [f"{action.option_strings[0]}={text}"])
        assert code is None, (text, stderr)
        got = getattr(parsed, action.dest)
        got = got[-1] if isinstance(got, list) else got
        got = got[1] if isinstance(action.type, Assignment) else got
        assert got == value

    refused()
    taken()

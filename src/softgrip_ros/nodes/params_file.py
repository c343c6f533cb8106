"""config/softgrip.yaml, written from the parameters' one source.

Each node's specs (nodes/specs.py, whose core fields take their meaning, unit and range from the
dataclasses' settings: softgrip_ros.settings) give every line: the default, then the range, unit
and meaning as a comment. ``python -m softgrip_ros.nodes.params_file`` prints the file,
``--write PATH`` replaces PATH with it, ``--check PATH`` exits 1 when PATH differs from it.
"""
from __future__ import annotations

import argparse
import pathlib
import sys

import yaml

HEADER = """\
# softgrip_ros parameters (a ROS 2 params file). Every parameter of every node, with its
# default, [range], unit and meaning. Pressures are gauge unless a name says otherwise.
# Use: ros2 run softgrip_ros <node> --ros-args --params-file config/softgrip.yaml
# Written by `python -m softgrip_ros.nodes.params_file --write config/softgrip.yaml` from the
# nodes' parameter specs; tests/test_parameters_file.py checks that it is current. Copy it to
# change values. The keys /**/<node> match each node in any namespace.
"""

# a comment above the first parameter of a group
GROUP_COMMENTS = {
    "can.frame_ids.": "arbitration ID per DBC message; 0 = the ID in config/softgrip.dbc",
    "safety.": "single-fault safety (softgrip_ros.control.safety): any finding vents with the "
               "regulator disabled",
    "fault.": "faults, settable at runtime: ros2 param set /sim_device fault.sensor_dropout "
              "chamber_a",
    "world.": "the physics world (MuJoCo): the fingers and an object; its ground truth on sim/*",
}


def node_specs() -> list:
    """[(node name, [ParamSpec])] in the file's order."""
    from softgrip_ros.canbus.codec import FrameCodec
    from softgrip_ros.nodes import sim_device
    from softgrip_ros.nodes.specs import (ESTIMATOR_SPECS, GRASP_MANAGER_SPECS, KINEMATICS_SPECS,
                                          PRESSURE_CONTROLLER_SPECS, frame_id_specs)

    frame_ids = frame_id_specs(FrameCodec().message_names)
    pressure = list(PRESSURE_CONTROLLER_SPECS)
    after_can = max(i for i, s in enumerate(pressure) if s.name.startswith("can.")) + 1
    pressure[after_can:after_can] = frame_ids
    return [("pressure_controller", pressure), ("sim_device", list(sim_device.SPECS)),
            ("estimator", list(ESTIMATOR_SPECS)), ("kinematics", list(KINEMATICS_SPECS)),
            ("grasp_manager", list(GRASP_MANAGER_SPECS))]


def _value(value) -> str:
    text = yaml.safe_dump(value, default_flow_style=True, width=1000).strip()
    return text[:-len("\n...")].strip() if text.endswith("...") else text


def _number(value) -> str:
    return f"{value:g}"


def comment(spec) -> str:
    """The line's comment: [low, high] unit, the meaning, and the choices."""
    parts = []
    if spec.low is not None:
        parts.append(f"[{_number(spec.low)}, {_number(spec.high)}]"
                     + (f" {spec.unit}" if spec.unit else ""))
    elif spec.unit:
        parts.append(spec.unit)
    text = ", ".join(parts + [spec.description])
    if spec.choices:
        text += f" (one of: {' | '.join(map(str, spec.choices))})"
    return text


def render() -> str:
    """The whole file."""
    lines = [HEADER]
    for node, specs in node_specs():
        lines += [f"/**/{node}:", "  ros__parameters:"]
        started = set()
        width = max(len(s.name) + len(_value(s.default)) for s in specs) + 2
        for spec in specs:
            group = next((g for g in GROUP_COMMENTS if spec.name.startswith(g)), None)
            if group is not None and group not in started:
                started.add(group)
                lines.append(f"    # {GROUP_COMMENTS[group]}")
            entry = f"{spec.name}: {_value(spec.default)}"
            lines.append(f"    {entry.ljust(width)}  # {comment(spec)}")
        lines.append("")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m softgrip_ros.nodes.params_file",
        description="Print config/softgrip.yaml as the parameter specs make it, write it, or "
        "check a file against it.")
    action = parser.add_mutually_exclusive_group()
    action.add_argument("--write", type=pathlib.Path, metavar="PATH", help="replace PATH")
    action.add_argument("--check", type=pathlib.Path, metavar="PATH",
                        help="exit 1 when PATH differs")
    args = parser.parse_args(argv)
    text = render()
    if args.check is not None:
        try:
            current = args.check.read_text()
        except OSError as error:
            print(f"params_file: cannot read {args.check}: {error.strerror}", file=sys.stderr)
            return 1
        if current != text:
            print(f"params_file: {args.check} is not what the specs make; run "
                  f"python -m softgrip_ros.nodes.params_file --write {args.check}",
                  file=sys.stderr)
            return 1
        return 0
    if args.write is not None:
        from softgrip_ros.fileio import write_text_atomically

        try:
            write_text_atomically(args.write, text)
        except OSError as error:
            print(f"params_file: cannot write {args.write}: {error.strerror}", file=sys.stderr)
            return 1
        return 0
    sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""softgrip: drive a running gripper from the command line (no ros2 CLI needed).

    softgrip grasp --diameter 0.04 --mass 0.02       # open around it; ENVELOPED, then:
    softgrip clamp                                    # ... clamp it: HOLDING
    softgrip release
    softgrip state --watch
    softgrip open --spacing 0.05 --namespace /g1

Each task prints the phases as they come and ends with the result; the exit status is 0 when
the task succeeded, 1 when it was refused, failed (a clamp that closed on nothing, too) or
timed out, 3 when no gripper answered. Each line shows what the air says of the object, and
the result whether it is held: yes, no, or unknown (without object sensing, always unknown).
``grasp`` ends once the fingers are open around the object (ENVELOPED), unless
``--clamp-after S`` clamps S seconds later and waits for HOLDING.
"""
from __future__ import annotations

import argparse
import sys
import time

from softgrip_ros.argtypes import Number
from softgrip_ros.client import add_namespace_argument

PHASES = ("IDLE", "OPENING", "ENVELOPED", "CLAMPING", "HOLDING", "RELEASING", "FAULT")
OBJECT_STATUSES = ("unknown", "moving, no contact", "contact opening", "contact closing",
                   "held", "no object", "lost")


# the ranges of the options (softgrip_ros.argtypes): physical sanity, the grasp manager judges
# the rest against its limits and says why
TIMEOUT_S = Number(0.0, 3600.0, "s", low_open=True)
SIZE_M = Number(0.0, 0.5, "m")
MASS_KG = Number(0.0, 100.0, "kg")
FRICTION = Number(0.0, 10.0, low_open=True)
PRESSURE_PA = Number(-1e6, 1e6, "Pa")
DELAY_S = Number(0.0, 3600.0, "s")


def parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    add_namespace_argument(common)
    common.add_argument("--timeout", type=TIMEOUT_S, default=15.0,
                        help="seconds to wait for the gripper and for the task (default 15)")
    top = argparse.ArgumentParser(prog="softgrip", description=__doc__,
                                  formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = top.add_subparsers(dest="command", required=True)
    grasp = commands.add_parser("grasp", parents=[common],
                                help="envelop an object (ENVELOP_CLAMP), then clamp")
    grasp.add_argument("--diameter", type=SIZE_M, required=True, help="object size, m")
    grasp.add_argument("--mass", type=MASS_KG, required=True, help="object mass, kg")
    grasp.add_argument("--friction", type=FRICTION, help="friction coefficient (default: the "
                       "grasp manager's)")
    grasp.add_argument("--open-pressure", type=PRESSURE_PA, help="opening pressure override, Pa")
    grasp.add_argument("--clamp-pressure", type=PRESSURE_PA, help="clamp pressure override, Pa")
    grasp.add_argument("--clamp-after", type=DELAY_S, metavar="S",
                       help="clamp S seconds after ENVELOPED and wait for HOLDING")
    pinch = commands.add_parser("pinch", parents=[common], help="close the tips on a thin object")
    pinch.add_argument("--diameter", type=SIZE_M, required=True, help="object size, m")
    pinch.add_argument("--mass", type=MASS_KG, required=True, help="object mass, kg")
    opening = commands.add_parser("open", parents=[common], help="open and hold")
    opening.add_argument("--spacing", type=SIZE_M, help="tip spacing D2, m (default: "
                         "fully open)")
    clamp = commands.add_parser("clamp", parents=[common],
                                help="clamp what the gripper holds open")
    clamp.add_argument("--diameter", type=SIZE_M, help="object size, m (after open)")
    clamp.add_argument("--mass", type=MASS_KG, help="object mass, kg (after open)")
    clamp.add_argument("--clamp-pressure", type=PRESSURE_PA, help="clamp pressure override, Pa")
    commands.add_parser("release", parents=[common], help="vent, then open to let go")
    commands.add_parser("stop", parents=[common], help="vent now")
    state = commands.add_parser("state", parents=[common], help="print grasp_state")
    state.add_argument("--watch", action="store_true", help="keep printing it on every change")
    return top


def describe(state) -> str:
    phase = PHASES[state.phase] if state.phase < len(PHASES) else str(state.phase)
    sensed = (OBJECT_STATUSES[state.object_status] if state.object_status < len(OBJECT_STATUSES)
              else str(state.object_status))
    if state.object_size_m == state.object_size_m and state.object_size_m > 0.0:  # not NaN
        sensed += f" ({state.object_size_m * 1e3:.0f} mm)"
    return (f"{phase:9s} {state.estimated_gauge_pressure_pa / 1e3:6.1f} kPa  D2 "
            f"{state.tip_spacing_m * 1e3:5.1f} mm  force {state.clamp_force_n:5.2f} N  "
            f"object: {sensed}  {state.message}")


def _overrides(args) -> dict:
    names = {"friction": "friction_coefficient", "open_pressure": "open_pressure_pa",
             "clamp_pressure": "clamp_pressure_pa", "diameter": "object_diameter_m",
             "mass": "object_mass_kg"}
    return {field: getattr(args, name) for name, field in names.items()
            if getattr(args, name, None) is not None}


def _follow(client, until, timeout_s: float) -> bool:
    """Print each phase as it comes until ``until(state)`` or the task ends; whether ``until``
    was met (or, without one, whether the task succeeded)."""
    from action_msgs.msg import GoalStatus
    from softgrip_interfaces.msg import GripperState
    deadline, last = time.monotonic() + timeout_s, None
    while time.monotonic() < deadline:
        state = client.feedback() or client.state()
        if state is not None and (state.phase, state.message, state.object_status) != last:
            last = (state.phase, state.message, state.object_status)
            print(describe(state), flush=True)
        if until is not None and state is not None and until(state):
            return True
        if client.is_task_complete():
            result = client.result()
            if result is None:
                print("refused: the grasp manager did not accept the goal", file=sys.stderr)
                return False
            phase = PHASES[result.final_phase] if result.final_phase < len(PHASES) else "?"
            # object_held false is "not sensed held": the status tells unknown from no
            unknown = last is None or last[2] == GripperState.OBJECT_UNKNOWN
            held = "yes" if result.object_held else ("unknown" if unknown else "no")
            print(f"result: {phase}, {result.final_gauge_pressure_pa / 1e3:.1f} kPa: "
                  f"{result.message}; object held: {held}")
            return until is None and client.status() == GoalStatus.STATUS_SUCCEEDED
        time.sleep(0.02)
    print(f"timed out after {timeout_s:g} s", file=sys.stderr)
    return False


def run(args, client) -> int:
    if args.command == "state":
        state = client.state()
        print(describe(state))
        last = state
        while args.watch:
            time.sleep(0.05)
            state = client.state()
            if (state.phase, state.message, state.object_status) != (
                    last.phase, last.message, last.object_status):
                print(describe(state), flush=True)
                last = state
        return 0
    fields = _overrides(args)
    if args.command == "grasp":
        client.envelop_clamp(args.diameter, args.mass, **{
            k: v for k, v in fields.items() if k not in ("object_diameter_m", "object_mass_kg")})
        if not _follow(client, lambda s: s.phase == s.ENVELOPED, args.timeout):
            return 1
        if args.clamp_after is None:
            print("enveloped: place the object, then `softgrip clamp`")
            return 0
        time.sleep(args.clamp_after)
        client.clamp()
        return 0 if _follow(client, None, args.timeout) else 1
    start = {
        "pinch": lambda: client.pinch(args.diameter, args.mass),
        "open": lambda: client.open(args.spacing),
        "clamp": lambda: client.clamp(**fields),
        "release": client.release,
        "stop": client.stop,
    }[args.command]
    start()
    return 0 if _follow(client, None, args.timeout) else 1


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    import rclpy

    from softgrip_ros.client import GripperClient
    rclpy.init()
    client = GripperClient(namespace=args.namespace, node_name="softgrip_cli")
    try:
        # a grasp, a pinch, an open or a clamp needs the pressure; a vent, or reading the state,
        # must not wait for it
        if not client.wait_until_ready(args.timeout, sensing=args.command in (
                "grasp", "pinch", "open", "clamp")):
            print(f"softgrip: no gripper answered in {args.timeout:g} s on "
                  f"{client.action_name!r} (is the controller running, in this namespace and "
                  "ROS_DOMAIN_ID?)", file=sys.stderr)
            return 3
        return run(args, client)
    except KeyboardInterrupt:
        return 130
    finally:
        client.close()
        rclpy.try_shutdown()


if __name__ == "__main__":
    raise SystemExit(main())

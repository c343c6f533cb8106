#!/usr/bin/env python3
"""The single-fault matrix (#20): every simulated fault in every grasp phase, on the composed suite
over DDS, judged on the simulated device's true chamber pressure; then fault-free grasps for
false alarms. The device runs in a process of its own on a softgrip_ipc bus, as a real device
has its own processor.

For each (fault, phase) it reports whether the true pressure stayed within [min - margin,
max + margin], how long after the injection the fault's named evidence appeared, whether the
gripper ended in the fault's documented state, and whether a new grasp worked once the fault
was cleared (softgrip_ros.devtools.fault_matrix says how each case runs). Then ``--grasps``
fault-free grasps, counting every diagnostic at WARN or above and every safety flag.

Keys of --json: ``limit_violations`` (must be 0), ``false_alarms_fault_free`` (must be 0 over
``fault_free_grasps``), ``undetected``, ``wrong_end_state``, ``not_recovered``, ``cases``,
``detection_s`` ({fault: {median, max}}), ``true_range_pa``, ``failures`` (the failed cases),
``retried`` (what ran once more, and why).
--quick runs each fault once (its phase rotating through the six) and 2 fault-free grasps.
Writes its section of docs/benchmarks.md unless --json or --quick; exits 1 when a case fails.
Reproduce: source scripts/env.sh; python scripts/bench_faults.py
"""
import os
import sys
import time

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("ROS_DOMAIN_ID", str(60 + os.getpid() % 40))  # not the default domain 0

import rclpy

from softgrip_ros.devtools.benchmarking import (benchmark_parser, host_load, machine_line,
                                                strict_json, update_section)
from softgrip_ros.devtools.fault_matrix import (FAULTS, FAULTS_BY_NAME, PHASES, Rig,
                                                fault_free_grasps, run_case, summarise)


def cases(args) -> list:
    faults = [FAULTS_BY_NAME[name] for name in args.faults] if args.faults else list(FAULTS)
    phases = args.phases or list(PHASES)
    if args.quick:
        return [(fault, phases[i % len(phases)]) for i, fault in enumerate(faults)]
    return [(fault, phase) for fault in faults for phase in phases]


def markdown(results, summary, fault_free, grasps, retried, seconds, command) -> str:
    lines = [
        f"Reproduce: `{command}` ({machine_line()}; {seconds / 60:.1f} min).", "",
        "Each fault injected in each grasp phase of an ENVELOP_CLAMP 40 mm grasp on the composed "
        "suite over DDS "
        "(`softgrip_ros/devtools/fault_matrix.py`). *True* pressures are the simulated device's "
        "plant, every "
        "plant step, not what a sensor said; the limits are [-65, 55] kPa (min - margin, max + "
        "margin). "
        "Detection: from the injection to the first status flag or diagnostic that names the "
        "fault; a fault that "
        "shows only once the pressure moves is named once the grasp moves it.", "",
        "| key | value | target |", "|---|---|---|",
        f"| `limit_violations` | {summary['limit_violations']} of {summary['cases']} | 0 |",
        f"| `false_alarms_fault_free` | {fault_free.warnings} over {grasps} grasps | 0 |",
        f"| `undetected` | {summary['undetected']} | 0 |",
        f"| `not_run` (the grasp could not reach the phase; no fault injected) | "
        f"{summary['not_run']} | 0 |",
        f"| `wrong_end_state` | {summary['wrong_end_state']} | 0 |",
        f"| `not_recovered` | {summary['not_recovered']} | 0 |",
        f"| true pressure range | {summary['true_range_pa'][0] / 1e3:.1f} to "
        f"{summary['true_range_pa'][1] / 1e3:.1f} kPa"
        f" | within [-65, 55] |", "",
        "Detection latency per fault (s, over its phases), and the evidence that named it in its "
        "first case:", "", "| fault | what | median | max | end state | evidence (first case) |",
        "|---|---|---|---|---|---|"
    ]
    for fault in FAULTS:
        mine = [r for r in results if r.fault == fault.name]
        if not mine:
            continue
        latency = summary["detection_s"].get(fault.name)
        evidence = next((r.evidence for r in mine if r.evidence), "").replace("|", "/")
        lines.append(
            f"| `{fault.name}` | {fault.what} | {latency['median']:.3f} | {latency['max']:.3f} | "
            f"{fault.end} | "
            f"{evidence[:110]} |"
            if latency else f"| `{fault.name}` | {fault.what} | - | - | {fault.end} | "
            f"**not detected** |")
    lines += [
        "",
        "Every case (true low / high kPa, detection s; PASS needs the limits, the evidence, the "
        "end state and "
        "the recovery grasp):", "", "| fault | " + " | ".join(PHASES) + " |",
        "|---|" + "---|" * len(PHASES)
    ]
    for fault in FAULTS:
        row = []
        for phase in PHASES:
            r = next((r for r in results if r.fault == fault.name and r.phase == phase), None)
            row.append("" if r is
                       None else f"{'PASS' if r.passed else '**FAIL**'} {r.true_low_pa / 1e3:.0f}/"
                       f"{r.true_high_pa / 1e3:.0f}, {r.detection_s:.2f}")
        if any(row):
            lines.append(f"| `{fault.name}` | " + " | ".join(row) + " |")
    failures = [r for r in results if not r.passed]
    if failures:
        lines += (["", "Failed cases:", ""] +
                  [f"- `{r.fault}` in {r.phase}: {r.problem or r.end_state}" for r in failures])
    if fault_free.texts:
        lines += ["", "Fault-free warnings:", ""] + [f"- {w}" for w in fault_free.texts[:20]]
    if retried:
        lines += ["", "Run once more (`--retries`), the first run's problem:", ""] + [
            f"- {r['fault']} {r['phase']}: {r['problem']}" for r in retried]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = benchmark_parser(__doc__, "each fault once, phases rotating; 2 fault-free grasps",
                              load=True)
    parser.add_argument("--faults", nargs="+", choices=sorted(FAULTS_BY_NAME),
                        help="only these faults")
    parser.add_argument("--phases", nargs="+", choices=PHASES, help="only these phases")
    parser.add_argument("--grasps", type=int, default=None,
                        help="fault-free grasps (default 20; --quick 2)")
    parser.add_argument(
        "--retries", type=int, default=0,
        help="run a failed case again this many times when the true pressure stayed within the "
        "limits (a limit violation is never run again), and the fault-free grasps when they "
        "warned while the control loop was held up past the valves' lifetime (a host stall); "
        "each retry is reported (default 0)")
    args = parser.parse_args(argv)
    grasps = args.grasps if args.grasps is not None else (2 if args.quick else 20)
    if grasps < 0 or args.retries < 0:
        parser.error("--grasps and --retries must be >= 0")
    todo = cases(args)
    started = time.monotonic()
    results, retried = [], []
    rclpy.init()
    try:
        with host_load(args.load), Rig() as rig:
            for index, (fault, phase) in enumerate(todo, 1):
                result = run_case(rig, fault, phase)
                for _ in range(args.retries):
                    if result.passed or (result.injected and not result.within_limits):
                        break  # a limit violation is never run again
                    retried.append({"fault": fault.name, "phase": phase,
                                    "problem": result.problem or result.end_state})
                    print(f"[{index}/{len(todo)}] {fault.name} {phase}: failed "
                          f"({result.problem or result.end_state}); once more",
                          file=sys.stderr, flush=True)
                    result = run_case(rig, fault, phase)
                results.append(result)
                print(
                    f"[{index}/{len(todo)}] {fault.name:24s} {phase:9s} "
                    f"{'PASS' if result.passed else 'FAIL'}  true "
                    f"{result.true_low_pa / 1e3:6.1f} .. {result.true_high_pa / 1e3:5.1f} kPa, "
                    "named after "
                    f"{result.detection_s:.3f} s  {result.problem}", file=sys.stderr, flush=True)
            print(f"fault-free: {grasps} grasps ...", file=sys.stderr, flush=True)
            fault_free, fault_free_retried = fault_free_grasps(
                rig, grasps, args.retries,
                on_retry=lambda: print(f"fault-free: warned while the control loop was held up; "
                                       f"{grasps} grasps once more ...", file=sys.stderr,
                                       flush=True))
            retried += fault_free_retried
    finally:
        rclpy.try_shutdown()
    seconds = time.monotonic() - started
    summary = summarise(results)
    figures = {
        **summary, "case_list": [[r.fault, r.phase] for r in results],
        "false_alarms_fault_free": fault_free.warnings, "fault_free_grasps": grasps,
        "fault_free_warnings": fault_free.texts[:20],
        "fault_free_valve_lapses": fault_free.valve_lapses,
        "seconds": round(seconds, 1), "retried": retried, "load_processes": args.load,
        "failures": [{
            "fault": r.fault, "phase": r.phase, "problem": r.problem or r.end_state,
            "within_limits": r.within_limits, "detected": r.detected,
            "end_state_ok": r.end_state_ok, "recovered": r.recovered
        } for r in results if not r.passed]
    }
    if args.json:
        print(strict_json(figures))
    else:
        text = markdown(results, summary, fault_free, grasps, retried, seconds,
                        "python scripts/bench_faults.py" + (" --quick" if args.quick else ""))
        print(text)
        if not (args.quick or args.faults or args.phases or args.load):
            update_section("bench_faults", "## Single-fault matrix (bench_faults)\n\n" + text)
    failed = figures["failures"] or fault_free.warnings
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

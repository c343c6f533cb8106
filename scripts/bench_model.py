#!/usr/bin/env python3
"""Benchmark the physics core: L0 single and batched, L1 single, and the inverse D2 -> p.

Writes its section of docs/benchmarks.md; --json prints the figures instead of a table.
Reproduce: scripts/env.sh sourced, then  python scripts/bench_model.py
"""
import sys

import numpy as np

from softgrip_ros.devtools.benchmarking import (benchmark_parser, machine_line, median_seconds,
                                                update_section, verdict, strict_json)
from softgrip_ros.model.calibration import build_kinematics

TARGETS_US = {
    "l0_single_us": 20.0, "l0_batch_us_per_pressure": 0.2, "l1_single_us": 200.0,
    "inverse_us": 200.0
}
BATCH = 100_000
NOTES = (
    "How the L0 batch gets there (it read 0.29-0.38 us before these changes, on the same "
    "machine):\n\n"
    "- Page faults were a third of the time: the results, as separate arrays and then "
    "concatenated from the "
    "chunks, landed in fresh memory, ~4,600 minor faults per 100k call at ~2.6 us each on this "
    "VM. The "
    "float results are now rows of one block of 11 x N, which numpy backs with huge pages (4 MB "
    "or more): "
    "no faults after the first call (getrusage).\n"
    "- A pose needs sin, cos and sinc of 7 half-angles (5 segments, 2 measured chamber faces). "
    "numpy's "
    "float64 sin costs ~9 ns per element here; for half-angles within 1 rad (segments bent by "
    "less than "
    "2 rad, checked per chunk) an in-place Horner polynomial for sinc (to x^16, truncation below "
    "1e-17) "
    "does it in ~3 ns, and gives sin = x sinc x with no division and no special case at 0; "
    "cos = sqrt(1 - sin^2). Larger bends use np.sin and np.cos.\n"
    "- The saturation evaluates p - w log1p(exp((p - p_sat)/w)) (np.exp is vectorised) instead of "
    "np.logaddexp, ~4x cheaper; a knee so narrow that exp would overflow falls back to "
    "logaddexp.\n"
    "- The chamber faces' z coordinates, which no output uses, are no longer computed.\n\n"
    "Results are equal to the scalar path to 1e-12 relative (tests in "
    "tests/test_model_kinematics.py). "
    "Five runs of `--json` in a row on 2026-11-22 gave 0.13-0.19 us for the batch: this VM is "
    "noisy, "
    "and the figure is a median of 15 calls within one run.")


def measure(repeat: int) -> dict:
    l0, l1 = build_kinematics("l0"), build_kinematics("l1")
    rng = np.random.default_rng(0)
    singles = rng.uniform(0.0, 50e3, 256).tolist()
    targets = [l0.pose(p).tip_spacing_m for p in rng.uniform(1e3, 49e3, 64)]
    batch = rng.uniform(l0.contact_pressure_pa, 50e3, BATCH)
    cycle = {"i": 0}

    def next_of(values):
        cycle["i"] = (cycle["i"] + 1) % len(values)
        return values[cycle["i"]]

    return {
        "l0_single_us": 1e6 * median_seconds(lambda: l0.pose(next_of(singles)), 2000, repeat),
        "l0_batch_us_per_pressure": 1e6 * median_seconds(lambda: l0.poses(batch), 3, repeat) /
        BATCH,
        "l1_single_us": 1e6 * median_seconds(lambda: l1.pose(next_of(singles)), 300, repeat),
        "l1_batch_us_per_pressure": 1e6 *
        median_seconds(lambda: l1.poses(batch[:10_000]), 1, repeat) / 10_000,
        "inverse_us": 1e6 *
        median_seconds(lambda: l0.pressure_for_tip_spacing(next_of(targets)), 300, repeat),
    }


def main(argv=None) -> int:
    parser = benchmark_parser(__doc__, "3 timed runs per figure; writes nothing", 15)
    args = parser.parse_args(argv)
    if args.quick:
        args.repeat = 3
    figures = measure(args.repeat)
    if args.json or args.quick:
        print(strict_json(figures))
        return 0
    rows = ["| key | what | median | target | |", "|---|---|---|---|---|"]
    what = {
        "l0_single_us": "L0 full state (both tips, alpha, D1, D2), one pressure",
        "l0_batch_us_per_pressure":
            f"L0 full state batched over {BATCH:,} pressures, per pressure",
        "l1_single_us": "L1 full state, one pressure (5 Brent solves)",
        "l1_batch_us_per_pressure": "L1 batched (bracketed Newton), per pressure",
        "inverse_us": "inverse D2 -> p (Brent on L0)"
    }
    for key, value in figures.items():
        target = TARGETS_US.get(key)
        rows.append(
            f"| `{key}` | {what[key]} | {value:.3g} us | "
            f"{'<= %g us' % target if target else 'reported'} | "
            f"{verdict(value, target) if target else ''} |"
        )
    update_section(
        "bench_model", "## Physics core (`scripts/bench_model.py`)\n\n"
        f"Command: `python scripts/bench_model.py` ({machine_line()}, median of {args.repeat} "
        "runs)\n\n"
        + "\n".join(rows) + "\n\n" + NOTES)
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())

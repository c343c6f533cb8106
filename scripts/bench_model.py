#!/usr/bin/env python3
"""Benchmark the physics core: L0 single and batched, L1 single, and the inverse D2 -> p.

Writes its section of docs/benchmarks.md; --json prints the figures instead of a table.
Reproduce: scripts/env.sh sourced, then  python scripts/bench_model.py
"""
import argparse
import json
import sys

import numpy as np

from softgrip_ros.benchmarking import machine_line, median_seconds, repeat_count, update_section, verdict
from softgrip_ros.model.calibration import build_kinematics

TARGETS_US = {"l0_single_us": 20.0, "l0_batch_us_per_pressure": 0.2, "l1_single_us": 200.0, "inverse_us": 200.0}
BATCH = 100_000
NOTES = ("Where the L0 batch stands: a pose needs 7 float64 sines (5 segments, 2 measured chamber faces; the "
         "cosines come from sqrt(1 - sin^2)), and numpy's float64 sin costs about 10 ns per element here, so "
         "trigonometry alone is ~0.07 us; the rest is ~200 elementwise operations in 8192-element chunks "
         "(whole 100k arrays run about 2x slower, out of cache) and the saturation's logaddexp.\n\n"
         "A third of the figure is the kernel, not numpy: one 100k call takes ~3,300 minor page faults (its outputs "
         "and the chunks' temporaries land in fresh memory, which glibc hands back to the system between chunks) "
         "and 8-11 ms of system time, ~2.6 us a fault on this VM (getrusage, strace -c). With the allocator told "
         "to keep freed memory (MALLOC_TOP_PAD_=100000000) the same call makes no faults and ran at 0.23 us per "
         "pressure against 0.35 us without, in one run on a loaded machine. Arithmetic in place (out= buffers) "
         "saved only another ~8 %, and writing chunks into preallocated outputs nothing. Not adopted: a "
         "process-wide allocator setting is not a library's to make, and going clearly below 0.2 us would "
         "need a compiled kernel (numba or C), which the core avoids as a dependency.")


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
        "l0_batch_us_per_pressure": 1e6 * median_seconds(lambda: l0.poses(batch), 3, repeat) / BATCH,
        "l1_single_us": 1e6 * median_seconds(lambda: l1.pose(next_of(singles)), 300, repeat),
        "l1_batch_us_per_pressure": 1e6 * median_seconds(lambda: l1.poses(batch[:10_000]), 1, repeat) / 10_000,
        "inverse_us": 1e6 * median_seconds(lambda: l0.pressure_for_tip_spacing(next_of(targets)), 300, repeat),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", action="store_true", help="print the figures as JSON, write nothing")
    parser.add_argument("--repeat", type=repeat_count, default=15, help="timed runs per figure (median)")
    args = parser.parse_args(argv)
    figures = measure(args.repeat)
    if args.json:
        print(json.dumps(figures, indent=2))
        return 0
    rows = ["| key | what | median | target | |", "|---|---|---|---|---|"]
    what = {"l0_single_us": "L0 full state (both tips, alpha, D1, D2), one pressure",
            "l0_batch_us_per_pressure": f"L0 full state batched over {BATCH:,} pressures, per pressure",
            "l1_single_us": "L1 full state, one pressure (5 Brent solves)",
            "l1_batch_us_per_pressure": "L1 batched (bracketed Newton), per pressure",
            "inverse_us": "inverse D2 -> p (Brent on L0)"}
    for key, value in figures.items():
        target = TARGETS_US.get(key)
        rows.append(f"| `{key}` | {what[key]} | {value:.3g} us | "
                    f"{'<= %g us' % target if target else 'reported'} | {verdict(value, target) if target else ''} |")
    update_section("bench_model", "## Physics core (`scripts/bench_model.py`)\n\n"
                   f"Command: `python scripts/bench_model.py` ({machine_line()}, median of {args.repeat} runs)\n\n"
                   + "\n".join(rows) + "\n\n" + NOTES)
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())

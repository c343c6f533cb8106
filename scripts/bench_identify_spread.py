#!/usr/bin/env python3
"""How far the pneumatic fit's values and intervals can be trusted (#23): the same truths fitted
over many draws of the sensors' noise.

bench_identify runs softgrip_identify live, once per truth, so each of its figures is one draw
of the sensors' noise. Here each truth's excitation is recorded offline (the control core in its
identification mode on the truth plant, with the simulated device's sensors:
softgrip_ros.devtools.identification_sim; no ROS, no CAN) once per noise seed, and each recording
is fitted as softgrip_identify fits it. Per value, over every fit:

* the share of fits within the issue's recovery target;
* the median and the largest |relative error|;
* the share whose 95 % interval holds the truth (nominally 0.95), and the median half width.

Writes its section of docs/benchmarks.md unless --json or --quick.
Reproduce: source scripts/env.sh; python scripts/bench_identify_spread.py
"""
import os

# one BLAS thread per fit: the fits run side by side, one per core
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import concurrent.futures  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

from softgrip_ros.devtools.benchmarking import (benchmark_parser, machine_line,  # noqa: E402
                                                strict_json, update_variant_section)
from softgrip_ros.devtools.identification_sim import (BENCHMARK_TRUTHS,  # noqa: E402
                                                      recovery_spread, seeded_fit,
                                                      spread_seeds, truth)

FIRST_SEED = 20  # the recovery tests use seed 3: these draws are not the ones they were tuned on


def progress(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def run_fits(seeds: dict, quick: bool, jobs: int,
             pump_level_given: bool = False) -> tuple[list, list]:
    """(fits, failures): every truth fitted at each of its seeds, ``jobs`` at a time."""
    fits, failures = [], []
    truths = list(seeds)
    tasks = [(name, seed) for name in truths for seed in seeds[name]]
    with concurrent.futures.ProcessPoolExecutor(max_workers=jobs) as pool:
        futures = {pool.submit(seeded_fit, name, seed, quick, pump_level_given): (name, seed)
                   for name, seed in tasks}
        for done, future in enumerate(concurrent.futures.as_completed(futures), 1):
            name, seed = futures[future]
            try:
                fit = future.result()
            except (ValueError, TimeoutError, RuntimeError) as error:
                failures.append({"truth": name, "seed": seed, "error": str(error)})
                progress(f"fit {done}/{len(tasks)}: {name} seed {seed}: failed: {error}")
                continue
            fits.append(fit)
            vent = fit["values"]["vent_critical_ratio"]["rel_err"]
            progress(f"fit {done}/{len(tasks)}: {name} seed {seed}: vent critical ratio "
                     f"{100 * vent:+.1f} %, fit {fit['fit_s']:.0f} s")
    fits.sort(key=lambda f: (truths.index(f["truth"]), f["seed"]))
    return fits, failures


def half_width(relative: float) -> str:
    return f"{100 * relative:.2f} %" if relative < 10.0 else "unbounded (flagged)"


def markdown(spread: dict, per_truth: dict, fits: list, command: str, seconds: float,
             pump_level_given: bool) -> str:
    truths = list(per_truth)
    seeds = {name: sorted(fit["seed"] for fit in fits if fit["truth"] == name) for name in truths}
    lines = [
        f"Reproduce: `{command}` ({machine_line()}; {seconds / 60:.1f} min).", "",
        f"Each truth ({', '.join(truths)}: as in the live table above) recorded offline once per "
        "noise seed, each truth its own seeds (" +
        ", ".join(f"{name} {s[0]}-{s[-1]}" for name, s in seeds.items()) +
        "; the recovery tests use seed 3) and fitted as "
        "softgrip_identify fits it, the truth's volume given" +
        (" and its pump's level (--vacuum-source-pa)" if pump_level_given else "") +
        f": {len(fits)} fits. Per value: the "
        "share of fits within the issue's target (and per truth), the median and largest "
        "|relative error|, the share of 95 % intervals that hold the truth (nominally 0.95) and "
        "their median half width, the errors' spread over the intervals (the rms of each error "
        "over its interval's sigma on the truth's side, half width / 1.96, over the unflagged "
        "fits: 1 for intervals as wide as the errors spread, above 1 for narrow ones), and the "
        "share the fit flagged.", "",
        "| value | target | within | " + " | ".join(truths) +
        " | median \\|error\\| | largest | interval holds the truth | median half width | "
        "spread over interval | flagged |",
        "|---|---|---|" + "---|" * len(truths) + "---|---|---|---|---|---|"]
    for name, row in spread.items():
        cells = [f"`{name}`", f"{100 * row['target']:.0f} %", f"{row['within_target']:.2f}"]
        cells += [f"{per_truth[t][name]['within_target']:.2f}" for t in truths]
        exact = row["median_half_width"] < 1e-6
        cells += [f"{100 * row['median_abs_err']:.2f} %", f"{100 * row['max_abs_err']:.1f} %",
                  "-" if exact else f"{row['covered']:.2f}",
                  half_width(row["median_half_width"]),
                  "-" if exact or math.isnan(row["spread_over_interval"])
                  else f"{row['spread_over_interval']:.2f}", f"{row['flagged']:.2f}"]
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "-: an interval without width: the regulator's lag (its reports carry no noise "
              "in these recordings) and a value given as measured; for the spread, also a value "
              "flagged in every fit. Unless the pump's level is "
              "given, the vacuum path's critical ratio and the level are flagged by design (see "
              "the live table's note). What these figures "
              "mean for a fit, and what is known about them, is in "
              "[identification.md](identification.md#how-far-to-trust-a-fit).", ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = benchmark_parser(__doc__, "one truth (slow_large), two seeds, the quick excitation; "
                              "writes nothing")
    parser.add_argument("--seeds", type=positive_int, default=10,
                        help="noise seeds per truth (default 10)")
    parser.add_argument("--truth", action="append",
                        help="slow_large, drawn_<seed> or a plant file to play the user's "
                        f"hardware (repeatable; default: {', '.join(BENCHMARK_TRUTHS)})")
    parser.add_argument("--pump-level-given", action="store_true",
                        help="give each fit its truth's vacuum pump level, as "
                        "softgrip_identify --vacuum-source-pa does (its own section)")
    parser.add_argument("--jobs", type=positive_int, default=max(1, min(2, os.cpu_count() or 1)),
                        help="fits at a time (default: the cores, at most 2)")
    args = parser.parse_args(argv)
    truths = args.truth or list(BENCHMARK_TRUTHS[:1] if args.quick else BENCHMARK_TRUTHS)
    seeds = spread_seeds(truths, 2 if args.quick else args.seeds, FIRST_SEED)
    for name in truths:
        try:
            truth(name)
        except (ValueError, OSError) as error:
            parser.error(str(error))
    started = time.perf_counter()
    progress(f"{sum(map(len, seeds.values()))} fits, {args.jobs} at a time")
    fits, failures = run_fits(seeds, args.quick, args.jobs, args.pump_level_given)
    seconds = time.perf_counter() - started
    spread = recovery_spread(fits)
    per_truth = {name: recovery_spread([f for f in fits if f["truth"] == name])
                 for name in truths}
    summary = {"spread": spread, "per_truth": per_truth, "failures": failures, "fits": fits,
               "seconds": seconds}
    if failures:
        print(strict_json(summary))
        progress(f"{len(failures)} fits failed; docs/benchmarks.md not written")
        return 1
    if args.json or args.quick:
        print(strict_json(summary))
        return 0
    command = "python scripts/bench_identify_spread.py" + (
        f" --seeds {args.seeds}" if args.seeds != 10 else "") + "".join(
        f" --truth {name}" for name in (args.truth or [])) + (
        " --pump-level-given" if args.pump_level_given else "")
    text = markdown(spread, per_truth, fits, command, seconds, args.pump_level_given)
    update_variant_section("bench_identify_spread", "## How far an identification can be trusted "
                           "(`scripts/bench_identify_spread.py`)", text,
                           "pump_level" if args.pump_level_given else "",
                           "### The same fits with the pump's level measured "
                           "(`--pump-level-given`)")
    progress(f"done in {seconds:.0f} s; wrote docs/benchmarks.md")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())

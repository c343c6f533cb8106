#!/usr/bin/env python3
"""Benchmark the pressure estimators: step cost, accuracy against the best raw sensor, NEES.

Step cost: one predict plus a fused update of both sensors (``add_measurements`` with two
samples, gating included), over the scripted fill/hold/evacuate/vent trajectory at 200 Hz.
Accuracy: RMSE against the plant's truth on the same trajectory with the device's sensors
(chamber_a 500 Hz 300 Pa, chamber_b 200 Hz 150 Pa), divided by the best raw sensor's RMSE.
Consistency: 50 Monte Carlo runs (truth with the filter's own process noise), time-averaged
ANEES inside the 95 % chi-square interval.

Writes its section of docs/benchmarks.md and docs/estimator_speed_accuracy.png; --json prints
the figures instead. Reproduce: scripts/env.sh sourced, then  python scripts/bench_estimator.py
"""
import pathlib
import statistics
import sys
import time

import numpy as np
from softgrip_ros.devtools.benchmarking import (benchmark_parser, figure_rows, interleaved_seconds,
                                                machine_line, update_section, strict_json)
from softgrip_ros.devtools import estimator_simulation as sim
from softgrip_ros.estimation.estimator import PressureEstimator
from softgrip_ros.estimation.filters import FILTER_TYPES

ROOT = pathlib.Path(__file__).resolve().parent.parent
CHART = ROOT / "docs" / "estimator_speed_accuracy.png"
TARGETS = {
    "kf_step_us": (40.0, True), "ekf_step_us": (80.0, True), "ukf_step_us": (250.0, True),
    "kf_step_over_raw_filterpy": (2.0, True), "rmse_ratio_vs_best_sensor": (0.85, True)
}


def progress(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


RAW = "raw_filterpy"  # filterpy's KalmanFilter alone: the floor of a KF step
# the KF step's pieces, timed where they run (a method of the estimator or of its filter):
# (label, owner, method)
PIECES = (("record for rewinds", "estimator", "_record"),
          ("screen and lateness", "estimator", "_screen"),
          ("screen and lateness", "estimator", "_late"),
          ("predict (transition + filterpy)", "filter", "predict"),
          ("sample-timing rate (plant step)", "estimator", "_state_rate"),
          ("update (filterpy + symmetrise)", "filter", "update"))


def _pairs(trajectory) -> list:
    """[(t, {sensor: gauge Pa})]: both sensors at every 5 ms of the trajectory."""
    rng = np.random.default_rng(1)
    times = np.arange(0.0, trajectory.truth_t[-1], 0.005)
    truth = np.interp(times, trajectory.truth_t, trajectory.truth[:, 0])
    return [(t, {"chamber_a": p + rng.normal(0, 300.0), "chamber_b": p + rng.normal(0, 150.0)})
            for t, p in zip(times, truth)]


def _estimator_pass(trajectory, pairs, estimator) -> None:
    feed = sim.InputFeed(trajectory.input_changes)
    for t, samples in pairs:
        feed.until(estimator, t)
        estimator.add_measurements(samples, t)


def _raw_filterpy_pass(pairs) -> None:
    """A bare filterpy KalmanFilter, 2 states and the two samples' mean as 1 measurement:
    predict() and update(z) per instant, as the estimator's kf does, without its model."""
    from filterpy.kalman import KalmanFilter
    kf = KalmanFilter(dim_x=2, dim_z=1)
    kf.F = np.array([[0.9, 0.1], [0.0, 0.95]])
    kf.H = np.array([[1.0, 0.0]])
    kf.Q = np.diag([1e4, 1e4])
    kf.R = np.array([[2e4]])
    for _, samples in pairs:
        kf.predict()
        kf.update(np.array([[0.5 * (samples["chamber_a"] + samples["chamber_b"])]]))


def step_costs_us(trajectory, repeat: int) -> dict:
    """{filter, and RAW: the mean cost (us) of one predict + 2-sensor update in each of
    ``repeat`` passes over the trajectory}, the passes interleaved (see interleaved_seconds)."""
    pairs = _pairs(trajectory)
    passes = {
        f: (lambda config=sim.config_for(trajectory, f):
            _estimator_pass(trajectory, pairs, PressureEstimator(config)))
        for f in FILTER_TYPES
    }
    passes[RAW] = lambda: _raw_filterpy_pass(pairs)
    return {
        f: [1e6 * s / len(pairs) for s in seconds]
        for f, seconds in interleaved_seconds(passes, repeat).items()
    }


def kf_piece_costs_us(trajectory, repeat: int) -> dict:
    """{piece label: its cost (us) per KF step}, and "whole step", in the pass of median whole
    step among ``repeat``: each piece timed by a wrapper around its method (on the classes,
    restored after; the wrappers' own cost, about 0.2 us a call, falls in the piece); "the rest"
    is the step less the pieces: the gate's arithmetic, the bookkeeping, the calls between
    them."""
    from softgrip_ros.estimation.filters import LinearFilter
    pairs = _pairs(trajectory)
    config = sim.config_for(trajectory, "kf")
    owners = {"estimator": PressureEstimator, "filter": LinearFilter}
    rounds = []
    spent = {}
    originals = [(owners[owner], method, owners[owner].__dict__[method])
                 for _, owner, method in PIECES]
    for (label, _, _), (owner, method, original) in zip(PIECES, originals):
        def timed(*args, _original=original, _label=label, **kwargs):
            start = time.perf_counter()
            try:
                return _original(*args, **kwargs)
            finally:
                spent[_label] += time.perf_counter() - start
        setattr(owner, method, timed)
    try:
        for round_index in range(repeat + 1):  # the first pass warms the caches: not counted
            spent.update({label: 0.0 for label, _, _ in PIECES})
            start = time.perf_counter()
            _estimator_pass(trajectory, pairs, PressureEstimator(config))
            whole = time.perf_counter() - start
            if round_index == 0:
                continue
            pieces = {label: 1e6 * seconds / len(pairs) for label, seconds in spent.items()}
            pieces["the rest"] = 1e6 * (whole - sum(spent.values())) / len(pairs)
            pieces["whole step"] = 1e6 * whole / len(pairs)
            rounds.append(pieces)
    finally:
        for owner, method, original in originals:
            setattr(owner, method, original)
    rounds.sort(key=lambda pieces: pieces["whole step"])
    return rounds[len(rounds) // 2]


def measure(repeat: int, runs: int) -> tuple[dict, dict]:
    trajectory = sim.simulate(seed=7)
    raw = {name: trajectory.raw_rmse(name) for name in trajectory.sensor_std}
    best_name = min(raw, key=raw.get)
    figures, details = {}, {
        "raw_rmse_pa": raw, "rmse_pa": {}, "anees": {}, "best_sensor_alone_rmse_pa": {}
    }
    progress(f"step costs ({repeat} rounds, one pass of each filter a round)")
    costs = step_costs_us(trajectory, repeat)
    details["step_us_quartiles"] = {
        f: [float(q) for q in np.percentile(c, [25, 50, 75])]
        for f, c in costs.items() if f != RAW
    }
    figures[f"{RAW}_step_us"] = statistics.median(costs[RAW])
    figures["kf_step_over_raw_filterpy"] = (statistics.median(costs["kf"]) /
                                            figures[f"{RAW}_step_us"])
    details["kf_over_raw_per_round"] = [k / r for k, r in zip(costs["kf"], costs[RAW])]
    progress(f"the kf step's pieces ({repeat} passes)")
    details["kf_pieces_us"] = kf_piece_costs_us(trajectory, repeat)
    for filter_type in FILTER_TYPES:
        figures[f"{filter_type}_step_us"] = statistics.median(costs[filter_type])
        run = sim.run(trajectory, sim.config_for(trajectory, filter_type))
        details["rmse_pa"][filter_type] = run.rmse()
        alone = sim.run(trajectory, sim.config_for(trajectory, filter_type), sensors=(best_name,))
        details["best_sensor_alone_rmse_pa"][filter_type] = alone.rmse()
        figures[f"rmse_ratio_{filter_type}"] = run.rmse() / raw[best_name]
        progress(f"[{filter_type}] NEES over {runs} Monte Carlo runs")
        values, bounds = sim.anees(filter_type, runs)
        details["anees"][filter_type] = {"value": float(values.mean()), "bounds": bounds}
    details["nees_bounds"] = bounds
    figures["rmse_ratio_vs_best_sensor"] = max(figures[f"rmse_ratio_{f}"] for f in FILTER_TYPES)
    figures["nees_in_bounds"] = all(b[0] <= d["value"] <= b[1] for d in details["anees"].values()
                                    for b in [d["bounds"]])
    details["best_sensor"] = best_name
    return figures, details


def chart(figures: dict, details: dict, path: pathlib.Path = CHART) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for filter_type, marker in zip(FILTER_TYPES, "osD"):
        cost, rmse = figures[f"{filter_type}_step_us"], details["rmse_pa"][filter_type]
        alone = details["best_sensor_alone_rmse_pa"][filter_type]
        ax.plot(cost, rmse, marker, ms=9, label=f"{filter_type.upper()}, both sensors")
        ax.plot(cost, alone, marker, ms=9, mfc="none", color=ax.lines[-1].get_color(),
                label=f"{filter_type.upper()}, {details['best_sensor']} alone")
    for name, rmse in details["raw_rmse_pa"].items():
        ax.axhline(rmse, ls="--", lw=1, color="grey")
        ax.text(1.02 * min(figures[f"{f}_step_us"] for f in FILTER_TYPES) / 2, rmse * 1.04,
                f"raw {name}", color="grey")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlim(
        min(figures[f"{f}_step_us"] for f in FILTER_TYPES) / 2.5, 2 * figures["ukf_step_us"])
    ax.set_xlabel("cost of one predict + 2-sensor update [us] (median)")
    ax.set_ylabel("RMSE against the plant's truth [Pa]")
    ax.set_title("Pressure estimators: accuracy against cost")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    parser = benchmark_parser(__doc__, "3 rounds, 10 Monte Carlo runs; writes nothing", 15,
                              "rounds of timed passes, one of each filter a round (median)")
    parser.add_argument("--runs", type=int, default=50, help="Monte Carlo runs for the NEES check")
    args = parser.parse_args(argv)
    if args.quick:
        args.repeat, args.runs = 3, 10
    if args.runs < 10:
        parser.error("--runs must be at least 10")
    started = time.perf_counter()
    figures, details = measure(args.repeat, args.runs)
    if args.json or args.quick:
        print(
            strict_json({**figures, "details": details}) if args.json else "\n".
            join(figure_rows(figures, TARGETS)))
        return 0
    chart(figures, details)
    rows = figure_rows(figures, TARGETS)
    anees_text = ", ".join(f"{f} {d['value']:.2f}" for f, d in details["anees"].items())
    low, high = details["nees_bounds"]
    notes = (
        "RMSE on the scripted trajectory: raw sensors "
        f"{', '.join(f'{n} {v:.0f} Pa' for n, v in details['raw_rmse_pa'].items())}; "
        f"fused {', '.join(f'{f} {v:.0f} Pa' for f, v in details['rmse_pa'].items())}; the same "
        "filters on "
        f"{details['best_sensor']} alone "
        f"{', '.join(f'{f} {v:.0f} Pa' for f, v in details['best_sensor_alone_rmse_pa'].items())}"
        ". "
        "`rmse_ratio_vs_best_sensor` is the worst of the three filters. Time-averaged ANEES over "
        f"{args.runs} runs: "
        f"{anees_text} (95 % interval [{low:.2f}, {high:.2f}], 2 states). Most of each step is "
        "the plant model in "
        "pure Python (one backward-Euler Newton solve per step, five for the UKF's sigma points) "
        "and filterpy's "
        "per-call overhead. Step costs, quartiles over the rounds: " +
        "; ".join(f"{f} {q[0]:.0f}-{q[2]:.0f} us"
                  for f, q in details["step_us_quartiles"].items()) +
        ". The three filters' passes are interleaved, round after round, so that a busy moment of "
        "this "
        "shared host falls on all of them; timed as 7 passes of one filter in a row, the kf's "
        "median read "
        "31.6, 33.7 and 51.6 us in three runs a minute apart (2026-11-22). Compare the filters "
        "within one "
        "run. Every filter widens P at each input change by the change in the state's rate times "
        "`input_timing_std` (10 ms): on this trajectory, whose inputs are timed exactly, that "
        "costs about "
        "10 % of the RMSE (kf 44, ekf 43, ukf 42 Pa without it, in the run before it); with "
        "inputs 4 ms late it "
        "is what keeps the gate from rejecting a boosted fill (test_estimation). "
        f"Against filterpy alone: its KalmanFilter's predict and update, 2 states and 1 "
        f"measurement, cost {figures[f'{RAW}_step_us']:.1f} us in the same rounds, so the kf "
        f"step is {figures['kf_step_over_raw_filterpy']:.2f} times that (median of the rounds' "
        "ratios "
        f"{statistics.median(details['kf_over_raw_per_round']):.2f}). Its pieces in one pass "
        "(us per step): " + ", ".join(f"{label} {value:.1f}" for label, value in
                                      details["kf_pieces_us"].items()) + ". "
        "Beyond filterpy's own calls, the plant's transition (the model a fixed-F filter does "
        "not have: two evaluations of the orifice law and the regulator's step) and the "
        "estimator's bookkeeping (the gate, the NIS window, the state kept for rewinds, the "
        "sample-timing variance) make up the rest. "
        "Chart: `docs/estimator_speed_accuracy.png`.")
    update_section(
        "bench_estimator", "## Pressure estimators (`scripts/bench_estimator.py`)\n\n"
        f"Command: `python scripts/bench_estimator.py` ({machine_line()}, step cost median of "
        f"{args.repeat} "
        f"interleaved passes over {2.2:.1f} s of trajectory at 200 Hz)\n\n" + "\n".join(rows) +
        "\n\n" + notes)
    print("\n".join(rows))
    progress(f"done in {time.perf_counter() - started:.0f} s; wrote docs/benchmarks.md and "
             f"{CHART.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

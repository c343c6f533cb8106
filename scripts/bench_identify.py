#!/usr/bin/env python3
"""Pneumatic identification against known truths (#23): softgrip_identify run live, as a user
runs it, on a simulated device whose plant is not the suite's.

For each truth (a plant file): ``sim_device`` with that file as its truth and ``controller``
with the shipped config/plant.yaml start as processes on a softgrip_ipc bus; ``softgrip_identify``
runs its excitation through the controller over DDS and CAN and fits; it never reads the truth.
It is given the truth's chamber volume with --volume-m3, as a user gives the volume they measured:
pressure data cannot tell the volume from the conductances (softgrip_ros.estimation.
identification). Then, for the default file and the identified one, against the truth:

* each parameter's relative error (``param_rel_err``), and whether the fit flagged it;
* ``validation_rmse_over_noise``: the held-out excitation, predicted;
* the closed loop on the truth (the control core without ROS, softgrip_ros.devtools.
  closed_loop): a 25 kPa step's rise against the valve fully open, overshoot and steady-state
  error, with the controller's model the default file, then the identified one;
* the estimator's ANEES on the truth (20 Monte Carlo runs, the node's EKF) with each model, and
  whether it lies within its 95 % bounds;
* ``excitation_s`` (gripper time) and ``fit_s``.

Without --truth it runs the issue's case (a slower supply path and a larger chamber) and two
seeded draws (each parameter scaled by a factor in [0.5, 2]). Writes its section of
docs/benchmarks.md unless --json or --quick. A truth whose live run fails (a process that stops,
softgrip_identify's non-zero exit) is named on stderr and the others still run; then it prints
``{"failed": [{name, error}], "identified": [names]}``, writes nothing and exits 1. A truth whose
fit runs over its budget, or leaves a value outside its recovery target unflagged, is named on
stderr with what it missed, and its recording and fit are kept (outside the temporary directory
unless --workdir is given) so that the fit can be repeated from the log and traced (not with
--quick, whose short excitation is not held to the targets).
Reproduce: source scripts/env.sh; python scripts/bench_identify.py
"""
import contextlib
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile
import time
import uuid

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("ROS_DOMAIN_ID", str(60 + os.getpid() % 40))

import numpy as np

from softgrip_ros.devtools.benchmarking import (benchmark_parser, host_load, machine_line,
                                                update_variant_section, strict_json)
from softgrip_ros.devtools.closed_loop import step_figures
from softgrip_ros.devtools.estimator_simulation import anees
from softgrip_ros.devtools import identification_sim
from softgrip_ros.devtools.processes import installed_executable, stop_process
from softgrip_ros.estimation.identification import FIT_BUDGET_S, excitation
from softgrip_ros.model import plant_file
from softgrip_ros.model.pneumatics import PneumaticPlant
from softgrip_ros.tools import identify

STEP_PA = 25e3
IDENTIFIED = ("supply_conductance", "vacuum_conductance", "vent_conductance",
              "supply_critical_ratio", "vacuum_critical_ratio", "vent_critical_ratio",
              "chamber_compliance_m3_per_pa", "vacuum_compliance_m3_per_pa",
              "vacuum_source_gauge_pa", "regulator_time_constant_s",
              "regulator_rate_limit_pa_per_s")


def progress(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def identify_live(truth_path: pathlib.Path, truth: plant_file.PlantDescription, quick: bool,
                  workdir: pathlib.Path, pump_level_given: bool = False) -> dict:
    channel = f"bench-identify-{uuid.uuid4().hex[:8]}"
    ros_args = ["--ros-args", "-p", "can.interface:=softgrip_ipc", "-p",
                f"can.channel:={channel}", "--log-level", "warn"]
    device = subprocess.Popen([installed_executable("sim_device"), *ros_args, "-p",
                               f"plant_file:={truth_path}"])
    controller = subprocess.Popen([installed_executable("controller"), *ros_args])
    output = workdir / f"identified-{truth_path.stem}"
    started = time.perf_counter()
    try:
        time.sleep(2.0)  # the processes come up
        argv = ["--output", str(output), "--volume-m3", f"{truth.parameters.chamber_volume_m3!r}",
                "--timeout", "30"] + (["--quick"] if quick else []) + (
                    ["--vacuum-source-pa", repr(truth.parameters.vacuum_source_gauge_pa)]
                    if pump_level_given else [])
        with contextlib.redirect_stdout(sys.stderr):  # its progress; stdout is the JSON
            code = identify.main(argv)
    finally:
        codes = [stop_process(p, timeout_s=15.0) for p in (controller, device)]
    if code != 0:
        raise RuntimeError(f"softgrip_identify exited {code}")
    if codes[0] != 0:
        raise RuntimeError(f"the controller exited {codes[0]}")
    return {"path": output / "plant.yaml", "wall_s": time.perf_counter() - started}


def target_misses(figures: dict) -> list:
    """What one truth's run missed of the issue's targets, in words: a fit over its budget, and
    each value outside its recovery target that the fit did not flag."""
    misses = []
    if figures["fit_s"] > FIT_BUDGET_S:
        misses.append(f"the fit took {figures['fit_s']:.1f} s "
                      f"(budget {FIT_BUDGET_S:g} s)")
    for name, error in figures["param_rel_err"].items():
        target = identification_sim.RECOVERY_TARGETS.get(name)
        if target is not None and name not in figures["flagged"] and abs(error) > target:
            misses.append(f"{name} {100 * error:+.1f} %, unflagged (target +-{100 * target:g} %)")
    return misses


def keep_for_tracing(truth_path: pathlib.Path, output: pathlib.Path) -> pathlib.Path:
    """A copy of one truth's plant file and its live run's ``output`` (the recording, the fit's
    files) in a new directory that outlives the temporary workdir: a live run is not repeatable,
    but a fit from its log is."""
    kept = pathlib.Path(tempfile.mkdtemp(prefix=f"bench_identify_kept_{truth_path.stem}_"))
    shutil.copy2(truth_path, kept / truth_path.name)
    shutil.copytree(output, kept / output.name)
    return kept


def evaluate(truth: plant_file.PlantDescription, identified_path: pathlib.Path,
             runs: int) -> dict:
    identified = plant_file.load(identified_path)
    truth_plant = PneumaticPlant(truth.parameters)
    shipped = plant_file.default_description()
    figures = {"param_rel_err": {}, "flagged": []}
    for name in IDENTIFIED:
        true, found = getattr(truth.parameters, name), getattr(identified.parameters, name)
        figures["param_rel_err"][name] = found / true - 1.0
        if identified.details.get(name, {}).get("flag"):
            figures["flagged"].append(name)
    for name, model in truth.sensors.items():
        figures["param_rel_err"][f"{name}.noise_std_pa"] = (
            identified.sensors[name].noise_std_pa / model.noise_std_pa - 1.0)
        figures[f"{name}_bias_error_pa"] = identified.sensors[name].bias_pa - model.bias_pa
    provenance = identified.provenance
    figures["fit_flags"] = len(provenance.get("flags", []))
    figures["validation_rmse_over_noise"] = float(provenance["validation_rmse_over_noise"])
    figures["fit_s"] = float(provenance["fit_s"])
    # the truth as the controller's model: what a perfect identification would reach
    step = step_figures(STEP_PA, truth_plant, truth_plant)
    figures.update({f"truth_model_{key}": value for key, value in step.items()})
    for label, model in (("default", shipped), ("identified", identified)):
        step = step_figures(STEP_PA, truth_plant, PneumaticPlant(model.parameters))
        figures.update({f"{label}_{key}": value for key, value in step.items()})
        values, (low, high) = anees("ekf", runs=runs, truth=truth_plant,
                                    model=PneumaticPlant(model.parameters))
        figures[f"nees_{label}"] = float(np.mean(values))
        figures[f"nees_{label}_in_bounds"] = bool(low <= np.mean(values) <= high)
        figures["nees_bounds"] = [float(low), float(high)]
    return figures


def markdown(rows: list, command: str, seconds: float, pump_level_given: bool = False) -> str:
    lines = [
        f"Reproduce: `{command}` ({machine_line()}; {seconds / 60:.1f} min).", "",
        "softgrip_identify run live through `controller` (the shipped plant file) on `sim_device` "
        "with another truth, over DDS and a softgrip_ipc CAN bus; it is given the truth's chamber "
        "volume (--volume-m3, as a user gives a measured one" + (
            "; and its pump's level, --vacuum-source-pa" if pump_level_given else "") +
        "). Relative errors of the identified "
        "values against the truth (flagged ones marked *); closed loop: a 25 kPa step on the "
        "truth with the controller's model the default file, then the identified one (targets: "
        "rise <= 1.3x the valve fully open, overshoot <= 3 %, steady state <= 0.2 kPa); "
        "ANEES of the estimator (EKF, 20 runs) against its 95 % bounds.", ""]
    names = list(rows[0]["figures"]["param_rel_err"])
    lines.append("| value | " + " | ".join(r["name"] for r in rows) + " |")
    lines.append("|---|" + "---|" * len(rows))
    for name in names:
        cells = []
        for row in rows:
            value = row["figures"]["param_rel_err"][name]
            cells.append(f"{100 * value:+.1f} %" + (" *" if name in row["figures"]["flagged"]
                                                    else ""))
        lines.append(f"| `{name}` | " + " | ".join(cells) + " |")
    for key, label in (("validation_rmse_over_noise", "validation RMSE / noise (<= 1.5)"),
                       ("default_rise_time_ratio", "default file: rise ratio"),
                       ("default_overshoot_pct", "default file: overshoot %"),
                       ("default_steady_state_error_kpa", "default file: steady-state kPa"),
                       ("identified_rise_time_ratio", "identified: rise ratio (<= 1.3)"),
                       ("identified_overshoot_pct", "identified: overshoot % (<= 3)"),
                       ("identified_steady_state_error_kpa", "identified: steady state kPa "
                        "(<= 0.2)"),
                       ("truth_model_rise_time_ratio", "the truth as the model: rise ratio"),
                       ("truth_model_overshoot_pct", "the truth as the model: overshoot %"),
                       ("nees_default", "ANEES, default file"),
                       ("nees_identified", "ANEES, identified"),
                       ("fit_flags", "flags the fit raised (values and residuals)"),
                       ("excitation_s", "excitation (gripper s, <= 60)"),
                       ("fit_s", f"fit (s, <= {FIT_BUDGET_S:g})")):
        cells = []
        for row in rows:
            value = row["figures"][key]
            extra = ""
            if key.startswith("nees_"):
                extra = " (in)" if row["figures"][f"{key}_in_bounds"] else " (out)"
            cells.append(f"{value:.3g}{extra}")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    bounds = rows[0]["figures"]["nees_bounds"]
    lines += ["", f"ANEES 95 % bounds: [{bounds[0]:.2f}, {bounds[1]:.2f}]. Flagged (*): the fit "
              "says the data do not determine the value (within the pressure limits the vacuum "
              "path's flow is choked nearly all the way, so its critical ratio and the source's "
              "level trade off); the flag and the interval are in the written file. \"The truth "
              "as the model\": the controller given the truth itself, the best any identified "
              "file can do. The boost's ceiling (a valve stuck open must stay within the limit, "
              "control.pressure.boost_ceiling_pa) is simulated on the controller's model for the "
              "target; a wrong model can make it too low (a slow rise) or too high.", ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = benchmark_parser(__doc__, "one truth, the quick excitation, 5 NEES runs; writes "
                              "nothing", load=True)
    parser.add_argument("--truth", type=pathlib.Path, action="append",
                        help="a plant file to play the user's hardware (repeatable)")
    parser.add_argument("--pump-level-given", action="store_true",
                        help="give softgrip_identify each truth's vacuum pump level "
                        "(--vacuum-source-pa), as a user with a gauge would (its own section)")
    parser.add_argument("--workdir", type=pathlib.Path,
                        help="keep the truths' plant files, the recordings and the fits here "
                        "(default: a temporary directory, removed at the end; a truth that "
                        "missed a target keeps its own)")
    args = parser.parse_args(argv)
    with contextlib.ExitStack() as stack:
        if args.workdir:
            args.workdir.mkdir(parents=True, exist_ok=True)
            workdir = args.workdir
        else:
            workdir = pathlib.Path(
                stack.enter_context(tempfile.TemporaryDirectory(prefix="bench_identify_")))
        stack.enter_context(host_load(args.load))
        return run_benchmark(parser, args, workdir)


def run_benchmark(parser, args, workdir: pathlib.Path) -> int:
    started = time.perf_counter()
    runs = 5 if args.quick else 20
    truths = []
    if args.truth:
        for path in args.truth:
            try:
                truths.append((path.stem, path, plant_file.load(path)))
            except ValueError as error:
                parser.error(str(error))
    else:
        names = identification_sim.BENCHMARK_TRUTHS
        for name in names[:1] if args.quick else names:
            description = identification_sim.truth(name)
            path = plant_file.save(description, workdir / f"{name}.yaml")
            truths.append((name, path, description))
    rows, failed = [], []
    for name, path, truth in truths:
        progress(f"truth {name}: identifying live")
        try:
            live = identify_live(path, truth, args.quick, workdir, args.pump_level_given)
            progress(f"truth {name}: evaluating")
            figures = evaluate(truth, live["path"], runs)
        except (RuntimeError, ValueError, OSError) as error:
            # one truth's failed run (a process that stopped, no plant file) is reported, and the
            # others still run
            progress(f"truth {name}: failed: {error}")
            failed.append({"name": name, "error": str(error)})
            continue
        steps, _ = excitation(quick=args.quick)
        figures["excitation_s"] = sum(step.duration_s for step in steps)
        figures["missed"] = [] if args.quick else target_misses(figures)
        if figures["missed"]:
            output = live["path"].parent
            if not args.workdir:
                output = keep_for_tracing(path, output) / output.name
            figures["kept_in"] = str(output)
            progress(f"truth {name}: missed: {'; '.join(figures['missed'])}. Its recording and "
                     f"fit are kept in {output}; refit: softgrip_identify --from-log "
                     f"{output / 'recording'} --output DIR")
        rows.append({"name": name, "figures": figures})
    seconds = time.perf_counter() - started
    if failed:
        print(strict_json({"failed": failed, "identified": [row["name"] for row in rows]}))
        progress(f"{len(failed)} of {len(truths)} truths failed; docs/benchmarks.md not written")
        return 1
    first = rows[0]["figures"]
    summary = {key: first[key] for key in (
        "param_rel_err", "validation_rmse_over_noise", "default_rise_time_ratio",
        "default_overshoot_pct", "default_steady_state_error_kpa", "identified_rise_time_ratio",
        "identified_overshoot_pct", "identified_steady_state_error_kpa",
        "nees_default_in_bounds", "nees_identified_in_bounds", "excitation_s", "fit_s")}
    summary["flagged"] = first["flagged"]
    summary["truths"] = rows
    summary["load_processes"] = args.load
    if args.json or args.quick or args.load:
        print(strict_json(summary))
        return 0
    command = "python scripts/bench_identify.py" + (
        "".join(f" --truth {p}" for p in args.truth) if args.truth else "") + (
        " --pump-level-given" if args.pump_level_given else "")
    text = markdown(rows, command, seconds, args.pump_level_given)
    update_variant_section("bench_identify", "## Pneumatic identification "
                           "(`scripts/bench_identify.py`)", text,
                           "pump_level" if args.pump_level_given else "",
                           "### With the pump's level measured (`--pump-level-given`)")
    progress(f"done in {seconds:.0f} s; wrote docs/benchmarks.md")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())

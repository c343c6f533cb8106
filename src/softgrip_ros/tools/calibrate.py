"""softgrip_calibrate: fit the bending model to measurements of your own fingers.

    softgrip_calibrate measurements.csv --name my_gripper --geometry my_fingers.yaml
    softgrip_calibrate measurements.csv --name my_gripper --live   # hold pressures, ask, fit
    ros2 run softgrip_ros controller --ros-args -p gripper_model:=my_gripper

The CSV has a column pressure_pa and any of alpha_deg, tip_spacing_m, root_spacing_m,
left_tip_x_m, left_tip_y_m (tip_pose's z: along the fingers), each with an optional std_<column>;
an empty cell is a quantity not measured at that pressure. The geometry file holds your Table 1
values, in the fields of config/gripper_geometry.yaml; without it the base model's geometry is
used. The gain is always fitted; the ballooning compliance when a position (D1, D2, the tip) was
measured; the saturation when there are points above 45 kPa; --fit chooses instead. Everything
else is inherited from --base, and the report says what (softgrip_ros.model.bending_fit).

Writes NAME.yaml into the calibration directory ($SOFTGRIP_CALIBRATION_DIR, else
$ROS_HOME/softgrip_calibrations, else ~/.ros/softgrip_calibrations) or to --output, and beside
it NAME_calibration.md (the report: constants with their intervals, leave-one-out residuals,
flags) and NAME_calibration.png (the fit against the measurements). The nodes select it with
their gripper_model parameter.

With --live, the running controller holds each of --pressures in turn (an OPEN goal with that
open_pressure_pa); once settled you type what you measured (--columns), and each row is appended
to the CSV at once. Then the CSV is fitted as above. At the end, on Ctrl-C or on a failure the
gripper vents; the rows measured so far stay in the CSV.

Exit status: 0 written (flags, if any, are printed and recorded in the file); 1 refused (the
data cannot determine what was asked, a bad file, the calibration exists without --force, or a
live run stopped); 2 bad arguments; 3 no gripper answered (--live).
"""
from __future__ import annotations

import argparse
import datetime
import hashlib
import math
import pathlib
import re
import sys

import numpy as np

from softgrip_ros.argtypes import Number
from softgrip_ros.client import add_namespace_argument
from softgrip_ros.fileio import (OutputError, check_writable_directory, replacing,
                                write_text_atomically)
from softgrip_ros.model import bending_fit, gripper_models
from softgrip_ros.model.geometry import load_geometry
from softgrip_ros.tools import calibrate_live

NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]*$")


def parser() -> argparse.ArgumentParser:
    top = argparse.ArgumentParser(prog="softgrip_calibrate", description=__doc__,
                                  formatter_class=argparse.RawDescriptionHelpFormatter)
    top.add_argument("measurements", type=pathlib.Path, help="the CSV of measurements")
    top.add_argument("--name", required=True, help="the calibration's name (letters, digits, "
                     "_ and -), which the nodes' gripper_model parameter selects")
    top.add_argument("--geometry", type=pathlib.Path, help="your finger geometry (YAML, the "
                     "fields of config/gripper_geometry.yaml; default: the base model's)")
    top.add_argument("--geometry-type", help="the type to take when the geometry file has "
                     "several (default: its default_type)")
    top.add_argument("--base", default="type_II", help="the model whose constants the data do "
                     "not determine are inherited: a built-in type or a calibration "
                     "(default: type_II)")
    top.add_argument("--fit", help="comma-separated constants to fit instead of what the data "
                     f"determine: {', '.join(bending_fit.CONSTANTS)}")
    top.add_argument("--loss", default="linear", choices=("linear", "soft_l1", "huber", "cauchy"),
                     help="robust loss for outliers (default: linear, plain least squares)")
    top.add_argument("--confidence", type=Number(0.5, 1.0, high_open=True), default=0.95,
                     help="the intervals' level")
    top.add_argument("--output", type=pathlib.Path, help="the calibration file (default: "
                     "NAME.yaml in the calibration directory)")
    top.add_argument("--force", action="store_true", help="replace an existing calibration")
    top.add_argument("--no-plot", action="store_true", help="skip the figure")
    live = top.add_argument_group("live measurement (through the running controller)")
    live.add_argument("--live", action="store_true", help="hold each pressure and ask for the "
                      "measurements, appending them to the CSV, then fit")
    live.add_argument("--pressures", default="5000,10000,15000,20000,25000,30000,35000,40000",
                      help="the pressures to hold, Pa, comma-separated (default: 5 to 40 kPa)")
    live.add_argument("--columns", default="alpha_deg,tip_spacing_m", help="what you measure at "
                      "each (default: alpha_deg,tip_spacing_m)")
    add_namespace_argument(live)
    return top


def main(argv=None) -> int:
    top = parser()
    args = top.parse_args(argv)
    if not NAME_PATTERN.match(args.name) or args.name in gripper_models.built_in():
        top.error(f"--name {args.name!r}: letters, digits, _ and - only, and not a built-in "
                  f"type ({', '.join(gripper_models.built_in())})")
    output = args.output or gripper_models.calibration_dir() / f"{args.name}.yaml"
    command = "softgrip_calibrate " + " ".join(sys.argv[1:] if argv is None else argv)
    if args.live:
        columns = [c.strip() for c in args.columns.split(",") if c.strip()]
        unknown = [c for c in columns if c not in bending_fit.QUANTITIES]
        if unknown or not columns:
            top.error(f"--columns {args.columns!r}: give some of "
                      f"{', '.join(bending_fit.QUANTITIES)}")
        try:
            pressures = calibrate_live.parse_pressures(args.pressures)
        except ValueError as error:
            top.error(str(error))
    try:
        if output.exists() and not args.force:
            raise ValueError(f"{output} exists; --force replaces it")
        check_writable_directory(output.parent)  # before a fit whose result it could not keep
        if args.live:
            calibrate_live.measure(pressures, columns, args.measurements, args.namespace)
        print(f"reading {args.measurements}", flush=True)
        data = bending_fit.load_csv(args.measurements)
        base_geometry, base = gripper_models.resolve(args.base)
        geometry = (load_geometry(args.geometry_type, args.geometry) if args.geometry
                    else base_geometry)
        requested = [n.strip() for n in args.fit.split(",") if n.strip()] if args.fit else None
        names = bending_fit.choose_constants(data, requested)
        print(f"fitting {', '.join(names)} to {data.observations()} measured values at "
              f"{len(data)} pressures (then {len(data)} leave-one-out refits)", flush=True)
        result = bending_fit.fit(data, geometry, base, requested, args.loss, args.confidence)
    except (ValueError, OutputError) as error:
        print(f"softgrip_calibrate: {error}; nothing written", file=sys.stderr)
        return 1
    except ConnectionError as error:
        print(f"softgrip_calibrate: {error}", file=sys.stderr)
        return 3
    except (calibrate_live.LiveStopped, KeyboardInterrupt, EOFError) as error:
        reason = str(error) if isinstance(error, calibrate_live.LiveStopped) else "stopped"
        print(f"softgrip_calibrate: {reason}; vented; the rows measured so far are in "
              f"{args.measurements}; no calibration written", file=sys.stderr)
        return 1
    try:
        written = write(result, geometry, args, output, command)
    except OutputError as error:
        print(f"softgrip_calibrate: {error}", file=sys.stderr)
        return 1
    for flag in result.flags:
        print(f"softgrip_calibrate: flagged: {flag}", file=sys.stderr)
    print(summary(result))
    print(f"wrote {', '.join(str(p) for p in written)}\nselect it with: "
          f"-p gripper_model:={args.name if args.output is None else output}")
    return 0


def summary(result: bending_fit.BendingFit) -> str:
    lines = [f"{'constant':30s} {'value':>12s}  {result.confidence:.0%} interval / source"]
    for name, (value, _, (low, high)) in result.fitted.items():
        lines.append(f"{name:30s} {value:12.5g}  [{low:.5g}, {high:.5g}]")
    for name, value in result.inherited.items():
        lines.append(f"{name:30s} {value:12.5g}  inherited")
    return "\n".join(lines)


def _rms(values) -> float:
    finite = np.asarray(values)[np.isfinite(values)]
    return float(np.sqrt(np.mean(finite**2))) if finite.size else math.nan


def write(result: bending_fit.BendingFit, geometry, args, output: pathlib.Path,
          command: str) -> list:
    data = result.measurements
    fit_record = {
        "fitted": {n: {"value": v, "standard_error": se, "interval": [lo, hi]}
                   for n, (v, se, (lo, hi)) in result.fitted.items()},
        "inherited_from": args.base,
        "inherited": sorted(result.inherited),
        "confidence": result.confidence,
        "noise": "stated (std columns)" if result.noise_known else "estimated from residuals",
        "chi2_per_dof": result.chi2_per_dof,
        "loss": result.loss,
        "rms_residual": {c: _rms(r) for c, r in result.residuals.items()},
        "rms_leave_one_out": {c: _rms(r) for c, r in result.loo_residuals.items()},
        "flags": list(result.flags),
    }
    digest = hashlib.sha256(args.measurements.read_bytes()).hexdigest()
    provenance = {
        "source": "calibrated", "date": datetime.date.today().isoformat(),
        "tool": "softgrip_calibrate", "command": command,
        "measurements": f"{args.measurements} (sha256 {digest[:16]}), {len(data)} rows, "
                        f"pressures {data.pressure_pa.min():.0f} to "
                        f"{data.pressure_pa.max():.0f} Pa",
        "geometry": str(args.geometry) if args.geometry else f"{args.base}'s",
        "model": "L0 (eq. 16-17) with ballooning and saturation; L1 uses the same constants",
    }
    # the report and its figure first, the model last: a model on disk always has its report
    stem = output.with_name(f"{output.stem}_calibration")
    figure = None
    if not args.no_plot:
        figure = stem.with_suffix(".png")
        with replacing(figure) as temporary:
            plot(result, geometry, args.base, temporary)
    report = write_text_atomically(stem.with_suffix(".md"),
                                   markdown(result, fit_record, provenance, figure))
    model = gripper_models.write_file(output, args.name, geometry, result.calibration,
                                      _plain(fit_record), provenance)
    return [model, report] + ([figure] if figure else [])


def _plain(value):
    """numpy scalars and tuples as YAML's plain types."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return float(f"{float(value):.8g}") if math.isfinite(value) else None
    return value


def markdown(result, fit_record: dict, provenance: dict, figure) -> str:
    lines = ["# Bending calibration", "", f"Command: `{provenance['command']}`", "",
             f"- measurements: {provenance['measurements']}",
             f"- geometry: {provenance['geometry']}", f"- model: {provenance['model']}",
             f"- noise: {fit_record['noise']}; loss {result.loss}; chi^2/dof "
             f"{result.chi2_per_dof:.3g} over {result.dof} degrees of freedom", "",
             f"| constant | value | {result.confidence:.0%} interval | source |",
             "|---|---|---|---|"]
    for name, (value, _, (low, high)) in result.fitted.items():
        lines.append(f"| {name} | {value:.5g} | [{low:.5g}, {high:.5g}] | fitted |")
    for name, value in result.inherited.items():
        lines.append(f"| {name} | {value:.5g} | | inherited from {fit_record['inherited_from']} |")
    lines += ["", "| quantity | RMS residual | RMS leave-one-out |", "|---|---|---|"]
    for column in result.residuals:
        lines.append(f"| {column} | {fit_record['rms_residual'][column]:.4g} | "
                     f"{fit_record['rms_leave_one_out'].get(column, math.nan):.4g} |")
    lines += ["", "Leave-one-out: each row predicted by a fit without it. A row far beyond the "
              "others is worth measuring again.", ""]
    lines += ["## Flags", ""] + ([f"- {flag}" for flag in result.flags] or ["None."])
    if figure:
        lines += ["", f"![fit]({figure.name})"]
    return "\n".join(lines) + "\n"


def plot(result, geometry, base_name: str, path: pathlib.Path) -> pathlib.Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    data = result.measurements
    columns = list(data.values)
    figure, axes = plt.subplots(2, len(columns), figsize=(4.5 * len(columns), 6), squeeze=False,
                                sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    low = min(0.0, float(data.pressure_pa.min()))
    pressures = np.linspace(max(low, -20e3), float(data.pressure_pa.max()), 200)
    fitted = bending_fit.predict(geometry, result.calibration, pressures)
    _, base = gripper_models.resolve(base_name)
    before = bending_fit.predict(geometry, base, pressures)
    for i, column in enumerate(columns):
        top, bottom = axes[0, i], axes[1, i]
        measured = np.isfinite(data.values[column])
        kpa = data.pressure_pa[measured] / 1e3
        top.errorbar(kpa, data.values[column][measured], yerr=data.weights(column)[measured],
                     fmt="o", ms=4, label="measured")
        top.plot(pressures / 1e3, fitted[column], label="fitted")
        top.plot(pressures / 1e3, before[column], "--", label=f"{base_name} (before)")
        top.set_ylabel(bending_fit.QUANTITIES[column].label)
        bottom.plot(kpa, result.residuals[column][measured], "o", ms=4, label="residual")
        loo = result.loo_residuals.get(column)
        if loo is not None:
            bottom.plot(kpa, loo[measured], "x", label="leave-one-out")
        bottom.axhline(0.0, color="grey", lw=0.8)
        bottom.set_xlabel("gauge pressure (kPa)")
        bottom.set_ylabel("measured - model")
    axes[0, 0].legend(fontsize=8)
    axes[1, 0].legend(fontsize=8)
    figure.suptitle(f"softgrip_calibrate: {', '.join(result.fitted)} fitted")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


if __name__ == "__main__":
    raise SystemExit(main())

"""What softgrip_identify writes: the plant file with its provenance, a markdown report and its
plot of measured against fitted pressure with the residuals."""
from __future__ import annotations

import math
import pathlib

import numpy as np

from softgrip_ros.estimation.identification import Identification
from softgrip_ros.model import plant_file

FIGURE = "identification.png"
REPORT = "identification.md"
PLANT = "plant.yaml"


def description(result: Identification, base: plant_file.PlantDescription,
                provenance: dict) -> plant_file.PlantDescription:
    """The plant file of ``result``: every value with its source, interval and flag."""
    details = {}
    for name, estimate in result.estimates.items():
        detail = {"source": estimate.source}
        low, high = estimate.ci95
        if estimate.source == "identified" and math.isfinite(low) and math.isfinite(high):
            detail["ci95"] = [float(f"{low:.6g}"), float(f"{high:.6g}")]
        if estimate.flag:
            detail["flag"] = estimate.flag
        details[name] = detail
    sensors = dict(base.sensors)
    sensors.update({name: plant_file.SensorModel(result.sensor_noise_pa[name],
                                                 result.sensor_bias_pa[name])
                    for name in result.sensor_noise_pa})
    return plant_file.PlantDescription(result.parameters, sensors, provenance, details)


def plot(result: Identification, path: pathlib.Path) -> pathlib.Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    figure, (top, bottom) = plt.subplots(2, 1, figsize=(10, 6), sharex=True,
                                         gridspec_kw={"height_ratios": [2, 1]})
    origin = min(float(t[0]) for t, _, _ in result.trace.values() if len(t))
    for k, (name, (times, measured, fitted)) in enumerate(sorted(result.trace.items())):
        t = times - origin
        top.plot(t, measured / 1e3, ".", ms=1.5, color=f"C{k}", alpha=0.35,
                 label=f"{name} measured (bias off)")
        top.plot(t, fitted / 1e3, "-", lw=0.8, color=f"C{k}", label=f"{name} fitted model")
        bottom.plot(t, (measured - fitted) / 1e3, ".", ms=1.0, color=f"C{k}", alpha=0.5,
                    label=f"{name}: {result.residual_rms_pa[name]:.0f} Pa rms")
    top.set_ylabel("gauge pressure (kPa)")
    top.legend(fontsize=7, loc="upper right", ncol=2)
    top.set_title("identification: the fitted segments (held-out part not shown)", fontsize=9)
    bottom.set_ylabel("residual (kPa)")
    bottom.set_xlabel("time (s)")
    bottom.legend(fontsize=7, loc="upper right")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


def _number(value: float) -> str:
    return f"{value:.4g}" if math.isfinite(value) else str(value)


def markdown(result: Identification, base: plant_file.PlantDescription, provenance: dict,
             command: str) -> str:
    lines = [
        "# Pneumatic identification", "",
        f"Command: `{command}`; {provenance.get('date', '')}. Recording: "
        f"`{provenance.get('recording', '')}`. Fit: {result.fit_s:.1f} s.", "",
        f"Base file: `{provenance.get('base', '')}`. "
        f"Chamber volume: {provenance.get('volume', '')}. Pressure data fix each conductance "
        "and compliance only relative to the volume (see softgrip_ros.estimation."
        "identification), so they are as right as the volume is.", "",
        "| value | base | identified | 95 % interval | +-% | source | flag |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, estimate in result.estimates.items():
        if "." in name:
            continue
        low, high = estimate.ci95
        width = (100.0 * max(estimate.value - low, high - estimate.value) / abs(estimate.value)
                 if estimate.value and math.isfinite(low) and math.isfinite(high) else math.nan)
        base_value = getattr(base.parameters, name)
        lines.append(f"| `{name}` | {_number(base_value)} | {_number(estimate.value)} | "
                     f"{_number(low)} .. {_number(high)} | {_number(width)} | {estimate.source} "
                     f"| {estimate.flag} |")
    lines += ["", "| sensor | noise (Pa) | bias (Pa) | fit residual (Pa rms) | lag-1 "
              "autocorrelation |", "|---|---|---|---|---|"]
    for name in sorted(result.sensor_noise_pa):
        lines.append(f"| `{name}` | {result.sensor_noise_pa[name]:.0f} | "
                     f"{result.sensor_bias_pa[name]:+.0f} | {result.residual_rms_pa[name]:.0f} | "
                     f"{result.whiteness[name]:+.2f} |")
    lines += ["", "Validation on the held-out excitation: RMSE "
              f"{result.validation_rmse_pa:.0f} Pa, {result.validation_rmse_over_noise:.2f}x the "
              "sensors' noise (target <= 1.5).", ""]
    shifts_ms = 1e3 * np.array(list(result.switch_shifts_s.values()) or [0.0])
    lines += [f"Valve switches: the fit dated {len(result.switch_shifts_s)} of them from the "
              f"readings about each, moving them by {np.sqrt(np.mean(shifts_ms**2)):.2f} ms rms "
              f"(at most {np.abs(shifts_ms).max():.2f} ms) from their recorded times. Much more "
              "than a millisecond says the log's or the valves' timing is off.", ""]
    if result.sensor_delay_s:
        delays = ", ".join(f"`{name}` {1e3 * delay:+.2f} ms"
                           for name, delay in sorted(result.sensor_delay_s.items()))
        lines += [f"Sensor latency (each reading taken as the chamber that long before its "
                  f"stamp, fitted with the switches): {delays}. A negative one is a stamp "
                  "earlier than the reading, against the valve switches' clock.", ""]
    if result.flags:
        lines += ["**Flagged** (written, but not to be trusted as it stands):", ""]
        lines += [f"- {flag}" for flag in result.flags] + [""]
    else:
        lines += ["Nothing flagged.", ""]
    lines += [f"![measured against fitted pressure, and the residuals]({FIGURE})", ""]
    return "\n".join(lines)


def write(result: Identification, base: plant_file.PlantDescription, provenance: dict,
          output: pathlib.Path, command: str) -> dict:
    """Write the figure, the report and then the plant file into ``output`` (made if missing),
    each whole or not at all, so that a plant file on disk has its report; their paths.
    OutputError (one line) for what the file system refused."""
    from softgrip_ros.fileio import replacing, write_text_atomically
    provenance = dict(provenance, flags=list(result.flags),
                      validation_rmse_over_noise=round(result.validation_rmse_over_noise, 3),
                      fit_s=round(result.fit_s, 1))
    figure = output / FIGURE
    with replacing(figure) as temporary:
        plot(result, temporary)
    report = write_text_atomically(output / REPORT, markdown(result, base, provenance, command))
    plant = plant_file.save(description(result, base, provenance), output / PLANT,
                            header=f"identified by softgrip_identify: {command}\n"
                                   f"report: {REPORT}")
    return {"plant": plant, "report": report, "figure": figure}

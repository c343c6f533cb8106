"""softgrip_identify's known-object step: the fingers' contact learnt on a rigid object of known
size, so that the grasp sensing (docs/grasp_sensing.md) judges with this gripper's
``bending_volume_share`` and not the model's prediction.

    softgrip_identify --known-object-m 0.03 --base my_gripper/plant.yaml --output my_contact

Live, in the controller's identification mode: from an opening wider than the object, clamps on
nothing (the empty hand), then, once the user has placed the object between the fingers and
pressed Enter, clamps on it (softgrip_ros.estimation.contact_identification fits both). The
output's plant.yaml is the base file with its ``contact`` section; contact.md and contact.png say
how well the share is pinned and how the felt sizes moved.
"""
from __future__ import annotations

import dataclasses
import datetime
import pathlib
import select
import sys
import time

from softgrip_ros.estimation.grasp_sensing import AirRecord, MotionJob
from softgrip_ros.model import plant_file
from softgrip_ros.model.pneumatics import PlantInputs

REPORT, FIGURE = "contact.md", "contact.png"
OPEN_MARGIN_M = 0.01  # the opening clears the object by this much of D2
CLAMP_PA = -30e3  # deep enough that the closing's transient decides (docs/grasp_sensing.md)
OPEN_S, CLAMP_S = 1.5, 1.0  # the opening settles; the clamp's transient and its settling
# the object is asked for once the chamber reads the opening within this: an object brought in
# while the fingers still close on the last clamp is knocked away by them
OPEN_TOLERANCE_PA = 1e3
OPEN_TIMEOUT_S = 5.0  # ... and the step stops when it does not within this after OPEN_S
JUDGED_S = 0.8  # the part of a clamp that is fitted
STEADY_S = 0.3  # ... and the opening's readings before it, its starting pressure
# a clamp the controller interrupted (its valves held closed while its readings were late, say)
# is not the closing the fit models: it is done again, this many times in a step at most
MAX_REDONE = 4
EMPTY_CLOSINGS, OBJECT_CLOSINGS = 2, 3
PLACE_PROMPT = "then press Enter"


@dataclasses.dataclass(frozen=True)
class ContactPlan:
    """The step's pressures (Pa gauge): the opening wider than the object and the clamp."""

    known_size_m: float
    open_pa: float
    clamp_pa: float


def plan(model, known_size_m: float, max_pa: float, min_pa: float) -> ContactPlan:
    """Where to open and clamp for an object of ``known_size_m`` within the limits (Pa gauge);
    ValueError when the gripper cannot open around it."""
    open_pa = float(model.pressure_for_tip_spacing(known_size_m + OPEN_MARGIN_M))
    if not open_pa < max_pa:
        widest = model.tip_spacing_m(max_pa) * 1e3
        raise ValueError(f"a {known_size_m * 1e3:.1f} mm object needs an opening to "
                         f"{open_pa / 1e3:.1f} kPa, above the {max_pa / 1e3:.1f} kPa the limits "
                         f"allow ({widest:.0f} mm): use a smaller object")
    return ContactPlan(known_size_m, open_pa, max(CLAMP_PA, min_pa))


def run(live, contact_plan: ContactPlan, sensors: list, progress, wait_placed) -> list:
    """The closings, live (``live``: softgrip_ros.tools.identify.Live, in identification mode):
    [(kind 'empty' or 'object', when the clamp was sent, ROS s)]. ``wait_placed(check)`` blocks
    until the user has placed the object, calling ``check()`` meanwhile (EOFError: never).
    A clamp during which the controller changed its outputs again is done again (MAX_REDONE
    in all). Raises identify.Stopped."""
    from softgrip_ros.tools.identify import Stopped, hold_for
    with live.lock:
        live.recording = True
    closings, redone = [], 0
    for kind, count in (("empty", EMPTY_CLOSINGS), ("object", OBJECT_CLOSINGS)):
        if kind == "object":
            _open_for_placing(live, sensors, contact_plan.open_pa)
            progress(f"open for a {contact_plan.known_size_m * 1e3:.1f} mm object: place it "
                     f"between the fingers, level with their tip chambers, {PLACE_PROMPT}")

            def check():
                reason = live.problem(sensors)
                if reason:
                    raise Stopped(reason)
                live.send("SUPPLY", contact_plan.open_pa)
            try:
                wait_placed(check)
            except EOFError as error:  # no one to place the object
                raise Stopped(str(error)) from None
        index = 0
        while index < count:
            target = "nothing" if kind == "empty" else "the object"
            progress(f"clamp {index + 1}/{count} on {target}: open to "
                     f"{contact_plan.open_pa / 1e3:+.1f} kPa, clamp at "
                     f"{contact_plan.clamp_pa / 1e3:+.1f} kPa")
            live.send("SUPPLY", contact_plan.open_pa)
            hold_for(live, sensors, "SUPPLY", contact_plan.open_pa, OPEN_S)
            sent = live.node.get_clock().now().nanoseconds * 1e-9
            live.send("SUPPLY", contact_plan.clamp_pa)
            hold_for(live, sensors, "SUPPLY", contact_plan.clamp_pa, CLAMP_S)
            # the clamp's own change, and no other while the opening and the closing are read
            extra = live.output_changes_between(sent - STEADY_S, sent + JUDGED_S)[1:]
            if extra:
                redone += 1
                why = "; ".join(dict.fromkeys(message or "no message" for _, message in extra))
                if redone > MAX_REDONE:
                    raise Stopped(f"{redone} clamps interrupted by the controller (the last: "
                                  f"{why}): a busy host or a slow bus?")
                progress(f"clamp {index + 1}/{count} on {target} interrupted: the controller "
                         f"changed its outputs {len(extra)} times mid-clamp ({why}); again")
                continue
            closings.append((kind, sent))
            index += 1
    live.send("SUPPLY", contact_plan.open_pa)
    hold_for(live, sensors, "SUPPLY", contact_plan.open_pa, 0.5)
    with live.lock:
        live.recording = False
    return closings


def _open_for_placing(live, sensors: list, open_pa: float) -> None:
    """Hold the opening (Pa gauge) for OPEN_S, and on until the controller measures it within
    OPEN_TOLERANCE_PA; identify.Stopped when it does not within OPEN_TIMEOUT_S more."""
    from softgrip_ros.tools.identify import Stopped, hold_for
    live.send("SUPPLY", open_pa)
    hold_for(live, sensors, "SUPPLY", open_pa, OPEN_S)
    deadline = time.monotonic() + OPEN_TIMEOUT_S
    while not live.measured_gauge_pa() >= open_pa - OPEN_TOLERANCE_PA:
        if time.monotonic() > deadline:
            raise Stopped(f"the fingers did not open to {open_pa / 1e3:.1f} kPa for the object "
                          f"(the chamber reads {live.measured_gauge_pa() / 1e3:.1f} kPa)")
        hold_for(live, sensors, "SUPPLY", open_pa, 0.1)


def wait_for_enter(check, period_s: float = 0.05) -> None:
    """Block until a line arrives on stdin (Enter), calling ``check()`` every ``period_s``;
    EOFError when stdin ends first (no one to place the object)."""
    while True:
        check()
        ready, _, _ = select.select([sys.stdin], [], [], period_s)
        if ready:
            if not sys.stdin.readline():
                raise EOFError("stdin closed before the object was placed")
            return


def jobs_from_log(recording, info: dict, base: plant_file.PlantDescription) -> tuple:
    """(closings on the object, closings on nothing) as MotionJobs, from a log's Recording
    (softgrip_identify.recording_from_log) and its info. The readings are taken as the
    controller published them (the base file's biases off), as the sensing reads them."""
    contact = info["contact"]
    clamp_pa = float(contact["clamp_pa"])
    changes = sorted(recording.inputs, key=lambda change: change.time_s)
    inputs = [(c.time_s, PlantInputs(c.regulator_setpoint_pa, c.regulator_enabled, (c.valve,)))
              for c in changes]
    readings = []
    for name, (times, values) in recording.sensors.items():
        sensor = base.sensor(name)
        readings += [(float(t), float(v) - sensor.bias_pa, sensor.noise_std_pa)
                     for t, v in zip(times, values)]
    readings.sort()
    object_jobs, empty_jobs = [], []
    for kind, sent in contact["closings"]:
        start = next((c.time_s for c in changes if c.time_s >= sent - 0.05 and
                      abs(c.regulator_setpoint_pa - clamp_pa) < 1.0), None)
        if start is None:
            raise ValueError(f"the log holds no clamp output after {sent:.3f} s")
        before = sorted(v for t, v, _ in readings if start - STEADY_S <= t < start - 0.01)
        if len(before) < 5:
            raise ValueError(f"the log holds no steady opening before the clamp at {start:.3f} s")
        record = AirRecord(start, before[len(before) // 2])
        for stamp, value in inputs:
            record.add_inputs(stamp, value)
        for stamp, value, std in readings:
            if start < stamp <= start + JUDGED_S:
                record.add_sample(stamp, value, std)
        job = MotionJob(record, False, float(contact["known_object_m"]), clamp_pa,
                        start + JUDGED_S)
        (object_jobs if kind == "object" else empty_jobs).append(job)
    return object_jobs, empty_jobs


def description(fit, base: plant_file.PlantDescription, provenance: dict
                ) -> plant_file.PlantDescription:
    """The base plant file with the identified share in its contact section."""
    details = dict(base.details)
    details["contact.bending_volume_share"] = {
        "source": "identified", "ci95": [float(f"{b:.4g}") for b in fit.ci95],
        "known_object_m": float(fit.known_size_m)}
    merged = dict(base.provenance)
    merged["contact"] = provenance
    return dataclasses.replace(base, provenance=merged, details=details,
                               bending_volume_share=float(f"{fit.bending_volume_share:.4g}"))


def write(fit, base: plant_file.PlantDescription, model_share: float, output: pathlib.Path,
          command: str) -> dict:
    """contact.png, contact.md and then plant.yaml into ``output`` (made if missing), each
    written whole or not at all, so that a plant file on disk has its report. OutputError (one
    line) for what the file system refused."""
    from softgrip_ros.fileio import write_text_atomically
    provenance = {"source": "identified", "date": datetime.date.today().isoformat(),
                  "tool": "softgrip_identify --known-object-m",
                  "object_m": float(fit.known_size_m)}
    figure = _plot(fit, model_share, output / FIGURE)
    low, high = fit.ci95
    felt = ", ".join(f"{s * 1e3:.1f}" for s in fit.felt_sizes_m)
    before = ", ".join(f"{s * 1e3:.1f}" for s in fit.felt_sizes_before_m)
    report = "\n".join([
        "# Contact identification",
        "",
        f"`{command}`",
        "",
        f"Clamps from {fit.known_contact_pa / 1e3:.1f} kPa of the fingers' shape: on a "
        f"{fit.known_size_m * 1e3:.1f} mm rigid object and on nothing.",
        "",
        "| | value |",
        "|---|---|",
        f"| `bending_volume_share` identified | {fit.bending_volume_share:.3f} "
        f"(95 %: {low:.3f} to {high:.3f}) |",
        f"| the model's prediction | {model_share:.3f} |",
        f"| sizes felt on the object, identified share (mm) | {felt} |",
        f"| ... with the model's prediction (mm) | {before} |",
        f"| reduced chi-square | {fit.reduced_chi2:.2f} |",
        "",
        f"![chi-square against the share]({FIGURE})",
        "",
    ])
    write_text_atomically(output / REPORT, report)
    plant = plant_file.save(description(fit, base, provenance), output / "plant.yaml",
                            f"softgrip_ros plant, its contact identified: {command}")
    return {"plant": plant, "report": output / REPORT, "figure": figure}


def _plot(fit, model_share: float, path: pathlib.Path) -> pathlib.Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    figure, axes = plt.subplots(figsize=(7, 4))
    costs = np.array(fit.costs)
    axes.plot(fit.shares, costs - costs.min(), "-", lw=1.0, label="closings' chi-square")
    axes.axvline(fit.bending_volume_share, color="C1", label="identified")
    axes.axvspan(*fit.ci95, color="C1", alpha=0.2, label="95 % interval")
    axes.axvline(model_share, color="C2", ls="--", label="the model's prediction")
    axes.set_yscale("symlog")
    axes.set_xlabel("bending_volume_share")
    axes.set_ylabel("chi-square above its minimum")
    axes.legend(fontsize=8)
    figure.tight_layout()
    from softgrip_ros.fileio import replacing
    with replacing(path) as temporary:
        figure.savefig(temporary, dpi=110)
    plt.close(figure)
    return path

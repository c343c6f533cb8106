"""softgrip_replay: run a recorded trial through the estimator and kinematics cores, offline.

    softgrip_replay trial1                 # as fast as it goes
    softgrip_replay trial1 --speed 1       # at the recorded pace

It reads a softgrip_record bag, builds the estimator the recorded run had (its parameters from
the bag's custom_data, else the defaults), and runs it through the estimator's journal
(pressure/estimator_input: every event it took, in the order it took them). On the same code the
replayed estimates equal the recorded ones to within 1e-9 relative; a difference shows what
changed, and where it starts. Without a journal it runs the recorded sensor readings and
controller status in stamp order instead, the readings batched at the recorded estimates'
instants: close, not exact. The kinematics core (free bending, the grasp manager's default
model) turns each replayed estimate into the tip spacing D2, beside the one grasp_state
recorded.

Writes into --output (default: BAG_replay/): estimates.csv, replay.png (pressure, estimates and
D2 over time, with the recorded estimate beside the replayed one) and summary.json. Use it for
bug reports, and for identification from logs (softgrip_identify --from-log).

Exit status: 0 the recorded estimates reproduced (or nothing recorded to compare with); 1 they
differ beyond 1e-9; 2 bad input (not a bag, a truncated or corrupt one, no readings in it).
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import pathlib
import statistics
import sys
import time

from softgrip_ros.argtypes import Number

REPRODUCED_RELATIVE = 1e-9
SENSOR_RANGE_PA = (-101_325.0, 700_000.0)  # PressureSensor1/2's GaugePressure in the DBC
D2_POINTS = 2000  # the kinematics is evaluated at most this often over the run


def parser() -> argparse.ArgumentParser:
    top = argparse.ArgumentParser(prog="softgrip_replay", description=__doc__,
                                  formatter_class=argparse.RawDescriptionHelpFormatter)
    top.add_argument("bag", type=pathlib.Path, help="a softgrip_record bag directory")
    pace = top.add_mutually_exclusive_group()
    pace.add_argument("--speed", type=Number(0.0, 1000.0, low_open=True),
                      help="replay at this multiple of the recorded pace (e.g. 1 or 10)")
    pace.add_argument("--fast", action="store_true", help="as fast as it goes (the default)")
    top.add_argument("--output", type=pathlib.Path, help="where to write (default: BAG_replay)")
    top.add_argument("--no-plot", action="store_true", help="write no replay.png")
    return top


def _plausible(gauge_pa: float) -> bool:
    """Whether a gauge pressure lies in the range a sensor frame can carry (the DBC's)."""
    return SENSOR_RANGE_PA[0] <= gauge_pa <= SENSOR_RANGE_PA[1]


def load(path: pathlib.Path) -> dict:
    """What a replay needs from the bag; ValueError when it cannot be read or a reading in it
    is impossible (not finite, beyond the sensors' range)."""
    from softgrip_ros.control.reports import outputs_changed_at
    from softgrip_ros.estimation.runner import JOURNAL_TOPIC, Event
    from softgrip_ros.model.pneumatics import P_ATM_PA
    from softgrip_ros.nodes.common import stamp_seconds
    from softgrip_ros.tools import bag
    found = {"journal": [], "estimates": [], "sensors": [], "status": [], "d2": []}
    for topic, _, _, message in bag.read(path, bag.note_unknown):
        if topic.endswith(JOURNAL_TOPIC):
            samples = tuple(zip(message.sensor_names, map(float, message.gauge_pressure_pa),
                                map(float, message.sample_stamps_s)))
            command_pa = float(message.regulator_command_gauge_pressure_pa)
            # NaN: an event that carries no command
            if not ((math.isnan(command_pa) or _plausible(command_pa)) and all(
                    _plausible(gauge) and math.isfinite(stamp) for _, gauge, stamp in samples)):
                raise ValueError(f"{path}: estimator journal event {int(message.sequence)} holds "
                                 "a reading or a command no sensor or regulator can give")
            found["journal"].append(Event(
                int(message.sequence), int(message.kind), samples, command_pa,
                bool(message.regulator_enabled), int(message.valve), float(message.stamp_s)))
        elif topic.endswith("pressure/estimate"):
            found["estimates"].append((message.header.stamp.sec, message.header.stamp.nanosec,
                                       float(message.fluid_pressure), float(message.variance)))
        elif "/pressure/sensor/" in topic:
            gauge_pa = float(message.fluid_pressure) - P_ATM_PA
            if not _plausible(gauge_pa):
                raise ValueError(f"{path}: a reading on {topic} ({gauge_pa:g} Pa gauge) no "
                                 "sensor can give")
            found["sensors"].append((stamp_seconds(message.header.stamp), topic.rsplit("/", 1)[1],
                                     gauge_pa))
        elif topic.endswith("controller/status") and len(message.valve_states):
            # as the estimator takes it: from when its outputs went out
            found["status"].append((outputs_changed_at(stamp_seconds(message.header.stamp),
                                                       float(message.output_change_age_s)),
                                    float(message.regulator_command_gauge_pressure_pa),
                                    bool(message.regulator_enabled),
                                    int(message.valve_states[0])))
        elif topic.endswith("grasp_state"):
            found["d2"].append((stamp_seconds(message.header.stamp), float(message.tip_spacing_m)))
    found["custom"] = bag.custom_data(path)
    return found


def events_from_topics(found: dict) -> list:
    """No journal: the readings and the controller's status in stamp order, as events. The
    readings go in batches that end where a recorded estimate's stamp is a reading's: the live
    estimator gave an estimate at the newest reading of a batch, so the replay gives its own at
    the same instants and fuses its windows there (one reading at a time, its estimates fell
    between the recorded ones: 6 of ~300 shared a stamp in CI)."""
    from softgrip_ros.estimation.runner import INPUTS, SAMPLES, Event
    timeline = [(s, 0, (name, gauge)) for s, name, gauge in found["sensors"]]
    timeline += [(s, 1, rest) for s, *rest in found["status"]]
    estimated = {sec * 10**9 + nanosec for sec, nanosec, *_ in found["estimates"]}
    events, batch = [], []

    def close_batch():
        if batch:
            events.append(Event(len(events), SAMPLES, tuple(batch)))
            batch.clear()

    for stamp, kind, payload in sorted(timeline, key=lambda e: e[:2]):
        if kind == 0:
            batch.append((payload[0], payload[1], stamp))
            if not estimated or round(stamp * 1e9) in estimated:
                close_batch()
        else:
            close_batch()
            command, enabled, valve = payload
            events.append(Event(len(events), INPUTS, (), command, enabled, valve, stamp))
    close_batch()
    return events


def build_runner(custom: dict):
    """The estimator the recorded run had: (runner, the parameter values, a note)."""
    import yaml

    from softgrip_ros.estimation.estimator import PressureEstimator
    from softgrip_ros.estimation.runner import EstimatorRunner
    from softgrip_ros.model.pneumatics import PneumaticPlant
    from softgrip_ros.nodes.specs import ESTIMATOR_SPECS, estimator_config, load_plant
    specs = {spec.name: spec for spec in ESTIMATOR_SPECS}
    values = {name: spec.default for name, spec in specs.items()}
    recorded = custom.get("softgrip.estimator_parameters")
    note = "the estimator's recorded parameters"
    if recorded:
        try:
            parameters = yaml.safe_load(recorded)
        except yaml.YAMLError:
            parameters = None
        if not isinstance(parameters, dict):
            raise ValueError("the bag's softgrip.estimator_parameters is not a YAML mapping")
        for name, value in parameters.items():
            # a parameter this version does not have is the recording's, not the replay's
            if name in specs:
                problem = specs[name].check(value)
                if problem:
                    raise ValueError(f"the bag's estimator parameters: {problem}")
                values[name] = value
    else:
        note = "no parameters in the bag: the estimator's defaults"
    plant = load_plant(values)
    estimator = PressureEstimator(estimator_config(values, plant),
                                  PneumaticPlant(plant.parameters))
    return (EstimatorRunner(estimator, 1.0 / values["frequency"],
                            1.0 / values["rest_frequency"]), values, note)


def run(runner, events, speed: float | None):
    """The replayed estimates, paced at ``speed`` times the recorded pace (None: at once)."""
    from softgrip_ros.estimation.runner import SAMPLES
    estimates, start_wall, start_stamp = [], time.monotonic(), None
    for event in sorted(events, key=lambda e: e.sequence):
        if speed is not None:
            stamp = event.samples[-1][2] if event.kind == SAMPLES else event.stamp_s
            if math.isfinite(stamp):
                start_stamp = stamp if start_stamp is None else start_stamp
                delay = (stamp - start_stamp) / speed - (time.monotonic() - start_wall)
                if delay > 0.0:
                    time.sleep(delay)
        estimate = runner.apply(event)
        if estimate is not None:
            estimates.append(estimate)
    return estimates


def compare(replayed: list, recorded: list) -> dict:
    """Recorded estimates against the replayed ones of the same stamp (to the nanosecond)."""
    from softgrip_ros.model.pneumatics import P_ATM_PA
    by_stamp = {}
    for e in replayed:
        nanoseconds = round(e.stamp_s * 1e9)
        by_stamp[(nanoseconds // 10**9, nanoseconds % 10**9)] = e
    worst, worst_at, matched, first_off = 0.0, math.nan, 0, None
    worst_pa = worst_variance = 0.0
    differences_pa = []
    for sec, nanosec, absolute_pa, variance in recorded:
        e = by_stamp.get((sec, nanosec))
        if e is None:
            continue
        matched += 1
        difference_pa = abs(e.gauge_pa + P_ATM_PA - absolute_pa)
        variance_off = abs(e.variance_pa2 - variance) / max(abs(variance), 1e-300)
        worst_pa, worst_variance = max(worst_pa, difference_pa), max(worst_variance, variance_off)
        differences_pa.append(difference_pa)
        off = max(difference_pa / abs(absolute_pa), variance_off)
        if off > REPRODUCED_RELATIVE and first_off is None:
            first_off = sec + 1e-9 * nanosec
        if off > worst:
            worst, worst_at = off, sec + 1e-9 * nanosec
    return {"recorded": len(recorded), "replayed": len(replayed), "matched": matched,
            "max_relative_difference": worst, "at_s": worst_at, "first_beyond_s": first_off,
            "max_pressure_difference_pa": worst_pa,
            "median_pressure_difference_pa": (statistics.median(differences_pa)
                                              if differences_pa else math.nan),
            "p95_pressure_difference_pa": (statistics.quantiles(differences_pa, n=20)[-1]
                                           if len(differences_pa) > 1 else math.nan),
            "max_variance_relative_difference": worst_variance}


def d2_of(estimates: list, fidelity: str = "l0", gripper_model: str = "type_II") -> list:
    """(stamp, D2 m) in free bending, as grasp_state reports it (the grasp manager's default
    model, L0), for at most D2_POINTS of ``estimates``."""
    from softgrip_ros.model.calibration import build_kinematics
    model = build_kinematics(fidelity, gripper_model)
    low, high = model.MODEL_MIN_PRESSURE_PA, model.MODEL_MAX_PRESSURE_PA
    every = max(1, len(estimates) // D2_POINTS)
    return [(e.stamp_s, model.pose(min(max(e.gauge_pa, low), high)).tip_spacing_m)
            for e in estimates[::every]]


def plot(path: pathlib.Path, found: dict, replayed: list, d2: list) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from softgrip_ros.model.pneumatics import P_ATM_PA
    stamps = [e.stamp_s for e in replayed] or [0.0]
    t0 = min(stamps)
    figure, (pressure, difference, spacing) = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    for name in sorted({n for _, n, _ in found["sensors"]}):
        points = [(s - t0, g / 1e3) for s, n, g in found["sensors"] if n == name]
        pressure.plot(*zip(*points), ".", ms=1.5, alpha=0.4, label=f"sensor {name}")
    recorded = [(sec + 1e-9 * ns - t0, (a - P_ATM_PA) / 1e3)
                for sec, ns, a, _ in found["estimates"]]
    if recorded:
        pressure.plot(*zip(*recorded), "-", lw=2.5, alpha=0.5, label="estimate, recorded")
    pressure.plot([s - t0 for s in stamps[:len(replayed)]],
                  [e.gauge_pa / 1e3 for e in replayed], "-", lw=1, label="estimate, replayed")
    pressure.set_ylabel("gauge pressure (kPa)")
    pressure.legend(loc="best", fontsize=8)
    by_stamp = {round(e.stamp_s * 1e9): e.gauge_pa for e in replayed}
    gaps = [(sec + 1e-9 * ns - t0, abs(by_stamp[sec * 10**9 + ns] + P_ATM_PA - a) / a)
            for sec, ns, a, _ in found["estimates"] if sec * 10**9 + ns in by_stamp]
    if gaps and max(g for _, g in gaps) == 0.0:
        difference.text(0.5, 0.5, f"all {len(gaps)} recorded estimates reproduced exactly "
                        "(difference 0)", transform=difference.transAxes, ha="center")
        difference.set_yscale("log")
        difference.set_ylim(1e-17, 1e-6)
    elif gaps:
        difference.semilogy(*zip(*[(t, max(g, 1e-17)) for t, g in gaps]), ".", ms=2)
    difference.axhline(REPRODUCED_RELATIVE, color="r", lw=1, label="1e-9")
    difference.set_ylabel("|replayed - recorded|\n/ recorded (abs. pressure)")
    difference.legend(loc="best", fontsize=8)
    if d2:
        spacing.plot([s - t0 for s, _ in d2], [v * 1e3 for _, v in d2], "-",
                     label="D2 from the replayed estimate (free bending)")
    if found["d2"]:
        spacing.plot([s - t0 for s, _ in found["d2"]], [v * 1e3 for _, v in found["d2"]], ".",
                     ms=2, label="D2, recorded (grasp_state)")
    spacing.set_ylabel("tip spacing D2 (mm)")
    spacing.set_xlabel("time (s)")
    spacing.legend(loc="best", fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def replay(path: pathlib.Path, speed: float | None) -> tuple:
    """The bag at ``path`` read and run through the estimator: (found, replayed estimates,
    source, note), where ``found`` is :func:`load`'s, ``source`` says which events ran and
    ``note`` which parameters. ValueError, in one line, for a bag that cannot be read or whose
    recorded parameters do not hold, and for one with nothing to replay."""
    found = load(path)
    events = found["journal"]
    source = "the estimator's journal"
    if events and min(e.sequence for e in events) != 0:
        source += (f" from event {min(e.sequence for e in events)} (recorded after the "
                   "estimator's start: its state then is unknown, and the first estimates "
                   "differ)")
    sequences = sorted(e.sequence for e in events)
    lost = sum(b - a - 1 for a, b in zip(sequences, sequences[1:]) if b - a > 1)
    if lost:
        source += f", with {lost} events lost in recording (the replay diverges from the first)"
    if not events:
        events = events_from_topics(found)
        source = ("no journal: the sensor readings and controller status in stamp order, "
                  "batched at the recorded estimates' instants (close, not exact)")
    if not events:
        raise ValueError(f"{path} holds no sensor readings and no estimator journal")
    runner, _, note = build_runner(found["custom"])
    print(f"[replay] {len(events)} events ({source}); {note}", file=sys.stderr, flush=True)
    return found, run(runner, events, speed), source, note


def write_outputs(output: pathlib.Path, found: dict, replayed: list, summary: dict,
                  plot_it: bool) -> None:
    """estimates.csv, summary.json and (``plot_it``) replay.png into ``output``, each whole or
    not at all; OutputError (one line) for what the file system refused."""
    import io

    from softgrip_ros.fileio import replacing, write_text_atomically
    rows = io.StringIO()
    writer = csv.writer(rows)
    writer.writerow(["stamp_s", "gauge_pa", "variance_pa2"])
    for e in replayed:
        writer.writerow([f"{e.stamp_s:.9f}", repr(e.gauge_pa), repr(e.variance_pa2)])
    write_text_atomically(output / "estimates.csv", rows.getvalue())
    write_text_atomically(output / "summary.json", json.dumps(summary, indent=1))
    if plot_it:
        with replacing(output / "replay.png") as temporary:
            plot(temporary, found, replayed, d2_of(replayed))


def main(argv=None) -> int:
    from softgrip_ros.fileio import OutputError, check_writable_directory
    args = parser().parse_args(argv)
    output = args.output or args.bag.with_name(args.bag.name + "_replay")
    try:
        check_writable_directory(output)
        found, replayed, source, _ = replay(args.bag, args.speed)
    except (ValueError, OutputError) as error:
        print(f"softgrip_replay: {error}", file=sys.stderr)
        return 2
    summary = compare(replayed, found["estimates"])
    summary["source"] = source
    try:
        write_outputs(output, found, replayed, summary, not args.no_plot)
    except OutputError as error:
        print(f"softgrip_replay: {error}", file=sys.stderr)
        return 2
    reproduced = summary["max_relative_difference"] <= REPRODUCED_RELATIVE
    print(f"[replay] {summary['replayed']} estimates replayed, {summary['matched']} of "
          f"{summary['recorded']} recorded ones matched by stamp; largest relative difference "
          f"{summary['max_relative_difference']:.3g} (pressure "
          f"{summary['max_pressure_difference_pa']:.3g} Pa, variance "
          f"{summary['max_variance_relative_difference']:.3g} of it)" +
          ("" if reproduced else f", beyond 1e-9 from t = {summary['first_beyond_s']:.3f} s") +
          f"; wrote {output}")
    return 0 if reproduced else 1


if __name__ == "__main__":
    sys.exit(main())

"""The estimator's event rules, free of ROS, and the journal that replays them.

The estimator node takes three kinds of event: a batch of readings (after which an estimate goes
out when one is due), new process-model inputs (the controller's status, or a VENT or HOLD
command), and, while no reading comes, a prediction on its timer. :class:`EstimatorRunner` holds
those rules; the node calls it under its lock and publishes what it returns. Each event it takes
is also handed to ``journal`` as an :class:`Event` with a sequence number, in the order taken:
``softgrip_record`` logs them (pressure/estimator_input), and :func:`replay` runs a fresh
estimator through them to the same estimates, bit for bit on the same code and configuration.
"""
from __future__ import annotations

import dataclasses
import math

from softgrip_ros.estimation.estimator import Estimate, PressureEstimator

SAMPLES, INPUTS, PREDICT = 0, 1, 2  # the kinds of softgrip_interfaces/msg/EstimatorInput
JOURNAL_TOPIC = "pressure/estimator_input"  # where the estimator node publishes the journal
# the journal goes out for this long after the node's start whether or not anyone listens, and
# the last JOURNAL_HISTORY events stay for a subscriber that joins late (transient local): a
# recorder started before the controller gets it from its first event, which an exact replay
# needs
JOURNAL_STARTUP_S = 5.0
JOURNAL_HISTORY = 5000
# the timer predicts once neither a reading nor an estimate has come for two of its periods; it
# runs at most this often
PREDICTION_RATE_LIMIT_HZ = 50.0
# the longest the controller's status may pause before the report's clock runs on without it
STATUS_STALL_S = 0.5


def report_time_s(now_s: float, status_received_s: float | None) -> float:
    """The time at which the sensors' silence is judged: when the controller that carries their
    readings last reached this estimator, not the wall clock, while its status keeps coming.

    A loaded host holds up the controller, the bus reader and this node together now and then
    (bench_faults: 1 false "all sensors silent" in 60 fault-free grasps beside a busy process,
    at a 0.1 s threshold); after such a stall the report timer may run before the queued
    readings, which is no silence of the sensors. A silent bus keeps the status coming, so its
    silence is still seen at once; with no status for STATUS_STALL_S, or none yet, the wall
    clock judges."""
    if status_received_s is None or now_s - status_received_s > STATUS_STALL_S:
        return now_s
    return min(now_s, status_received_s)


@dataclasses.dataclass(frozen=True)
class Event:
    """One event as the estimator took it. samples: ((sensor name, gauge Pa, stamp s), ...)."""

    sequence: int
    kind: int
    samples: tuple = ()
    regulator_command_gauge_pa: float = math.nan
    regulator_enabled: bool = False
    valve: int = 0
    stamp_s: float = math.nan


class EstimatorRunner:
    """``estimator`` driven by events (see the module docstring).

    period_s, rest_period_s: an estimate after a batch of readings at most this often (while the
    chamber moves, while it rests). journal(event): told of each event taken, in order."""

    def __init__(self, estimator: PressureEstimator, period_s: float, rest_period_s: float,
                 journal=None):
        self.estimator = estimator
        self.period_s, self.rest_period_s = period_s, rest_period_s
        self.journal = journal
        self.last_publish_s = self.last_sample_s = -math.inf
        self._sequence = 0

    def _record(self, kind: int, **fields) -> None:
        if self.journal is not None:
            self.journal(Event(self._sequence, kind, **fields))
        self._sequence += 1

    def samples(self, samples) -> tuple[Estimate | None, ValueError | None]:
        """Readings [(sensor name, gauge Pa, stamp s)], oldest first; (the estimate, when one is
        due: the newest; the first ValueError of an unknown sensor, the others taken)."""
        samples = tuple((str(n), float(p), float(s)) for n, p, s in samples)
        self._record(SAMPLES, samples=samples)
        refused, newest = None, None
        for name, gauge_pa, stamp_s in samples:
            try:
                taken = self.estimator.add_measurement(name, gauge_pa, stamp_s)
            except ValueError as error:  # an unknown sensor: the rest of the batch still counts
                refused, taken = refused or error, False
            if taken:
                newest = stamp_s if newest is None else max(newest, stamp_s)
        if newest is not None:
            self.last_sample_s = max(self.last_sample_s, newest)
        due = newest is not None and newest - self.last_publish_s >= 0.9 * (
            self.rest_period_s if self.estimator.resting else self.period_s)
        return (self._take_estimate() if due else None), refused

    def inputs(self, regulator_command_gauge_pa: float, regulator_enabled: bool, valve: int,
               stamp_s: float) -> None:
        """The process model's inputs from ``stamp_s`` on; ValueError for a NaN command or an
        unknown valve (the last inputs kept)."""
        self._record(INPUTS, regulator_command_gauge_pa=float(regulator_command_gauge_pa),
                     regulator_enabled=bool(regulator_enabled), valve=int(valve),
                     stamp_s=float(stamp_s))
        self.estimator.set_inputs(regulator_command_gauge_pa, regulator_enabled, valve, stamp_s)

    def quiet(self, now: float) -> bool:
        """Whether neither a reading nor an estimate has come for two timer periods."""
        return self.estimator.initialised and now - max(
            self.last_publish_s, self.last_sample_s) >= 2.0 / PREDICTION_RATE_LIMIT_HZ

    def predict(self, now: float) -> Estimate | None:
        """The timer's prediction to ``now``, when :meth:`quiet`; committed: a reading older than
        it would be dropped as late anyway, and the published estimates' stamps never go back.
        (Uncommitted, an input held up behind a stalled thread would still count at its own
        stamp; tried, and the quick fault matrix's fault-free grasps then warned in CI, 3 NIS
        warnings in 2 grasps: not adopted.)"""
        if not self.quiet(now):
            return None
        return self._predict(float(now))

    def _predict(self, now: float) -> Estimate | None:
        self._record(PREDICT, stamp_s=now)
        self.estimator.predict_to(now)
        return self._take_estimate()

    def _take_estimate(self) -> Estimate | None:
        estimate = self.estimator.estimate()
        if estimate is not None:
            self.last_publish_s = estimate.stamp_s
        return estimate

    def apply(self, event: Event) -> Estimate | None:
        """Take a journal's event again (the estimate it gave, if any); errors as the original
        gave them are swallowed, as the node did."""
        if event.kind == SAMPLES:
            return self.samples(event.samples)[0]
        if event.kind == INPUTS:
            try:
                self.inputs(event.regulator_command_gauge_pa, event.regulator_enabled,
                            event.valve, event.stamp_s)
            except ValueError:
                pass
            return None
        if event.kind == PREDICT:
            return self._predict(event.stamp_s)  # the original was quiet then
        raise ValueError(f"unknown event kind {event.kind}")


def replay(runner: EstimatorRunner, events) -> list[Estimate]:
    """Every estimate ``runner`` gives for ``events``, taken in sequence order. ValueError when
    the sequence has a gap (a journal recorded with loss: the replay would diverge)."""
    estimates, expected = [], None
    for event in sorted(events, key=lambda e: e.sequence):
        if expected is not None and event.sequence != expected:
            raise ValueError(f"the journal lacks events {expected}..{event.sequence - 1}: it was "
                             "recorded with loss, and a replay would diverge from there")
        expected = event.sequence + 1
        estimate = runner.apply(event)
        if estimate is not None:
            estimates.append(estimate)
    return estimates

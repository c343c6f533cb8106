"""estimator: fuses the chamber pressure sensors into pressure/estimate (FluidPressure, absolute
Pa, with its variance).

In: pressure/sensor/<name> for each configured sensor; controller/status (the regulator command
and valve state, the process model's inputs); pressure/command (a VENT or HOLD is applied to the
model at once, ahead of the status that confirms it). Out: pressure/estimate, stamped with the
time the estimate refers to, after a sample (at most ``frequency``; while the chamber rests, at
most ``rest_frequency``: nothing moves, and every estimate costs the kinematics and the grasp
manager work and its subscribers a message) and, once neither a sample nor an estimate has come
for two periods of a timer at min(``frequency``, 50 Hz), the prediction: every 40 ms by default
while the sensors are silent (an rclpy timer at hundreds of Hz would starve the sensor
callbacks); /diagnostics at 2 Hz; pressure/estimator_input (EstimatorInput), the journal of every
event taken, while someone subscribes and for the first JOURNAL_STARTUP_S after start-up (kept
for a subscriber that joins late, transient local): what softgrip_replay runs again.
Parameters follow robot_localization where they fit. The filters live in softgrip_ros.estimation;
the event rules in softgrip_ros.estimation.runner.
"""
from __future__ import annotations

import collections
import threading

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from sensor_msgs.msg import FluidPressure

from softgrip_interfaces.msg import (ControllerStatus, EstimatorConsistency, EstimatorInput,
                                     PressureCommand)
from softgrip_ros.control.pressure import Source
from softgrip_ros.estimation.estimator import PressureEstimator
from softgrip_ros.estimation.runner import (JOURNAL_HISTORY, JOURNAL_STARTUP_S, JOURNAL_TOPIC,
                                             PREDICTION_RATE_LIMIT_HZ, EstimatorRunner,
                                             report_time_s)
from softgrip_ros.health import Health
from softgrip_ros.model.pneumatics import PneumaticPlant, Valve
from softgrip_ros.checks import future_stamp_reason
from softgrip_ros.nodes import messages
from softgrip_ros.nodes.common import NodeTimers, listened, publish, run_node, stamp_seconds
from softgrip_ros.nodes.parameters import check_all, declare
from softgrip_ros.nodes.specs import ESTIMATOR_SPECS as SPECS
from softgrip_ros.nodes.specs import estimator_config, load_plant
from softgrip_ros.runtime.core import (Consistency, ControllerReport, Estimate, Port,
                                       PressureOrder, Reading)

ESTIMATOR_STATUS = "softgrip: estimator"  # its /diagnostics status
# the NIS evidence for the pressure controller's safety checks, this often
EVIDENCE_PERIOD_S = 0.1
REFUSAL_REPORTED_S = 5.0  # a refused message keeps the diagnostics at WARN this long


class EstimatorNode(Node):
    """The estimator part of the runtime core (runtime.core): ports ``estimates`` and
    ``consistency``, emitted outside the estimator's lock, which is never held while calling out
    (so that no two parts' locks can wait on each other); inputs :meth:`take_readings`,
    :meth:`take_report` and :meth:`take_order`. in_process: composed, the inputs come from the
    pressure controller and the grasp manager by direct call (runtime.core.wire) instead of
    through their topics.
    """

    def __init__(self, in_process: bool = False, **kwargs):
        super().__init__("estimator", **kwargs)
        # the in-process path calls in from the controller's CAN thread
        self._lock = threading.Lock()
        self.estimates: Port[Estimate] = Port("estimates")
        # each sensor's NIS evidence, every EVIDENCE_PERIOD_S while connected
        self.consistency: Port[Consistency] = Port("consistency")
        self.future_stamps = 0  # messages ignored for a stamp too far ahead
        self.last_refusal, self.last_refusal_at = "", -float("inf")
        self.status_received_s = None  # when the last controller/status reached this node
        self.in_process = in_process
        # in-process statuses and commands not yet taken, each a call (see on_status)
        self._pending_inputs = collections.deque()
        self.closed = False
        specs = {s.name: s for s in SPECS}
        self.values = declare(self, SPECS)
        plant = load_plant(self.values)
        self.estimator = PressureEstimator(estimator_config(self.values, plant),
                                           PneumaticPlant(plant.parameters))
        self.journal_pub = self.create_publisher(
            EstimatorInput, JOURNAL_TOPIC,
            QoSProfile(depth=JOURNAL_HISTORY, durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.started_s = self._now()
        self.add_on_set_parameters_callback(lambda params: check_all(
            specs, params, lambda _: "estimator parameters apply at start-up: restart the node"))
        self.period_s = 1.0 / self.values["frequency"]
        self.rest_period_s = 1.0 / self.values["rest_frequency"]
        self.runner = EstimatorRunner(self.estimator, self.period_s, self.rest_period_s,
                                      journal=self._journal)
        self.estimate_pub = self.create_publisher(FluidPressure, "pressure/estimate", 10)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.consistency_pub = self.create_publisher(EstimatorConsistency,
                                                     messages.CONSISTENCY_TOPIC, 10)
        for name in [] if in_process else self.values["sensors.names"]:
            self.create_subscription(FluidPressure, f"pressure/sensor/{name}",
                                     lambda msg, name=name: self._on_sensor_message(name, msg), 50)
        if not in_process:
            self.create_subscription(ControllerStatus, "controller/status",
                                     self._on_status_message, 10)
            self.create_subscription(
                PressureCommand, "pressure/command",
                lambda msg: self.take_order(messages.pressure_order(msg)), 10)
        self.periodic = NodeTimers(self, in_process)
        self.periodic.every(max(self.period_s, 1.0 / PREDICTION_RATE_LIMIT_HZ), self._on_timer)
        self.periodic.every(0.5, self._publish_diagnostics)
        self.periodic.every(EVIDENCE_PERIOD_S, self._share_evidence)
        self.periodic.start()

    def close(self) -> None:
        """Nothing to vent: the estimator only listens. Later in-process samples are ignored."""
        self.periodic.stop()
        with self._lock:
            self.closed = True

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _refused(self, what: str, stamp_s: float) -> bool:
        """Whether a message's stamp lies too far ahead to take (then counted and logged)."""
        reason = future_stamp_reason(stamp_s, self._now(), self.values["stamp_tolerance"])
        if reason:
            self.future_stamps += 1
            self.last_refusal, self.last_refusal_at = f"{what} {reason}", self._now()
            self.get_logger().warn(self.last_refusal, throttle_duration_sec=5.0)
        return bool(reason)

    def take_readings(self, samples: list) -> None:
        """Readings [Reading], oldest first (a batch of the bus's, or one
        from a topic); then at most one estimate, when one is due: the newest, not one of a
        batch's older samples. A sensor this estimator does not fuse raises the estimator's
        ValueError, after the others are taken."""
        with self._lock:
            if self.closed:
                return
            self._take_pending_inputs()
            estimate, refused = self.runner.samples(samples)
        self._publish(estimate)
        if refused is not None:
            raise refused

    def _on_sensor_message(self, name: str, msg: FluidPressure) -> None:
        stamp_s = stamp_seconds(msg.header.stamp)
        if not self._refused(f"pressure/sensor/{name}", stamp_s):
            self.take_readings([Reading(name, messages.gauge_pa(msg), stamp_s)])

    def _on_status_message(self, msg: ControllerStatus) -> None:
        report = messages.controller_report(msg)
        if report is not None:
            self.take_report(report)

    def take_report(self, report: ControllerReport) -> None:
        """The process model's inputs: the regulator command and the valve state, from when the
        frames went out, not when the status was published.

        In process, the composed controller calls this from its control loop: the inputs wait
        for this node's next readings, timer or command, which take them first, in order. Taken
        here, a change stamped before the filter's time rewound the filter in the loop's thread
        behind this node's lock, and the loop went past the valves' lifetime without a
        ValveCommand (docs/architecture.md)."""
        if self._refused("controller/status", report.stamp_s):
            return
        self.status_received_s = self._now()
        inputs = (report.regulator_command_gauge_pa, report.regulator_enabled, report.valve,
                  report.outputs_changed_s)
        if self.in_process:
            self._pending_inputs.append(lambda: self._take_inputs(*inputs))
            return
        with self._lock:
            self._take_inputs(*inputs)

    def _take_pending_inputs(self) -> None:
        """The in-process statuses and commands that came since, in order (with the lock
        held)."""
        while self._pending_inputs:
            self._pending_inputs.popleft()()

    def _take_inputs(self, command_gauge_pa: float, enabled: bool, valve: int,
                     stamp_s: float) -> None:
        try:
            self.runner.inputs(command_gauge_pa, enabled, valve, stamp_s)
        # a NaN command or an unknown valve value: keep the last inputs
        except ValueError as error:
            self.get_logger().warn(f"controller/status ignored: {error}",
                                   throttle_duration_sec=5.0)

    def take_order(self, order: PressureOrder) -> None:
        """A pressure command (the topic's; composed, the grasp manager's by direct call, which
        waits with the statuses for this node's own threads, as :meth:`take_report` says): a
        VENT or HOLD is applied to the process model at once, ahead of the status that confirms
        it."""
        valve = {Source.VENT: Valve.VENT, Source.HOLD: Valve.CLOSED}.get(order.source)
        if valve is None or self._refused("pressure/command", order.stamp_s):
            return
        stamp_s = order.stamp_s or self._now()
        if self.in_process:
            self._pending_inputs.append(lambda: self._take_valve(valve, stamp_s))
            return
        with self._lock:
            self._take_pending_inputs()
            self._take_valve(valve, stamp_s)

    def _take_valve(self, valve: Valve, stamp_s: float) -> None:
        inputs = self.estimator.inputs
        self.runner.inputs(inputs.regulator_setpoint_gauge_pa, inputs.regulator_enabled, valve,
                           stamp_s)

    def _on_timer(self) -> None:
        """While no sample has come (and no estimate gone out) for two timer periods, publish the
        prediction."""
        now = self._now()
        with self._lock:
            self._take_pending_inputs()
            estimate = self.runner.predict(now)
        self._publish(estimate)

    def _journal(self, event) -> None:
        """An event the runner took (called with the lock held, so in order): published while
        someone listens or the start-up window lasts. The sequence number orders them; a
        subscriber sees a gap where it joined late or lost one."""
        if not (self._now() - self.started_s < JOURNAL_STARTUP_S or
                listened(self, self.journal_pub)):
            return
        names, values, stamps = zip(*event.samples) if event.samples else ((), (), ())
        message = EstimatorInput(
            sequence=event.sequence, kind=event.kind, sensor_names=list(names),
            gauge_pressure_pa=list(values), sample_stamps_s=list(stamps),
            regulator_command_gauge_pressure_pa=event.regulator_command_gauge_pa,
            regulator_enabled=event.regulator_enabled, valve=event.valve, stamp_s=event.stamp_s)
        message.header.stamp = self.get_clock().now().to_msg()
        publish(self, self.journal_pub, message)

    def _publish(self, estimate) -> None:
        if estimate is None:
            return
        if listened(self, self.estimate_pub):
            publish(
                self, self.estimate_pub,
                messages.fluid_pressure(estimate.gauge_pa, estimate.variance_pa2, estimate.stamp_s,
                                        "softgrip_chamber"))
        self.estimates.emit(Estimate(estimate.stamp_s, estimate.gauge_pa, estimate.variance_pa2))

    def _share_evidence(self) -> None:
        """The NIS of each sensor for the pressure controller's safety checks: to the composed
        one directly, on estimator/consistency to any subscriber."""
        published = listened(self, self.consistency_pub)
        if not (self.consistency.connected or published):
            return
        with self._lock:
            evidence, bound = self.estimator.nis_evidence(), self.estimator.nis_bounds[1]
        if published:
            message = EstimatorConsistency(sensor_names=list(evidence),
                                           mean_nis=[float(v) for v in evidence.values()],
                                           nis_upper_bound=float(bound))
            message.header.stamp = self.get_clock().now().to_msg()
            publish(self, self.consistency_pub, message)
        for name, mean_nis in evidence.items():
            self.consistency.emit(Consistency(name, mean_nis, bound))

    def _publish_diagnostics(self) -> None:
        with self._lock:
            self._take_pending_inputs()
            report = self.estimator.report(report_time_s(self._now(), self.status_received_s))
        report.values["future_stamps_ignored"] = self.future_stamps
        if self._now() - self.last_refusal_at < REFUSAL_REPORTED_S:
            report = report.with_note(Health.WARN, self.last_refusal)
        publish(
            self, self.diagnostics_pub,
            messages.diagnostics(report, ESTIMATOR_STATUS, "pressure",
                                 self.get_clock().now().to_msg()))


def main(args=None) -> int:
    return run_node(EstimatorNode, args)

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
callbacks); /diagnostics at 2 Hz.
Parameters follow robot_localization where they fit. The filters live in softgrip_ros.estimation.
"""
from __future__ import annotations

import threading

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from sensor_msgs.msg import FluidPressure
from std_msgs.msg import Header

from softgrip_interfaces.msg import ControllerStatus, PressureCommand
from softgrip_ros.estimation.estimator import EstimatorConfig, Health, PressureEstimator, Report, SensorConfig
from softgrip_ros.model.pneumatics import Valve
from softgrip_ros.nodes.common import (P_ATM_PA, NodeTimers, future_stamp_reason, listened, notify, publish, run_node,
                                       stamp_msg, stamp_seconds)
from softgrip_ros.nodes.parameters import ParamSpec, check_all, declare

_DEFAULTS = EstimatorConfig()
SPECS = [
    ParamSpec("frequency", 200.0, "largest pressure/estimate rate (predictions while silent: at most 50 Hz)", "Hz", 1.0, 2000.0),
    ParamSpec("rest_frequency", 20.0, "pressure/estimate rate while the chamber rests (see fusion_window); "
              "<= frequency", "Hz", 1.0, 2000.0),
    ParamSpec("sensor_timeout", _DEFAULTS.sensor_timeout_s, "a sensor silent this long is dropped from fusion", "s", 0.001, 10.0),
    ParamSpec("filter_type", _DEFAULTS.filter_type, "the filter", choices=("kf", "ekf", "ukf")),
    ParamSpec("fusion_window", 0.02, "while the chamber rests, samples this close are fused in one filter step "
              "(0: each at once; 20 ms: one fusion every other bus batch while the controller rests)", "s", 0.0, 0.02),
    ParamSpec("input_timing_std", _DEFAULTS.input_timing_std_s, "how far an input's effect at the device may lie "
              "from its stamp (1 sigma); P grows by the change in rate times this at each input change", "s", 0.0, 0.1),
    ParamSpec("nis_input_settle", _DEFAULTS.nis_input_settle_s, "samples this soon after an input change stay out "
              "of the NIS window (still gated and fused): the input's timing is uncertain there", "s", 0.0, 1.0),
    ParamSpec("max_fusion_shift_pa", _DEFAULTS.max_fusion_shift_pa, "the chamber rests (see fusion_window) while its "
              "modelled change over the window stays within this", "Pa", 1.0, 1000.0),
    ParamSpec("sensors.names", ["chamber_a", "chamber_b"], "sensors fused: topics pressure/sensor/<name>"),
    ParamSpec("sensors.noise_std_pa", [300.0, 150.0], "1-sigma noise of each sensor (R = noise^2)", "Pa"),
    ParamSpec("sensors.rejection_threshold", [16.0, 16.0], "Mahalanobis gate of each sensor, chi-square with 1 dof (16 = 4 sigma)"),
    ParamSpec("process_noise_covariance", list(_DEFAULTS.process_noise_pa2_per_s),
              "Q spectral density over [chamber, regulator]: 2 values (diagonal) or 4 (full, row-major)", "Pa^2/s"),
    ParamSpec("nis_window", _DEFAULTS.nis_window, "samples per sensor in the NIS consistency window", "", 10, 100000),
    ParamSpec("max_consecutive_rejections", _DEFAULTS.max_consecutive_rejections,
              "rejections in a row from every live sensor before re-initialising", "", 1, 100000),
    ParamSpec("stamp_tolerance", 0.5, "a sample, status or command stamped further ahead of this node's clock than "
              "this is ignored (and counted)", "s", 0.0, 60.0),
]
EVIDENCE_PERIOD_S = 0.1        # the NIS evidence handed to the composed pressure controller this often
REFUSAL_REPORTED_S = 5.0       # a refused message keeps the diagnostics at WARN this long
PREDICTION_RATE_LIMIT_HZ = 50.0
LEVELS = {Health.OK: DiagnosticStatus.OK, Health.WARN: DiagnosticStatus.WARN, Health.ERROR: DiagnosticStatus.ERROR}


def config_from(values: dict) -> EstimatorConfig:
    """The estimator's configuration from the parameter values; ValueError names a bad one."""
    names, noise, gates = values["sensors.names"], values["sensors.noise_std_pa"], values["sensors.rejection_threshold"]
    if not (len(names) == len(noise) == len(gates)):
        raise ValueError(f"sensors.names, sensors.noise_std_pa and sensors.rejection_threshold need one entry per "
                         f"sensor; got {len(names)}, {len(noise)} and {len(gates)}")
    sensors = tuple(SensorConfig(n, float(s), float(g)) for n, s, g in zip(names, noise, gates))
    return EstimatorConfig(filter_type=values["filter_type"], sensors=sensors, sensor_timeout_s=values["sensor_timeout"],
                           process_noise_pa2_per_s=tuple(float(v) for v in values["process_noise_covariance"]),
                           nis_window=values["nis_window"], max_consecutive_rejections=values["max_consecutive_rejections"],
                           fusion_window_s=values["fusion_window"], max_fusion_shift_pa=values["max_fusion_shift_pa"],
                           input_timing_std_s=values["input_timing_std"], nis_input_settle_s=values["nis_input_settle"])


class EstimatorNode(Node):
    """in_process: the readings and the controller status come by direct calls to
    :meth:`on_sensor_samples` and :meth:`on_status` from the composed controller's pressure
    controller, instead of through their topics (see nodes.controller).
    ``estimate_listeners``: in-process consumers of each published estimate,
    f(stamp_s, gauge_pa, variance_pa2); called outside the estimator's lock, which is never held
    while calling out (so that no two nodes' locks can wait on each other).
    """

    def __init__(self, in_process: bool = False, **kwargs):
        super().__init__("estimator", **kwargs)
        self._lock = threading.Lock()      # the in-process path calls in from the controller's CAN thread
        self.estimate_listeners = []
        self.consistency_listeners = []    # in-process: f(sensor, mean NIS, bound), every EVIDENCE_PERIOD_S
        self.future_stamps = 0             # messages ignored for a stamp too far ahead
        self.last_refusal, self.last_refusal_at = "", -float("inf")
        self.closed = False
        specs = {s.name: s for s in SPECS}
        self.values = declare(self, SPECS)
        self.estimator = PressureEstimator(config_from(self.values))
        self.add_on_set_parameters_callback(
            lambda params: check_all(specs, params, lambda _: "estimator parameters apply at start-up: restart the node"))
        if self.values["rest_frequency"] > self.values["frequency"]:
            raise ValueError(f"rest_frequency ({self.values['rest_frequency']:g} Hz) must not exceed frequency "
                             f"({self.values['frequency']:g} Hz)")
        self.period_s = 1.0 / self.values["frequency"]
        self.rest_period_s = 1.0 / self.values["rest_frequency"]
        self.last_publish_s = self.last_sample_s = -float("inf")
        self.estimate_pub = self.create_publisher(FluidPressure, "pressure/estimate", 10)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        for name in [] if in_process else self.values["sensors.names"]:
            self.create_subscription(FluidPressure, f"pressure/sensor/{name}",
                                     lambda msg, name=name: self._on_sensor_message(name, msg), 50)
        if not in_process:
            self.create_subscription(ControllerStatus, "controller/status", self.on_status, 10)
        self.create_subscription(PressureCommand, "pressure/command", self._on_command, 10)
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

    def on_sensor_samples(self, samples: list) -> None:
        """Readings [(sensor name, gauge Pa, stamp s)], oldest first (a batch of the bus's, or one
        from a topic); then at most one estimate, when one is due: the newest, not one of a
        batch's older samples. A sensor this estimator does not fuse raises the estimator's
        ValueError, after the others are taken."""
        refused = None
        with self._lock:
            newest = None
            for name, gauge_pa, stamp_s in samples:
                try:
                    taken = not self.closed and self.estimator.add_measurement(name, gauge_pa, stamp_s)
                except ValueError as error:      # an unknown sensor: the rest of the batch still counts
                    refused, taken = refused or error, False
                if taken:
                    newest = stamp_s if newest is None else max(newest, stamp_s)
            if newest is not None:
                self.last_sample_s = max(self.last_sample_s, newest)
            due = newest is not None and newest - self.last_publish_s >= 0.9 * (
                self.rest_period_s if self.estimator.resting else self.period_s)
            estimate = self._take_estimate() if due else None
        self._publish(estimate)
        if refused is not None:
            raise refused

    def _on_sensor_message(self, name: str, msg: FluidPressure) -> None:
        stamp_s = stamp_seconds(msg.header.stamp)
        if not self._refused(f"pressure/sensor/{name}", stamp_s):
            self.on_sensor_samples([(name, msg.fluid_pressure - P_ATM_PA, stamp_s)])

    def on_status(self, msg: ControllerStatus) -> None:
        """The process model's inputs: the regulator command and the valve state."""
        if not msg.valve_states or self._refused("controller/status", stamp_seconds(msg.header.stamp)):
            return
        try:
            with self._lock:
                self.estimator.set_inputs(msg.regulator_command_gauge_pressure_pa, msg.regulator_enabled,
                                          msg.valve_states[0], stamp_seconds(msg.header.stamp))
        except ValueError as error:     # a NaN command or an unknown valve value: keep the last inputs
            self.get_logger().warn(f"controller/status ignored: {error}", throttle_duration_sec=5.0)

    def _on_command(self, msg: PressureCommand) -> None:
        valve = {PressureCommand.VENT: Valve.VENT, PressureCommand.HOLD: Valve.CLOSED}.get(msg.source)
        if valve is not None and not self._refused("pressure/command", stamp_seconds(msg.header.stamp)):
            with self._lock:
                inputs = self.estimator.inputs
                self.estimator.set_inputs(inputs.regulator_setpoint_gauge_pa, inputs.regulator_enabled, valve,
                                          stamp_seconds(msg.header.stamp) or self._now())

    def _on_timer(self) -> None:
        """While no sample has come (and no estimate gone out) for two timer periods, publish the prediction."""
        now = self._now()
        with self._lock:
            estimate = None
            if self.estimator.initialised and now - max(self.last_publish_s, self.last_sample_s) >= 2.0 / PREDICTION_RATE_LIMIT_HZ:
                self.estimator.predict_to(now)    # committed: a sample older than this would be dropped as late anyway
                estimate = self._take_estimate()
        self._publish(estimate)

    def _take_estimate(self):
        """The current estimate, marked as published (call with the lock held)."""
        estimate = self.estimator.estimate()
        if estimate is not None:
            self.last_publish_s = estimate.stamp_s
        return estimate

    def _publish(self, estimate) -> None:
        if estimate is None:
            return
        if listened(self, self.estimate_pub):
            publish(self, self.estimate_pub, FluidPressure(
                header=Header(stamp=stamp_msg(estimate.stamp_s), frame_id="softgrip_chamber"),
                fluid_pressure=estimate.gauge_pa + P_ATM_PA, variance=estimate.variance_pa2))
        notify(self.estimate_listeners, estimate.stamp_s, estimate.gauge_pa, estimate.variance_pa2)

    def _share_evidence(self) -> None:
        """The NIS of each sensor to the composed pressure controller's safety checks."""
        if not self.consistency_listeners:
            return
        with self._lock:
            evidence, bound = self.estimator.nis_evidence(), self.estimator.nis_bounds[1]
        for name, mean_nis in evidence.items():
            notify(self.consistency_listeners, name, mean_nis, bound)

    def _publish_diagnostics(self) -> None:
        with self._lock:
            report = self.estimator.report(self._now())
        report.values["future_stamps_ignored"] = self.future_stamps
        if self._now() - self.last_refusal_at < REFUSAL_REPORTED_S:
            report = Report(max(report.health, Health.WARN), f"{report.message}; {self.last_refusal}", report.values)
        status = DiagnosticStatus(name="softgrip: estimator", hardware_id="pressure", level=LEVELS[report.health],
                                  message=report.message,
                                  values=[KeyValue(key=k, value=str(v)) for k, v in report.values.items()])
        publish(self, self.diagnostics_pub, DiagnosticArray(header=Header(stamp=self.get_clock().now().to_msg()), status=[status]))


def main(args=None) -> int:
    return run_node(EstimatorNode, args)

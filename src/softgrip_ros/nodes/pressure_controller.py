"""pressure_controller: the managed node that drives the valves and regulator over CAN.

configure opens the bus, activate starts the control loop, deactivate and shutdown vent.
It activates itself unless ``autostart`` is false. Topics: pressure/command in;
pressure/sensor/<name> (FluidPressure, absolute Pa), controller/status and /diagnostics out;
service ~/vent. The control law and safety rules are in softgrip_ros.control.pressure.
"""
from __future__ import annotations

import dataclasses

import can
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from sensor_msgs.msg import FluidPressure
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from softgrip_interfaces.msg import ControllerStatus, PressureCommand
from softgrip_ros.canbus.codec import FrameCodec
from softgrip_ros.canbus.controller_link import make_control_loop, ControllerLink, SensorBinding
from softgrip_ros.control.pressure import (Fault, PressureControlConfig, PressureController, Severity, fault_names,
                                          severity)
from softgrip_ros.nodes.common import (P_ATM_PA, future_stamp_reason, listened, notify, open_bus, publish, run_node,
                                       stamp_msg, stamp_seconds)
from softgrip_ros.nodes.parameters import CAN_SPECS, ParamSpec, check_all, declare

_DEFAULTS = PressureControlConfig()
_SAFETY = _DEFAULTS.safety
SPECS = CAN_SPECS + [
    ParamSpec("autostart", True, "configure and activate on start-up"),
    ParamSpec("control_rate_hz", 500.0, "control loop rate", "Hz", 10.0, 1000.0),
    ParamSpec("rest_rate_hz", 50.0, "control loop rate while venting, holding or faulted (a command or a reading "
              "beyond the limits steps at once); <= control_rate_hz", "Hz", 10.0, 1000.0),
    ParamSpec("rest_receive_period", 0.01, "while the controller rests (not regulating), received frames are taken "
              "in batches this often, one thread wake each instead of one per frame; a reading beyond the limits "
              "is then acted on within it; 0 = each frame at once", "s", 0.0, 0.05),
    ParamSpec("status_rate_hz", 50.0, "controller/status publish rate", "Hz", 1.0, 200.0),
    ParamSpec("command_frame_period", 0.01, "RegulatorSetpoint and ValveCommand re-sent this often when unchanged "
              "(a change goes out in its control period); 0 = every period", "s", 0.0, 0.1),
    ParamSpec("valve_lifetime", 0.025, "the device closes SUPPLY/VACUUM valves this long after the last ValveCommand "
              "(a stalled controller leaves the chamber held); >= 2 re-send periods", "s", 0.004, 0.255),
    ParamSpec("max_gauge_pressure_pa", _DEFAULTS.max_gauge_pa, "hard upper limit of the setpoint", "Pa", 1e3, 100e3),
    ParamSpec("min_gauge_pressure_pa", _DEFAULTS.min_gauge_pa, "hard lower limit of the setpoint", "Pa", -100e3, -1e3),
    ParamSpec("overpressure_margin_pa", _DEFAULTS.overpressure_margin_pa, "measured excess beyond a limit that vents", "Pa", 100.0, 50e3),
    ParamSpec("sensor_timeout", _DEFAULTS.sensor_timeout_s, "no valid reading for this long: hold and report", "s", 0.005, 10.0),
    ParamSpec("command_timeout", _DEFAULTS.command_timeout_s, "no command for this long while regulating: safe action", "s", 0.1, 3600.0),
    ParamSpec("command_timeout_action", _DEFAULTS.command_timeout_action, "safe action on a command timeout", choices=("hold", "vent")),
    ParamSpec("default_rate_pa_per_s", _DEFAULTS.default_rate_pa_per_s, "setpoint slew when a command gives none", "Pa/s", 1e3, 1e8),
    ParamSpec("kp", _DEFAULTS.kp, "proportional gain of the trim", "Pa/Pa", 0.0, 10.0),
    ParamSpec("ki_per_s", _DEFAULTS.ki_per_s, "integral gain of the trim", "1/s", 0.0, 1000.0),
    ParamSpec("trim_limit_pa", _DEFAULTS.trim_limit_pa, "largest trim of the regulator setpoint", "Pa", 0.0, 50e3),
    ParamSpec("use_estimate", False, "regulate on pressure/estimate while it is fresh (its latency makes the boost overshoot)"),
    ParamSpec("sensors.names", ["chamber_a", "chamber_b"], "sensor names: topics pressure/sensor/<name>"),
    ParamSpec("sensors.messages", ["PressureSensor1", "PressureSensor2"], "the DBC message of each sensor"),
    ParamSpec("sensors.noise_std_pa", [300.0, 150.0], "1-sigma noise of each sensor, for FluidPressure.variance "
              "and the noise check", "Pa"),
    ParamSpec("stamp_tolerance", 0.5, "a command stamped further ahead of this node's clock than this is refused",
              "s", 0.0, 60.0),
    ParamSpec("safety.reaction_time", _SAFETY.reaction_time_s, "the limit trip extrapolates each pressure over this: "
              "a control period, the bus and the valve's response", "s", 0.001, 0.2),
    ParamSpec("safety.disagreement_pa", _SAFETY.disagreement_pa, "two sensors further apart than this ...", "Pa",
              500.0, 50e3),
    ParamSpec("safety.disagreement_time", _SAFETY.disagreement_time_s, "... for this long: SENSOR_DISAGREE", "s",
              0.005, 5.0),
    ParamSpec("safety.stuck_time", _SAFETY.stuck_time_s, "a reading unchanged this long ...", "s", 0.01, 10.0),
    ParamSpec("safety.stuck_motion_pa", _SAFETY.stuck_motion_pa, "... while another sensor or the plant moved the "
              "pressure by this: SENSOR_STUCK", "Pa", 100.0, 50e3),
    ParamSpec("safety.noise_ratio", _SAFETY.noise_ratio, "a sensor's noise above this times its rated noise ...", "",
              1.5, 1000.0),
    ParamSpec("safety.noise_time", _SAFETY.noise_time_s, "... for this long: SENSOR_NOISE", "s", 0.01, 10.0),
    ParamSpec("safety.jump_sigmas", _SAFETY.jump_sigmas, "every sensor stepping, in one sample, by more than the "
              "plant's fastest rate allows plus this many noise sigmas: SENSOR_IMPLAUSIBLE", "", 3.0, 1000.0),
    ParamSpec("safety.response_window", _SAFETY.response_window_s, "the chamber's response to a valve state is "
              "judged over this", "s", 0.01, 1.0),
    ParamSpec("safety.response_settle", _SAFETY.response_settle_s, "... from this long after the valve state was "
              "commanded", "s", 0.0, 1.0),
    ParamSpec("safety.response_min_change_pa", _SAFETY.response_min_change_pa, "a change judged against the plant "
              "must be predicted this large; a chamber moving this much with the valves closed is a fault", "Pa",
              100.0, 50e3),
    ParamSpec("safety.response_tolerance", _SAFETY.response_tolerance, "the measured change may differ from the "
              "plant's by this fraction of it (the model's rates within about 2x of the hardware's)", "", 0.05, 0.95),
    ParamSpec("safety.response_time", _SAFETY.response_time_s, "a response off the plant in every check this long: "
              "RESPONSE", "s", 0.005, 5.0),
    ParamSpec("safety.regulator_deviation_pa", _SAFETY.regulator_deviation_pa, "the regulator's output further "
              "from its model than this ...", "Pa", 1e3, 200e3),
    ParamSpec("safety.regulator_deviation_time", _SAFETY.regulator_deviation_time_s, "... for this long: "
              "REGULATOR", "s", 0.005, 5.0),
    ParamSpec("safety.nis_ratio", _SAFETY.nis_ratio, "the estimator's windowed NIS of a sensor above this times "
              "its bound ...", "", 1.0, 1e6),
    ParamSpec("safety.nis_time", _SAFETY.nis_time_s, "... for this long: SENSOR_INCONSISTENT", "s", 0.01, 60.0),
    ParamSpec("safety.clear_time", _SAFETY.clear_time_s, "a safety fault clears on a new command once its evidence "
              "has been gone this long", "s", 0.05, 60.0),
]
LIVE = {"max_gauge_pressure_pa": "max_gauge_pa", "min_gauge_pressure_pa": "min_gauge_pa",
        "overpressure_margin_pa": "overpressure_margin_pa", "sensor_timeout": "sensor_timeout_s",
        "command_timeout": "command_timeout_s", "command_timeout_action": "command_timeout_action",
        "default_rate_pa_per_s": "default_rate_pa_per_s", "kp": "kp", "ki_per_s": "ki_per_s",
        "trim_limit_pa": "trim_limit_pa"}
SAFETY_LIVE = {"safety.reaction_time": "reaction_time_s", "safety.disagreement_pa": "disagreement_pa",
               "safety.disagreement_time": "disagreement_time_s", "safety.stuck_time": "stuck_time_s",
               "safety.stuck_motion_pa": "stuck_motion_pa", "safety.noise_ratio": "noise_ratio",
               "safety.noise_time": "noise_time_s", "safety.jump_sigmas": "jump_sigmas",
               "safety.response_window": "response_window_s", "safety.response_settle": "response_settle_s",
               "safety.response_min_change_pa": "response_min_change_pa",
               "safety.response_tolerance": "response_tolerance", "safety.response_time": "response_time_s",
               "safety.regulator_deviation_pa": "regulator_deviation_pa",
               "safety.regulator_deviation_time": "regulator_deviation_time_s", "safety.nis_ratio": "nis_ratio",
               "safety.nis_time": "nis_time_s", "safety.clear_time": "clear_time_s"}
ESTIMATOR_STATUS = "softgrip: estimator"     # the estimator's /diagnostics status (its NIS per sensor)
LEVELS = {Severity.OK: DiagnosticStatus.OK, Severity.WARN: DiagnosticStatus.WARN, Severity.ERROR: DiagnosticStatus.ERROR}


def _check_rest_rate(values) -> None:
    if values["rest_rate_hz"] > values["control_rate_hz"]:
        raise ValueError(f"rest_rate_hz ({values['rest_rate_hz']:g} Hz) must not exceed control_rate_hz "
                         f"({values['control_rate_hz']:g} Hz)")


class PressureControllerNode(LifecycleNode):
    """in_process: composed with the estimator, which hands its NIS evidence over by direct calls to
    :meth:`on_consistency`; alone, that evidence comes from the estimator's /diagnostics."""

    def __init__(self, in_process: bool = False, **kwargs):
        super().__init__("pressure_controller", **kwargs)
        self.specs = {s.name: s for s in SPECS}
        self.values = declare(self, SPECS)
        self.codec = FrameCodec()
        frame_specs = [ParamSpec(f"can.frame_ids.{name}", 0, f"arbitration ID of {name}; 0 = the DBC's", "", 0, 0x7FF)
                       for name in self.codec.message_names]
        self.specs.update({s.name: s for s in frame_specs})
        self.values.update(declare(self, frame_specs))
        _check_rest_rate(self.values)        # at start-up: exit 1 with the reason
        self.controller = PressureController(self._control_config(self.values), sensor_noise_pa=dict(
            zip(self.values["sensors.names"], self.values["sensors.noise_std_pa"])))
        self.add_on_set_parameters_callback(self._on_set)
        self.status_pub = self.create_publisher(ControllerStatus, "controller/status", 10)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.sensor_pubs = {}
        self.sensor_listeners = []       # in-process consumers of the readings: f([(name, gauge_pa, stamp_s)]) per batch
        self.status_listeners = []       # in-process consumers of each controller/status: f(ControllerStatus)
        self.create_subscription(PressureCommand, "pressure/command", self.on_command, 10)
        if not in_process:
            self.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)
        self.estimate_subscription = None
        self._subscribe_estimate(self.values["use_estimate"])
        self.create_service(Trigger, "~/vent", self._on_vent)
        self.bus = self.link = self.loop = None
        self.last_output = None
        self.last_note = ""
        self.create_timer(1.0, self._publish_diagnostics)
        if self.values["autostart"] and self.trigger_configure() == TransitionCallbackReturn.SUCCESS:
            self.trigger_activate()

    # ---- parameters ---------------------------------------------------------------------------
    def _control_config(self, values) -> PressureControlConfig:
        safety = dataclasses.replace(_SAFETY, **{field: values[name] for name, field in SAFETY_LIVE.items()})
        return dataclasses.replace(_DEFAULTS, safety=safety, **{field: values[name] for name, field in LIVE.items()})

    def _on_set(self, parameters):
        def extra(params):
            changed = {p.name: p.value for p in params}
            if any(n.startswith(("can.", "sensors.", "control_rate_hz", "rest_rate_hz", "rest_receive_period",
                                                "command_frame_period", "valve_lifetime")) for n in changed) and self.link is not None:
                return "CAN, sensor and rate parameters apply at configure: deactivate and clean up first"
            if any(n in LIVE or n in SAFETY_LIVE for n in changed):
                try:
                    config = self._control_config({**self.values, **changed})
                except ValueError as error:
                    return str(error)
                self.controller.config = config
            if "use_estimate" in changed:
                self._subscribe_estimate(changed["use_estimate"])
            self.values.update(changed)
            return ""
        return check_all(self.specs, parameters, extra)

    def _subscribe_estimate(self, wanted: bool) -> None:
        """pressure/estimate only while use_estimate: at the estimator's rate it is the busiest topic."""
        if wanted and self.estimate_subscription is None:
            # no QoS event handlers: destroying a subscription while the executor waits on its handler
            # raises InvalidHandle in the spin thread (rclpy Jazzy); plain subscriptions are guarded
            self.estimate_subscription = self.create_subscription(
                FluidPressure, "pressure/estimate", self._on_estimate, 10,
                event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=False))
        elif not wanted and self.estimate_subscription is not None:
            self.destroy_subscription(self.estimate_subscription)
            self.estimate_subscription = None

    # ---- lifecycle ------------------------------------------------------------------------------
    def on_configure(self, state) -> TransitionCallbackReturn:
        names, messages = self.values["sensors.names"], self.values["sensors.messages"]
        noise = self.values["sensors.noise_std_pa"]
        if not (len(names) == len(messages) == len(noise)) or not names:
            self.get_logger().error("sensors.names, sensors.messages and sensors.noise_std_pa need equal, non-zero lengths")
            return TransitionCallbackReturn.FAILURE
        try:
            _check_rest_rate(self.values)
            overrides = {n: self.values[f"can.frame_ids.{n}"] for n in self.codec.message_names
                         if self.values[f"can.frame_ids.{n}"]}
            self.codec = FrameCodec(frame_ids=overrides)
            self.bus = open_bus(self.values["can.interface"], self.values["can.channel"], self.values["can.bitrate"])
            self.link = ControllerLink(self.bus, self.controller, [SensorBinding(n, m) for n, m in zip(names, messages)],
                                       codec=self.codec, on_readings=self._publish_readings,
                                       rest_receive_period_s=self.values["rest_receive_period"],
                                       command_frame_period_s=self.values["command_frame_period"],
                                       valve_lifetime_s=self.values["valve_lifetime"],
                                       control_period_s=1.0 / self.values["control_rate_hz"])
        except (ValueError, can.CanError, OSError, ImportError) as error:
            self.get_logger().error(f"configure failed: {error}")
            self._close_bus()
            return TransitionCallbackReturn.FAILURE
        self.noise_variance = {n: float(v) ** 2 for n, v in zip(names, noise)}
        self.sensor_pubs = {n: self.create_publisher(FluidPressure, f"pressure/sensor/{n}", 10) for n in names}
        self.get_logger().info(f"bus {self.values['can.interface']}:{self.values['can.channel']} open")
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state) -> TransitionCallbackReturn:
        self.controller.active = True
        self.loop = make_control_loop(self.link, self.values["control_rate_hz"], self.values["status_rate_hz"],
                                      on_status=self._on_loop_output, rest_rate_hz=self.values["rest_rate_hz"])
        self.loop.start()
        return super().on_activate(state)

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        self._stop_loop_and_vent()
        return super().on_deactivate(state)

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        self._close_bus()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state) -> TransitionCallbackReturn:
        self.close()
        return TransitionCallbackReturn.SUCCESS

    def close(self) -> None:
        """Vent and release the bus (shutdown, SIGINT, SIGTERM)."""
        self._stop_loop_and_vent()
        self._close_bus()

    def _stop_loop_and_vent(self):
        if self.loop is not None:
            self.loop.stop()
            self.loop = None
        if self.link is not None:
            self.link.send_vent()
        self.controller.active = False

    def _close_bus(self):
        if self.link is not None:
            self.link.close()
            self.link = None
        if self.bus is not None:
            self.bus.shutdown()
            self.bus = None

    # ---- I/O ------------------------------------------------------------------------------------
    def _on_loop_output(self, output):
        self.last_output = output
        self._publish_status()

    def on_command(self, msg: PressureCommand):
        """A pressure command, from the topic or (composed) by a direct call from the grasp manager,
        which saves a trip through DDS and the executor; its later DDS copy is recognised and ignored
        (see :meth:`ControllerLink.command`). A command stamped further ahead than
        ``stamp_tolerance`` is refused, with its reason in the status."""
        if self.link is None:
            self.get_logger().warn("pressure command ignored: the controller is not configured")
            return
        stamp_s = stamp_seconds(msg.header.stamp)
        refused = future_stamp_reason(stamp_s, self.get_clock().now().nanoseconds * 1e-9, self.values["stamp_tolerance"])
        if refused:
            note = f"pressure command {refused}"
            self.link.reject_command(note)          # the status carries it until a command applies
        else:
            try:
                note = self.link.command(msg.target_gauge_pressure_pa, msg.source, msg.max_rate_pa_per_s, stamp_s,
                                         on_applied=self._set_note)
            except ValueError as error:
                note = self.last_note = f"command rejected: {error}"
        if note:
            self.get_logger().warn(note, throttle_duration_sec=1.0)

    def on_consistency(self, name: str, mean_nis: float, bound: float) -> None:
        """The estimator's evidence on a sensor (composed: a direct call; else from /diagnostics)."""
        if self.link is not None:
            self.link.update_consistency(name, mean_nis, bound)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        """The estimator's NIS per sensor, from its /diagnostics status (a separate estimator node)."""
        for status in msg.status:
            if status.name != ESTIMATOR_STATUS:
                continue
            values = {kv.key: kv.value for kv in status.values}
            try:
                bound = float(values["nis_upper_bound"])
                for name in self.values["sensors.names"]:
                    if f"{name}.mean_nis" in values:
                        self.on_consistency(name, float(values[f"{name}.mean_nis"]), bound)
            except (KeyError, ValueError):
                continue

    def _set_note(self, note: str) -> None:
        self.last_note = note     # before the step the command triggers publishes the status

    def _on_estimate(self, msg: FluidPressure):
        if self.values["use_estimate"] and self.link is not None:
            self.link.update_estimate(msg.fluid_pressure - P_ATM_PA)

    def _on_vent(self, request, response):
        """VENT frames go out at once and the controller keeps venting. The reply says "venting"
        only when a fresh reading can confirm it; blind, it says so."""
        if self.link is None:
            response.success, response.message = False, "not configured: no bus to vent through"
            return response
        self.link.send_vent()
        age_s = self.link.last_sensor_age_s()
        response.success = True
        response.message = ("venting" if age_s <= self.controller.config.sensor_timeout_s else
                            f"VENT sent, but it cannot be confirmed: no valid sensor reading for {age_s:.2f} s")
        return response

    def _publish_readings(self, readings: list):
        link = self.link
        if link is None:
            return
        # stamped when measured, not when processed (they differ when this process is starved)
        ros_now_s, link_now_s = self.get_clock().now().nanoseconds * 1e-9, link.clock()
        samples = [(name, gauge_pa, ros_now_s - max(0.0, link_now_s - sent_at)) for name, gauge_pa, sent_at in readings]
        wanted = {}       # whether anyone subscribes: asked once per sensor and batch, not per reading
        for name, gauge_pa, measured_s in samples:
            publisher = self.sensor_pubs.get(name)
            if publisher is not None and name not in wanted:
                wanted[name] = listened(self, publisher)
            if wanted.get(name):
                publish(self, publisher, FluidPressure(header=Header(stamp=stamp_msg(measured_s), frame_id=name),
                                                       fluid_pressure=gauge_pa + P_ATM_PA, variance=self.noise_variance[name]))
        notify(self.sensor_listeners, samples)

    def _header(self, frame_id="softgrip_base"):
        return Header(stamp=self.get_clock().now().to_msg(), frame_id=frame_id)

    def _publish_status(self):
        out, link = self.last_output, self.link
        if out is None or link is None:
            return
        status = ControllerStatus(
            header=self._header(), mode=int(out.mode), setpoint_gauge_pressure_pa=out.setpoint_gauge_pa,
            measured_gauge_pressure_pa=self.controller.measured(link.clock()),
            estimated_gauge_pressure_pa=self.controller.estimate_gauge_pa(link.clock()),
            regulator_actual_gauge_pressure_pa=link.regulator_actual_gauge_pa,
            regulator_command_gauge_pressure_pa=out.regulator_setpoint_gauge_pa, regulator_enabled=out.regulator_enabled,
            valve_states=[int(v) for v in out.valves], frames_rx=link.frames_rx, frames_tx=link.frames_tx,
            frames_bad=link.frames_bad, last_sensor_frame_age_s=link.last_sensor_age_s(),
            fault_flags=int(out.fault_flags), message="; ".join(m for m in (out.message, self.last_note) if m))
        if listened(self, self.status_pub):     # 50 Hz; the composed nodes take it by direct call
            publish(self, self.status_pub, status)
        notify(self.status_listeners, status)

    def _publish_diagnostics(self):
        out, link = self.last_output, self.link
        status = DiagnosticStatus(name="softgrip: pressure controller", hardware_id=self.values["can.channel"])
        if link is None or out is None:
            status.level, status.message = DiagnosticStatus.WARN, "not active"
        else:
            faults = out.fault_flags
            status.level = LEVELS[severity(out)]
            status.message = out.message or ("ok" if not faults else f"faults: {fault_names(faults)}")
            silent = [n for n in self.values["sensors.names"] if n not in self.controller.fresh_sensors(link.clock())]
            if silent and not faults & Fault.SENSOR_TIMEOUT:         # some sensors carry on without these
                status.level = max(status.level, DiagnosticStatus.WARN)
                status.message += f"; sensors silent: {', '.join(silent)}"
            if faults & Fault.FRAMES_REJECTED:
                rejected = ", ".join(f"{k} {v}" for k, v in link.codec.rejected.items() if v)
                status.message += f"; frames rejected by the E2E checks (so far: {rejected})"
            loop = self.loop
            status_errors = loop.errors if loop is not None else 0
            receive_errors, last_receive_error = link.receive_errors   # one read: the count and its text agree
            status.values = [KeyValue(key=k, value=str(v)) for k, v in (
                ("mode", out.mode.name), ("fault_flags", int(faults)), ("frames_rx", link.frames_rx),
                ("frames_tx", link.frames_tx), ("frames_bad", link.frames_bad),
                ("rejected", dict(link.codec.rejected)), ("last_sensor_age_s", f"{link.last_sensor_age_s():.4f}"),
                ("sensor_listener_errors", link.listener_errors), ("status_publish_errors", status_errors),
                ("receive_errors", receive_errors))]
            # a consumer of the readings or the status that raises (in the composed controller: the
            # estimator, kinematics, grasp manager) is caught so that control goes on; it must still be seen
            errors = [e for n, e in ((link.listener_errors, link.last_listener_error),
                                     (status_errors, loop.last_error if loop is not None else "")) if n]
            if errors:
                status.level = max(status.level, DiagnosticStatus.WARN)
                status.message = f"{status.message}; consumer error: {errors[-1]}"
            if receive_errors:
                status.level = max(status.level, DiagnosticStatus.WARN)
                status.message = f"{status.message}; bus read error: {last_receive_error}"
        publish(self, self.diagnostics_pub, DiagnosticArray(header=self._header(), status=[status]))


def main(args=None) -> int:
    return run_node(PressureControllerNode, args)


if __name__ == "__main__":
    raise SystemExit(main())

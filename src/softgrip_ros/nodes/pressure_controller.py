"""pressure_controller: the managed node that drives the valves and regulator over CAN.

configure opens the bus, activate starts the control loop, deactivate and shutdown vent.
It activates itself unless ``autostart`` is false. Topics: pressure/command in;
pressure/sensor/<name> (FluidPressure, absolute Pa), controller/status and /diagnostics out;
service ~/vent. The control law and safety rules are in softgrip_ros.control.pressure.
With ``identification_mode`` (set while inactive) it runs open loop for softgrip_identify:
commands come on ~/identification_command only, and pressure/command is ignored.
"""
from __future__ import annotations

import can
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from sensor_msgs.msg import FluidPressure
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from softgrip_interfaces.msg import ControllerStatus, EstimatorConsistency, PressureCommand
from softgrip_ros.canbus.codec import FrameCodec
from softgrip_ros.canbus.controller_link import (IGNORED_IN_IDENTIFICATION, ControllerLink,
                                                SensorBinding, make_control_loop)
from softgrip_ros.control.pressure import PressureController
from softgrip_ros.model.pneumatics import PneumaticPlant
from softgrip_ros.control.reports import pressure_controller_report
from softgrip_ros.nodes import messages
from softgrip_ros.canbus import open_bus
from softgrip_ros.nodes.common import (closed_if_cut_short, listened, publish, run_node,
                                       stamp_msg)
from softgrip_ros.nodes.parameters import check_all, declare
from softgrip_ros.nodes.specs import (PRESSURE_CONFIGURE_PREFIXES, check_rest_rate,
                                      frame_id_overrides, frame_id_specs, load_plant,
                                      pressure_control_config, sensor_settings)
from softgrip_ros.nodes.specs import PRESSURE_CONTROLLER_SPECS as SPECS
from softgrip_ros.realtime import clock_offset_s
from softgrip_ros.runtime.core import Consistency, ControllerReport, Port, PressureOrder, Reading


class PressureControllerNode(LifecycleNode):
    """The pressure part of the runtime core (runtime.core): ports ``readings`` and ``reports``;
    inputs :meth:`take_order` and :meth:`take_consistency`. in_process: composed, those inputs
    come from the estimator and the grasp manager (runtime.core.wire), and pressure/command is
    not subscribed (the grasp manager owns the pressure); alone, they come on
    estimator/consistency and pressure/command."""

    def __init__(self, in_process: bool = False, **kwargs):
        super().__init__("pressure_controller", **kwargs)
        self.specs = {s.name: s for s in SPECS}
        self.values = declare(self, SPECS)
        self.codec = FrameCodec()
        frame_specs = frame_id_specs(self.codec.message_names)
        self.specs.update({s.name: s for s in frame_specs})
        self.values.update(declare(self, frame_specs))
        check_rest_rate(self.values)  # at start-up: exit 1 with the reason
        self.plant = load_plant(self.values)
        self.sensors = sensor_settings(self.values, self.plant)
        self.controller = PressureController(
            pressure_control_config(self.values), PneumaticPlant(self.plant.parameters),
            {name: model.noise_std_pa for name, _, model in self.sensors})
        self.add_on_set_parameters_callback(self._on_set)
        self.status_pub = self.create_publisher(ControllerStatus, "controller/status", 100)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.sensor_pubs = {}
        # the runtime core's ports (runtime.core): each batch of readings, each status
        self.readings: Port[list] = Port("readings")
        self.reports: Port[ControllerReport] = Port("reports")
        if not in_process:  # composed, the grasp manager's commands come by direct call only
            self.create_subscription(PressureCommand, "pressure/command", self.on_command, 10)
        self.create_subscription(PressureCommand, "~/identification_command",
                                 self._on_identification_command, 10)
        if not in_process:
            self.create_subscription(EstimatorConsistency, messages.CONSISTENCY_TOPIC,
                                     self._on_consistency_message, 10)
        self.estimate_subscription = None
        self._subscribe_estimate(self.values["use_estimate"])
        self.create_service(Trigger, "~/vent", self._on_vent)
        self.bus = self.link = self.loop = None
        self.last_output = None
        self.last_note = ""
        self.ignored_said = False  # in identification mode: the ignored pressure/command, said
        self.create_timer(1.0, self._publish_diagnostics)
        if self.values["autostart"]:
            # rclpy's transitions pass a Ctrl-C on, with the control loop started
            with closed_if_cut_short(self):
                if self.trigger_configure() == TransitionCallbackReturn.SUCCESS:
                    self.trigger_activate()

    # ---- parameters ---------------------------------------------------------------------------
    def _on_set(self, parameters):

        def extra(params):
            changed = {p.name: p.value for p in params}
            if "plant_file" in changed:
                return "plant_file is read at start-up: restart the node"
            if "identification_mode" in changed and self.controller.active:
                return ("identification_mode changes only while the controller is inactive: "
                        "deactivate it first (it vents), then activate it again")
            if self.link is not None and any(
                    n.startswith(PRESSURE_CONFIGURE_PREFIXES) for n in changed):
                return ("CAN, sensor and rate parameters apply at configure: deactivate and clean "
                        "up first")
            if any(self.specs[n].field for n in changed if n in self.specs):
                try:
                    config = pressure_control_config({**self.values, **changed})
                except ValueError as error:
                    return str(error)
                self.controller.config = config
            if "use_estimate" in changed:
                self._subscribe_estimate(changed["use_estimate"])
            self.values.update(changed)
            return ""

        return check_all(self.specs, parameters, extra)

    def _subscribe_estimate(self, wanted: bool) -> None:
        """pressure/estimate only while use_estimate: at the estimator's rate it is the busiest
        topic."""
        if wanted and self.estimate_subscription is None:
            # no QoS event handlers: destroying a subscription while the executor waits on its
            # handler raises InvalidHandle in the spin thread (rclpy Jazzy); plain subscriptions
            # are guarded
            self.estimate_subscription = self.create_subscription(
                FluidPressure, "pressure/estimate", self._on_estimate, 10,
                event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=False))
        elif not wanted and self.estimate_subscription is not None:
            self.destroy_subscription(self.estimate_subscription)
            self.estimate_subscription = None

    # ---- lifecycle ------------------------------------------------------------------------------
    def on_configure(self, state) -> TransitionCallbackReturn:
        v = self.values
        try:
            sensors = sensor_settings(v, self.plant)
            check_rest_rate(v)
            self.codec = FrameCodec(frame_ids=frame_id_overrides(v, self.codec.message_names))
            self.bus = open_bus(v["can.interface"], v["can.channel"], v["can.bitrate"])
            self.link = ControllerLink(self.bus, self.controller,
                                       [SensorBinding(n, m, model.bias_pa)
                                        for n, m, model in sensors],
                                       codec=self.codec, on_readings=self._publish_readings,
                                       rest_receive_period_s=v["rest_receive_period"],
                                       command_frame_period_s=v["command_frame_period"],
                                       valve_lifetime_s=v["valve_lifetime"],
                                       control_period_s=1.0 / v["control_rate_hz"])
        except (ValueError, can.CanError, OSError, ImportError) as error:
            self.get_logger().error(f"configure failed: {error}")
            self._close_bus()
            return TransitionCallbackReturn.FAILURE
        self.noise_variance = {n: model.noise_std_pa**2 for n, _, model in sensors}
        self.sensor_pubs = {
            n: self.create_publisher(FluidPressure, f"pressure/sensor/{n}", 100)
            for n, _, _ in sensors
        }
        self.get_logger().info(f"bus {v['can.interface']}:{v['can.channel']} open")
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state) -> TransitionCallbackReturn:
        self.controller.identification = self.values["identification_mode"]
        self.ignored_said = False
        if self.controller.identification:
            self.get_logger().warn(
                "identification mode: open loop, commands on ~/identification_command only; "
                "every limit and safety check stays")
        self.controller.active = True
        self.loop = make_control_loop(self.link, self.values["control_rate_hz"],
                                      self.values["status_rate_hz"],
                                      on_status=self._on_loop_output,
                                      rest_rate_hz=self.values["rest_rate_hz"])
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

    def _on_identification_command(self, msg: PressureCommand):
        self._take(messages.pressure_order(msg), identification_topic=True)

    def on_command(self, msg: PressureCommand):
        """A pressure command on the topic (the node alone)."""
        self.take_order(messages.pressure_order(msg))

    def take_order(self, order: PressureOrder) -> None:
        """A pressure command: composed, the grasp manager's, which owns the pressure there
        (refusals: :meth:`ControllerLink.take`)."""
        self._take(order)

    def _take(self, order: PressureOrder, identification_topic: bool = False):
        if self.link is None:
            self.get_logger().warn("pressure command ignored: the controller is not configured")
            return
        note = self.link.take(order.target_gauge_pa, order.source, order.max_rate_pa_per_s,
                              order.stamp_s, self.get_clock().now().nanoseconds * 1e-9,
                              self.values["stamp_tolerance"], identification_topic,
                              on_applied=self._set_note)
        if note == IGNORED_IN_IDENTIFICATION:
            # said once: the grasp manager refreshes its command every second, and a live
            # identification's log was a warning a second for a minute
            if self.ignored_said:
                return
            self.ignored_said = True
            note += (": pressure/command (the grasp manager's refresh too) is ignored until "
                     "identification_mode is off; said once")
        if note:
            self.get_logger().warn(note, throttle_duration_sec=1.0)

    def take_consistency(self, evidence: Consistency) -> None:
        """The estimator's evidence on a sensor (composed: a direct call; else from
        estimator/consistency)."""
        if self.link is not None:
            self.link.update_consistency(evidence.sensor, evidence.mean_nis, evidence.bound)

    def _on_consistency_message(self, msg: EstimatorConsistency) -> None:
        """The estimator's NIS per sensor (a separate estimator node)."""
        if len(msg.mean_nis) != len(msg.sensor_names):
            self.get_logger().warn(
                f"{messages.CONSISTENCY_TOPIC} ignored: {len(msg.sensor_names)} sensor names, "
                f"{len(msg.mean_nis)} values", throttle_duration_sec=5.0)
            return
        for name, mean_nis in zip(msg.sensor_names, msg.mean_nis):
            if name in self.values["sensors.names"]:
                self.take_consistency(Consistency(name, mean_nis, msg.nis_upper_bound))

    def _set_note(self, note: str) -> None:
        self.last_note = note  # before the step the command triggers publishes the status

    def _on_estimate(self, msg: FluidPressure):
        if self.values["use_estimate"] and self.link is not None:
            self.link.update_estimate(messages.gauge_pa(msg))

    def _on_vent(self, request, response):
        """VENT frames go out at once and the controller keeps venting. The reply says "venting"
        only when a fresh reading can confirm it; blind, it says so."""
        if self.link is None:
            response.success, response.message = False, "not configured: no bus to vent through"
            return response
        response.success, response.message = True, self.link.vent_and_say()
        return response

    def _publish_readings(self, readings: list):
        link = self.link
        if link is None:
            return
        # stamped when measured, not when processed (they differ when this process is starved)
        link_now_s, ros_minus_link_s = link.clock(), self._ros_minus_link_s(link)
        samples = [Reading(name, gauge_pa, ros_minus_link_s + min(sent_at, link_now_s))
                   for name, gauge_pa, sent_at in readings]
        # whether anyone subscribes: asked once per sensor and batch, not per reading
        wanted = {}
        for name, gauge_pa, measured_s in samples:
            publisher = self.sensor_pubs.get(name)
            if publisher is not None and name not in wanted:
                wanted[name] = listened(self, publisher)
            if wanted.get(name):
                publish(
                    self, publisher,
                    messages.fluid_pressure(gauge_pa, self.noise_variance[name], measured_s, name))
        self.readings.emit(samples)

    def _ros_minus_link_s(self, link) -> float:
        """ROS time less the link's clock, read at one instant."""
        return clock_offset_s(link.clock, lambda: self.get_clock().now().nanoseconds * 1e-9)

    def _publish_status(self):
        link = self.link
        if link is None:
            return
        outputs = link.status_outputs()
        if not outputs:
            return
        # their stamp and their ages (when the estimator's inputs change) at one instant of the
        # link's clock
        now = link.clock()
        ros_minus_link_s = self._ros_minus_link_s(link)
        header = None
        for out, changed, note in outputs:
            note = note or self.last_note
            if listened(self, self.status_pub):  # 50 Hz; the composed parts take the report
                if header is None:
                    header = Header(stamp=stamp_msg(now + ros_minus_link_s),
                                    frame_id="softgrip_base")
                publish(self, self.status_pub,
                        messages.controller_status(out, link, header, note, now, changed))
            self.reports.emit(ControllerReport(
                now + ros_minus_link_s, changed + ros_minus_link_s, int(out.fault_flags),
                link.controller.measured(now), out.regulator_setpoint_gauge_pa,
                out.regulator_enabled, int(out.valves[0]),
                "; ".join(m for m in (out.message, note) if m)))

    def _publish_diagnostics(self):
        link, loop = self.link, self.loop
        stats = None if link is None else link.stats(self.values["sensors.names"], loop)
        report = pressure_controller_report(self.last_output, stats)
        publish(
            self, self.diagnostics_pub,
            messages.diagnostics(report, "softgrip: pressure controller",
                                 self.values["can.channel"],
                                 self.get_clock().now().to_msg()))


def main(args=None) -> int:
    return run_node(PressureControllerNode, args)


if __name__ == "__main__":
    raise SystemExit(main())

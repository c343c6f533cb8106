"""grasp_manager: grasp commands in, pressure commands out, and the gripper's state.

In: grasp_command (GraspCommand), the actions (softgrip's Grasp on ``grasp``, control_msgs'
GripperCommand on ``gripper_action`` and ParallelGripperCommand on ``parallel_gripper_action``:
see nodes.grasp_actions), pressure/estimate, controller/status, and with ``object_sensing``
pressure/sensor/<name> (the air's verdict on the object: softgrip_ros.control.object_sensing,
its motions judged on a worker thread).
Out: pressure/command (on every change, and refreshed every ``command_refresh_s`` so that the
controller's command timeout never trips during a long hold), grasp_state (GripperState) on
every change and at ``state_rate_hz``, /diagnostics. The state machine is
softgrip_ros.control.grasp_fsm; the clamp force law is softgrip_ros.model.force_law.
"""
from __future__ import annotations

import concurrent.futures
import math
import threading

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from rclpy.task import Future
from sensor_msgs.msg import FluidPressure
from std_msgs.msg import Header

from softgrip_interfaces.msg import (ControllerStatus, GraspCommand, GraspScene, GripperState,
                                     PressureCommand)
from softgrip_ros.control.grasp_fsm import (ControllerFeedback, GraspMode, GraspRequest,
                                            GraspStateMachine, Phase, Rejection)
from softgrip_ros.control.object_sensing import ObjectSensingLink
from softgrip_ros.control.reports import grasp_report, sensing_report
from softgrip_ros.estimation.grasp_sensing import GraspSensing, contact_model_for
from softgrip_ros.model.calibration import build_kinematics
from softgrip_ros.model.fidelity import FREE, Scene, SceneModel
from softgrip_ros.nodes import messages
from softgrip_ros.nodes.grasp_actions import GraspActions
from softgrip_ros.nodes.common import NodeTimers, listened, publish, run_node, stamp_seconds
from softgrip_ros.nodes.parameters import check_all, declare
from softgrip_ros.nodes.specs import GRASP_MANAGER_SPECS as SPECS
from softgrip_ros.nodes.specs import clamp_force_law, grasp_config, load_plant, sensing_sensors
from softgrip_ros.runtime.core import ControllerReport, Estimate, Port, PressureOrder, Reading
from softgrip_ros.runtime.motion_judge import MotionJudgeProcess



class GraspManagerNode(Node):
    """The grasp part of the runtime core (runtime.core): ports ``orders`` (its pressure
    commands) and ``scenes``; inputs :meth:`take_estimate`, :meth:`take_report` and
    :meth:`take_readings`. in_process: composed, they come from the estimator and the pressure
    controller by direct call (runtime.core.wire) instead of through their topics. Every entry
    point holds ``_lock``, because those calls come from the controller's threads."""

    def __init__(self, in_process: bool = False, **kwargs):
        super().__init__("grasp_manager", **kwargs)
        self._lock = threading.RLock()
        self.closed = False
        specs = {s.name: s for s in SPECS}
        v = self.values = declare(self, SPECS)
        self.add_on_set_parameters_callback(lambda params: check_all(
            specs, params, lambda _: "grasp_manager parameters apply at start-up: restart the node"
        ))
        config, force_law = grasp_config(v), clamp_force_law(v)
        kinematics = build_kinematics(v["fidelity"], v["gripper_model"],
                                      max_pressure_pa=v["max_gauge_pressure_pa"])
        scene_model = SceneModel(v["scene_fidelity"], v["tolerance_m"], v["gripper_model"])
        self.fsm = GraspStateMachine(kinematics, config, force_law, scene_model)
        self.scene = FREE
        self.scenes: Port[Scene] = Port("scenes")
        # the pressure controller and the estimator take them without a lock of ours
        self.orders: Port[PressureOrder] = Port("orders")
        self.scene_pub = self.create_publisher(
            GraspScene, "grasp_scene",
            QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.feedback = ControllerFeedback(v["estimate_timeout"], v["status_timeout"],
                                           v["sensor_fault_grace"])
        self.sent = (None, -math.inf)
        self.published_changes = -1
        self.waiters: list[Future] = []
        self.state_pub = self.create_publisher(GripperState, "grasp_state", 10)
        self.command_pub = self.create_publisher(PressureCommand, "pressure/command", 10)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(GraspCommand, "grasp_command", self._on_command, 10)
        if not in_process:
            self.create_subscription(
                FluidPressure, "pressure/estimate",
                lambda msg: self.take_estimate(Estimate(stamp_seconds(msg.header.stamp),
                                                        messages.gauge_pa(msg), msg.variance)), 10)
            self.create_subscription(ControllerStatus, "controller/status",
                                     self._on_status_message, 10)
        self.sensing: ObjectSensingLink | None = None
        self._worker = self._judge_process = None
        # checked whether or not the sensing runs: a bad value is refused at start-up
        plant = load_plant(v)
        sensors = sensing_sensors(v, plant)
        if v["object_sensing"]:
            self._start_sensing(in_process, sensors, plant)
        self.periodic = NodeTimers(self, in_process)
        self.periodic.every(1.0 / v["state_rate_hz"], self._on_timer)
        self.periodic.every(1.0, self._publish_diagnostics)
        self.actions = GraspActions(self)
        self.periodic.start()

    def close(self) -> None:
        """Stop whatever runs (the pressure controller vents on its own shutdown too); later
        in-process calls are ignored, as this node is destroyed before the ones that call it."""
        self.periodic.stop()
        if self.context.ok() and self.fsm.state.phase != Phase.IDLE:
            self.submit(GraspRequest(GraspMode.STOP, command_id="shutdown"))
        with self._lock:
            self.closed = True
        if self._worker is not None:
            self._worker.shutdown(wait=False, cancel_futures=True)
        if self._judge_process is not None:
            self._judge_process.close()
        self.actions.destroy()

    # ---- object sensing -------------------------------------------------------------------------
    def _start_sensing(self, in_process: bool, sensors: dict, plant) -> None:
        """The contact model is built on the worker (MuJoCo compiles the fingers' chain: about a
        second); the sensing joins the state machine once it is ready. The motions are judged in
        a child process (MotionJudgeProcess), which builds a model of its own."""
        v = self.values
        self._judge_process = MotionJudgeProcess(v["gripper_model"], v["fidelity"],
                                                 plant.parameters, plant.bending_volume_share)
        self._worker = concurrent.futures.ThreadPoolExecutor(
            1, thread_name_prefix="grasp_sensing")
        build = self._worker.submit(contact_model_for, v["gripper_model"], v["fidelity"],
                                    plant.parameters, plant.bending_volume_share)
        build.add_done_callback(lambda done: self._sensing_ready(done, sensors))
        if not in_process:
            for name in sensors:
                self.create_subscription(
                    FluidPressure, f"pressure/sensor/{name}",
                    lambda msg, name=name: self.take_readings(
                        [Reading(name, messages.gauge_pa(msg), stamp_seconds(msg.header.stamp))]),
                    100)

    def _sensing_ready(self, build, sensors: dict) -> None:
        try:
            model = build.result()
        except Exception as error:  # noqa: BLE001 (reported, and the grasp goes on without)
            if not build.cancelled():
                self.get_logger().error(f"object sensing off: {error}")
            return
        with self._lock:
            if not self.closed:
                self.sensing = ObjectSensingLink(self.fsm, GraspSensing(model, sensors),
                                                 self._judge)

    def _judge(self, job, done) -> None:
        """ObjectSensingLink's runner: ``job`` judged in the child, ``done`` back under the
        lock."""
        def finish(future):
            with self._lock:
                if self.closed or future.cancelled():
                    return
                done(future.exception() or future.result())
                self._after_change(self._now())
        try:
            self._judge_process.submit(job).add_done_callback(finish)
        except RuntimeError:  # shut down
            pass

    def take_readings(self, samples: list) -> None:
        """Readings [Reading] for the object sensing."""
        with self._lock:
            if self.sensing is not None and not self.closed:
                for name, gauge_pa, stamp_s in samples:
                    self.sensing.reading(name, stamp_s, gauge_pa)

    # ---- inputs ---------------------------------------------------------------------------------
    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _controller_fault(self, now: float) -> str:
        return self.feedback.fault(now, idle=self.fsm.state.phase == Phase.IDLE)

    def submit(self, request: GraspRequest) -> Rejection | None:
        """Apply a command from the topic or the action; its Rejection, or None."""
        with self._lock:
            now = self._now()
            fault = self._controller_fault(now)
            rejection = self.fsm.command(request, now, fault)
            self._sense(now, fault)
            self._after_change(now)
        if rejection is not None:
            self.get_logger().warn(f"grasp command {request.command_id!r} rejected: {rejection}")
        return rejection

    def _on_command(self, msg: GraspCommand) -> None:
        self.submit(messages.grasp_request(msg))

    def take_estimate(self, estimate: Estimate) -> None:
        """The pressure estimate; the state machine steps on each."""
        with self._lock:
            if self.closed:
                return
            self.feedback.on_estimate(estimate.gauge_pa,
                                      math.sqrt(max(estimate.variance_pa2, 0.0)), self._now())
            self._tick()

    def _on_status_message(self, msg: ControllerStatus) -> None:
        report = messages.controller_report(msg)
        if report is not None:
            self.take_report(report)

    def take_report(self, report: ControllerReport) -> None:
        """The pressure controller's status: its faults and reading, and for the object sensing
        the outputs it sent."""
        with self._lock:
            if not self.closed:
                self.feedback.on_status(report.fault_flags, report.measured_gauge_pa,
                                        self._now(), report.message)
                if self.sensing is not None:
                    self.sensing.controller_outputs(
                        report.outputs_changed_s, report.regulator_command_gauge_pa,
                        report.regulator_enabled, report.valve)

    def _on_timer(self) -> None:
        with self._lock:
            self._tick(force_state=True)

    def _tick(self, force_state: bool = False) -> None:
        now = self._now()
        gauge, std = self.feedback.pressure(now)
        fault = self._controller_fault(now)
        self.fsm.update(now, gauge, std, fault, controller_blind=bool(fault) and
                        self.feedback.blind(now),
                        controller_safe_state=self.feedback.safe_state(now))
        self._sense(now, fault)
        self._after_change(now, force_state)

    def _sense(self, now: float, fault: str) -> None:
        if self.sensing is not None:
            self.sensing.after(now, self.feedback.pressure(now)[0], fault)

    def _after_change(self, now: float, force_state: bool = False) -> None:
        request, (sent, sent_at) = self.fsm.request, self.sent
        if request != sent or now - sent_at >= self.values["command_refresh_s"]:
            self._send(request, now)
        if force_state or self.fsm.changes != self.published_changes:
            self.published_changes = self.fsm.changes
            self._publish_state()
            self._share_scene()
            for waiter in self.waiters:
                waiter.set_result(True)
            self.waiters.clear()

    # ---- outputs --------------------------------------------------------------------------------
    def _send(self, request, now: float) -> None:
        self.sent = (request, now)
        header = self._header()
        self.orders.emit(PressureOrder(request.target_gauge_pa, request.source, math.nan,
                                       stamp_seconds(header.stamp)))
        if listened(self, self.command_pub):
            publish(self, self.command_pub,
                    messages.pressure_command(request.target_gauge_pa, request.source, header))

    def state_message(self) -> GripperState:
        return messages.gripper_state(self.fsm.state, self._header())

    def _share_scene(self) -> None:
        scene = self.fsm.scene()
        if scene != self.scene:
            self.scene = scene
            message = messages.scene_message(scene)
            message.header = self._header()
            publish(self, self.scene_pub, message)
            self.scenes.emit(scene)

    def _publish_state(self) -> None:
        publish(self, self.state_pub, self.state_message())

    def _header(self) -> Header:
        return Header(stamp=self.get_clock().now().to_msg(), frame_id="softgrip_base")

    def _publish_diagnostics(self) -> None:
        with self._lock:
            report, sensed = grasp_report(self.fsm.state), sensing_report(self.fsm.state)
        stamp = self.get_clock().now().to_msg()
        array = messages.diagnostics(report, "softgrip: grasp manager", "gripper", stamp)
        if self.sensing is not None:
            array.status += messages.diagnostics(sensed, "softgrip: grasp sensing", "gripper",
                                                 stamp).status
        publish(self, self.diagnostics_pub, array)


def main(args=None) -> int:
    return run_node(GraspManagerNode, args)

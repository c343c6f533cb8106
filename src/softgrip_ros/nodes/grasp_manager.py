"""grasp_manager: grasp commands in, pressure commands out, and the gripper's state.

In: grasp_command (GraspCommand), the actions (softgrip's Grasp on ``grasp``, control_msgs'
GripperCommand on ``gripper_action`` and ParallelGripperCommand on ``parallel_gripper_action``:
see nodes.grasp_actions), pressure/estimate, controller/status.
Out: pressure/command (on every change, and refreshed every ``command_refresh_s`` so that the
controller's command timeout never trips during a long hold), grasp_state (GripperState) on
every change and at ``state_rate_hz``, /diagnostics. The state machine is
softgrip_ros.control.grasp_fsm; the clamp force law is softgrip_ros.model.force_law.
"""
from __future__ import annotations

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
                                            GraspStateMachine, Phase)
from softgrip_ros.control.reports import grasp_report
from softgrip_ros.model.calibration import build_kinematics
from softgrip_ros.model.fidelity import FREE, SceneModel
from softgrip_ros.nodes import messages
from softgrip_ros.nodes.grasp_actions import GraspActions
from softgrip_ros.nodes.common import NodeTimers, notify, publish, run_node
from softgrip_ros.nodes.parameters import check_all, declare
from softgrip_ros.nodes.specs import GRASP_MANAGER_SPECS as SPECS
from softgrip_ros.nodes.specs import clamp_force_law, grasp_config


class GraspManagerNode(Node):
    """in_process: the estimate and the controller status come by direct calls to
    :meth:`on_estimate` and :meth:`on_status` from the composed controller's nodes, instead of
    through their topics (see nodes.controller). Every entry point holds ``_lock``, because those
    calls come from the controller's threads."""

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
        self.scene_listeners = []  # in-process: kinematics.on_scene
        # in-process: pressure_controller.on_command (it takes no lock of ours)
        self.command_listeners = []
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
                lambda msg: self.on_estimate(None, messages.gauge_pa(msg), msg.variance), 10)
            self.create_subscription(ControllerStatus, "controller/status", self.on_status, 10)
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
        self.actions.destroy()

    # ---- inputs ---------------------------------------------------------------------------------
    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _controller_fault(self, now: float) -> str:
        return self.feedback.fault(now, idle=self.fsm.state.phase == Phase.IDLE)

    def submit(self, request: GraspRequest) -> str:
        """Apply a command from the topic or the action; '' or the rejection reason."""
        with self._lock:
            now = self._now()
            reason = self.fsm.command(request, now, self._controller_fault(now))
            self._after_change(now)
        if reason:
            self.get_logger().warn(f"grasp command {request.command_id!r} rejected: {reason}")
        return reason

    def _on_command(self, msg: GraspCommand) -> None:
        self.submit(messages.grasp_request(msg))

    def on_estimate(self, _stamp_s, gauge_pa: float, variance_pa2: float) -> None:
        """The pressure estimate (gauge Pa, Pa^2); the state machine steps on each."""
        with self._lock:
            if self.closed:
                return
            self.feedback.on_estimate(gauge_pa, math.sqrt(max(variance_pa2, 0.0)), self._now())
            self._tick()

    def on_status(self, msg: ControllerStatus) -> None:
        with self._lock:
            if not self.closed:
                self.feedback.on_status(msg.fault_flags, msg.measured_gauge_pressure_pa,
                                        self._now(), msg.message)

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
        self._after_change(now, force_state)

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
        message = messages.pressure_command(request.target_gauge_pa, request.source,
                                            self._header())
        notify(self.command_listeners, message)
        publish(self, self.command_pub, message)

    def state_message(self) -> GripperState:
        return messages.gripper_state(self.fsm.state, self._header())

    def _share_scene(self) -> None:
        scene = self.fsm.scene()
        if scene != self.scene:
            self.scene = scene
            message = messages.scene_message(scene)
            message.header = self._header()
            publish(self, self.scene_pub, message)
            notify(self.scene_listeners, scene)

    def _publish_state(self) -> None:
        publish(self, self.state_pub, self.state_message())

    def _header(self) -> Header:
        return Header(stamp=self.get_clock().now().to_msg(), frame_id="softgrip_base")

    def _publish_diagnostics(self) -> None:
        with self._lock:
            report = grasp_report(self.fsm.state)
        publish(
            self, self.diagnostics_pub,
            messages.diagnostics(report, "softgrip: grasp manager", "gripper",
                                 self.get_clock().now().to_msg()))


def main(args=None) -> int:
    return run_node(GraspManagerNode, args)

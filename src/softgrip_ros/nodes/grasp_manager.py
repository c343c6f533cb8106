"""grasp_manager: grasp commands in, pressure commands out, and the gripper's state.

In: grasp_command (GraspCommand), the Grasp action, pressure/estimate, controller/status.
Out: pressure/command (on every change, and refreshed every ``command_refresh_s`` so that the
controller's command timeout never trips during a long hold), grasp_state (GripperState) on
every change and at ``state_rate_hz``, /diagnostics. The state machine is
softgrip_ros.control.grasp_fsm; the clamp force law is softgrip_ros.model.grasp.
"""
from __future__ import annotations

import math
import threading

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from rclpy.task import Future
from sensor_msgs.msg import FluidPressure
from std_msgs.msg import Header

from softgrip_interfaces.action import Grasp
from softgrip_interfaces.msg import ControllerStatus, GraspCommand, GraspScene, GripperState, PressureCommand
from softgrip_ros.control.grasp_fsm import (ControllerFeedback, GraspConfig, GraspRequest, GraspStateMachine, Mode,
                                            Phase)
from softgrip_ros.control.pressure import Source
from softgrip_ros.model.calibration import build_kinematics
from softgrip_ros.model.fidelity import CHOICES as FIDELITY_CHOICES
from softgrip_ros.model.fidelity import FREE, SceneModel
from softgrip_ros.model.grasp import ClampForceLaw
from softgrip_ros.nodes.common import P_ATM_PA, NodeTimers, notify, publish, run_node
from softgrip_ros.nodes.kinematics import scene_message
from softgrip_ros.nodes.parameters import ParamSpec, check_all, declare

_G, _F = GraspConfig(), ClampForceLaw()
SPECS = [
    ParamSpec("cavity_type", "type_II", "finger type of config/gripper_geometry.yaml", choices=("type_I", "type_II", "type_III")),
    ParamSpec("fidelity", "l0", "bending law of the grasp model (opening pressures, D2)", choices=("l0", "l1")),
    ParamSpec("scene_fidelity", "auto", "model reported in grasp_state for the scene: as the kinematics node's fidelity",
              choices=FIDELITY_CHOICES),
    ParamSpec("tolerance_m", 1e-3, "as the kinematics node's tolerance_m", "m", 1e-6, 0.1),
    ParamSpec("state_rate_hz", 20.0, "grasp_state publish rate (and on every change)", "Hz", 10.0, 200.0),
    ParamSpec("command_refresh_s", 0.5, "pressure/command re-sent this often", "s", 0.05, 10.0),
    ParamSpec("estimate_timeout", 0.1, "an estimate older than this is not used (controller/status instead)", "s", 0.01, 5.0),
    ParamSpec("status_timeout", 1.0, "no controller/status this long during a grasp: FAULT", "s", 0.1, 60.0),
    ParamSpec("sensor_fault_grace", 0.3, "a sensor timeout or silent bus this long during a grasp: FAULT "
              "(the controller holds meanwhile)", "s", 0.0, 5.0),
    ParamSpec("max_gauge_pressure_pa", _G.max_gauge_pa, "highest pressure a command may ask for", "Pa", 1e3, 100e3),
    ParamSpec("min_gauge_pressure_pa", _G.min_gauge_pa, "lowest pressure a command may ask for", "Pa", -100e3, -1e3),
    ParamSpec("envelop_margin_m", _G.envelop_margin_m, "D2 beyond the object before ENVELOPED", "m", 1e-4, 0.1),
    ParamSpec("pinch_max_diameter_m", _G.pinch_max_diameter_m, "largest object for PINCH", "m", 1e-4, 0.02),
    ParamSpec("release_tip_spacing_m", _G.release_tip_spacing_m, "least opening after RELEASE", "m", 1e-3, 0.15),
    ParamSpec("pressure_tolerance_pa", _G.pressure_tolerance_pa, "a phase's pressure counts as reached within this", "Pa", 100.0, 20e3),
    ParamSpec("settle_time", _G.settle_s, "time within tolerance before a phase completes", "s", 0.01, 5.0),
    ParamSpec("auto_clamp_delay", _G.auto_clamp_delay_s, "ENVELOPED to CLAMPING on its own after this; < 0: wait for CLAMP", "s", -1.0, 600.0),
    ParamSpec("opening_timeout", _G.opening_timeout_s, "OPENING longer than this: FAULT", "s", 0.1, 60.0),
    ParamSpec("clamping_timeout", _G.clamping_timeout_s, "CLAMPING longer than this: FAULT", "s", 0.1, 60.0),
    ParamSpec("releasing_timeout", _G.releasing_timeout_s, "RELEASING longer than this: FAULT", "s", 0.1, 60.0),
    ParamSpec("hold_error_limit_pa", _G.hold_error_limit_pa, "HOLDING pressure off target by more than this ...", "Pa", 500.0, 50e3),
    ParamSpec("hold_error_time", _G.hold_error_time_s, "... for this long: FAULT", "s", 0.01, 10.0),
    ParamSpec("clamp_stiffness_n_per_pa", _F.stiffness_n_per_pa, "clamp force law: normal force per Pa below contact", "N/Pa", 1e-6, 1e-2),
    ParamSpec("friction_coefficient", _F.friction_coefficient, "friction when a command gives none", "", 0.05, 2.0),
    ParamSpec("safety_factor", _F.safety_factor, "clamp force over what the weight needs", "", 1.0, 10.0),
]


def _request_from(msg: GraspCommand) -> GraspRequest:
    friction = math.nan if msg.friction_coefficient == 0.0 else msg.friction_coefficient   # 0 (unset): the default
    return GraspRequest(mode=msg.mode, object_diameter_m=msg.object_diameter_m, object_mass_kg=msg.object_mass_kg,
                        target_tip_spacing_m=msg.target_tip_spacing_m, friction_coefficient=friction,
                        open_pressure_pa=msg.open_pressure_pa, clamp_pressure_pa=msg.clamp_pressure_pa,
                        command_id=msg.command_id)


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
        self.add_on_set_parameters_callback(
            lambda params: check_all(specs, params, lambda _: "grasp_manager parameters apply at start-up: restart the node"))
        config = GraspConfig(
            max_gauge_pa=v["max_gauge_pressure_pa"], min_gauge_pa=v["min_gauge_pressure_pa"], envelop_margin_m=v["envelop_margin_m"],
            pinch_max_diameter_m=v["pinch_max_diameter_m"], release_tip_spacing_m=v["release_tip_spacing_m"],
            pressure_tolerance_pa=v["pressure_tolerance_pa"], settle_s=v["settle_time"], auto_clamp_delay_s=v["auto_clamp_delay"],
            opening_timeout_s=v["opening_timeout"], clamping_timeout_s=v["clamping_timeout"],
            releasing_timeout_s=v["releasing_timeout"], hold_error_limit_pa=v["hold_error_limit_pa"],
            hold_error_time_s=v["hold_error_time"])
        force_law = ClampForceLaw(v["clamp_stiffness_n_per_pa"], v["friction_coefficient"], v["safety_factor"])
        kinematics = build_kinematics(v["fidelity"], v["cavity_type"], max_pressure_pa=v["max_gauge_pressure_pa"])
        scene_model = SceneModel(v["scene_fidelity"], v["tolerance_m"], v["cavity_type"])
        self.fsm = GraspStateMachine(kinematics, config, force_law, scene_model)
        self.scene = FREE
        self.scene_listeners = []            # in-process: kinematics.on_scene
        self.command_listeners = []          # in-process: pressure_controller.on_command (it takes no lock of ours)
        self.scene_pub = self.create_publisher(GraspScene, "grasp_scene", QoSProfile(
            depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.feedback = ControllerFeedback(v["estimate_timeout"], v["status_timeout"], v["sensor_fault_grace"])
        self.sent = (None, -math.inf)
        self.published_changes = -1
        self.waiters: list[Future] = []
        self.state_pub = self.create_publisher(GripperState, "grasp_state", 10)
        self.command_pub = self.create_publisher(PressureCommand, "pressure/command", 10)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(GraspCommand, "grasp_command", self._on_command, 10)
        if not in_process:
            self.create_subscription(FluidPressure, "pressure/estimate", lambda msg: self.on_estimate(
                None, msg.fluid_pressure - P_ATM_PA, msg.variance), 10)
            self.create_subscription(ControllerStatus, "controller/status", self.on_status, 10)
        self.periodic = NodeTimers(self, in_process)
        self.periodic.every(1.0 / v["state_rate_hz"], self._on_timer)
        self.periodic.every(1.0, self._publish_diagnostics)
        self.action_server = ActionServer(self, Grasp, "grasp", execute_callback=self._execute,
                                          goal_callback=lambda _: GoalResponse.ACCEPT,
                                          cancel_callback=lambda _: CancelResponse.ACCEPT)
        self.periodic.start()

    def close(self) -> None:
        """Stop whatever runs (the pressure controller vents on its own shutdown too); later
        in-process calls are ignored, as this node is destroyed before the ones that call it."""
        self.periodic.stop()
        if self.context.ok() and self.fsm.state.phase != Phase.IDLE:
            self.submit(GraspRequest(Mode.STOP, command_id="shutdown"))
        with self._lock:
            self.closed = True
        self.action_server.destroy()

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
        self.submit(_request_from(msg))

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
                self.feedback.on_status(msg.fault_flags, msg.measured_gauge_pressure_pa, self._now(), msg.message)

    def _on_timer(self) -> None:
        with self._lock:
            self._tick(force_state=True)

    def _tick(self, force_state: bool = False) -> None:
        now = self._now()
        gauge, std = self.feedback.pressure(now)
        fault = self._controller_fault(now)
        self.fsm.update(now, gauge, std, fault, controller_blind=bool(fault) and self.feedback.blind(now))
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
        source = {Source.SUPPLY: PressureCommand.SUPPLY, Source.VACUUM: PressureCommand.VACUUM,
                  Source.VENT: PressureCommand.VENT, Source.HOLD: PressureCommand.HOLD}[request.source]
        message = PressureCommand(header=self._header(), target_gauge_pressure_pa=request.target_gauge_pa,
                                  max_rate_pa_per_s=math.nan, source=source)
        notify(self.command_listeners, message)
        publish(self, self.command_pub, message)

    def state_message(self) -> GripperState:
        s = self.fsm.state
        return GripperState(
            header=self._header(), phase=int(s.phase), mode=int(s.mode), command_id=s.command_id,
            command_rejected=s.command_rejected, target_gauge_pressure_pa=s.target_gauge_pa,
            estimated_gauge_pressure_pa=s.estimated_gauge_pa, estimated_gauge_pressure_std_pa=s.estimated_std_pa,
            included_angle_rad=s.included_angle_rad, tip_spacing_m=s.tip_spacing_m, root_spacing_m=s.root_spacing_m,
            clamp_force_n=s.clamp_force_n, model_fidelity=s.model_fidelity,
            pressure_in_validated_range=s.in_validated_range, message=s.message)

    def _share_scene(self) -> None:
        scene = self.fsm.scene()
        if scene != self.scene:
            self.scene = scene
            message = scene_message(scene)
            message.header = self._header()
            publish(self, self.scene_pub, message)
            notify(self.scene_listeners, scene)

    def _publish_state(self) -> None:
        publish(self, self.state_pub, self.state_message())

    def _header(self) -> Header:
        return Header(stamp=self.get_clock().now().to_msg(), frame_id="softgrip_base")

    def _publish_diagnostics(self) -> None:
        with self._lock:
            s = self.fsm.state
        level = DiagnosticStatus.ERROR if s.phase == Phase.FAULT else DiagnosticStatus.OK
        status = DiagnosticStatus(name="softgrip: grasp manager", hardware_id="gripper", level=level, message=s.message,
                                  values=[KeyValue(key="phase", value=s.phase.name),
                                          KeyValue(key="command_id", value=s.command_id),
                                          KeyValue(key="model_fidelity", value=s.model_fidelity)])
        publish(self, self.diagnostics_pub, DiagnosticArray(header=self._header(), status=[status]))

    # ---- the Grasp action -----------------------------------------------------------------------
    async def _execute(self, goal_handle):
        request = _request_from(goal_handle.request.command)
        with self._lock:       # the generation is the one this goal's command started
            reason = self.submit(request)
            generation = self.fsm.accepted
        if reason:
            goal_handle.abort()
            return self._result(False, f"rejected: {reason}")
        while True:
            with self._lock:   # check and register the waiter in one step, so that no change slips between
                if goal_handle.is_cancel_requested:
                    self.submit(GraspRequest(Mode.STOP, command_id=request.command_id))
                    goal_handle.canceled()
                    return self._result(False, "canceled: venting")
                if self.fsm.accepted != generation:
                    goal_handle.abort()
                    return self._result(False, f"superseded by command {self.fsm.state.command_id!r}")
                if self.fsm.done(request.mode):
                    held = self.fsm.state.phase == Phase.HOLDING
                    (goal_handle.succeed if self.fsm.state.phase != Phase.FAULT else goal_handle.abort)()
                    return self._result(held, self.fsm.state.message)
                feedback = Grasp.Feedback(state=self.state_message())
                waiter = Future()
                self.waiters.append(waiter)
            goal_handle.publish_feedback(feedback)
            await waiter

    def _result(self, held: bool, message: str) -> Grasp.Result:
        s = self.fsm.state
        return Grasp.Result(object_held=held, final_phase=int(s.phase), final_gauge_pressure_pa=s.estimated_gauge_pa,
                            clamp_force_n=s.clamp_force_n, message=message)


def main(args=None) -> int:
    return run_node(GraspManagerNode, args)

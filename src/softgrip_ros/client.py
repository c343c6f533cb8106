"""GripperClient: drive one softgrip gripper from Python, as nav2_simple_commander's
BasicNavigator drives a robot: start a task, poll ``is_task_complete()``, read ``feedback()``
and ``result()``, ``cancel()`` it.

    import rclpy
    from softgrip_ros.client import GripperClient

    rclpy.init()
    gripper = GripperClient(namespace="/g1")
    gripper.wait_until_ready(timeout_s=10.0)
    gripper.envelop_clamp(diameter_m=0.04, mass_kg=0.02)
    while gripper.state() is None or gripper.state().phase != gripper.state().ENVELOPED:
        time.sleep(0.05)          # open around the object: the arm places it now
    gripper.clamp()               # goes on with the envelop_clamp task, which ends HOLDING
    while not gripper.is_task_complete():
        time.sleep(0.05)
    print(gripper.result().object_held)
    gripper.close()

Every task is a goal of the grasp manager's Grasp action; unset fields go as NaN (automatic).
The client is its own node, spun in a background thread, unless ``node`` is given: then the
caller spins that node, and the client only uses it.
"""
from __future__ import annotations

import math
import threading
import time
import uuid

from softgrip_ros.control.grasp_fsm import GraspMode

_FIELDS = ("object_diameter_m", "object_mass_kg", "target_tip_spacing_m", "friction_coefficient",
           "open_pressure_pa", "clamp_pressure_pa")


def serial_action_client(node, action_type, action_name: str, qos: dict | None = None):
    """An rclpy ActionClient whose goal responses wait until their request is registered; its
    services' queues as the servers' (``qos``: rclpy's keyword arguments, to choose others).

    rclpy registers a goal's future only after the request has gone out; an executor thread that
    takes the response in between drops it ("Ignoring unexpected goal response", rclpy#1123),
    and the goal never completes (CI: test_multi_gripper's clamp() returned False so)."""
    from rclpy.action import ActionClient

    class SerialActionClient(ActionClient):

        def __init__(self, *args, **kwargs):
            self._registering = threading.Lock()
            super().__init__(*args, **kwargs)

        def send_goal_async(self, *args, **kwargs):
            with self._registering:
                return super().send_goal_async(*args, **kwargs)

        async def execute(self, taken_data):
            with self._registering:  # a request being sent is registered first
                pass
            return await super().execute(taken_data)

    from softgrip_ros.nodes.common import action_qos
    return SerialActionClient(node, action_type, action_name,
                              **(action_qos() if qos is None else qos))


def grasp_command(mode: int, command_id: str = "", **fields):
    """A softgrip_interfaces/GraspCommand with every field not given NaN (automatic)."""
    from softgrip_interfaces.msg import GraspCommand
    unknown = set(fields) - set(_FIELDS)
    if unknown:
        raise ValueError(f"unknown GraspCommand fields {sorted(unknown)}; known: {list(_FIELDS)}")
    values = {name: float(fields.get(name, math.nan)) for name in _FIELDS}
    return GraspCommand(mode=int(mode), command_id=command_id, **values)


ACCEPT_TIMEOUT_S = 5.0  # a goal's acceptance normally takes milliseconds


def _cancel_if_accepted(future) -> None:
    handle = future.result()
    if handle is not None and handle.accepted:
        handle.cancel_goal_async()


def check_namespace(namespace: str) -> str:
    """``namespace`` ('' or e.g. "/g1") if the gripper's topics can live under it; ValueError
    with the reason in one line if not (a space, a '-', an empty level...)."""
    from rclpy.expand_topic_name import expand_topic_name
    from rclpy.validate_full_topic_name import validate_full_topic_name
    from rclpy.validate_topic_name import validate_topic_name

    if not isinstance(namespace, str):
        raise ValueError(f"a namespace is a string, got {namespace!r}")
    topic = f"{namespace.rstrip('/')}/grasp_state"
    try:
        validate_topic_name(topic)
        validate_full_topic_name(expand_topic_name(topic, "softgrip", "/"))
    except Exception as error:  # rclpy raises its own types, and rcl's errors as RuntimeError
        # its messages: "Invalid topic name: <why>:", then the name with a caret below it; or
        # "topic name '...' is invalid: <why>, at <C source file>"
        first = str(error).splitlines()[0].rstrip(":").split(", at /")[0]
        reason = first.split(": ", 1)[1] if ": " in first else first
        raise ValueError(f"invalid namespace {namespace!r}: {reason}") from None
    return namespace


def add_namespace_argument(parser) -> None:
    """The tools' --namespace option, checked as it is parsed (a one-line usage error)."""
    import argparse

    def checked(text: str) -> str:
        try:
            return check_namespace(text)
        except ValueError as error:
            raise argparse.ArgumentTypeError(str(error)) from None

    parser.add_argument("--namespace", default="", type=checked,
                        help="the gripper's namespace (e.g. /g1)")


class GripperClient:
    """One gripper's grasp manager, reached in ``namespace`` ('' or e.g. "/g1"); ValueError for
    a namespace no topic can live under."""

    def __init__(self, node=None, namespace: str = "", context=None,
                 node_name: str = "softgrip_client"):
        import rclpy
        from softgrip_interfaces.action import Grasp
        from softgrip_interfaces.msg import GripperState

        check_namespace(namespace)
        self._own = node is None
        self.node = node if node is not None else rclpy.create_node(
            f"{node_name}_{uuid.uuid4().hex[:6]}", context=context)
        prefix = namespace.rstrip("/") + "/" if namespace else ""
        self._lock = threading.Lock()
        self._state = None
        self._feedback = None
        self._goal = None          # (goal future, result future or None)
        self._result = None
        self._subscription = self.node.create_subscription(
            GripperState, f"{prefix}grasp_state", self._on_state, 10)
        self.action_name = f"{prefix}grasp"
        self._action = serial_action_client(self.node, Grasp, self.action_name)
        self._spinner = None
        if self._own:
            from softgrip_ros.nodes.common import spinning
            self._spinner = spinning(self.node, context=self.node.context, threads=1)
            self._spinner.__enter__()

    # ---- the gripper's tasks ------------------------------------------------------------------
    def envelop_clamp(self, diameter_m: float, mass_kg: float, command_id: str = "",
                      **overrides) -> bool:
        """Open around an object, wait for :meth:`clamp` (or the automatic clamp), hold it.
        ``overrides``: GraspCommand's other fields (friction_coefficient, open_pressure_pa,
        clamp_pressure_pa). Whether the goal was accepted."""
        return self._send(GraspMode.ENVELOP_CLAMP, command_id, object_diameter_m=diameter_m,
                          object_mass_kg=mass_kg, **overrides)

    def pinch(self, diameter_m: float, mass_kg: float, command_id: str = "", **overrides) -> bool:
        """Close the tips on a thin object (up to the grasp manager's pinch_max_diameter_m)."""
        return self._send(GraspMode.PINCH, command_id, object_diameter_m=diameter_m,
                          object_mass_kg=mass_kg, **overrides)

    def open(self, tip_spacing_m: float | None = None, command_id: str = "",
             pressure_pa: float | None = None) -> bool:
        """Open to ``tip_spacing_m`` (None: fully) and hold there; or, given ``pressure_pa`` (> 0,
        with ``tip_spacing_m`` at most what it opens to), hold that pressure."""
        spacing = math.nan if tip_spacing_m is None else tip_spacing_m
        pressure = math.nan if pressure_pa is None else pressure_pa
        return self._send(GraspMode.OPEN, command_id, target_tip_spacing_m=spacing,
                          open_pressure_pa=pressure)

    def clamp(self, command_id: str = "", **overrides) -> bool:
        """Clamp what the gripper holds open (after envelop_clamp, or open with the object's
        diameter and mass in ``overrides``)."""
        return self._send(GraspMode.CLAMP, command_id, **overrides)

    def release(self, command_id: str = "") -> bool:
        """Vent, then open to let go."""
        return self._send(GraspMode.RELEASE, command_id)

    def stop(self, command_id: str = "") -> bool:
        """Vent now, whatever runs."""
        return self._send(GraspMode.STOP, command_id)

    # ---- the task's progress ----------------------------------------------------------------
    def wait_until_ready(self, timeout_s: float = 10.0, sensing: bool = False) -> bool:
        """Whether the grasp action server and grasp_state were found within ``timeout_s``.
        ``sensing``: then also wait, within the same time, for grasp_state to show a pressure:
        just after bring-up the controller has not seen its sensors yet and refuses a grasp for
        that (seen in CI: "sensor timeout, bus silent" 0.9 s after the controller started). A
        gripper whose pressure stays unknown is ready all the same at the deadline; its commands
        then say why they are refused."""
        deadline = time.monotonic() + timeout_s
        found = False
        while time.monotonic() < deadline:
            found = found or (self._action.server_is_ready() and self.state() is not None)
            if found and (not sensing or math.isfinite(
                    self.state().estimated_gauge_pressure_pa)):
                return True
            time.sleep(0.02)
        return found

    def is_task_complete(self) -> bool:
        """Whether the last task has ended (succeeded, failed, superseded, canceled or
        rejected); True when none was started."""
        with self._lock:
            goal = self._goal
        if goal is None:
            return True
        goal_future, _ = goal
        if not goal_future.done():
            return False
        handle = goal_future.result()
        if handle is None or not handle.accepted:
            return True
        return self._result_future().done()

    def feedback(self):
        """The last task's latest feedback, a GripperState (None before the first)."""
        with self._lock:
            return self._feedback

    def result(self):
        """The last task's Grasp.Result, once it has ended (None before, or when the goal was
        not accepted)."""
        if not self.is_task_complete():
            return None
        with self._lock:
            goal = self._goal
        if goal is None or not goal[0].result() or not goal[0].result().accepted:
            return None
        response = self._result_future().result()
        return None if response is None else response.result

    def status(self) -> int:
        """The last task's action_msgs/GoalStatus code (0: unknown, e.g. not yet ended)."""
        future = self._result_future() if self._goal and self._goal[0].done() else None
        if future is None or not future.done() or future.result() is None:
            return 0
        return future.result().status

    def cancel(self) -> bool:
        """Cancel the last task (the grasp manager vents); whether a cancel was sent."""
        with self._lock:
            goal = self._goal
        if goal is None or not goal[0].done() or goal[0].result() is None:
            return False
        goal[0].result().cancel_goal_async()
        return True

    def state(self):
        """The latest grasp_state (softgrip_interfaces/GripperState), None before the first."""
        with self._lock:
            return self._state

    def object_status(self):
        """What the air says of the object now: (ObjectStatus, its size as the fingers felt it
        in m, NaN when none); (UNKNOWN, NaN) before the first grasp_state."""
        from softgrip_ros.estimation.grasp_sensing import ObjectStatus
        state = self.state()
        if state is None:
            return ObjectStatus.UNKNOWN, math.nan
        try:
            return ObjectStatus(state.object_status), float(state.object_size_m)
        except ValueError:
            return ObjectStatus.UNKNOWN, math.nan

    def close(self) -> None:
        self._action.destroy()
        self.node.destroy_subscription(self._subscription)
        if self._own:
            self._spinner.__exit__(None, None, None)
            self.node.destroy_node()

    # ---- internals ----------------------------------------------------------------------
    def _send(self, mode: int, command_id: str, **fields) -> bool:
        from softgrip_interfaces.action import Grasp
        command = grasp_command(mode, command_id or f"client-{uuid.uuid4().hex[:8]}", **fields)
        if not self._action.wait_for_server(timeout_sec=5.0):
            raise RuntimeError(f"no grasp action server on {self.action_name!r}: is the "
                               "controller running, in this namespace?")
        future = self._action.send_goal_async(Grasp.Goal(command=command),
                                              feedback_callback=self._on_feedback)
        with self._lock:
            self._goal, self._feedback = (future, None), None
        deadline = time.monotonic() + ACCEPT_TIMEOUT_S
        while not future.done() and time.monotonic() < deadline:
            time.sleep(0.005)
        if not future.done():
            # Withdrawn: the caller is told it did not start, so should its acceptance still
            # come (a loaded host delays DDS), it is cancelled then, which stops and vents,
            # rather than left to move the fingers unannounced.
            with self._lock:
                if self._goal is not None and self._goal[0] is future:
                    self._goal = None
            future.add_done_callback(_cancel_if_accepted)
            return False
        handle = future.result()
        return bool(handle is not None and handle.accepted)

    def _result_future(self):
        with self._lock:
            goal_future, result_future = self._goal
            if result_future is None:
                result_future = goal_future.result().get_result_async()
                self._goal = (goal_future, result_future)
            return result_future

    def _on_feedback(self, message) -> None:
        with self._lock:   # only the last task's: an earlier goal may still be reporting
            goal_future = self._goal[0] if self._goal else None
            handle = goal_future.result() if goal_future is not None and goal_future.done() \
                else None
            if handle is None or bytes(handle.goal_id.uuid) == bytes(message.goal_id.uuid):
                self._feedback = message.feedback.state

    def _on_state(self, message) -> None:
        with self._lock:
            self._state = message

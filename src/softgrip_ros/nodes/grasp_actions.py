"""The grasp manager's actions: softgrip's Grasp, and control_msgs' GripperCommand and
ParallelGripperCommand for arm stacks (MoveIt, behaviour trees). The semantics of the latter are
in softgrip_ros.control.gripper_command: ``position`` is the tip spacing D2 in m, opening goes
to it with positive pressure, closing clamps with ``max_effort`` N per finger, a cancel holds
the present pressure. Every position and effort reported is the model's (there is no finger
encoder). A goal that cannot be done is aborted at once; the reason is in grasp_state's message
and the log (control_msgs' results have no text)."""
from __future__ import annotations

from control_msgs.action import GripperCommand, ParallelGripperCommand
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.task import Future
from sensor_msgs.msg import JointState

from softgrip_interfaces.action import Grasp
from softgrip_ros.control.grasp_fsm import GoalOutcome, GraspMode, GraspRequest, Rejection
from softgrip_ros.control.gripper_command import (gripper_progress, present_progress,
                                                  start_gripper_goal)
from softgrip_ros.nodes import messages
from softgrip_ros.nodes.common import action_qos


# after acting on a cancel, how many milliseconds a goal waits for the server to mark it
CANCEL_MARK_POLLS = 1000


def _goal_id(goal_handle) -> bytes:
    return bytes(goal_handle.goal_id.uuid)


class GraspActions:
    """The three action servers of ``manager`` (a GraspManagerNode), each goal followed through
    the manager's state machine under its lock."""

    def __init__(self, manager):
        self.manager = manager
        v = manager.values
        self.joint = v["prefix"] + messages.TIP_SPACING_JOINT
        # goal id -> what cancelling the goal does, while it is followed
        self._cancels: dict = {}
        self._cancelled_early: set = set()
        accept = {"goal_callback": lambda _: GoalResponse.ACCEPT,
                  "cancel_callback": self._on_cancel, **action_qos()}
        self.servers = [
            ActionServer(manager, Grasp, "grasp", execute_callback=self._execute_grasp, **accept),
            ActionServer(manager, GripperCommand, v["gripper_action"],
                         execute_callback=self._execute_gripper, **accept),
            ActionServer(manager, ParallelGripperCommand, v["parallel_gripper_action"],
                         execute_callback=self._execute_parallel, **accept),
        ]

    def destroy(self) -> None:
        for server in self.servers:
            server.destroy()

    def _on_cancel(self, goal_handle) -> CancelResponse:
        """Accept a cancel, and act on it at once (the valves stop or hold now), then wake the
        goal to end it: it waited for the next state change, up to the manager's 0.5 s tick."""
        m, goal = self.manager, _goal_id(goal_handle)
        with m._lock:
            cancel = self._cancels.get(goal)
            if cancel is not None and goal not in self._cancelled_early:
                cancel()
                self._cancelled_early.add(goal)
            for waiter in m.waiters:
                waiter.set_result(True)
            m.waiters.clear()
        return CancelResponse.ACCEPT

    def _shortly(self) -> Future:
        """A future done in a millisecond, by a one-shot timer."""
        done, m = Future(), self.manager
        timer = None

        def fire():
            m.destroy_timer(timer)
            if not done.done():
                done.set_result(True)

        timer = m.create_timer(0.001, fire)
        return done

    async def _follow(self, goal_handle, outcome_of, feedback_of, cancel) -> GoalOutcome:
        """Wait, a state change at a time, until ``outcome_of()`` says the goal ended, or a
        cancel (``cancel()`` runs, once, in the cancel's callback or here): the GoalOutcome, with
        the goal handle ended to match. Each check
        registers its waiter under the lock, so that no change slips between."""
        m, goal = self.manager, _goal_id(goal_handle)
        with m._lock:
            self._cancels[goal] = cancel
        polls = 0
        try:
            while True:
                with m._lock:
                    early = goal in self._cancelled_early
                    if goal_handle.is_cancel_requested:
                        if not early:
                            cancel()
                        goal_handle.canceled()
                        return GoalOutcome.CANCELED
                    if not early:
                        outcome = outcome_of()
                        if outcome.ended:
                            (goal_handle.succeed if outcome == GoalOutcome.SUCCEEDED
                             else goal_handle.abort)()
                            return outcome
                        feedback = feedback_of()
                        waiter = Future()
                        m.waiters.append(waiter)
                if early:  # acted on; the server marks the goal canceling right after
                    polls += 1
                    if polls > CANCEL_MARK_POLLS:  # it never did: end the goal all the same
                        with m._lock:
                            goal_handle.abort()
                        return GoalOutcome.CANCELED
                    await self._shortly()
                    continue
                goal_handle.publish_feedback(feedback)
                await waiter
        finally:
            with m._lock:
                self._cancels.pop(goal, None)
                self._cancelled_early.discard(goal)

    # ---- softgrip_interfaces/action/Grasp ---------------------------------------------------
    async def _execute_grasp(self, goal_handle):
        """A goal runs its command's task (see GraspStateMachine.outcome): a CLAMP that goes on
        with it, from the topic or another goal, keeps it running to HOLDING; any other command
        supersedes it; a cancel stops and vents."""
        m = self.manager
        request = messages.grasp_request(goal_handle.request.command)
        with m._lock:  # the task is the one this goal's command started or went on with
            rejection = m.submit(request)
            task = m.fsm.task
        if rejection is not None:
            goal_handle.abort()
            return self._grasp_result(False, f"rejected: {rejection}")
        outcome = await self._follow(
            goal_handle, lambda: m.fsm.outcome(task, request.mode),
            lambda: Grasp.Feedback(state=m.state_message()),
            lambda: m.submit(GraspRequest(GraspMode.STOP, command_id=request.command_id)))
        with m._lock:
            if outcome == GoalOutcome.CANCELED:
                return self._grasp_result(False, "canceled: venting")
            if outcome == GoalOutcome.SUPERSEDED:
                return self._grasp_result(
                    False, f"superseded by command {m.fsm.state.command_id!r}")
            return self._grasp_result(m.fsm.object_held(), m.fsm.state.message)

    def _grasp_result(self, held: bool, message: str) -> Grasp.Result:
        s = self.manager.fsm.state
        return Grasp.Result(object_held=held, final_phase=int(s.phase),
                            final_gauge_pressure_pa=s.estimated_gauge_pa,
                            clamp_force_n=s.clamp_force_n, message=message)

    # ---- control_msgs ---------------------------------------------------------------------
    async def _execute_gripper(self, goal_handle):
        command = goal_handle.request.command
        progress = await self._run_gripper_goal(goal_handle, command.position,
                                                command.max_effort, "gripper_cmd",
                                                self._gripper_feedback)
        return GripperCommand.Result(position=progress.position_m, effort=progress.effort_n,
                                     stalled=progress.stalled,
                                     reached_goal=progress.reached_goal)

    def _gripper_feedback(self, progress) -> GripperCommand.Feedback:
        return GripperCommand.Feedback(position=progress.position_m, effort=progress.effort_n,
                                       stalled=progress.stalled,
                                       reached_goal=progress.reached_goal)

    async def _execute_parallel(self, goal_handle):
        """One joint, ``<prefix>tip_spacing`` (a goal naming no joint means it too); its
        effort, when given, is the closing force; a velocity is not used."""
        command = goal_handle.request.command
        names, positions = list(command.name), list(command.position)
        if names not in ([], [self.joint]) or len(positions) != 1:
            m = self.manager
            reason = (f"one joint, {self.joint!r}, and one position, got names "
                      f"{_listed(names)} and positions {_listed(positions)}")
            with m._lock:  # said on grasp_state, as every other refusal is
                m.fsm.refuse("parallel_gripper_cmd", reason)
                m._after_change(m._now())
            m.get_logger().warn(f"parallel_gripper_cmd goal refused: {reason}")
            goal_handle.abort()
            return self._parallel_result(self._present())
        effort = float(command.effort[0]) if len(command.effort) else 0.0
        progress = await self._run_gripper_goal(goal_handle, positions[0], effort,
                                                "parallel_gripper_cmd", self._parallel_feedback)
        return self._parallel_result(progress)

    def _joint_state(self, progress) -> JointState:
        return JointState(header=self.manager._header(), name=[self.joint],
                          position=[progress.position_m], effort=[progress.effort_n])

    def _parallel_feedback(self, progress) -> ParallelGripperCommand.Feedback:
        return ParallelGripperCommand.Feedback(state=self._joint_state(progress))

    def _parallel_result(self, progress) -> ParallelGripperCommand.Result:
        return ParallelGripperCommand.Result(state=self._joint_state(progress),
                                             stalled=progress.stalled,
                                             reached_goal=progress.reached_goal)

    def _present(self):
        with self.manager._lock:
            return present_progress(self.manager.fsm)

    async def _run_gripper_goal(self, goal_handle, position_m, max_effort_n, action, feedback):
        """Start the goal (refused at once when it cannot be done) and follow it."""
        m, v = self.manager, self.manager.values
        with m._lock:
            now = m._now()
            goal = start_gripper_goal(m.fsm, float(position_m), float(max_effort_n),
                                      v["default_effort_n"], v["goal_tolerance_m"], now, action,
                                      m._controller_fault(now))
            m._after_change(now)
        if isinstance(goal, Rejection):
            m.get_logger().warn(f"{action} goal refused: {goal}")
            goal_handle.abort()
            return self._present()

        def cancel():
            now = m._now()
            m.fsm.hold_here(now, f"{action} canceled: holding the present pressure")
            m._after_change(now)

        tolerance = v["goal_tolerance_m"]
        await self._follow(goal_handle,
                           lambda: gripper_progress(m.fsm, goal, tolerance).outcome,
                           lambda: feedback(gripper_progress(m.fsm, goal, tolerance)), cancel)
        with m._lock:
            return gripper_progress(m.fsm, goal, tolerance)


def _listed(values: list, shown: int = 4) -> str:
    """``values`` as a list in a message, its first ``shown`` only (a goal may carry thousands):
    strings quoted and escaped, so that the message stays one line."""
    head = ", ".join(repr(v) for v in values[:shown])
    return f"[{head}, ... {len(values)} in all]" if len(values) > shown else f"[{head}]"

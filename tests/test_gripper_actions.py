"""control_msgs' GripperCommand and ParallelGripperCommand, and the GripperClient, through DDS on
the composed suite with the simulated device; the softgrip command against the installed
controller."""
import math
import subprocess

import pytest

from softgrip_ros.model.force_law import ObjectKind

from softgrip_ros.devtools.processes import installed_executable, stop_process
from tests.helpers.ros import spinning, unique, wait_for

pytestmark = pytest.mark.ros
TOLERANCE_M = 0.005   # the grasp manager's default goal_tolerance_m


@pytest.fixture
def suite(rclpy_context):
    """The composed nodes on a private virtual channel; a user node and a GripperClient on it."""
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from softgrip_ros.client import GripperClient
    from softgrip_ros.nodes.common import close_all
    from softgrip_ros.nodes.controller import make_nodes

    nodes = make_nodes(rclpy_context, {
        "pressure_controller": [Parameter("can.channel", value=unique("gripper"))],
        "grasp_manager": [Parameter("prefix", value="g1_")]})
    user = Node("gripper_action_user", context=rclpy_context)
    client = GripperClient(node=user)
    try:
        with spinning(rclpy_context, *nodes, user, threads=2):
            assert client.wait_until_ready(10.0)
            yield {n.get_name(): n for n in nodes}, user, client
    finally:
        client.close()
        close_all(nodes)
        user.destroy_node()


def test_a_client_waiting_to_sense_waits_for_a_pressure_then_for_nothing_more():
    """Just after bring-up grasp_state comes before the controller has seen a sensor, and a grasp
    sent then is refused ("sensor timeout, bus silent", CI once). wait_until_ready(sensing=True)
    waits for a pressure; without it, or when none comes by the deadline, the client is ready
    once the server and the state are there."""
    import threading
    import time
    from types import SimpleNamespace

    from softgrip_ros.client import GripperClient

    client = GripperClient.__new__(GripperClient)
    client._lock = threading.Lock()
    client._action = SimpleNamespace(server_is_ready=lambda: True)
    client._state = SimpleNamespace(estimated_gauge_pressure_pa=math.nan)
    seen = threading.Timer(0.3, lambda: setattr(
        client, "_state", SimpleNamespace(estimated_gauge_pressure_pa=120.0)))
    waited_from = time.monotonic()
    seen.start()
    try:
        assert client.wait_until_ready(10.0, sensing=True)
        # not before the pressure came (a bound on the order of events, not on speed)
        assert time.monotonic() - waited_from >= 0.3
        assert client.state().estimated_gauge_pressure_pa == 120.0
    finally:
        seen.cancel()
    client._state = SimpleNamespace(estimated_gauge_pressure_pa=math.nan)
    assert client.wait_until_ready(10.0)  # a vent does not wait for the pressure
    assert client.wait_until_ready(0.1, sensing=True)  # none by the deadline: ready all the same
    client._state = None
    assert not client.wait_until_ready(0.1, sensing=True)  # no state: nothing answered


def send(action_client, goal, feedback=None):
    future = action_client.send_goal_async(goal, feedback_callback=feedback)
    handle = wait_for(lambda: future.done() and future.result(), message="goal accepted")
    result = handle.get_result_async()
    return handle, result


def result_of(future, timeout=8.0):
    return wait_for(lambda: future.done() and future.result(), timeout=timeout,
                    message="the goal's result")


def gripper_goal(position_m, max_effort_n=0.0):
    from control_msgs.action import GripperCommand
    goal = GripperCommand.Goal()
    goal.command.position, goal.command.max_effort = position_m, max_effort_n
    return goal


def test_gripper_command_opens_then_closes_with_its_effort(suite):
    from action_msgs.msg import GoalStatus
    from control_msgs.action import GripperCommand
    from softgrip_ros.client import serial_action_client
    from softgrip_interfaces.msg import GripperState
    nodes, user, client = suite
    action = serial_action_client(user, GripperCommand, "gripper_cmd")
    assert action.wait_for_server(timeout_sec=5.0)
    feedback = []
    _, opened = send(action, gripper_goal(0.05), feedback.append)
    response = result_of(opened)
    assert response.status == GoalStatus.STATUS_SUCCEEDED
    assert response.result.reached_goal and not response.result.stalled
    assert response.result.position == pytest.approx(0.05, abs=TOLERANCE_M)
    assert feedback and all(f.feedback.position >= 0.0 for f in feedback)
    # grasp_state is its own topic: its ENVELOPED may land just after the result
    wait_for(lambda: client.state().phase == GripperState.ENVELOPED, timeout=2.0,
             message="grasp_state ENVELOPED")
    _, closed = send(action, gripper_goal(0.03, max_effort_n=0.8))
    response = result_of(closed)
    assert response.status == GoalStatus.STATUS_SUCCEEDED, response
    assert response.result.reached_goal and not response.result.stalled
    law = nodes["grasp_manager"].fsm.force_law
    target = law.pressure_for_force(0.8, 0.03, ObjectKind.ROUND)
    slope = (law.normal_force_n(target - 2e3, 0.03, ObjectKind.ROUND) -
             law.normal_force_n(target + 2e3, 0.03, ObjectKind.ROUND)) / 4e3
    assert response.result.effort == pytest.approx(0.8, abs=2e3 * slope)
    wait_for(lambda: client.state().phase == GripperState.HOLDING, timeout=2.0,
             message="grasp_state HOLDING")
    assert client.stop()
    wait_for(lambda: client.is_task_complete() and client.state().phase == GripperState.IDLE,
             message="IDLE after stop")


def test_parallel_gripper_command_carries_the_prefixed_tip_spacing_joint(suite):
    from action_msgs.msg import GoalStatus
    from control_msgs.action import ParallelGripperCommand
    from softgrip_ros.client import serial_action_client
    nodes, user, client = suite
    action = serial_action_client(user, ParallelGripperCommand, "parallel_gripper_cmd")
    assert action.wait_for_server(timeout_sec=5.0)
    goal = ParallelGripperCommand.Goal()
    goal.command.name, goal.command.position = ["g1_tip_spacing"], [0.04]
    _, opened = send(action, goal)
    response = result_of(opened)
    assert response.status == GoalStatus.STATUS_SUCCEEDED and response.result.reached_goal
    assert list(response.result.state.name) == ["g1_tip_spacing"]
    assert response.result.state.position[0] == pytest.approx(0.04, abs=TOLERANCE_M)
    wrong = ParallelGripperCommand.Goal()
    wrong.command.name, wrong.command.position = ["left_finger"], [0.02]
    _, refused = send(action, wrong)
    assert result_of(refused).status == GoalStatus.STATUS_ABORTED
    # and why, on grasp_state, as the README says (it was a log line only: #52, class 3)
    wait_for(lambda: "'g1_tip_spacing'" in client.state().message, timeout=2.0,
             message="the refusal's reason on grasp_state")
    state = client.state()
    assert state.message.startswith("rejected: one joint") and "left_finger" in state.message
    assert state.command_id == "parallel_gripper_cmd"


@pytest.mark.parametrize("position_m, effort_n", [
    (math.nan, 0.0), (-0.01, 0.0), (0.5, 0.0), (0.0, -1.0), (0.0, 1e3)])
def test_an_invalid_gripper_goal_is_aborted_at_once_and_nothing_moves(suite, position_m,
                                                                     effort_n):
    from action_msgs.msg import GoalStatus
    from control_msgs.action import GripperCommand
    from softgrip_ros.client import serial_action_client
    nodes, user, client = suite
    action = serial_action_client(user, GripperCommand, "gripper_cmd")
    assert action.wait_for_server(timeout_sec=5.0)
    before = nodes["grasp_manager"].fsm.request
    _, refused = send(action, gripper_goal(position_m, effort_n))
    response = result_of(refused, timeout=2.0)
    assert response.status == GoalStatus.STATUS_ABORTED and not response.result.reached_goal
    assert nodes["grasp_manager"].fsm.request == before
    assert client.state().phase == client.state().IDLE


def test_a_canceled_gripper_goal_holds_the_present_pressure(suite):
    from action_msgs.msg import GoalStatus
    from control_msgs.action import GripperCommand
    from softgrip_ros.client import serial_action_client
    from softgrip_ros.control.pressure import Source
    nodes, user, client = suite
    action = serial_action_client(user, GripperCommand, "gripper_cmd")
    assert action.wait_for_server(timeout_sec=5.0)
    handle, result = send(action, gripper_goal(0.07))
    manager = nodes["grasp_manager"]
    wait_for(lambda: manager.fsm.state.estimated_gauge_pa > 3e3, message="part way open")
    handle.cancel_goal_async()
    assert result_of(result).status == GoalStatus.STATUS_CANCELED
    assert manager.fsm.request.source == Source.HOLD and manager.fsm.request.target_gauge_pa > 0
    # grasp_state is a topic of its own: it may land after the result (CI: 'opening' still)
    wait_for(lambda: "canceled: holding" in client.state().message, timeout=2.0,
             message="grasp_state saying 'canceled: holding'",
             detail=lambda: f"it says {client.state().message!r}")


def test_a_cancel_early_in_an_open_holds_near_the_pressure_it_came_at(suite):
    """A cancel 14 ms into an OPEN let the gripper open fully: the goal learnt of it only at the
    next state change, up to the manager's 0.5 s tick later (#52, class 2). The cancel now acts
    in its own callback, so the hold is set near where the pressure was when it came. Five
    cancels; how far on the hold is, per how far the opening had still to go: measured 0.00 in
    each, and 0.02-0.88 (median 0.69) before."""
    import statistics
    import time

    from action_msgs.msg import GoalStatus
    from control_msgs.action import GripperCommand
    from softgrip_ros.client import serial_action_client
    from softgrip_ros.control.pressure import Source
    nodes, user, client = suite
    manager = nodes["grasp_manager"]
    action = serial_action_client(user, GripperCommand, "gripper_cmd")
    assert action.wait_for_server(timeout_sec=5.0)
    shares = []
    for _ in range(5):
        wait_for(lambda: abs(manager.fsm.state.estimated_gauge_pa) < 500.0, timeout=5.0,
                 message="at rest")
        handle, result = send(action, gripper_goal(0.07))
        goal_pa = wait_for(lambda: manager.fsm.request.target_gauge_pa > 1e3 and
                           manager.fsm.request.target_gauge_pa, message="opening")
        time.sleep(0.014)
        at_cancel = manager.fsm.state.estimated_gauge_pa
        handle.cancel_goal_async()
        assert result_of(result).status == GoalStatus.STATUS_CANCELED
        held = manager.fsm.request
        assert held.source == Source.HOLD
        shares.append((held.target_gauge_pa - at_cancel) / (goal_pa - at_cancel))
        assert client.stop()
    assert statistics.median(shares) < 0.25 and max(shares) < 0.6, shares


def _storm(actions, goals_each=100, period_s=0.01) -> list:
    """Each action client sends ``goals_each`` GripperCommand goals, ``period_s`` apart, all at
    once in threads; every goal's result status, once each is answered and has ended."""
    import threading
    import time

    sent = [[] for _ in actions]

    def storm(index):
        for i in range(goals_each):
            sent[index].append(actions[index].send_goal_async(gripper_goal(0.02 + 2e-4 * i)))
            time.sleep(period_s)

    threads = [threading.Thread(target=storm, args=(i,)) for i in range(len(actions))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    goals = [future for each in sent for future in each]
    wait_for(lambda: all(f.done() for f in goals), timeout=20.0,
             message="an answer to every goal",
             detail=lambda: f"{sum(not f.done() for f in goals)} of {len(goals)} unanswered")
    handles = [f.result() for f in goals]
    assert all(h.accepted for h in handles)
    results = [h.get_result_async() for h in handles]
    wait_for(lambda: all(r.done() for r in results), timeout=20.0, message="every goal's end",
             detail=lambda: f"{sum(not r.done() for r in results)} without an end")
    return [r.result().status for r in results]


def test_a_storm_of_goals_from_two_clients_gets_every_goal_an_answer_and_an_end(suite):
    """Two clients each send 100 GripperCommand goals a second, at once: every goal is answered
    and ends, each superseded by the next but one. The servers kept rclpy's 10 requests, and 5
    to 22 of 100 went unanswered (#52, class 1); they keep ACTION_QUEUE_DEPTH now. A client's
    own queues must keep as many: with rclpy's 10, two such clients lost 75 of 200 answers here,
    and even one lost one in 100 beside them; the product's client keeps as many as the
    servers."""
    from action_msgs.msg import GoalStatus
    from control_msgs.action import GripperCommand
    from softgrip_ros.client import serial_action_client
    nodes, user, client = suite
    actions = [serial_action_client(user, GripperCommand, "gripper_cmd") for _ in range(2)]
    assert all(action.wait_for_server(timeout_sec=5.0) for action in actions)
    statuses = _storm(actions)
    assert len(statuses) == 200
    assert statuses.count(GoalStatus.STATUS_SUCCEEDED) <= 1, statuses
    assert statuses.count(GoalStatus.STATUS_ABORTED) >= 199  # superseded
    assert client.stop()


def test_the_client_drives_a_full_envelop_clamp_release(suite):
    from action_msgs.msg import GoalStatus
    from softgrip_interfaces.msg import GripperState as S
    nodes, user, client = suite
    assert client.envelop_clamp(0.04, 0.02)
    wait_for(lambda: client.feedback() is not None and client.feedback().phase == S.ENVELOPED,
             message="ENVELOPED")
    assert client.clamp()
    wait_for(client.is_task_complete, message="the clamp task's end")
    assert client.status() == GoalStatus.STATUS_SUCCEEDED
    assert client.result().final_phase == S.HOLDING and not client.result().object_held
    assert client.release()
    wait_for(client.is_task_complete, message="released")
    assert client.state().phase == S.IDLE and client.result().final_phase == S.IDLE


def test_the_softgrip_command_drives_a_full_grasp_on_the_installed_controller(tmp_path):
    channel = unique("cli")
    ros_args = ["--ros-args", "-r", "__ns:=/cli_test", "-p", f"can.channel:={channel}"]
    log = open(tmp_path / "controller.log", "w+")
    controller = subprocess.Popen([installed_executable("controller"), *ros_args], stdout=log,
                                  stderr=subprocess.STDOUT)
    softgrip = installed_executable("softgrip")

    def run(*args, timeout=60):
        return subprocess.run([softgrip, *args, "--namespace", "/cli_test", "--timeout", "30"],
                              capture_output=True, text=True, timeout=timeout)

    try:
        grasped = run("grasp", "--diameter", "0.04", "--mass", "0.02", "--clamp-after", "0.2")
        assert grasped.returncode == 0, grasped.stdout + grasped.stderr
        # object sensing off: the air says nothing of the object
        assert "HOLDING" in grasped.stdout and "object held: unknown" in grasped.stdout
        state = run("state")
        assert state.returncode == 0 and state.stdout.startswith("HOLDING")
        released = run("release")
        assert released.returncode == 0 and "IDLE" in released.stdout, released.stdout
        refused = run("open", "--spacing", "0.5")
        assert refused.returncode == 1 and "wider than the gripper opens" in refused.stdout
        usage = subprocess.run([softgrip, "grasp", "--diameter", "-1", "--mass", "0.2"],
                               capture_output=True, text=True, timeout=30)
        assert usage.returncode == 2 and "--diameter: must lie in [0, 0.5] m" in usage.stderr
        endless = subprocess.run([softgrip, "grasp", "--diameter", "0.04", "--mass", "0.02",
                                  "--clamp-after", "inf"], capture_output=True, text=True,
                                 timeout=30)  # it would have waited for ever
        assert endless.returncode == 2 and "got inf" in endless.stderr
        nobody = subprocess.run([softgrip, "state", "--namespace", "/nobody", "--timeout", "1"],
                                capture_output=True, text=True, timeout=30)
        assert nobody.returncode == 3 and "no gripper answered" in nobody.stderr
    finally:
        assert stop_process(controller) == 0, (tmp_path / "controller.log").read_text()
        log.close()


def test_a_goal_whose_acceptance_comes_too_late_is_reported_unstarted_and_then_cancelled(
        rclpy_context, monkeypatch):
    """A loaded host can delay a goal's acceptance past the client's wait: the caller is told the
    task did not start, so when the acceptance does come the goal is cancelled (stop, vent)."""
    from rclpy.node import Node
    from rclpy.task import Future
    from softgrip_ros import client as client_module
    node = Node("late_acceptance_user", context=rclpy_context)
    gripper = client_module.GripperClient(node=node)
    pending, cancelled = Future(), []

    class LateHandle:
        accepted = True

        def cancel_goal_async(self):
            cancelled.append(True)

    try:
        monkeypatch.setattr(client_module, "ACCEPT_TIMEOUT_S", 0.1)
        monkeypatch.setattr(gripper._action, "wait_for_server", lambda timeout_sec: True)
        monkeypatch.setattr(gripper._action, "send_goal_async", lambda goal, **_: pending)
        assert gripper.open(0.05) is False
        assert gripper.is_task_complete() and gripper.result() is None
        assert not cancelled
        pending.set_result(LateHandle())
        assert cancelled == [True]
    finally:
        gripper.close()
        node.destroy_node()


def test_a_storm_on_both_actions_with_random_cancels_ends_every_goal_within_the_limits(suite):
    """GripperCommand and ParallelGripperCommand at once, 100 goals a second each, from fully
    open to a hard close, with a third of them cancelled at a random point (#52, the load test):
    every goal is answered and ends (succeeded, superseded or cancelled), a goal after the storm
    is cancelled on each, and the device's true pressure, sampled every millisecond, stays within
    the controller's limits."""
    import random
    import threading
    import time

    from action_msgs.msg import GoalStatus
    from control_msgs.action import GripperCommand, ParallelGripperCommand
    from softgrip_ros.client import serial_action_client
    nodes, user, client = suite
    device = nodes["sim_device"].device
    limits = nodes["pressure_controller"].controller.config
    gripper = serial_action_client(user, GripperCommand, "gripper_cmd")
    parallel = serial_action_client(user, ParallelGripperCommand, "parallel_gripper_cmd")
    assert gripper.wait_for_server(timeout_sec=5.0) and parallel.wait_for_server(timeout_sec=5.0)
    chooser = random.Random(52)
    # a cancel comes 0-5 ms after the goal's acceptance: the next goal supersedes it in 10 ms
    plan = [(chooser.choice([0.0, 0.01, 0.04, 0.2]), chooser.choice([0.0, 0.5, 20.0]),
             chooser.random() < 0.33, chooser.uniform(0.0, 0.005)) for _ in range(100)]
    sampled, stop_sampling = [], threading.Event()

    def sample():
        while not stop_sampling.is_set():
            sampled.append(device.chamber_gauge_pa())
            time.sleep(0.001)

    def goal_of(kind, position, effort):
        if kind is GripperCommand:
            return gripper_goal(position, effort)
        goal = ParallelGripperCommand.Goal()
        goal.command.name, goal.command.position = ["g1_tip_spacing"], [position]
        goal.command.effort = [effort]
        return goal

    sent = {GripperCommand: [], ParallelGripperCommand: []}
    cancels = []

    def cancel_after(future, delay_s):
        deadline = time.monotonic() + 2.0
        while not future.done() and time.monotonic() < deadline:
            time.sleep(0.0005)
        time.sleep(delay_s)
        if future.done() and future.result().accepted:
            future.result().cancel_goal_async()

    def storm(kind, action):
        for index, (position, effort, cancel, delay) in enumerate(plan):
            if kind is ParallelGripperCommand:
                position, cancel = plan[-1 - index][0], plan[-1 - index][2]
            future = action.send_goal_async(goal_of(kind, position, effort))
            sent[kind].append(future)
            if cancel:
                canceller = threading.Thread(target=cancel_after, args=(future, delay))
                cancels.append(canceller)
                canceller.start()
            time.sleep(0.01)

    sampler = threading.Thread(target=sample)
    sampler.start()
    threads = [threading.Thread(target=storm, args=pair)
               for pair in ((GripperCommand, gripper), (ParallelGripperCommand, parallel))]
    try:
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        for canceller in cancels:
            canceller.join()
        goals = [future for each in sent.values() for future in each]
        wait_for(lambda: all(f.done() for f in goals), timeout=20.0,
                 message="an answer to every goal",
                 detail=lambda: f"{sum(not f.done() for f in goals)} of {len(goals)} unanswered")
        handles = [f.result() for f in goals]
        results = [h.get_result_async() for h in handles if h.accepted]
        wait_for(lambda: all(r.done() for r in results), timeout=20.0,
                 message="every goal's end",
                 detail=lambda: f"{sum(not r.done() for r in results)} without an end")
        ended = {GoalStatus.STATUS_SUCCEEDED, GoalStatus.STATUS_ABORTED,
                 GoalStatus.STATUS_CANCELED}
        statuses = [r.result().status for r in results]
        assert len(statuses) == 200 and set(statuses) <= ended, statuses
        # most cancels meet a goal already superseded; a goal that is not is cancelled, on
        # either action, and the storm leaves neither server stuck
        for action, kind in ((gripper, GripperCommand), (parallel, ParallelGripperCommand)):
            handle, result = send(action, goal_of(kind, 0.06, 0.0))
            time.sleep(chooser.uniform(0.005, 0.03))
            handle.cancel_goal_async()
            assert result_of(result).status == GoalStatus.STATUS_CANCELED
    finally:
        stop_sampling.set()
        sampler.join()
    margin = limits.overpressure_margin_pa
    assert limits.min_gauge_pa - margin <= min(sampled), min(sampled)
    assert max(sampled) <= limits.max_gauge_pa + margin, max(sampled)
    assert client.stop()


def test_a_client_killed_mid_goal_leaves_its_goal_to_end_and_the_server_serving(suite):
    """A client process sends an opening goal and is killed (SIGKILL) while it runs (#52): the
    goal still reaches a terminal status on the action's status topic, and the next client's
    goal is served."""
    import os
    import signal
    import sys

    from action_msgs.msg import GoalStatus, GoalStatusArray
    from control_msgs.action import GripperCommand
    from softgrip_ros.client import serial_action_client
    nodes, user, client = suite
    terminal = {GoalStatus.STATUS_SUCCEEDED, GoalStatus.STATUS_ABORTED,
                GoalStatus.STATUS_CANCELED}
    seen = {}
    user.create_subscription(
        GoalStatusArray, "gripper_cmd/_action/status",
        lambda msg: seen.update({bytes(s.goal_info.goal_id.uuid).hex(): s.status
                                 for s in msg.status_list}), 10)
    dying = subprocess.Popen([sys.executable, "-m", "tests.helpers.goal_then_die", "0.07"],
                             cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        goal_id = dying.stdout.readline().strip()
        assert len(goal_id) == 32, dying.stderr.read() if dying.poll() is not None else goal_id
        wait_for(lambda: seen.get(goal_id) == GoalStatus.STATUS_EXECUTING, timeout=5.0,
                 message="the goal running")
        dying.send_signal(signal.SIGKILL)
        dying.wait(timeout=10)
    finally:
        stop_process(dying)
        dying.stdout.close()
        dying.stderr.close()
    wait_for(lambda: seen.get(goal_id) in terminal, timeout=15.0,
             message="the killed client's goal ended", detail=lambda: seen.get(goal_id))
    action = serial_action_client(user, GripperCommand, "gripper_cmd")
    assert action.wait_for_server(timeout_sec=5.0)
    _, closed = send(action, gripper_goal(0.02))
    assert result_of(closed).status == GoalStatus.STATUS_SUCCEEDED
    assert client.stop()


def test_any_parallel_goal_is_answered_and_a_refusal_says_why_in_one_line(suite):
    """ParallelGripperCommand goals with any names, positions, velocities and efforts (#52's
    property tests over each action's goal fields; GripperCommand's two numbers are drawn in
    tests/test_control_gripper_command.py without ROS): each is answered and ends; a refused one
    is aborted with its reason on grasp_state in one line of bounded length, whatever the
    client sent (thousands of names, newlines in them); an accepted one is cancelled and ends
    canceled or done."""
    from action_msgs.msg import GoalStatus
    from control_msgs.action import ParallelGripperCommand
    from hypothesis import example, given, settings
    from hypothesis import strategies as st
    from softgrip_ros.client import serial_action_client
    from softgrip_interfaces.msg import GripperState
    _, user, client = suite
    action = serial_action_client(user, ParallelGripperCommand, "parallel_gripper_cmd")
    assert action.wait_for_server(timeout_sec=5.0)
    # every state, as a later tick may restate the phase's own message before one is looked at
    states = []
    user.create_subscription(GripperState, "grasp_state", states.append, 100)
    numbers = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                        st.floats(min_value=0.0, max_value=0.1))
    names = st.one_of(st.sampled_from([[], ["g1_tip_spacing"], ["left_finger"],
                                       ["g1_tip_spacing", "g1_tip_spacing"], ["a\nb"],
                                       [f"joint_{i}" for i in range(5000)]]),
                      st.lists(st.text(max_size=12), max_size=3))

    @settings(max_examples=20, deadline=None)
    @example(names=[f"joint_{i}" for i in range(5000)], positions=[0.02], velocities=[],
             efforts=[])
    @example(names=["a\nb"], positions=[0.02, math.nan], velocities=[], efforts=[])
    @given(names=names, positions=st.lists(numbers, max_size=3),
           velocities=st.lists(numbers, max_size=2), efforts=st.lists(numbers, max_size=2))
    def check(names, positions, velocities, efforts):
        goal = ParallelGripperCommand.Goal()
        goal.command.name, goal.command.position = names, positions
        goal.command.velocity, goal.command.effort = velocities, efforts
        since = len(states)
        handle, result = send(action, goal)
        if not (names in ([], ["g1_tip_spacing"]) and len(positions) == 1):
            assert result_of(result, timeout=5.0).status == GoalStatus.STATUS_ABORTED
            refusals = wait_for(lambda: [s.message for s in states[since:] if s.command_id ==
                                         "parallel_gripper_cmd" and s.message.startswith(
                                             "rejected: one joint")], timeout=2.0,
                                message="the refusal on grasp_state")
            assert "\n" not in refusals[0] and len(refusals[0]) < 400, refusals[0]
        else:
            handle.cancel_goal_async()
            assert result_of(result, timeout=5.0).status in (
                GoalStatus.STATUS_CANCELED, GoalStatus.STATUS_ABORTED,
                GoalStatus.STATUS_SUCCEEDED)
        assert client.stop()

    check()

"""End to end: the composed suite (the `controller` executable's nodes) on the simulated device,
driven over DDS by topic and by action, in-process and as the installed executable."""
import math
import signal
import subprocess
import time

import can
import pytest

from softgrip_ros.client import grasp_command as grasp
from softgrip_ros.devtools.processes import installed_executable, stop_process

from tests.helpers.ros import spinning, unique, wait_for

pytestmark = pytest.mark.ros
NAN = math.nan


@pytest.fixture
def suite(rclpy_context):
    """The composed nodes on a private virtual channel, and a user node watching grasp_state."""
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from softgrip_interfaces.msg import GraspCommand, GripperState
    from softgrip_ros.nodes.common import close_all
    from softgrip_ros.nodes.controller import make_nodes

    nodes = make_nodes(rclpy_context,
                       {"pressure_controller": [Parameter("can.channel", value=unique("e2e"))]})
    user = Node("test_user", context=rclpy_context)
    states = []
    user.create_subscription(GripperState, "grasp_state", states.append, 100)
    publisher = user.create_publisher(GraspCommand, "grasp_command", 10)
    try:
        with spinning(rclpy_context, *nodes, user, threads=2):
            wait_for(lambda: states and publisher.get_subscription_count(), message="grasp_state")
            yield {n.get_name(): n for n in nodes}, user, publisher, states
    finally:
        close_all(nodes)
        user.destroy_node()


def phases_after(states, start):
    """The phases since ``start``, each once per run, after the IDLE the command found."""
    seen = []
    for s in states[start:]:
        if (seen or s.phase != 0) and (not seen or seen[-1] != s.phase):
            seen.append(s.phase)
    return seen


def test_envelop_clamp_40mm_then_release_over_topics(suite):
    from softgrip_interfaces.msg import GraspCommand, GripperState as S
    nodes, user, publisher, states = suite
    start = len(states)
    publisher.publish(
        grasp(GraspCommand.ENVELOP_CLAMP, object_diameter_m=0.04, object_mass_kg=0.02,
              command_id="g40"))
    enveloped = wait_for(lambda: next((s for s in states[start:] if s.phase == S.ENVELOPED), None),
                         timeout=3.0, message="ENVELOPED")
    assert enveloped.tip_spacing_m >= 0.04 + 0.01 and enveloped.command_id == "g40"
    publisher.publish(grasp(GraspCommand.CLAMP, command_id="g40-clamp"))
    holding = wait_for(lambda: next((s for s in states[start:] if s.phase == S.HOLDING), None),
                       timeout=3.0, message="HOLDING")
    assert phases_after(states, start)[:4] == [S.OPENING, S.ENVELOPED, S.CLAMPING, S.HOLDING]
    # the time bounds are the phases' own timeouts (3 s each; in simulated time, test_control_grasp
    # pins the phases under 1 s): none tripped into FAULT
    assert S.FAULT not in phases_after(states, start)
    target = holding.target_gauge_pressure_pa
    assert target < 0.0 and abs(holding.estimated_gauge_pressure_pa - target) <= 1.5e3
    hold_start = len(states)
    time.sleep(2.0)  # HOLDING stays stable for 2 s
    held = states[hold_start:]
    # >= 10 Hz (20 Hz configured)
    assert len(held) >= 30 and all(s.phase == S.HOLDING for s in held)
    # a starved host can leave a tick with neither a fresh estimate nor a fresh reading (CI,
    # twice: one state of ~40 with a NaN pressure and std); such a state says its force is
    # unknown, and the rest hold on the target with a force
    known = [s for s in held if math.isfinite(s.estimated_gauge_pressure_pa)]
    assert len(known) >= 0.9 * len(held), [s.estimated_gauge_pressure_pa for s in held]
    assert max(abs(s.estimated_gauge_pressure_pa - target) for s in known) < 3e3
    assert all(s.clamp_force_n > 0.0 for s in known), [
        (s.estimated_gauge_pressure_pa, s.estimated_gauge_pressure_std_pa, s.clamp_force_n,
         s.message) for s in known if not s.clamp_force_n > 0.0]
    assert all(math.isnan(s.clamp_force_n) for s in held
               if not math.isfinite(s.estimated_gauge_pressure_pa))
    # the clamp is a contact scene: the grasp reports L2, and kinematics poses the fingers on the
    # object
    assert all(s.model_fidelity == S.FIDELITY_L2 for s in held)
    kinematics = nodes["kinematics"]
    # the L2 solves run in a child process niced below the control path: on a starved host the
    # first poses of the hold still use the opening's solve (CI: 'l2 at 18029 Pa' at -9.9 kPa, no
    # contact), so wait for a solve of the clamp itself
    on_object = wait_for(
        lambda: (kinematics.last and kinematics.last[1].model == "l2" and
                 kinematics.last[1].contact_force_n > 0.0 and kinematics.last[1]),
        timeout=20.0, message="kinematics on L2, in contact",
        detail=lambda: kinematics.last and kinematics.last[1].message)
    assert "cylinder" in on_object.message and on_object.pressure_pa < 0.0
    publisher.publish(grasp(GraspCommand.RELEASE, command_id="rel"))
    wait_for(lambda: states[-1].phase == S.IDLE and states[-1].command_id == "rel", timeout=5.0,
             message="IDLE after RELEASE")
    wait_for(lambda: kinematics.last[1].model in ("l0", "l1"),
             message="kinematics back on free bending")


def test_the_composed_nodes_keep_fast_work_off_the_executor_and_serialise_only_what_is_taken(
        suite):
    """Each rclpy timer wakes the executor, whose wait set is rebuilt over every entity of every
    node: the composed nodes' periodic work runs on their own timer threads (grasp_state at >= 10
    Hz from there is checked in the grasp above); the pressure controller keeps a 1 Hz diagnostics
    timer. A reading, estimate or status topic nobody subscribes to is not published, while the
    in-process consumers still take every one; a subscriber gets them at once."""
    from sensor_msgs.msg import FluidPressure
    from softgrip_interfaces.msg import ControllerStatus
    nodes, user, _, _ = suite
    periods = [t.timer_period_ns * 1e-9 for n in nodes.values() for t in n.timers]
    assert periods and min(periods) >= 0.5, periods
    assert all(nodes[name].periodic.thread is not None
               for name in ("estimator", "kinematics", "grasp_manager"))
    controller = nodes["pressure_controller"]
    for publisher, port, message_type, topic in ((controller.sensor_pubs["chamber_a"],
                                                  controller.readings, FluidPressure,
                                                  "pressure/sensor/chamber_a"),
                                                 (controller.status_pub, controller.reports,
                                                  ControllerStatus, "controller/status")):
        published, taken = [], []
        real_publish = publisher.publish
        publisher.publish = (lambda message, real=real_publish, out=published:
                             out.append(message) or real(message))
        port.connect(taken.append)
        wait_for(lambda: len(taken) >= 20, message=f"{topic} taken in-process")
        assert not published, topic
        received = []
        user.create_subscription(message_type, topic, received.append, 10)
        wait_for(lambda: received, timeout=5.0, message=f"{topic} once subscribed")
        assert published


def test_the_grasp_manager_owns_the_pressure_in_the_composed_controller(suite):
    """Composed, no node of the suite subscribes to pressure/command: the grasp manager's
    commands reach the pressure controller and the estimator by direct call only, so there is no
    DDS copy to recognise. The grasp manager still publishes them for observers."""
    from softgrip_interfaces.msg import PressureCommand
    nodes, user, _, _ = suite
    topic = nodes["grasp_manager"].resolve_topic_name("pressure/command")
    assert user.get_subscriptions_info_by_topic(topic) == []
    received = []
    user.create_subscription(PressureCommand, "pressure/command", received.append, 10)
    wait_for(lambda: received, timeout=3.0, message="the grasp manager's refreshed command")


def test_pinch_a_sheet_by_action_with_feedback_and_result(suite):
    from softgrip_ros.client import serial_action_client
    from softgrip_interfaces.action import Grasp
    from softgrip_interfaces.msg import GraspCommand, GripperState as S
    nodes, user, publisher, states = suite
    # destroyed with the user node, after the executor stops
    client = serial_action_client(user, Grasp, "grasp")
    assert client.wait_for_server(timeout_sec=5.0)
    feedback = []
    future = client.send_goal_async(
        Grasp.Goal(command=grasp(GraspCommand.PINCH, object_diameter_m=1e-4, object_mass_kg=0.05,
                                 command_id="sheet")), feedback_callback=feedback.append)
    handle = wait_for(lambda: future.done() and future.result(), message="goal accepted")
    result_future = handle.get_result_async()
    result = wait_for(lambda: result_future.done() and result_future.result(), timeout=5.0,
                      message="result").result
    # without object sensing nothing says the sheet is there
    assert not result.object_held and result.final_phase == S.HOLDING
    assert result.clamp_force_n > 0.0
    assert result.final_gauge_pressure_pa < 0.0 and feedback
    rejected = client.send_goal_async(
        Grasp.Goal(command=grasp(GraspCommand.PINCH, object_diameter_m=0.03, object_mass_kg=0.05)))
    handle = wait_for(lambda: rejected.done() and rejected.result(), message="goal")
    result_future = handle.get_result_async()
    result = wait_for(lambda: result_future.done() and result_future.result(),
                      message="result").result
    assert not result.object_held and "PINCH takes objects up to 5.0 mm" in result.message


def test_stop_during_opening_vents_within_a_control_period(suite):
    from softgrip_interfaces.msg import GraspCommand, GripperState as S
    from softgrip_ros.model.pneumatics import Valve
    nodes, user, publisher, states = suite
    device = nodes["sim_device"].device
    publisher.publish(grasp(GraspCommand.ENVELOP_CLAMP, object_diameter_m=0.06,
                            object_mass_kg=0.1))
    wait_for(lambda: states[-1].phase == S.OPENING and device.chamber_gauge_pa() > 3e3,
             message="OPENING")
    publisher.publish(grasp(GraspCommand.STOP))
    wait_for(lambda: device.valves()[0] == Valve.VENT, timeout=1.0, period=0.0005,
             message="vent valves")
    # "within one control period": the controller's first step after a VENT command vents
    # (test_control_pressure.test_vent_returns_to_atmosphere); the DDS and CAN latency on top is
    # a benchmark figure, not a timed test. Here: the chain really carried a VENT, with no HOLD
    # between.
    from softgrip_ros.control.pressure import Source
    assert nodes["grasp_manager"].fsm.request.source == Source.VENT
    assert nodes["pressure_controller"].controller.last_output.valves == (Valve.VENT,)
    wait_for(lambda: abs(device.chamber_gauge_pa()) < 1e3, timeout=2.0, message="vented")


def test_faults_during_holding_give_fault_and_a_safe_state(suite):
    from softgrip_interfaces.msg import GraspCommand, GripperState as S
    from softgrip_ros.model.pneumatics import Valve
    nodes, user, publisher, states = suite
    device = nodes["sim_device"].device
    for fault, value in (("sensor_dropout", "all"), ("regulator_overshoot_pa", 30e3)):
        publisher.publish(grasp(GraspCommand.PINCH, object_diameter_m=1e-3, object_mass_kg=0.02))
        wait_for(lambda: states[-1].phase == S.HOLDING, timeout=5.0, message="HOLDING")
        peak = []
        device.set_fault(fault, value)
        try:
            wait_for(
                lambda: (peak.append(device.chamber_gauge_pa()) or states[-1].phase == S.FAULT),
                timeout=3.0, message=f"FAULT after {fault}")
            assert fault.split("_")[0] in states[-1].message or "regulator" in states[-1].message
            wait_for(lambda: device.valves()[0] in (Valve.VENT, Valve.CLOSED),
                     message="a safe valve state")
            assert max(peak) < 50e3 + 5e3
        finally:
            device.set_fault(fault, "" if isinstance(value, str) else 0.0)
        # every halting fault gone from the grasp manager's view, a sensor timeout too (whose text
        # lacks the word "fault": a next grasp sent while it lasted was rejected for it)
        manager = nodes["grasp_manager"]
        wait_for(lambda: not manager._controller_fault(manager._now()), timeout=3.0,
                 message="the controller fault clears")
        publisher.publish(grasp(GraspCommand.STOP))
        wait_for(lambda: states[-1].phase == S.IDLE, message="IDLE after STOP")


@pytest.mark.parametrize("command, reason", [
    (dict(mode=1, object_diameter_m=NAN, object_mass_kg=0.1), "object_diameter_m must be finite"),
    (dict(mode=1, object_diameter_m=0.2, object_mass_kg=0.1), "wider than the gripper opens"),
    (dict(mode=1, object_diameter_m=0.04, object_mass_kg=0.1,
          clamp_pressure_pa=-95e3), "beyond the pressure limits"),
    (dict(mode=7), "unknown mode 7"),
])
def test_rejected_commands_say_why_over_the_topic_and_move_nothing(suite, command, reason):
    from softgrip_interfaces.msg import GripperState as S
    nodes, user, publisher, states = suite
    from softgrip_ros.control.pressure import Source
    from softgrip_ros.model.pneumatics import Valve
    device, request = nodes["sim_device"].device, nodes["grasp_manager"].fsm.request
    # start from the valves the idle grasp manager's request settles to: its first vent may still
    # be on its way to the device when grasp_state first comes
    settled = {Source.VENT: Valve.VENT, Source.HOLD: Valve.CLOSED}[request.source]
    before = wait_for(lambda: device.valves() if set(device.valves()) == {settled} else None,
                      message=f"the device's valves at {settled.name}")
    # not the parameter's own dict: a repeated run reuses it
    command = dict(command)
    publisher.publish(grasp(command.pop("mode"), command_id="bad", **command))
    state = wait_for(
        lambda: next(
            (s for s in reversed(states) if s.command_rejected and s.command_id == "bad"), None),
        message="a rejection")
    assert reason in state.message and state.phase == S.IDLE
    assert device.valves() == before


def test_the_installed_controller_grasps_over_dds_and_exits_cleanly_on_sigterm(tmp_path, ros_node):
    """The real user path: <prefix>/lib/softgrip_ros/controller as a process; this process sends
    the grasp and watches grasp_state and tip_pose/left; the device runs apart on the inter-process
    bus so that the vent frames on SIGTERM can be seen."""
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from softgrip_interfaces.msg import GraspCommand, GripperState
    from softgrip_ros.canbus.codec import FrameCodec

    channel = unique("e2e-proc")
    ros_args = ["--ros-args", "-p", "can.interface:=softgrip_ipc", "-p", f"can.channel:={channel}"]
    monitor = can.Bus(interface="softgrip_ipc", channel=channel)
    codec, valve_frames = FrameCodec(max_counter_delta=15, sync_frames=0), []
    notifier = can.Notifier(monitor, [
        lambda f: (lambda d: d and d.name == "ValveCommand" and valve_frames.append(d))
        (codec.decode(f))
    ], timeout=0.05)
    log = open(tmp_path / "controller.log", "w+")
    device = subprocess.Popen([installed_executable("sim_device"), *ros_args],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    controller = subprocess.Popen([installed_executable("controller"), *ros_args], stdout=log,
                                  stderr=subprocess.STDOUT, text=True)
    states, poses = [], []
    ros_node.create_subscription(GripperState, "grasp_state", states.append, 100)
    ros_node.create_subscription(PoseWithCovarianceStamped, "tip_pose/left", poses.append, 100)
    publisher = ros_node.create_publisher(GraspCommand, "grasp_command", 10)
    try:
        with spinning(ros_node.context, ros_node, threads=1):
            wait_for(lambda: states and publisher.get_subscription_count(), timeout=30.0,
                     message="the controller's grasp_state")
            publisher.publish(
                grasp(GraspCommand.OPEN, target_tip_spacing_m=0.06, command_id="open60"))
            wait_for(
                lambda: states[-1].phase == GripperState.ENVELOPED and states[-1].command_id ==
                "open60", timeout=5.0, message="open to 60 mm")
            wait_for(lambda: poses and abs(-2 * poses[-1].pose.pose.position.x) > 0.05,
                     message="tip_pose follows")
            assert poses[-1].pose.covariance[0] > 0.0
        controller.send_signal(signal.SIGTERM)
        controller.wait(timeout=15)
        output = (tmp_path / "controller.log").read_text()
        assert controller.returncode == 0, output
        assert "Traceback" not in output
        # no callback publishing into a shut-down context
        assert "never retrieved" not in output, output
        time.sleep(0.3)
        assert valve_frames and valve_frames[-1].signals[
            "Channel0"] == 3, "the last valve frame must vent"
    finally:
        for process in (controller, device):
            stop_process(process)
        notifier.stop()
        monitor.shutdown()
        log.close()


def _goal(client, command, feedback=None):
    """Send a Grasp goal; its handle once accepted."""
    from softgrip_interfaces.action import Grasp
    future = client.send_goal_async(Grasp.Goal(command=command), feedback_callback=feedback)
    return wait_for(lambda: future.done() and future.result(), message="goal accepted")


def _envelop_goal(client, command_id):
    """An ENVELOP_CLAMP goal for a 40 mm, 0.02 kg object; its handle once the feedback says
    ENVELOPED (the fingers open around the object, waiting for CLAMP)."""
    from softgrip_interfaces.msg import GraspCommand, GripperState
    feedback = []
    handle = _goal(client, grasp(GraspCommand.ENVELOP_CLAMP, object_diameter_m=0.04,
                                 object_mass_kg=0.02, command_id=command_id), feedback.append)
    wait_for(lambda: feedback and feedback[-1].feedback.state.phase == GripperState.ENVELOPED,
             message="ENVELOPED feedback")
    return handle


def _result(handle, timeout=5.0):
    future = handle.get_result_async()
    return wait_for(lambda: future.done() and future.result(), timeout=timeout,
                    message="goal result")


def test_an_envelop_clamp_goal_continued_by_a_clamp_on_the_topic_succeeds_holding(suite):
    """#21.1: a CLAMP on grasp_command that continues the goal's ENVELOP_CLAMP aborted the goal as
    "superseded", although the gripper went on to HOLDING. It is part of the goal."""
    from action_msgs.msg import GoalStatus
    from softgrip_ros.client import serial_action_client
    from softgrip_interfaces.action import Grasp
    from softgrip_interfaces.msg import GraspCommand, GripperState as S
    nodes, user, publisher, states = suite
    client = serial_action_client(user, Grasp, "grasp")
    assert client.wait_for_server(timeout_sec=5.0)
    handle = _envelop_goal(client, "act-cup")
    publisher.publish(grasp(GraspCommand.CLAMP, command_id="act-cup"))
    response = _result(handle)
    assert response.status == GoalStatus.STATUS_SUCCEEDED, response.result.message
    assert not response.result.object_held and response.result.final_phase == S.HOLDING
    assert response.result.clamp_force_n > 0.0


def test_an_action_client_completes_the_grasp_with_a_clamp_goal(suite):
    """Without a side topic: ENVELOP_CLAMP, then a CLAMP goal once ENVELOPED; both goals
    succeed."""
    from action_msgs.msg import GoalStatus
    from softgrip_ros.client import serial_action_client
    from softgrip_interfaces.action import Grasp
    from softgrip_interfaces.msg import GraspCommand, GripperState as S
    nodes, user, publisher, states = suite
    client = serial_action_client(user, Grasp, "grasp")
    assert client.wait_for_server(timeout_sec=5.0)
    envelop = _envelop_goal(client, "bt-cup")
    clamp = _goal(client, grasp(GraspCommand.CLAMP, command_id="bt-clamp"))
    for handle in (clamp, envelop):
        response = _result(handle)
        assert response.status == GoalStatus.STATUS_SUCCEEDED, response.result.message
        assert response.result.final_phase == S.HOLDING and not response.result.object_held


def test_a_different_command_supersedes_a_goal_and_a_cancel_vents(suite):
    from action_msgs.msg import GoalStatus
    from softgrip_ros.client import serial_action_client
    from softgrip_interfaces.action import Grasp
    from softgrip_interfaces.msg import GraspCommand, GripperState as S
    nodes, user, publisher, states = suite
    device = nodes["sim_device"].device
    client = serial_action_client(user, Grasp, "grasp")
    assert client.wait_for_server(timeout_sec=5.0)
    first = _goal(
        client,
        grasp(GraspCommand.ENVELOP_CLAMP, object_diameter_m=0.04, object_mass_kg=0.02,
              command_id="first"))
    wait_for(lambda: states[-1].phase == S.ENVELOPED, message="ENVELOPED")
    # rejected
    publisher.publish(
        grasp(GraspCommand.PINCH, object_diameter_m=0.04, object_mass_kg=0.02, command_id="bad"))
    wait_for(lambda: states[-1].command_rejected and states[-1].command_id == "bad",
             message="the rejection")
    publisher.publish(grasp(GraspCommand.STOP, command_id="stop"))
    response = _result(first)
    assert (response.status == GoalStatus.STATUS_ABORTED and
            "superseded by command 'stop'" in response.result.message)
    wait_for(lambda: states[-1].phase == S.IDLE, message="IDLE after the STOP")
    second = _goal(
        client,
        grasp(GraspCommand.ENVELOP_CLAMP, object_diameter_m=0.04, object_mass_kg=0.02,
              command_id="second"))
    wait_for(lambda: device.chamber_gauge_pa() > 5e3, message="opening")
    cancel = second.cancel_goal_async()
    wait_for(lambda: cancel.done(), message="cancel accepted")
    response = _result(second)
    assert response.status == GoalStatus.STATUS_CANCELED and "venting" in response.result.message
    wait_for(lambda: abs(device.chamber_gauge_pa()) < 1.5e3, timeout=3.0, message="vented")


def test_object_sensing_reports_through_the_state_the_action_and_diagnostics(rclpy_context):
    """object_sensing on, hold_air trap, on the simulated gripper without a world: a pinch's
    closing is judged (MOVING_NO_CONTACT while it moves); for a 0.1 mm sheet the air cannot
    tell, so the goal succeeds at HOLDING with object_held false, the status UNKNOWN, its
    evidence in the grasp-sensing entry of /diagnostics; the hold's air is then trapped. The
    verdict is awaited, not asserted at the result: no test may depend on an idle host."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from softgrip_interfaces.action import Grasp
    from softgrip_interfaces.msg import GraspCommand, GripperState as S
    from softgrip_ros.client import serial_action_client
    from softgrip_ros.nodes.common import close_all
    from softgrip_ros.nodes.controller import make_nodes

    nodes = make_nodes(rclpy_context, {
        "pressure_controller": [Parameter("can.channel", value=unique("sensing"))],
        "grasp_manager": [Parameter("object_sensing", value=True),
                          Parameter("hold_air", value="trap")]})
    named = {n.get_name(): n for n in nodes}
    user = Node("sensing_user", context=rclpy_context)
    states, diagnostics = [], []
    user.create_subscription(S, "grasp_state", states.append, 200)
    user.create_subscription(DiagnosticArray, "/diagnostics", diagnostics.append, 50)
    client = serial_action_client(user, Grasp, "grasp")
    try:
        with spinning(rclpy_context, *nodes, user, threads=2):
            wait_for(lambda: named["grasp_manager"].sensing is not None, timeout=20.0,
                     message="the contact model built")
            assert client.wait_for_server(timeout_sec=5.0)
            future = client.send_goal_async(Grasp.Goal(command=grasp(
                GraspCommand.PINCH, object_diameter_m=1e-4, object_mass_kg=0.005,
                command_id="sheet")))
            handle = wait_for(lambda: future.done() and future.result(), message="accepted")
            result_future = handle.get_result_async()
            result = wait_for(lambda: result_future.done() and result_future.result(),
                              timeout=10.0, message="result").result
            assert result.final_phase == S.HOLDING and not result.object_held
            seen = {s.object_status for s in states}
            assert S.OBJECT_MOVING_NO_CONTACT in seen
            # the verdict: on a busy host the judge (a niced child) may give it after the goal
            # stopped waiting (sensing_wait), which then succeeds without it, as designed
            wait_for(lambda: states[-1].object_status == S.OBJECT_UNKNOWN, timeout=10.0,
                     message="the closing's verdict: UNKNOWN")

            def evidence():
                for array in diagnostics:
                    for status in array.status:
                        if status.name == "softgrip: grasp sensing" and \
                                "cannot tell" in status.message:
                            return status
                return None
            wait_for(evidence, timeout=5.0, message="the grasp-sensing diagnostics")
            wait_for(lambda: named["grasp_manager"].fsm.air_trapped_since is not None,
                     timeout=5.0, message="the hold's air trapped")
    finally:
        close_all(nodes)
        user.destroy_node()

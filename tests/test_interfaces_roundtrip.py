"""Every softgrip_interfaces type crosses DDS between two processes with all fields intact."""
import os
import pathlib
import subprocess
import sys
import time

import pytest

from tests.helpers import sample_messages

REPO_ROOT = pathlib.Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.ros


@pytest.fixture
def peer_process():
    """The publisher/action-server peer as a separate process, ended by its PID afterwards."""
    process = subprocess.Popen([sys.executable, "-m", "tests.helpers.roundtrip_peer"],
                               cwd=REPO_ROOT, env=dict(os.environ), stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    try:
        yield process
    finally:
        if process.poll() is None:
            process.terminate()
        try:
            _, stderr = process.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            _, stderr = process.communicate()
        assert process.returncode == 0, f"peer exited {process.returncode}: {stderr}"
        assert "Traceback" not in stderr, stderr


def test_every_message_type_round_trips_across_processes(peer_process, ros_node):
    import rclpy
    from softgrip_ros.client import serial_action_client
    from rclpy.executors import SingleThreadedExecutor
    from softgrip_interfaces.action import Grasp

    received = {}
    for topic, (msg_type, _) in sample_messages.SAMPLES.items():
        ros_node.create_subscription(msg_type, topic,
                                     lambda msg, t=topic: received.setdefault(t, msg), 10)
    executor = SingleThreadedExecutor(context=ros_node.context)
    executor.add_node(ros_node)
    try:
        deadline = time.monotonic() + 30.0
        while len(received) < len(sample_messages.SAMPLES) and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        missing = set(sample_messages.SAMPLES) - set(received)
        assert not missing, f"never received {sorted(missing)} from the peer process"
        for topic, (_, factory) in sample_messages.SAMPLES.items():
            assert sample_messages.differences(factory(), received[topic]) == [], topic

        # The action itself: goal out, feedback and result back.
        client = serial_action_client(ros_node, Grasp, "roundtrip/grasp")
        assert client.wait_for_server(timeout_sec=20.0), "the peer's Grasp server never appeared"
        feedbacks = []
        send_future = client.send_goal_async(
            sample_messages.grasp_goal(),
            feedback_callback=lambda fb: feedbacks.append(fb.feedback))
        executor.spin_until_future_complete(send_future, timeout_sec=10.0)
        goal_handle = send_future.result()
        assert goal_handle is not None and goal_handle.accepted
        result_future = goal_handle.get_result_async()
        executor.spin_until_future_complete(result_future, timeout_sec=10.0)
        result = result_future.result().result
        # The peer compared the goal it received with the sample and sent the differences back.
        assert result.message == "[]", f"goal fields changed in transit: {result.message}"
        expected_result = sample_messages.grasp_result()
        expected_result.message = "[]"
        assert sample_messages.differences(expected_result, result) == []
        deadline = time.monotonic() + 5.0
        while not feedbacks and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        assert feedbacks, "no feedback arrived"
        expected_feedback = sample_messages.grasp_feedback()
        expected_feedback.state.command_id = sample_messages.grasp_command().command_id
        assert sample_messages.differences(expected_feedback, feedbacks[0]) == []
        client.destroy()
    finally:
        executor.shutdown()
        del rclpy  # imported for the context fixture's sake


def test_differences_detects_a_changed_field():
    """The comparison used above is not vacuous: it sees NaN vs number, sign of zero and list
    length."""
    sent, changed = sample_messages.controller_status(), sample_messages.controller_status()
    changed.measured_gauge_pressure_pa = 0.0
    changed.valve_states = [3]
    assert len(sample_messages.differences(sent, changed)) == 2
    state = sample_messages.gripper_state()
    flipped = sample_messages.gripper_state()
    flipped.clamp_force_n = 0.0
    assert sample_messages.differences(state,
                                       flipped) == ["msg.clamp_force_n: sent -0.0, received 0.0"]

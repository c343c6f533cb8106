"""GripperClient's action client against rclpy#1123: a goal response taken while its request is
still being registered waits for the registration instead of being dropped."""
import threading


def test_a_goal_response_waits_while_a_request_is_being_registered(ros_node):
    from softgrip_interfaces.action import Grasp

    from softgrip_ros.client import serial_action_client

    client = serial_action_client(ros_node, Grasp, "serial_action_test/grasp")
    done = threading.Event()

    def take_a_response():
        coroutine = client.execute({})  # nothing taken: returns at once unless it waits
        try:
            coroutine.send(None)
        except StopIteration:
            done.set()

    try:
        with client._registering:  # a send_goal_async in progress
            worker = threading.Thread(target=take_a_response)
            worker.start()
            assert not done.wait(0.2), "the response was handled during the registration"
        worker.join(5.0)
        assert done.is_set(), "the response was not handled once the registration ended"
    finally:
        client.destroy()

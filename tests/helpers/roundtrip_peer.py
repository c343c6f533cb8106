"""Peer process for the cross-process round trip: publishes every sample message and serves Grasp.

Run as ``python -m tests.helpers.roundtrip_peer``; it publishes at 20 Hz until
terminated. Its action server answers each goal with feedback and a result that
echo the goal's command, so the test can check the goal crossed intact.
"""
import signal
import sys
import threading

import rclpy
from rclpy.action import ActionServer
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from softgrip_interfaces.action import Grasp
from tests.helpers import sample_messages


class RoundTripPeer(Node):

    def __init__(self):
        super().__init__("softgrip_roundtrip_peer")
        self._sample_publishers = [(self.create_publisher(msg_type, topic, 10), factory)
                                   for topic, (msg_type,
                                               factory) in sample_messages.SAMPLES.items()]
        self.create_timer(0.05, self._publish_all)
        self._action_server = ActionServer(self, Grasp, "roundtrip/grasp", self._execute)

    def _publish_all(self):
        for publisher, factory in self._sample_publishers:
            publisher.publish(factory())

    def _execute(self, goal_handle):
        feedback = sample_messages.grasp_feedback()
        feedback.state.command_id = goal_handle.request.command.command_id
        goal_handle.publish_feedback(feedback)
        result = sample_messages.grasp_result()
        # Echo the goal's fields back so the client can check them all.
        result.message = repr(
            sample_messages.differences(sample_messages.grasp_goal(), goal_handle.request))
        goal_handle.succeed()
        return result


def main():
    rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = RoundTripPeer()
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    # SIGTERM only asks the loop to stop: shutting ROS down inside the handler could land in
    # the middle of a timer callback and fail its publish.
    stop_requested = threading.Event()
    for number in (signal.SIGTERM, signal.SIGINT):
        signal.signal(number, lambda *_: stop_requested.set())
    print("peer ready", flush=True)
    try:
        while not stop_requested.is_set():
            executor.spin_once(timeout_sec=0.05)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())

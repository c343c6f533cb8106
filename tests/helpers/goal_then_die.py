"""A client that sends one GripperCommand goal, prints its goal id once accepted, and then waits
to be killed: ``python -m tests.helpers.goal_then_die <position_m>``."""
import sys
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor

from control_msgs.action import GripperCommand
from softgrip_ros.client import serial_action_client


def main() -> int:
    rclpy.init()
    node = rclpy.create_node("softgrip_goal_then_die")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    action = serial_action_client(node, GripperCommand, "gripper_cmd")
    if not action.wait_for_server(timeout_sec=20.0):
        print("no server", file=sys.stderr, flush=True)
        return 1
    goal = GripperCommand.Goal()
    goal.command.position = float(sys.argv[1])
    future = action.send_goal_async(goal)
    executor.spin_until_future_complete(future, timeout_sec=20.0)
    handle = future.result()
    if handle is None or not handle.accepted:
        print("not accepted", file=sys.stderr, flush=True)
        return 1
    print(bytes(handle.goal_id.uuid).hex(), flush=True)
    while True:  # until killed, mid-goal
        executor.spin_once(timeout_sec=0.1)
        time.sleep(0.01)


if __name__ == "__main__":
    sys.exit(main())

"""The kinematics node on its own, over DDS: the scene arrives on grasp_scene (latched), auto
switches to L2 on an object (spawning the L2 child then, not before) and back to free bending,
and a malformed scene is refused."""
import math

import pytest

from softgrip_ros.runtime.core import Estimate

from tests.helpers.ros import spinning, wait_for

pytestmark = pytest.mark.ros


@pytest.fixture
def wired(rclpy_context):
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from sensor_msgs.msg import FluidPressure
    from softgrip_interfaces.msg import GraspScene
    from softgrip_ros.nodes.kinematics import KinematicsNode

    node = KinematicsNode(context=rclpy_context)
    user = Node("kinematics_test_user", context=rclpy_context)
    scenes = user.create_publisher(
        GraspScene, "grasp_scene", QoSProfile(depth=1,
                                              durability=DurabilityPolicy.TRANSIENT_LOCAL))
    estimates = user.create_publisher(FluidPressure, "pressure/estimate", 10)
    stamp = [0.0]

    def estimate(gauge_pa):
        stamp[0] += 0.05
        message = FluidPressure(fluid_pressure=101_325.0 + gauge_pa, variance=100.0)
        message.header.stamp.sec = int(stamp[0])
        message.header.stamp.nanosec = int((stamp[0] % 1) * 1e9)
        estimates.publish(message)

    try:
        with spinning(rclpy_context, node, user, threads=2):
            wait_for(
                lambda: estimates.get_subscription_count() and scenes.get_subscription_count(),
                message="discovery")
            yield node, scenes, estimate
    finally:
        node.close()
        node.destroy_node()
        user.destroy_node()


def model_after(node, estimate, gauge_pa, wanted):

    def check():
        estimate(gauge_pa)
        return node.last and node.last[1].model == wanted and node.last[1]

    return wait_for(check, timeout=10.0, period=0.05, message=f"kinematics on {wanted}")


def test_an_object_on_grasp_scene_switches_auto_to_l2_and_free_bending_back(wired):
    from softgrip_interfaces.msg import GraspScene
    node, scenes, estimate = wired
    # the default tolerance (10 mm): L0, the cheapest, is within it of the FE in free bending
    free = model_after(node, estimate, 20e3, "l0")
    assert free.scene_class == "free" and free.contact_force_n == 0.0
    assert not node.rod_solver.started  # no L2 child until a scene needs L2
    scenes.publish(
        GraspScene(kind=GraspScene.CYLINDER, object_diameter_m=0.04, object_center_z_m=0.0981,
                   opening_gauge_pressure_pa=30e3))
    on_object = model_after(node, estimate, -10e3, "l2")  # solved on the worker thread
    assert on_object.scene_class == "contact" and on_object.contact_force_n > 0.0
    assert node.rod_solver.started
    # held open by the object, not closed past it
    assert on_object.tip[0] < -0.02
    scenes.publish(GraspScene(kind=GraspScene.FREE))
    assert model_after(node, estimate, 20e3, "l0").scene_class == "free"


@pytest.mark.parametrize("kind, diameter, opening, reason",
                         [(9, 0.04, 0.0, "unknown scene kind"), (1, -0.04, 0.0, "radius"),
                          (1, 0.04, math.nan, "opening_gauge_pressure_pa")])
def test_a_malformed_scene_is_refused_and_the_last_one_kept(wired, kind, diameter, opening,
                                                            reason):
    from softgrip_interfaces.msg import GraspScene
    from softgrip_ros.model.fidelity import FREE
    from softgrip_ros.nodes.messages import scene_from_message
    node, scenes, estimate = wired
    message = GraspScene(kind=kind, object_diameter_m=diameter, object_center_z_m=0.1,
                         opening_gauge_pressure_pa=opening)
    with pytest.raises(ValueError, match=reason):
        scene_from_message(message)
    scenes.publish(message)
    model_after(node, estimate, 20e3, "l0")
    assert node.scene == FREE


def test_stamps_go_forward_on_every_stream_under_concurrent_estimates(wired, rclpy_context):
    """Four threads feed estimates of rising stamps straight into the node, as the composed
    controller's threads do: each published stream's stamps still never go back (tip_pose and
    joint_states went back by up to 133 ms, once in five runs: #52, class 4)."""
    import threading

    from geometry_msgs.msg import PoseWithCovarianceStamped
    from rclpy.node import Node
    from sensor_msgs.msg import JointState

    node, _, _ = wired
    listener = Node("kinematics_stamp_listener", context=rclpy_context)
    seen = {"tip_pose/left": [], "joint_states": []}
    for topic, kind in (("tip_pose/left", PoseWithCovarianceStamped),
                        ("joint_states", JointState)):
        listener.create_subscription(
            kind, topic, lambda m, t=topic: seen[t].append(
                m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec), 1000)
    counter, lock = [1000.0], threading.Lock()

    def feed():
        for _ in range(150):
            with lock:
                counter[0] += node.period_s
                stamp = counter[0]
            node.take_estimate(Estimate(stamp, 20e3, 100.0))

    try:
        with spinning(rclpy_context, listener):
            wait_for(lambda: node.left_pub.get_subscription_count() and
                     node.joints_pub.get_subscription_count(), message="discovery")
            threads = [threading.Thread(target=feed) for _ in range(4)]
            for thread in threads:
                thread.start()
            for thread in threads:
                thread.join()
            wait_for(lambda: all(len(s) > 100 for s in seen.values()), timeout=10.0,
                     message="the poses")
            import time
            time.sleep(0.3)  # the last ones in flight
    finally:
        listener.destroy_node()
    for topic, stamps in seen.items():
        backwards = [b - a for a, b in zip(stamps, stamps[1:]) if b < a]
        assert backwards == [], (topic, backwards[:5])


def test_publish_drops_a_message_older_than_the_last_and_counts_it():
    from builtin_interfaces.msg import Time
    from std_msgs.msg import Header, String
    from sensor_msgs.msg import FluidPressure

    from softgrip_ros.nodes.common import dropped_stale, publish

    class Sent:
        def __init__(self):
            self.messages = []

        def publish(self, message):
            self.messages.append(message)

    def at(sec, nanosec=0):
        return FluidPressure(header=Header(stamp=Time(sec=sec, nanosec=nanosec)))

    publisher = Sent()
    assert publish(None, publisher, at(5)) and publish(None, publisher, at(5))  # equal: kept
    assert not publish(None, publisher, at(4, 999_999_999))
    assert publish(None, publisher, at(6)) and publish(None, publisher, String(data="x"))
    assert [getattr(m, "header", None) and m.header.stamp.sec for m in publisher.messages] == [
        5, 5, 6, None]
    assert dropped_stale(publisher) == 1

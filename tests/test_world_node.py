"""sim_device with a physics world: a scene is refused before the bus opens when it is bad, the
ground truth is published, the arm plays, and no node of the product listens to sim/ topics."""
import pathlib
import re

import pytest

from tests.helpers.ros import spinning, unique, wait_for

SCENES = pathlib.Path(__file__).resolve().parents[1] / "config" / "scenes"


@pytest.mark.parametrize("scene_text, reason", [
    ("object: {shape: cone}\n", "object.shape must be one of"),
    ("object: {shape: sphere, diameter_m: 0.03, mass_kg: -2, friction: 0.5}\n",
     r"mass_kg must lie in \[0.0001, 20\]"),
    ("object: {shape: cylinder, diameter_m: 0.04, mass_kg: 0.1, friction: 0.5, "
     "position_m: [0, 0, 0.16]}\narm: {start_m: [0, 0, 0.25]}\n", "starts .* inside the"),
])
def test_a_bad_scene_is_refused_before_the_simulated_device_opens_its_bus(
        rclpy_context, monkeypatch, tmp_path, scene_text, reason):
    from rclpy.parameter import Parameter
    from softgrip_ros.nodes import sim_device as module

    scene = tmp_path / "scene.yaml"
    scene.write_text(scene_text)
    opened = []
    monkeypatch.setattr(module, "open_bus", lambda *args, **kwargs: opened.append(args))
    with pytest.raises(ValueError, match=reason):
        module.SimDeviceNode(context=rclpy_context, parameter_overrides=[
            Parameter("world.scene", value=str(scene))])
    assert opened == []


@pytest.mark.ros
def test_the_world_publishes_its_truth_and_plays_the_arm(rclpy_context, ros_node):
    from geometry_msgs.msg import PoseStamped
    from rclpy.parameter import Parameter
    from softgrip_interfaces.msg import GraspTruth, SimContacts
    from softgrip_interfaces.srv import PlayArmMove
    from softgrip_ros.nodes.sim_device import SimDeviceNode

    device = SimDeviceNode(context=rclpy_context, parameter_overrides=[
        Parameter("can.channel", value=unique("world")),
        Parameter("world.scene", value=str(SCENES / "cylinder_40mm.yaml"))])
    received = {"pose": [], "contacts": [], "truth": []}
    for topic, kind, key in (("sim/object_pose", PoseStamped, "pose"),
                             ("sim/contacts", SimContacts, "contacts"),
                             ("sim/grasp_truth", GraspTruth, "truth")):
        ros_node.create_subscription(kind, topic, received[key].append, 10)
    client = ros_node.create_client(PlayArmMove, "sim/play_arm_move")
    try:
        with spinning(rclpy_context, device, ros_node):
            wait_for(lambda: all(len(v) >= 3 for v in received.values()), timeout=10.0,
                     message="the world's ground truth")
            pose = received["pose"][-1].pose.position
            assert (pose.x, pose.y, pose.z) == pytest.approx((0.0, 0.0, 0.152), abs=1e-3)
            assert received["truth"][-1].state == GraspTruth.FREE
            assert not received["contacts"][-1].left_touching
            assert client.wait_for_service(timeout_sec=5.0)
            refused = client.call(PlayArmMove.Request(move="wave"), timeout_sec=5.0)
            assert not refused.accepted and "no arm move 'wave'" in refused.message
            assert client.call(PlayArmMove.Request(move="approach"), timeout_sec=5.0).accepted
            wait_for(lambda: received["truth"][-1].arm_move == "approach", timeout=5.0,
                     message="the approach playing")
    finally:
        device.close()
        device.destroy_node()


def test_no_node_of_the_product_subscribes_to_a_sim_topic():
    """The ground truth is for tests, benchmarks and the demo: the product's nodes, the client and
    the tools never read it (a source check over every module outside the simulation and the
    benchmarks' devtools; the running graph is checked by the grasp benchmark's test)."""
    source = pathlib.Path(__file__).resolve().parents[1] / "src" / "softgrip_ros"
    simulation = {source / "nodes" / "sim_device.py", source / "nodes" / "messages.py"}
    offenders = []
    for path in source.rglob("*.py"):
        parts = path.relative_to(source).parts
        if path in simulation or "world" in parts or parts[0] == "devtools":
            continue
        text = path.read_text()
        if re.search(r"create_(subscription|client)\([^)]*[\"']sim/", text) or any(
                name in text for name in ("GraspTruth", "SimContacts", "PlayArmMove")):
            offenders.append(str(path.relative_to(source)))
    assert offenders == []

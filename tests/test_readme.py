"""The README as a user reads it: its interface table against the ROS graph of a running
``controller`` (and of each node alone), its Python example run as written, its shape."""
import pathlib
import re
import subprocess
import sys
import time

import pytest

from tests.helpers.ros import spinning, unique

REPO_ROOT = pathlib.Path(__file__).resolve().parents[1]
README = (REPO_ROOT / "README.md").read_text()
KINDS = {
    "publishes": "publishers", "subscribes": "subscriptions", "service": "services",
    "action": "actions"
}
# what every rclpy node and every lifecycle node has, which the table leaves out (it says so)
STANDARD = {("publishers", "/rosout"), ("publishers", "/parameter_events"),
            ("subscriptions", "/parameter_events"), ("publishers", "/diagnostics")}
STANDARD_SUFFIXES = ("/describe_parameters", "/get_parameter_types", "/get_parameters",
                     "/list_parameters", "/set_parameters", "/set_parameters_atomically",
                     "/get_type_description", "/change_state", "/get_state",
                     "/get_available_states", "/get_available_transitions",
                     "/get_transition_graph", "/transition_event")


def table() -> dict:
    """{node: {"always" | "alone" | "world": {(kind, name): type}}} from the README: the rows
    marked 'alone' exist when the node runs alone, those marked 'with world.scene' when the
    simulated device has a physics world."""
    lines = README.split("| node (executable) | kind | name | type |",
                         1)[1].split("\n\n", 1)[0].splitlines()[2:]
    rows, node = {}, None
    for line in lines:
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if cells[0]:
            node = cells[0].strip("`")
            rows.setdefault(node, {"always": {}, "alone": {}, "world": {}})
        if not cells[2]:
            continue
        kind, _, qualifier = cells[1].partition(", ")
        bucket = {"": "always", "alone": "alone", "with world.scene": "world"}[qualifier]
        for name in re.findall(r"`([^`]+)`", cells[2]):
            full = f"/{node}/{name[2:]}" if name.startswith("~/") else (
                name if name.startswith("/") else f"/{name}")
            rows[node][bucket][(KINDS[kind], full)] = cells[3].strip("`")
    return rows


def graph_of(probe, node_name: str, namespace: str) -> dict:
    """{(kind, name): type} of a node in the graph, the standard entries left out; the names
    without ``namespace``. Each test runs its nodes in a namespace of its own: the nodes of an
    earlier test, destroyed but still in another participant's view of the graph for a while,
    would otherwise answer for the same node name."""
    from rclpy.action.graph import get_action_server_names_and_types_by_node
    found = {}
    for kind, query in (("publishers", probe.get_publisher_names_and_types_by_node),
                        ("subscriptions", probe.get_subscriber_names_and_types_by_node),
                        ("services", probe.get_service_names_and_types_by_node),
                        ("actions",
                         lambda n, ns: get_action_server_names_and_types_by_node(probe, n, ns))):
        for name, types in query(node_name, namespace):
            if name.startswith(namespace + "/"):
                name = name[len(namespace):]
            if (kind, name) in STANDARD or name.endswith(STANDARD_SUFFIXES) or "/_action/" in name:
                continue
            found[(kind, name)] = types[0]
    return found


def wait_for_graph(probe, node_name, namespace, expected, timeout=10.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = graph_of(probe, node_name, namespace)
        if found == expected:
            return found
        time.sleep(0.1)
    return graph_of(probe, node_name, namespace)


@pytest.fixture
def namespaced_context():
    """A context whose nodes all run in a fresh namespace (as ``-r __ns:=`` does); yields
    (context, namespace)."""
    import rclpy
    namespace = "/" + unique("readme").replace("-", "_")
    context = rclpy.Context()
    rclpy.init(context=context, args=["--ros-args", "-r", f"__ns:={namespace}"])
    try:
        yield context, namespace
    finally:
        rclpy.try_shutdown(context=context)


def test_the_table_names_every_node_of_the_suite():
    assert set(table()) == {
        "pressure_controller", "estimator", "kinematics", "grasp_manager", "sim_device"
    }


@pytest.mark.ros
def test_the_interface_table_is_the_graph_of_a_running_controller(namespaced_context):
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from softgrip_ros.nodes.common import close_all
    from softgrip_ros.nodes.controller import make_nodes

    rclpy_context, namespace = namespaced_context
    nodes = make_nodes(rclpy_context,
                       {"pressure_controller": [Parameter("can.channel", value=unique("readme"))]})
    probe = Node("readme_probe", context=rclpy_context)
    try:
        with spinning(rclpy_context, *nodes, probe, threads=2):
            for node, rows in table().items():
                found = wait_for_graph(probe, node, namespace, rows["always"])
                assert found == rows["always"], node
    finally:
        close_all(nodes)
        probe.destroy_node()


@pytest.mark.ros
@pytest.mark.parametrize(
    "node_name", ["pressure_controller", "estimator", "kinematics", "grasp_manager", "sim_device"])
def test_each_node_alone_has_the_rows_of_the_table(namespaced_context, node_name):
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from softgrip_ros.nodes import (estimator, grasp_manager, kinematics, pressure_controller,
                                    sim_device)

    rclpy_context, namespace = namespaced_context
    classes = {
        "pressure_controller": pressure_controller.PressureControllerNode,
        "estimator": estimator.EstimatorNode, "kinematics": kinematics.KinematicsNode,
        "grasp_manager": grasp_manager.GraspManagerNode, "sim_device": sim_device.SimDeviceNode
    }
    overrides = [Parameter("can.channel", value=unique("readme"))
                 ] if node_name in ("pressure_controller", "sim_device") else []
    node = classes[node_name](context=rclpy_context, parameter_overrides=overrides)
    probe = Node("readme_probe", context=rclpy_context)
    try:
        with spinning(rclpy_context, node, probe, threads=2):
            rows = table()[node_name]
            expected = {**rows["always"], **rows["alone"]}
            assert wait_for_graph(probe, node_name, namespace, expected) == expected
    finally:
        if hasattr(node, "close"):
            node.close()
        node.destroy_node()
        probe.destroy_node()


@pytest.mark.ros
def test_the_simulated_device_with_a_world_has_the_world_rows_too(namespaced_context):
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from softgrip_ros.nodes.sim_device import SimDeviceNode

    rclpy_context, namespace = namespaced_context
    node = SimDeviceNode(context=rclpy_context, parameter_overrides=[
        Parameter("can.channel", value=unique("readme")),
        Parameter("world.scene", value=str(REPO_ROOT / "config" / "scenes" / "empty.yaml"))])
    probe = Node("readme_probe", context=rclpy_context)
    try:
        with spinning(rclpy_context, node, probe, threads=2):
            rows = table()["sim_device"]
            expected = {**rows["always"], **rows["alone"], **rows["world"]}
            assert rows["world"] and wait_for_graph(probe, "sim_device", namespace,
                                                    expected) == expected
    finally:
        node.close()
        node.destroy_node()
        probe.destroy_node()


@pytest.mark.ros
@pytest.mark.slow
def test_the_python_example_grasps_as_written(rclpy_context):
    """The README's Python example, run as it stands against the composed suite (object sensing
    off, the default): the grasp ends in HOLDING, and nothing says the object is held: held
    False, the air's status UNKNOWN."""
    from rclpy.parameter import Parameter
    from softgrip_ros.nodes.common import close_all
    from softgrip_ros.nodes.controller import make_nodes

    code = README.split("From Python, with `softgrip_ros.client.GripperClient`", 1)[1].split(
        "```python\n", 1)[1].split("```", 1)[0]
    nodes = make_nodes(rclpy_context,
                       {"pressure_controller": [Parameter("can.channel", value=unique("readme"))]})
    try:
        with spinning(rclpy_context, *nodes, threads=2):
            result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                                    timeout=60)
    finally:
        close_all(nodes)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "phase: 4 held: False" in result.stdout and "ObjectStatus.UNKNOWN" in result.stdout


def test_the_readme_is_a_guide_of_at_most_250_lines():
    headings = [line[3:] for line in README.splitlines() if line.startswith("## ")]
    assert (headings == [
        "Install", "The demo", "Executables and their interfaces", "Sending a grasp",
        "Is the object held?", "On a robot arm", "Real hardware", "Safety", "Further reading"
    ])
    assert len(README.splitlines()) <= 250
    for link in re.findall(r"\]\(((?:docs/|CHANGELOG|LICENSE)[^)#]*)", README):
        assert (REPO_ROOT / link).exists(), link

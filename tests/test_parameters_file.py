"""config/softgrip.yaml holds every declared parameter of every node, at its declared default,
under a key that matches the node in any namespace."""
import pathlib

import pytest
import yaml

from softgrip_ros.nodes import (estimator, grasp_manager, kinematics, pressure_controller,
                                sim_device)

REPO_ROOT = pathlib.Path(__file__).resolve().parents[1]
PARAMS = yaml.safe_load((REPO_ROOT / "config" / "softgrip.yaml").read_text())


def declared(node):
    builtin = {"use_sim_time", "start_type_description_service"}  # rclpy declares these itself
    return {
        name: node.get_parameter(name).value
        for name in node._parameters if name not in builtin
    }


@pytest.mark.ros
@pytest.mark.parametrize("node_class, section",
                         [(pressure_controller.PressureControllerNode, "pressure_controller"),
                          (sim_device.SimDeviceNode, "sim_device"),
                          (estimator.EstimatorNode, "estimator"),
                          (kinematics.KinematicsNode, "kinematics"),
                          (grasp_manager.GraspManagerNode, "grasp_manager")])
def test_every_parameter_is_in_the_params_file_at_its_default(rclpy_context, node_class, section):
    from rclpy.parameter import Parameter
    node = node_class(
        context=rclpy_context, parameter_overrides=[Parameter("autostart", value=False)]
        if section == "pressure_controller" else [])
    try:
        in_code = declared(node)
        in_file = PARAMS[f"/**/{section}"]["ros__parameters"]
        if section == "pressure_controller":
            in_file = {**in_file, "autostart": False}
        assert set(in_code) == set(in_file), (f"only in code: {set(in_code) - set(in_file)}; "
                                              f"only in file: {set(in_file) - set(in_code)}")
        for name, value in in_code.items():
            assert in_file[name] == pytest.approx(value) if isinstance(
                value, float) else in_file[name] == value, name
        for name in in_code:
            descriptor = node.describe_parameter(name)
            assert descriptor.description, f"{name} has no description"
    finally:
        node.close()
        node.destroy_node()


@pytest.mark.ros
def test_the_params_file_applies_to_a_node_in_a_namespace(tmp_path):
    """Two grippers run in namespaces (/g1, /g2): the file's values must reach them too."""
    import rclpy
    from softgrip_ros.nodes.kinematics import KinematicsNode
    edited = tmp_path / "softgrip.yaml"
    edited.write_text((REPO_ROOT / "config" / "softgrip.yaml").read_text().replace(
        "frame_id:                      softgrip_base", "frame_id:                      hand"))
    context = rclpy.Context()
    rclpy.init(context=context, args=["--ros-args", "--params-file", str(edited), "-r",
                                      "__ns:=/g1"])
    try:
        node = KinematicsNode(context=context)
        try:
            assert node.get_namespace() == "/g1"
            assert node.get_parameter("frame_id").value == "hand"
        finally:
            node.close()
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)

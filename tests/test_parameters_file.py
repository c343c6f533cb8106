"""config/softgrip.yaml holds every declared parameter of every node, at its declared default."""
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
        in_file = PARAMS[section]["ros__parameters"]
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

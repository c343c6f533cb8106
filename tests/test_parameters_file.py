"""config/softgrip.yaml holds every declared parameter of every node, at its declared default,
under a key that matches the node in any namespace; it is what the specs make, and the specs and
the cores' dataclasses accept the same values."""
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
    text = (REPO_ROOT / "config" / "softgrip.yaml").read_text()
    assert "    frame_id: softgrip_base " in text
    edited.write_text(text.replace("    frame_id: softgrip_base ", "    frame_id: hand "))
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


def test_the_params_file_is_what_the_specs_make():
    from softgrip_ros.nodes import params_file
    assert (REPO_ROOT / "config" / "softgrip.yaml").read_text() == params_file.render(), (
        "run python -m softgrip_ros.nodes.params_file --write config/softgrip.yaml")


def test_the_params_file_check_says_when_a_file_is_stale(tmp_path, capsys):
    from softgrip_ros.nodes import params_file
    stale = tmp_path / "softgrip.yaml"
    stale.write_text(params_file.render().replace("response_tolerance: 0.75",
                                                  "response_tolerance: 0.7"))
    assert params_file.main(["--check", str(stale)]) == 1
    assert "--write" in capsys.readouterr().err
    assert params_file.main(["--write", str(stale)]) == 0
    assert params_file.main(["--check", str(stale)]) == 0


def _field_specs():
    from softgrip_ros.nodes import specs
    return (specs.PRESSURE_CONTROL_SPECS + specs.ESTIMATOR_FILTER_SPECS + specs.GRASP_FSM_SPECS +
            specs.CLAMP_FORCE_SPECS)


@pytest.mark.parametrize("spec", _field_specs(), ids=lambda s: s.name)
def test_a_parameter_and_its_core_field_accept_the_same_values(spec):
    """Each end of the range and just past it: the parameter's check and the dataclass agree
    (they had disagreed, e.g. safety.response_tolerance: [0.05, 0.95] against (0, 1))."""
    from softgrip_ros.nodes import specs
    from softgrip_ros.model.force_law import ClampForceLaw, load_table
    from softgrip_ros.nodes.parameters import replace_fields

    def make_core(value):
        if spec in specs.CLAMP_FORCE_SPECS:
            return ClampForceLaw(load_table("type_II", "l0"), **{spec.field: value})
        group, base = next((g, b) for g, b in (
            (specs.PRESSURE_CONTROL_SPECS, specs.PressureControlConfig()),
            (specs.ESTIMATOR_FILTER_SPECS, specs.EstimatorConfig(max_lag_s=0.05)),
            (specs.GRASP_FSM_SPECS, specs.GraspConfig())) if spec in g)
        return replace_fields(base, group, {**{s.name: s.default for s in group},
                                            spec.name: value})

    def core_accepts(value) -> bool:
        try:
            make_core(value)
        except ValueError:
            return False
        return True

    if spec.choices:
        for choice in spec.choices:
            assert core_accepts(choice) and not spec.check(choice)
        assert not core_accepts("nonsense") and spec.check("nonsense")
        return
    step = (spec.high - spec.low) * 1e-3 or 1.0
    if isinstance(spec.default, int):
        step = 1
    for value, ok in ((spec.low, True), (spec.high, True), (spec.low - step, False),
                      (spec.high + step, False)):
        value = type(spec.default)(value)
        assert (not spec.check(value)) == ok, (spec.name, value)
        assert core_accepts(value) == ok, (spec.name, value)

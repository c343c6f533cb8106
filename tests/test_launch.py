"""launch/softgrip.launch.py, checked without `launch` (not on PyPI): it compiles, it is
installed, every argument is declared and used; then its bring-up logic runs against small
stand-ins of the launch API names it imports, which record what would be started."""
import ast
import pathlib
import sys
import types

import pytest

REPO_ROOT = pathlib.Path(__file__).resolve().parents[1]
LAUNCH_FILE = REPO_ROOT / "launch" / "softgrip.launch.py"
ARGUMENTS = {"namespace", "prefix", "can_interface", "can_channel", "params_file", "use_sim",
             "standalone", "publish_robot_description"}


def test_it_compiles_and_every_argument_is_declared_and_used():
    source = LAUNCH_FILE.read_text()
    tree = ast.parse(source, str(LAUNCH_FILE))
    compile(tree, str(LAUNCH_FILE), "exec")
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call)]
    configurations = {n.args[0].value for n in calls
                      if getattr(n.func, "id", None) == "LaunchConfiguration"
                      and isinstance(n.args[0], ast.Constant)}
    flags = {n.args[1].value for n in calls if getattr(n.func, "id", None) == "_flag"}
    declared = next(ast.literal_eval(n.value) for n in ast.walk(tree)
                    if isinstance(n, ast.Assign) and getattr(n.targets[0], "id", "") ==
                    "ARGUMENTS")
    assert set(declared) == ARGUMENTS
    assert ARGUMENTS <= configurations | flags, ARGUMENTS - configurations - flags
    assert "generate_launch_description" in {n.name for n in tree.body
                                             if isinstance(n, ast.FunctionDef)}


def test_it_is_installed_to_the_share():
    from ament_index_python.packages import get_package_share_directory
    installed = pathlib.Path(get_package_share_directory("softgrip_ros")) / "launch"
    assert (installed / "softgrip.launch.py").read_text() == LAUNCH_FILE.read_text()
    assert (pathlib.Path(get_package_share_directory("softgrip_ros")) / "urdf" /
            "softgrip_macro.xacro").is_file()


class _Recorded:
    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


class _Configuration:
    def __init__(self, name):
        self.name = name

    def perform(self, context):
        return context.launch_configurations[self.name]


@pytest.fixture
def launch_file(monkeypatch):
    """The launch file's module, on stand-ins for launch and launch_ros that record actions."""
    fakes = {
        "launch": {"LaunchDescription": _Recorded},
        "launch.actions": {"DeclareLaunchArgument": _Recorded, "LogInfo": _Recorded,
                           "OpaqueFunction": _Recorded},
        "launch.substitutions": {"LaunchConfiguration": _Configuration},
        "launch_ros": {},
        "launch_ros.actions": {"Node": _Recorded},
    }
    for name, attributes in fakes.items():
        module = types.ModuleType(name)
        module.__dict__.update(attributes)
        monkeypatch.setitem(sys.modules, name, module)
    namespace = {"__name__": "softgrip_launch", "__file__": str(LAUNCH_FILE)}
    exec(compile(LAUNCH_FILE.read_text(), str(LAUNCH_FILE), "exec"), namespace)
    return types.SimpleNamespace(**namespace)


def bring_up(module, **arguments):
    description = module.generate_launch_description()
    actions = description.args[0]
    declared = {a.args[0]: a.kwargs["default_value"] for a in actions
                if "default_value" in a.kwargs}
    assert set(declared) == ARGUMENTS
    unknown = set(arguments) - set(declared)
    assert not unknown, unknown
    context = types.SimpleNamespace(launch_configurations={**declared, **arguments})
    opaque = actions[-1]
    return opaque.kwargs["function"](context)


def started(actions) -> dict:
    return {a.kwargs["executable"]: a.kwargs for a in actions if "executable" in a.kwargs}


def test_the_default_is_the_composed_controller_with_its_own_simulated_device(launch_file):
    nodes = started(bring_up(launch_file))
    assert set(nodes) == {"controller"}  # robot_state_publisher is not installed here
    params_file, overrides = nodes["controller"]["parameters"]
    assert params_file.endswith("config/softgrip.yaml") and pathlib.Path(params_file).is_file()
    assert overrides == {"prefix": "", "can.interface": "virtual", "can.channel": "softgrip"}


def test_standalone_on_a_shared_bus_starts_each_node_and_the_device_in_the_namespace(
        launch_file):
    nodes = started(bring_up(launch_file, standalone="true", can_interface="softgrip_ipc",
                             namespace="/g1", prefix="g1_", params_file="/tmp/mine.yaml"))
    assert set(nodes) == {"pressure_controller", "estimator", "kinematics", "grasp_manager",
                          "sim_device"}
    for kwargs in nodes.values():
        assert kwargs["namespace"] == "/g1" and kwargs["package"] == "softgrip_ros"
        assert kwargs["parameters"] == ["/tmp/mine.yaml", {
            "prefix": "g1_", "can.interface": "softgrip_ipc", "can.channel": "softgrip"}]


def test_hardware_starts_no_simulated_device(launch_file):
    nodes = started(bring_up(launch_file, can_interface="socketcan", can_channel="can0",
                             use_sim="false"))
    assert set(nodes) == {"controller"}
    assert nodes["controller"]["parameters"][1]["can.channel"] == "can0"


@pytest.mark.parametrize("arguments, reason", [
    ({"standalone": "true"}, "in-process only"),
    ({"use_sim": "false"}, "nothing would answer"),
    ({"use_sim": "yes"}, "must be true or false"),
])
def test_a_combination_that_cannot_work_says_why(launch_file, arguments, reason):
    with pytest.raises(ValueError, match=reason):
        bring_up(launch_file, **arguments)


def test_the_robot_description_is_the_prefixed_urdf_when_robot_state_publisher_exists(
        launch_file, monkeypatch):
    real = launch_file.get_package_share_directory
    monkeypatch.setitem(launch_file._robot_state_publisher.__globals__,
                        "get_package_share_directory",
                        lambda name: "/opt/rsp" if name == "robot_state_publisher" else real(name))
    nodes = started(bring_up(launch_file, prefix="g2_", namespace="/g2"))
    publisher = nodes["robot_state_publisher"]
    assert publisher["namespace"] == "/g2"
    description = publisher["parameters"][0]["robot_description"]
    assert '<link name="g2_left_tip"' in description and 'name="g2_tip_spacing"' in description
    absent = started(bring_up(launch_file, publish_robot_description="false"))
    assert "robot_state_publisher" not in absent

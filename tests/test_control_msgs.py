"""control_msgs: the gripper interfaces the grasp manager serves, wire-compatible with the real
Jazzy package (control_msgs 5.8.0) whether they come from it or from the partial stand-in that
scripts/setup.sh builds when no control_msgs is installed."""
import json
import os
import pathlib
import subprocess

import pytest

REPO_ROOT = pathlib.Path(__file__).resolve().parents[1]
JAZZY_HASHES = {   # control_msgs 5.8.0, as the issue that asked for these interfaces gives them
    "msg/GripperCommand":
        "RIHS01_57eb8f326c9889ca8bb34ead82cc94cc09bf6bc5c3b6c09546dca3a00b589890",
    "action/GripperCommand":
        "RIHS01_e17c0e644eccf14bea84a0a93e0977182872c2eb7873ca6694900059b46dbc84",
    "action/ParallelGripperCommand":
        "RIHS01_adfd3c1ebe8abc38ebcc0e454b6423d291d4010dd5697d14eca5b9be4726ae18",
}


@pytest.mark.parametrize("interface", sorted(JAZZY_HASHES))
def test_the_type_hash_is_the_real_packages(interface):
    from ament_index_python.packages import get_package_share_directory
    description = pathlib.Path(get_package_share_directory("control_msgs")) / f"{interface}.json"
    hashes = {h["type_name"]: h["hash_string"]
              for h in json.loads(description.read_text())["type_hashes"]}
    assert hashes[f"control_msgs/{interface}"] == JAZZY_HASHES[interface]


def test_the_fields_are_the_ones_the_grasp_manager_fills():
    from control_msgs.action import GripperCommand, ParallelGripperCommand
    goal = GripperCommand.Goal()
    goal.command.position, goal.command.max_effort = 0.05, 2.0
    result = GripperCommand.Result(position=0.05, effort=1.0, stalled=False, reached_goal=True)
    parallel = ParallelGripperCommand.Goal()
    parallel.command.name, parallel.command.position = ["tip_spacing"], [0.05]
    assert (goal.command.position, result.reached_goal, list(parallel.command.position)) == (
        0.05, True, [0.05])
    assert hasattr(ParallelGripperCommand.Result(), "stalled")
    assert hasattr(ParallelGripperCommand.Feedback(), "state")


def _which(prefixes: str) -> str:
    env = {**os.environ, "AMENT_PREFIX_PATH": prefixes}
    return subprocess.run(["bash", str(REPO_ROOT / "scripts" / "setup.sh"),
                           "--which-control-msgs"], env=env, capture_output=True, text=True,
                          check=True, timeout=60).stdout.strip()


def test_the_stand_in_is_built_only_when_no_real_control_msgs_is_found(tmp_path):
    """A partial control_msgs must never shadow a real one (MoveIt needs its other interfaces):
    setup.sh looks in every prefix but this workspace's install/."""
    real = tmp_path / "opt_ros"
    (real / "share" / "ament_index" / "resource_index" / "packages").mkdir(parents=True)
    (real / "share" / "ament_index" / "resource_index" / "packages" / "control_msgs").touch()
    own = REPO_ROOT / "install" / "control_msgs"
    assert _which(f"{own}:{tmp_path / 'elsewhere'}") == "stand-in"
    assert _which(f"{own}:{real}") == str(real)

"""Two grippers side by side in one DDS domain: two installed ``controller`` processes in the
namespaces /g1 and /g2, with the prefixes g1_ and g2_, each on its own simulated CAN bus."""
import subprocess

import pytest

from softgrip_ros.devtools.processes import installed_executable, stop_process
from tests.helpers.ros import spinning, unique, wait_for

pytestmark = pytest.mark.ros
GRIPPERS = ("g1", "g2")


@pytest.fixture
def two_grippers(rclpy_context, tmp_path):
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from rclpy.node import Node
    from sensor_msgs.msg import JointState
    from softgrip_ros.client import GripperClient

    processes, logs = {}, {}
    user = Node("two_gripper_user", context=rclpy_context)
    clients, received = {}, {}
    try:
        for name in GRIPPERS:
            logs[name] = open(tmp_path / f"{name}.log", "w+")
            processes[name] = subprocess.Popen(
                [installed_executable("controller"), "--ros-args", "-r", f"__ns:=/{name}",
                 "-p", f"prefix:={name}_", "-p", f"can.channel:={unique(name)}"],
                stdout=logs[name], stderr=subprocess.STDOUT)
            clients[name] = GripperClient(node=user, namespace=f"/{name}")
            received[name] = {"joint_states": [], "tip_pose": []}
            user.create_subscription(JointState, f"/{name}/joint_states",
                                     received[name]["joint_states"].append, 10)
            user.create_subscription(PoseWithCovarianceStamped, f"/{name}/tip_pose/left",
                                     received[name]["tip_pose"].append, 10)
        with spinning(rclpy_context, user, threads=2):
            for name, client in clients.items():
                assert client.wait_until_ready(30.0), (tmp_path / f"{name}.log").read_text()
            yield clients, received
    finally:
        for client in clients.values():
            client.close()
        user.destroy_node()
        codes = {name: stop_process(process) for name, process in processes.items()}
        for log in logs.values():
            log.close()
        assert codes == {name: 0 for name in processes}, {
            name: (tmp_path / f"{name}.log").read_text()[-2000:] for name in processes}


def test_a_grasp_on_one_gripper_leaves_the_other_idle_and_each_names_its_own_frames(
        two_grippers):
    from softgrip_interfaces.msg import GripperState as S
    clients, received = two_grippers
    g1, g2 = clients["g1"], clients["g2"]
    assert g1.envelop_clamp(0.04, 0.02)
    wait_for(lambda: g1.state().phase == S.ENVELOPED, timeout=10.0, message="g1 ENVELOPED")
    assert g1.clamp()
    wait_for(g1.is_task_complete, timeout=10.0, message="g1 HOLDING")
    # grasp_state is a topic of its own: it may land after the result
    assert g1.result().final_phase == S.HOLDING
    wait_for(lambda: g1.state().phase == S.HOLDING, timeout=2.0,
             message="g1's grasp_state HOLDING")
    assert g1.state().estimated_gauge_pressure_pa < -3e3
    # the other gripper never moved: IDLE, at 0 kPa within its sensors' noise
    assert g2.state().phase == S.IDLE
    assert abs(g2.state().estimated_gauge_pressure_pa) < 1e3
    for name in ("g1", "g2"):
        poses = wait_for(lambda n=name: received[n]["tip_pose"], message=f"{name} tip poses")
        joints = wait_for(lambda n=name: received[n]["joint_states"],
                          message=f"{name} joint_states")
        assert poses[-1].header.frame_id == f"{name}_softgrip_base"
        assert joints[-1].header.frame_id == f"{name}_softgrip_base"
        assert all(j.startswith(f"{name}_") for j in joints[-1].name)
        assert f"{name}_tip_spacing" in joints[-1].name
    assert g1.release()
    # generous: the test is about two grippers apart, and on a loaded 2-core host two controllers
    # and this process share it
    try:
        wait_for(g1.is_task_complete, timeout=20.0, message="g1's RELEASE to end")
    except AssertionError as error:
        raise AssertionError(f"{error}; grasp_state: {g1.state().message!r}") from None
    wait_for(lambda: g1.state().phase == S.IDLE, timeout=2.0, message="g1's grasp_state IDLE",
             detail=lambda: f"{g1.state().phase}: {g1.state().message!r}")
    assert g2.state().phase == S.IDLE

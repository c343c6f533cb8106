"""The physics world of the simulated gripper: the two fingers, an object and the arm in MuJoCo
(ROS-free). :func:`make_world` builds one from a scene file; the simulated device steps it with its
pneumatic plant (:class:`~softgrip_ros.canbus.sim_device.SimulatedDevice`)."""
from __future__ import annotations

BENDING_CHOICES = ("l0", "l1")


def make_world(scene_path, gripper_model: str = "type_II", bending: str = "l0", plant=None):
    """The world of the scene file ``scene_path`` with the fingers of ``gripper_model`` driven by
    its ``bending`` law; ``plant``: the pneumatics (PneumaticParameters) whose compliance the
    bending shares. Raises ValueError (a SceneError for the scene) naming what is wrong, and
    RuntimeError when MuJoCo is missing."""
    from softgrip_ros.model import gripper_models
    from softgrip_ros.model.world.fingers import PseudoRigidFinger
    from softgrip_ros.model.world.scene import load_scene
    from softgrip_ros.model.world.world import GripperWorld

    if bending not in BENDING_CHOICES:
        raise ValueError(f"world bending law must be one of {BENDING_CHOICES}, got {bending!r}")
    scene = load_scene(scene_path)
    geometry, calibration = gripper_models.resolve(gripper_model)
    finger = PseudoRigidFinger(geometry, calibration, bending=bending)
    return GripperWorld(scene, finger, plant=plant)

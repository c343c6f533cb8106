"""Side views of the physics world: the two fingers' outline and the object, seen along y (the
fingers' width), in the world's x-z plane with the floor at z = 0. For the demo's picture and for
looking at a grasp; needs matplotlib (imported when called)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from softgrip_ros.model.world.scene import ObjectShape


@dataclasses.dataclass(frozen=True)
class Snapshot:
    """What a side view shows: the base position (world, m), both fingers' hinge angles (2, J) and
    the chamber bulges (5,) at that instant, the object's centre (m) and its turn about y (rad),
    and a caption."""

    base_m: tuple
    hinge_angles: np.ndarray
    bulges_m: np.ndarray
    object_m: tuple | None
    object_pitch_rad: float
    caption: str


def snapshot_of_truth(finger, scene, truth, object_position_m, object_quaternion_wxyz,
                      caption: str) -> Snapshot:
    """A :class:`Snapshot` from the ground-truth messages' fields (sim/grasp_truth: the base, the
    hinge angles, the pressure; sim/object_pose: the object)."""
    w, _, y, _ = object_quaternion_wxyz
    pitch = 2.0 * math.atan2(y, w) if all(math.isfinite(q) for q in (w, y)) else 0.0
    return Snapshot(tuple(truth.base_position_m),
                    np.array([truth.left_hinge_angles_rad, truth.right_hinge_angles_rad]),
                    finger.bulges_m(truth.gauge_pressure_pa),
                    tuple(object_position_m) if scene.object else None, pitch, caption)


def snapshot(world, caption: str) -> Snapshot:
    """The world's present state as a :class:`Snapshot`."""
    truth = world.truth()
    quaternion = truth.object_quaternion_wxyz
    pitch = (2.0 * math.atan2(quaternion[2], quaternion[0])
             if all(math.isfinite(q) for q in quaternion) else 0.0)
    return Snapshot(truth.base_position_m, world.hinge_angles(), world.finger.bulges_m(
        world.pressure_pa), truth.object_position_m if world.scene.object else None, pitch,
                    caption)


def draw(ax, finger, scene, shot: Snapshot) -> None:
    """One side view on the matplotlib axes ``ax`` (millimetres)."""
    from matplotlib.patches import Circle, Polygon, Rectangle

    base_x, _, base_z = shot.base_m
    for side, sign in ((0, 1.0), (1, -1.0)):
        for polygon in finger.outline(shot.hinge_angles[side], shot.bulges_m):
            # the gripper's (x, z) with z towards the tips; the world's z is up
            points = np.column_stack([base_x + sign * polygon[:, 0], base_z - polygon[:, 1]])
            ax.add_patch(Polygon(points * 1e3, closed=True, facecolor="#e0a070",
                                 edgecolor="#8a5a30", linewidth=0.6))
    obj = scene.object
    if obj is not None and shot.object_m is not None and all(map(math.isfinite, shot.object_m)):
        x, _, z = (1e3 * v for v in shot.object_m)
        style = dict(facecolor="#4a7bd0", edgecolor="#203a70", alpha=0.85)
        if obj.shape in (ObjectShape.CYLINDER, ObjectShape.SPHERE):
            ax.add_patch(Circle((x, z), 0.5e3 * obj.size_m[0], **style))
        else:
            width, height = 1e3 * max(obj.size_m[0], 4e-4), 1e3 * obj.size_m[2]
            patch = Rectangle((x - 0.5 * width, z - 0.5 * height), width, height, **style)
            angle = math.degrees(shot.object_pitch_rad)
            from matplotlib.transforms import Affine2D
            patch.set_transform(Affine2D().rotate_deg_around(x, z, -angle) + ax.transData)
            ax.add_patch(patch)
    if scene.floor:
        ax.axhline(0.0, color="0.4", linewidth=1.0)
    ax.set_aspect("equal")
    ax.set_title(shot.caption, fontsize=9)
    ax.set_xlabel("x (mm)")


def draw_sequence(path, finger, scene, shots, title: str = "", follow: bool = False) -> None:
    """Side views of ``shots`` in a row, saved to ``path`` (PNG); ``follow``: each view centred on
    the gripper where it is (the arm may have moved it), else one frame for all."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, len(shots), figsize=(3.2 * len(shots), 3.8),
                                sharey=not follow)
    axes = np.atleast_1d(axes)
    xs = [1e3 * s.base_m[0] for s in shots]
    zs = [1e3 * s.base_m[2] for s in shots]
    for ax, shot in zip(axes, shots):
        draw(ax, finger, scene, shot)
        if follow:
            x, _, z = (1e3 * v for v in shot.base_m)
            ax.set_xlim(x - 90, x + 90)
            ax.set_ylim(z - 190, z + 15)
        else:
            ax.set_xlim(min(xs) - 110, max(xs) + 110)
            ax.set_ylim(-5, max(zs) + 25)
    axes[0].set_ylabel("z (mm)")
    if title:
        figure.suptitle(title, fontsize=10)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)

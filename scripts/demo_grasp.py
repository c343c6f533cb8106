#!/usr/bin/env python3
"""The grasp demo: `ros2 run softgrip_ros controller` on the simulated gripper, driven over DDS.

Starts the installed ``sim_device`` (the simulated gripper, with the physics world of
config/scenes/cylinder_20mm.yaml) and ``controller`` (every node) as two processes on an
inter-process CAN bus (softgrip_ipc), as a real device has its own processor; sends ENVELOP_CLAMP
for a 20 mm, 0.02 kg object (friction 0.8) on ``grasp_command``; once ENVELOPED the arm brings the
object between the fingers (the scene's ``approach``), then CLAMP; once HOLDING the arm lifts it
0.2 m at 1 g (``settle``, ``lift``); then RELEASE. Prints the phase sequence with timings and
what the world says happened to the object; saves a plot of the raw sensor pressure, the estimate
+- 1 sigma and the tip spacing D2 against time with the phases shaded, and a side view of the
fingers and the object at ENVELOPED, HOLDING (lifted) and after the release; stops both with
SIGTERM and exits 0 when every phase was reached and both exited cleanly.
"""
import argparse
import math
import os
import pathlib
import subprocess
import sys
import time
import uuid

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

import rclpy
from rclpy.node import Node
from sensor_msgs.msg import FluidPressure

from geometry_msgs.msg import PoseStamped
from softgrip_interfaces.msg import GraspCommand, GraspTruth, GripperState, SimContacts
from softgrip_interfaces.srv import PlayArmMove
from softgrip_ros.client import grasp_command as command
from softgrip_ros.config_paths import config_file
from softgrip_ros.model.pneumatics import P_ATM_PA
from softgrip_ros.nodes.common import spinning, stamp_seconds
from softgrip_ros.devtools.processes import installed_executable, stop_process

REPO_ROOT = pathlib.Path(__file__).resolve().parents[1]
PHASES = {
    getattr(GripperState, n): n
    for n in ("IDLE", "OPENING", "ENVELOPED", "CLAMPING", "HOLDING", "RELEASING", "FAULT")
}
COLOURS = {
    "OPENING": "#cfe8ff", "ENVELOPED": "#e0f5d0", "CLAMPING": "#ffe3c2", "HOLDING": "#ffd0d0",
    "RELEASING": "#eadcff", "FAULT": "#ff8080"
}


def wait_phase(states, phase, timeout):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if states and states[-1].phase == phase:
            return states[-1]
        if states and states[-1].phase == GripperState.FAULT:
            return None
        time.sleep(0.01)
    return None


def world_normal(world, side: str) -> float:
    """The world's normal force on the object of one finger (sim/contacts), N."""
    contacts = world.contacts
    return math.nan if contacts is None else getattr(contacts, f"{side}_normal_force_n")


def plot(path, states, samples, start):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    t = [stamp_seconds(s.header.stamp) - start for s in states]
    estimate = [s.estimated_gauge_pressure_pa / 1e3 for s in states]
    sigma = [
        s.estimated_gauge_pressure_std_pa /
        1e3 if math.isfinite(s.estimated_gauge_pressure_std_pa) else 0.0 for s in states
    ]
    figure, (top, bottom) = plt.subplots(2, 1, figsize=(8.5, 5.6), sharex=True)
    top.plot([a - start for a, _ in samples], [p / 1e3 for _, p in samples], lw=0.5, color="grey",
             label="raw sensor chamber_b")
    top.plot(t, estimate, color="C0", label="estimate (EKF)")
    top.fill_between(t, [e - 3 * s for e, s in zip(estimate, sigma)],
                     [e + 3 * s for e, s in zip(estimate, sigma)], color="C0", alpha=0.3,
                     label="estimate +- 3 sigma")
    top.step(t, [s.target_gauge_pressure_pa / 1e3 for s in states], where="post", color="k",
             lw=0.8, ls="--", label="target")
    top.set_ylabel("gauge pressure (kPa)")
    top.legend(fontsize=8, loc="lower left")
    bottom.plot(t, [s.tip_spacing_m * 1e3 for s in states], color="C1",
                label="modelled tip spacing D2 (held: the object)")
    bottom.axhline(20.0, color="k", lw=0.8, ls=":", label="object (20 mm)")
    bottom.set_ylabel("D2 (mm)")
    bottom.set_xlabel("time (s)")
    bottom.legend(fontsize=8, loc="lower right")
    for axis in (top, bottom):
        begin, current = t[0], PHASES[states[0].phase]
        for when, s in zip(t, states):
            name = PHASES[s.phase]
            if name != current:
                if current in COLOURS:
                    axis.axvspan(begin, when, color=COLOURS[current], alpha=0.6, lw=0)
                begin, current = when, name
        axis.grid(alpha=0.3)
    for name, colour in COLOURS.items():
        if name != "FAULT":
            top.axvspan(0, 0, color=colour, label=name)
    top.legend(fontsize=7, loc="center", ncol=2)
    top.set_title(
        "softgrip grasp demo: ENVELOP_CLAMP 20 mm, 0.02 kg, then RELEASE (simulated gripper)")
    figure.tight_layout()
    figure.savefig(path, dpi=110)


SCENE = "cylinder_20mm.yaml"


class World:
    """The world's ground truth as the demo reads it, and its arm."""

    def __init__(self, node):
        self.truth, self.pose, self.contacts = None, None, None
        node.create_subscription(GraspTruth, "sim/grasp_truth",
                                 lambda m: setattr(self, "truth", m), 10)
        node.create_subscription(SimContacts, "sim/contacts",
                                 lambda m: setattr(self, "contacts", m), 10)
        node.create_subscription(PoseStamped, "sim/object_pose",
                                 lambda m: setattr(self, "pose", m), 10)
        self.arm = node.create_client(PlayArmMove, "sim/play_arm_move")

    def play(self, *moves, timeout=15.0) -> bool:
        """Play ``moves`` and wait until the arm rests again."""
        if not self.arm.wait_for_service(timeout_sec=10.0):  # the device's, in its process
            return False
        for move in moves:
            future = self.arm.call_async(PlayArmMove.Request(move=move))
            deadline = time.monotonic() + 5.0
            while not future.done() and time.monotonic() < deadline:
                time.sleep(0.01)
            if not (future.done() and future.result().accepted):
                return False
        deadline = time.monotonic() + timeout
        while self.truth is not None and self.truth.arm_move == "" and \
                time.monotonic() < deadline:
            time.sleep(0.01)
        while self.truth is not None and self.truth.arm_move != "" and \
                time.monotonic() < deadline:
            time.sleep(0.01)
        return time.monotonic() < deadline

    def snapshot(self, finger, scene, caption):
        from softgrip_ros.model.world.drawing import snapshot_of_truth
        position = self.pose.pose.position
        orientation = self.pose.pose.orientation
        return snapshot_of_truth(finger, scene, self.truth, (position.x, position.y, position.z),
                                 (orientation.w, orientation.x, orientation.y, orientation.z),
                                 caption)


def draw_world(path, shots) -> None:
    from softgrip_ros.model import gripper_models
    from softgrip_ros.model.world.drawing import draw_sequence
    from softgrip_ros.model.world.fingers import PseudoRigidFinger
    from softgrip_ros.model.world.scene import load_scene
    finger = PseudoRigidFinger(*gripper_models.resolve("type_II"))
    draw_sequence(path, finger, load_scene(config_file(f"scenes/{SCENE}")), shots,
                  "The physics world's view: type_II fingers, a 20 mm, 20 g cylinder",
                  follow=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--plot", default=str(REPO_ROOT / "docs" / "demo_grasp.png"),
                        help="where to save the plot")
    parser.add_argument("--world-plot", default=str(REPO_ROOT / "docs" / "demo_world.png"),
                        help="where to save the side view of the fingers and the object")
    args = parser.parse_args(argv)
    scene = config_file(f"scenes/{SCENE}")
    # the device on its own, as a real one has its own processor: its world then steps on a
    # core of its own rather than beside the controller's threads in one process
    bus = ["-p", "can.interface:=softgrip_ipc", "-p", f"can.channel:=demo-{uuid.uuid4().hex[:8]}"]
    device = subprocess.Popen([installed_executable("sim_device"), "--ros-args", "--log-level",
                               "warn", *bus, "-p", f"world.scene:={scene}"])
    controller = subprocess.Popen(
        [installed_executable("controller"), "--ros-args", "--log-level", "warn", *bus])
    rclpy.init()
    node = Node("softgrip_demo")
    world = World(node)
    from softgrip_ros.model import gripper_models
    from softgrip_ros.model.world.fingers import PseudoRigidFinger
    from softgrip_ros.model.world.scene import load_scene
    finger, world_scene = PseudoRigidFinger(*gripper_models.resolve("type_II")), load_scene(scene)
    shots = []
    states, samples = [], []
    node.create_subscription(GripperState, "grasp_state", states.append, 200)
    node.create_subscription(
        FluidPressure, "pressure/sensor/chamber_b", lambda m: samples.append(
            (stamp_seconds(m.header.stamp), m.fluid_pressure - P_ATM_PA)), 500)
    publisher = node.create_publisher(GraspCommand, "grasp_command", 10)
    status = 1
    try:
        with spinning(node, threads=1):
            deadline = time.monotonic() + 60
            while not (states and world.truth is not None and
                       publisher.get_subscription_count()) and time.monotonic() < deadline:
                time.sleep(0.05)
            if not states:
                print("demo: the controller never published grasp_state", file=sys.stderr)
                return 1
            start = node.get_clock().now().nanoseconds * 1e-9
            log = []

            def step(label, msg, phase, timeout):
                sent = node.get_clock().now().nanoseconds * 1e-9
                publisher.publish(msg)
                reached = wait_phase(states, phase, timeout)
                took = node.get_clock().now().nanoseconds * 1e-9 - sent
                log.append(reached is not None)
                detail = (f"reached {PHASES[phase]} after {took * 1e3:5.0f} ms: {reached.message}"
                          if reached is not None else
                          f"did NOT reach {PHASES[phase]}: {states[-1].message}")
                print(f"{sent - start:6.2f} s  {label:34s} {detail}")
                return reached

            print("phase sequence (times from the first command):")
            step(
                "ENVELOP_CLAMP 20 mm, 0.02 kg, friction 0.8",
                command(GraspCommand.ENVELOP_CLAMP, "demo-grasp", object_diameter_m=0.02,
                        object_mass_kg=0.02, friction_coefficient=0.8),
                GripperState.ENVELOPED, 5.0)
            # the arm brings the object between the fingers
            log.append(world.play("approach"))
            shots.append(world.snapshot(finger, world_scene, "ENVELOPED: the object between"))
            held = step("CLAMP (the arm is in place)", command(GraspCommand.CLAMP, "demo-clamp"),
                        GripperState.HOLDING, 5.0)
            log.append(world.play("settle", "lift"))
            if held is not None:
                s = states[-1]
                print(
                    f"{'':10}holding at {s.estimated_gauge_pressure_pa / 1e3:.1f} +- "
                    f"{s.estimated_gauge_pressure_std_pa / 1e3:.2f} kPa, clamp force "
                    f"{s.clamp_force_n:.2f} N per finger (the clamp force law)")
            truth = world.truth
            print(f"{'':10}the world after a 0.2 m lift at 1 g: object "
                  f"{'held' if truth.object_in_hand else 'NOT held'} (left "
                  f"{world_normal(world, 'left'):.2f} N, right {world_normal(world, 'right'):.2f}"
                  f" N), slipped {truth.slip_distance_m * 1e3:.1f} mm")
            shots.append(world.snapshot(finger, world_scene, "HOLDING, lifted 0.2 m"))
            step("RELEASE", command(GraspCommand.RELEASE, "demo-release"), GripperState.IDLE, 6.0)
            time.sleep(0.5)
            shots.append(world.snapshot(finger, world_scene, "released: it falls"))
            plot(args.plot, list(states), list(samples), start)
            print(f"plot: {args.plot}")
            draw_world(args.world_plot, shots)
            print(f"side view: {args.world_plot}")
            status = 0 if all(log) else 1
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        for name, process in (("controller", controller), ("simulated device", device)):
            returncode = stop_process(process, timeout_s=15.0)
            if returncode != 0:
                print(f"demo: the {name} exited with {returncode} (None: killed)",
                      file=sys.stderr)
                status = 1
    return status


if __name__ == "__main__":
    sys.exit(main())

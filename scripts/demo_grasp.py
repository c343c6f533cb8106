#!/usr/bin/env python3
"""The grasp demo: `ros2 run softgrip_ros controller` on the simulated gripper, driven over DDS.

Starts the installed ``controller`` executable (every node, plus the simulated device on a
virtual CAN bus), sends ENVELOP_CLAMP for a 40 mm, 0.2 kg object on ``grasp_command``, clamps
once ENVELOPED (as an arm would after placing the object), holds, then sends RELEASE. Prints
the phase sequence with timings, saves a plot of the raw sensor pressure, the estimate +- 1
sigma and the tip spacing D2 against time with the phases shaded, stops the controller with
SIGTERM and exits 0 when every phase was reached and the controller exited cleanly.
"""
import argparse
import math
import os
import pathlib
import subprocess
import sys
import time

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

import rclpy
from rclpy.node import Node
from sensor_msgs.msg import FluidPressure

from softgrip_interfaces.msg import GraspCommand, GripperState
from softgrip_ros.client import grasp_command as command
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
    bottom.axhline(40.0, color="k", lw=0.8, ls=":", label="object (40 mm)")
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
        "softgrip grasp demo: ENVELOP_CLAMP 40 mm, 0.2 kg, then RELEASE (simulated gripper)")
    figure.tight_layout()
    figure.savefig(path, dpi=110)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--plot", default=str(REPO_ROOT / "docs" / "demo_grasp.png"),
                        help="where to save the plot")
    args = parser.parse_args(argv)
    controller = subprocess.Popen(
        [installed_executable("controller"), "--ros-args", "--log-level", "warn"])
    rclpy.init()
    node = Node("softgrip_demo")
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
            while not (states and
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
                "ENVELOP_CLAMP 40 mm, 0.2 kg",
                command(GraspCommand.ENVELOP_CLAMP, "demo-grasp", object_diameter_m=0.04,
                        object_mass_kg=0.2), GripperState.ENVELOPED, 5.0)
            # the arm moves the object between the fingers
            time.sleep(0.5)
            held = step("CLAMP (the arm is in place)", command(GraspCommand.CLAMP, "demo-clamp"),
                        GripperState.HOLDING, 5.0)
            time.sleep(1.5)
            if held is not None:
                s = states[-1]
                print(
                    f"{'':10}holding at {s.estimated_gauge_pressure_pa / 1e3:.1f} +- "
                    f"{s.estimated_gauge_pressure_std_pa / 1e3:.2f} kPa, clamp force "
                    f"{s.clamp_force_n:.2f} N per finger"
                )
            step("RELEASE", command(GraspCommand.RELEASE, "demo-release"), GripperState.IDLE, 6.0)
            time.sleep(0.3)
            plot(args.plot, list(states), list(samples), start)
            print(f"plot: {args.plot}")
            status = 0 if all(log) else 1
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        returncode = stop_process(controller, timeout_s=15.0)
        if returncode != 0:
            print(f"demo: the controller exited with {returncode} (None: killed)", file=sys.stderr)
            status = 1
    return status


if __name__ == "__main__":
    sys.exit(main())

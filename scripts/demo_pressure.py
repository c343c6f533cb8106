#!/usr/bin/env python3
"""The pressure demo: the real executables on a shared CAN bus, driven over DDS.

Starts ``sim_device`` and ``pressure_controller`` as separate processes on the softgrip_ipc
bus, sends pressure steps on ``pressure/command`` (open with positive pressure, clamp with
vacuum, vent), prints each step with its timing as the controller reports it, saves a plot
of sensor pressure and setpoint against time, stops both processes with SIGTERM and exits 0.
(The grasp demo replaces this when the grasp manager and the ``controller`` bringup land.)
"""
import argparse
import math
import os
import pathlib
import signal
import subprocess
import sys
import time
import uuid

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

import rclpy  # noqa: E402
from rclpy.node import Node  # noqa: E402
from sensor_msgs.msg import FluidPressure  # noqa: E402

from softgrip_interfaces.msg import ControllerStatus, PressureCommand  # noqa: E402
from softgrip_ros.nodes.common import spinning  # noqa: E402

REPO_ROOT = pathlib.Path(__file__).resolve().parents[1]
STEPS = [("open: +25 kPa (envelop)", 25e3, PressureCommand.SUPPLY, 1.5),
         ("clamp: -20 kPa (vacuum)", -20e3, PressureCommand.VACUUM, 1.5),
         ("release: vent", 0.0, PressureCommand.VENT, 1.0)]


def executable(name):
    from ament_index_python.packages import get_package_prefix
    return os.path.join(get_package_prefix("softgrip_ros"), "lib", "softgrip_ros", name)


def reach_time(samples, sent: float, until: float, target: float, band_pa: float = 1e3, run: int = 5):
    """Seconds from ``sent`` to the first of ``run`` consecutive samples within ``band_pa`` of the target."""
    window = [(t, p) for t, p in samples if sent <= t <= until]
    for i in range(len(window) - run + 1):
        if all(abs(p - target) < band_pa for _, p in window[i:i + run]):
            return window[i][0] - sent
    return None


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--plot", default=str(REPO_ROOT / "docs" / "demo_pressure.png"), help="where to save the plot")
    args = parser.parse_args(argv)
    channel = f"demo-{uuid.uuid4().hex[:6]}"
    ros_args = ["--ros-args", "-p", "can.interface:=softgrip_ipc", "-p", f"can.channel:={channel}", "--log-level", "warn"]
    processes = [subprocess.Popen([executable(name), *ros_args]) for name in ("sim_device", "pressure_controller")]
    rclpy.init()
    node = Node("softgrip_demo")

    def now() -> float:
        return node.get_clock().now().nanoseconds * 1e-9
    samples, statuses = [], []      # samples: (stamp s, gauge Pa), by the controller's own stamps
    node.create_subscription(FluidPressure, "pressure/sensor/chamber_b",
                             lambda m: samples.append((m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec,
                                                       m.fluid_pressure - 101_325.0)), 200)
    node.create_subscription(ControllerStatus, "controller/status", statuses.append, 50)
    command = node.create_publisher(PressureCommand, "pressure/command", 10)
    setpoints = []
    status = 0
    try:
        with spinning(node, threads=1):
            deadline = time.monotonic() + 30
            while not (samples and command.get_subscription_count()) and time.monotonic() < deadline:
                time.sleep(0.05)
            if not samples:
                print("demo: the controller never published a sensor reading", file=sys.stderr)
                return 1
            start = now()
            print(f"{'t (s)':>7}  step")
            for label, target, source, hold in STEPS:
                sent = now()
                command.publish(PressureCommand(target_gauge_pressure_pa=target, max_rate_pa_per_s=math.nan, source=source))
                setpoints.append((sent, target))
                time.sleep(hold)
                # judge by the samples' own stamps; on a busy machine they may arrive late, so wait for them
                deadline = time.monotonic() + 5.0
                while samples[-1][0] < sent + hold and time.monotonic() < deadline:
                    time.sleep(0.05)
                reached = reach_time(samples, sent, sent + hold, target)
                mode = statuses[-1].mode if statuses else -1
                print(f"{sent - start:7.2f}  {label:28s} within 1 kPa after {reached * 1e3:6.0f} ms" if reached is not None
                      else f"{sent - start:7.2f}  {label:28s} NOT reached in {hold} s", f"(controller mode {mode})")
                status |= reached is None
            stamps = [t - start for t, _ in samples]
            pressures = [p / 1e3 for _, p in samples]
            import matplotlib
            matplotlib.use("Agg")
            import matplotlib.pyplot as plt
            figure, axis = plt.subplots(figsize=(8, 3.6))
            axis.plot(stamps, pressures, lw=0.8, label="sensor chamber_b (gauge)")
            times = [t - start for t, _ in setpoints] + [stamps[-1]]
            axis.step(times, [v / 1e3 for _, v in setpoints] + [setpoints[-1][1] / 1e3], where="post", label="command")
            axis.set_xlabel("time (s)")
            axis.set_ylabel("pressure (kPa)")
            axis.set_title("softgrip pressure demo: simulated device over CAN, commands over DDS")
            axis.grid(alpha=0.3)
            axis.legend()
            figure.tight_layout()
            figure.savefig(args.plot, dpi=110)
            print(f"plot: {args.plot}")
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        for process in processes:
            process.send_signal(signal.SIGTERM)
        for process in processes:
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                process.kill()
                status = 1
            status |= process.returncode != 0
    return int(status)


if __name__ == "__main__":
    sys.exit(main())

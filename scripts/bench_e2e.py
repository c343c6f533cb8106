#!/usr/bin/env python3
"""End-to-end latency and load of the installed ``controller``, the real user path.

Starts ``sim_device`` and ``controller`` as processes on one inter-process CAN bus
(``softgrip_ipc``, so that this script can watch the frames), then drives grasps over DDS
from here, as an arm would:

* ``cmd_to_valve_frame_ms``: from ``grasp_command`` published here to the first ValveCommand
  frame whose channel-0 state differs from the one before the command (the CAN frame's
  sender timestamp). Commands: ENVELOP_CLAMP (vent -> supply), CLAMP (-> vacuum), STOP (-> vent).
* ``sensor_to_tip_pose_ms``: from a PressureSensor frame (sender timestamp) to ``tip_pose/left``
  published by the controller (the DDS sample's source timestamp, which the writer takes as it
  publishes), through the composed estimator and kinematics. The pose's stamp is its fused
  sample's, which the pressure controller takes from the frame's own timestamp; its frame is the
  newest sensor frame sent by then (plus STAMP_MATCH_S for the microseconds that converting
  between clocks can put the stamp before the frame).
* ``sensor_to_tip_pose_received_ms``: the same, to the pose's reception here (the rmw's reception
  timestamp): one DDS hop more, what a subscriber in another process sees.
* ``controller_cpu_pct_idle`` / ``_grasp``: the user + system CPU time of the controller process
  and its child (the L2 rod solver) over wall time (100 = one core), in windows while IDLE and
  while grasping at the default 500 Hz control rate; median over the windows. The device simulation
  runs in its own process and is not counted.
* ``start_to_ready_s``: from the controller's exec to the first ``grasp_state`` received here
  (this process already subscribed, the simulated device already sending).
* ``controller_rss_mb``: resident memory at the end (VmRSS), and its peak (VmHWM); the L2
  solver child's VmRSS separately (``controller_children_rss_mb``: summing shared pages twice
  would overstate the total).
* ``receive_floor_cpu_pct``: the idle figure's floor, a bare python-can loop in a process of its
  own receiving the same frames, drained every 10 ms as the resting controller takes them;
  ``_per_frame``: the same loop with one blocking ``recv`` per frame; ``idle_over_receive_floor``:
  the idle controller's CPU over the first (measured one after the other, the controller idle;
  the loop's own process time, not ticks).
* ``controller_cpu_pct_device_paused``: idle CPU again with the device process stopped
  (SIGSTOP), so that no frame arrives: what the frames' reception, estimation and kinematics
  cost is the difference from ``_idle``.
* Then as an arm stack uses it, with ``joint_states`` subscribed too (not during the CPU windows
  above, which keep #6's definition): ``sensor_to_joint_states_ms`` as the pose's, beside
  ``sensor_to_tip_pose_arm_ms`` from the same estimates, and ``joint_states_p99_excess_ms``, the
  first's p99 less the second's; ``gripper_open_s``, a control_msgs GripperCommand opening goal
  from its acceptance to its result (``reached_goal``), and ``grasp_open_s``, the grasp manager's
  own OPEN to the same D2 as a Grasp action goal, in alternation from IDLE (40 and 60 mm); their
  medians' ratio is ``gripper_open_ratio``.
* ``cancel_to_valve_frame_ms``: a GripperCommand opening goal from IDLE, cancelled a random
  0-150 ms after its first valve frame (the opening under way), from the cancel request sent
  here to the end of the last supply after it: the ValveCommand frame after which channel 0
  stays off the supply for 0.5 s (held, as ros2_controllers' gripper controllers stop where
  they are), or 0 when the supply was shut at the request (between the opening's pulses) and
  never reopened, as the bus then shows no change to time; ``--cancels`` of them per run.
  ``cancel_to_hold_stamp_ms``: from the same request to the stamp of the first ``grasp_state``
  that says the goal was canceled, when the grasp manager ordered the hold (for every cancel,
  those between pulses too).
* ``safety_reaction_ms``: from the first PressureSensor frame past the overpressure limit (the
  simulated device's readings biased by ``fault.sensor_bias_pa`` while the gripper is held open
  at 40 mm) to the first ValveCommand frame that vents (both sender timestamps); ``--reactions``
  of them per run.

Each figure is the median over ``--runs`` whole measurements (3; fresh processes each): on a
shared 2-core VM a p99 or a CPU median moves by about a millisecond or a percent from run to run.
Writes its section of docs/benchmarks.md; --json prints the figures instead.
Reproduce: scripts/env.sh sourced, then  python scripts/bench_e2e.py
"""
import bisect
import os
import pathlib
import signal
import statistics
import subprocess
import sys
import time
import uuid

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("ROS_DOMAIN_ID", str(60 + os.getpid() % 40))  # not the default domain 0

import can
import numpy as np
import rclpy
from geometry_msgs.msg import PoseWithCovarianceStamped
from rclpy.node import Node
from sensor_msgs.msg import JointState

from demo_grasp import wait_phase
from softgrip_interfaces.msg import ControllerStatus, GraspCommand, GripperState
from softgrip_ros.client import grasp_command as command
from softgrip_ros.devtools.benchmarking import (benchmark_parser, figure_rows, host_load,
                                                machine_line, paired_rows, reference_checkout,
                                                strict_json, update_section, UnknownReference)
from softgrip_ros.canbus.codec import FrameCodec
from softgrip_ros.canbus.reader import BatchReader
from softgrip_ros.nodes.common import spinning, stamp_seconds
from softgrip_ros.devtools.processes import installed_executable, stop_process

ROOT = pathlib.Path(__file__).resolve().parent.parent
# the hot path's budget: latency, CPU and memory; a cancel's and a safety reaction's latency
TARGETS = {
    "cmd_to_valve_frame_ms_p99": (5.0, True), "sensor_to_tip_pose_ms_p99": (3.0, True),
    "controller_cpu_pct_idle": (6.0, True), "controller_cpu_pct_grasp": (20.0, True),
    "controller_rss_mb": (150.0, True), "start_to_ready_s": (1.5, True),
    "joint_states_p99_excess_ms": (0.5, True),
    "gripper_open_ratio": (1.2, True), "cancel_to_valve_frame_ms_p99": (20.0, True),
    "safety_reaction_ms_p99": (5.0, True), "idle_over_receive_floor": (5.0, True),
}
# the idle figure's floor (#51): a bare python-can loop receiving the same frames in a process of
# its own for argv[3] s, drained every RECEIVE_FLOOR_PERIOD_S as the resting controller takes them
# (0 in argv[2]: one blocking recv per frame); it prints its CPU and wall seconds
RECEIVE_FLOOR_PERIOD_S = 0.01
RECEIVE_FLOOR_LOOP = """
import sys, threading, time, can
bus = can.Bus(interface="softgrip_ipc", channel=sys.argv[1])
period_s, seconds, wait = float(sys.argv[2]), float(sys.argv[3]), threading.Event().wait
while bus.recv(0.0) is not None:
    pass
cpu0, start = time.process_time(), time.monotonic()
while time.monotonic() - start < seconds:
    if period_s > 0.0:
        wait(period_s)
        while bus.recv(0.0) is not None:
            pass
    else:
        bus.recv(1.0)
print(time.process_time() - cpu0, time.monotonic() - start, flush=True)
bus.shutdown()
"""
VENT = 3  # ValveCommand's channel state
FAULT_MODE = 4  # ControllerStatus.mode in the safe state
REACTION_OPEN_M = 0.04  # held open at this D2 (about 20 kPa) when the readings jump
REACTION_BIAS_PA = 45e3  # the readings' bias: past 50 kPa + the 5 kPa margin from 10 kPa up
CANCEL_DELAY_S = (0.0, 0.15)  # after the goal's first valve frame: the opening under way
CANCEL_WATCH_S = 0.5  # after a cancel, how long the supply must stay shut
SUPPLY = 1  # ValveCommand's channel state
OPEN_SPACINGS_M = (0.04, 0.06)  # the gripper and grasp opening goals, in alternation
SENSOR_FRAMES = ("PressureSensor1", "PressureSensor2")
STAMP_MATCH_S = 2e-4  # well under the 1.4 ms between sensor frames
WATCH_PERIOD_S = 0.02  # the bus watch reads the frames queued this often
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def progress(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


class BusWatch:
    """Every ValveCommand and sensor frame on the bus, by sender timestamp, from a reader thread.

    The thread (the controller's own :class:`BatchReader`) takes what is queued every
    ``WATCH_PERIOD_S`` and decodes only the valve frames (the sensor frames are told by their ID):
    read and decoded one at a time, the ~1,600 frames a second took about 6 % of a core of this
    2-core machine from the controller under test. The frames carry their sender's time, so
    reading them later changes no figure."""

    def __init__(self, channel: str):
        self.bus = can.Bus(interface="softgrip_ipc", channel=channel)
        self.codec = FrameCodec(max_counter_delta=15, sync_frames=0)
        self._sensor_ids = {self.codec.frame_ids[name] for name in SENSOR_FRAMES}
        self._valve_id = self.codec.frame_ids["ValveCommand"]
        self.valve_times: list = []  # sender time of each ValveCommand, and its channel-0 state
        self.valve_states: list = []
        self.sensor_times: list = []
        self.kept_sensor_frames: list | None = None  # every sensor frame while a list
        self._reader = BatchReader(self.bus, self._on_frames, rest_period_s=WATCH_PERIOD_S,
                                   resting=lambda: True, name="bench-bus")

    def _on_frames(self, frames):
        for frame in frames:
            if frame.arbitration_id in self._sensor_ids:
                self.sensor_times.append(frame.timestamp)
                if self.kept_sensor_frames is not None:
                    self.kept_sensor_frames.append(frame)
            elif frame.arbitration_id == self._valve_id and (decoded := self.codec.decode(frame)):
                self.valve_times.append(frame.timestamp)
                self.valve_states.append(int(decoded.signals["Channel0"]))

    def first_valve_change_after(self, sent_s: float, timeout_s: float = 2.0):
        """Sender time of the first valve frame after ``sent_s`` whose state differs from the last
        one before it."""
        change = self.valve_change_after(sent_s, timeout_s)
        return None if change is None else change[0]

    def valve_change_after(self, sent_s: float, timeout_s: float = 2.0):
        """(sender time, channel-0 state) of the first valve frame after ``sent_s`` whose state
        differs from the last one before it; None if none comes within ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            count = len(self.valve_states)  # appended after the times: both hold this many
            first_after = bisect.bisect_right(self.valve_times, sent_s, 0, count)
            previous = self.valve_states[first_after - 1] if first_after else None
            for index in range(first_after, count):
                if self.valve_states[index] != previous:
                    return self.valve_times[index], self.valve_states[index]
            time.sleep(WATCH_PERIOD_S)
        return None

    def valve_state_at(self, when_s: float):
        """Channel 0's state in the last valve frame sent by ``when_s`` (None before the first)."""
        count = len(self.valve_states)
        index = bisect.bisect_right(self.valve_times, when_s, 0, count) - 1
        return self.valve_states[index] if index >= 0 else None

    def valve_frames(self, after_s: float, until_s: float) -> list:
        """(sender time, channel-0 state) of every valve frame sent in (after_s, until_s]."""
        count = len(self.valve_states)
        first = bisect.bisect_right(self.valve_times, after_s, 0, count)
        last = bisect.bisect_right(self.valve_times, until_s, 0, count)
        return list(zip(self.valve_times[first:last], self.valve_states[first:last]))

    def first_reading_above(self, limit_pa: float, after_s: float):
        """Sender time of the first kept sensor frame after ``after_s`` that reads above
        ``limit_pa`` (None if none)."""
        for frame in list(self.kept_sensor_frames or ()):
            if frame.timestamp > after_s:
                decoded = self.codec.decode(frame)
                if decoded is not None and decoded.signals["GaugePressure"] > limit_pa:
                    return frame.timestamp
        return None

    def sensor_frame_before(self, stamp_s: float):
        """Sender time of the newest sensor frame sent by ``stamp_s`` (None if none)."""
        index = bisect.bisect_right(self.sensor_times, stamp_s + STAMP_MATCH_S) - 1
        return self.sensor_times[index] if index >= 0 else None

    def close(self):
        self._reader.stop(timeout_s=2.0)
        self.bus.shutdown()


def process_tree(pid: int) -> list:
    """``pid`` and its descendants (the controller's L2 rod-solver child), from /proc."""
    pids = [pid]
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except FileNotFoundError:
        return []
    for tid in tasks:
        try:
            with open(f"/proc/{pid}/task/{tid}/children") as children:
                for child in children.read().split():
                    pids += process_tree(int(child))
        except FileNotFoundError:
            continue
    return pids


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of ``pid`` and its live descendants."""
    total = 0.0
    for member in process_tree(pid):
        try:
            with open(f"/proc/{member}/stat") as stat:
                fields = stat.read().rsplit(")", 1)[1].split()
        except FileNotFoundError:
            continue
        total += (int(fields[11]) + int(fields[12])) / CLOCK_TICKS  # utime, stime
    return total


def memory_mb(pid: int) -> dict:
    values = {}
    with open(f"/proc/{pid}/status") as status:
        for line in status:
            key, _, rest = line.partition(":")
            if key in ("VmRSS", "VmHWM"):
                values[key] = int(rest.split()[0]) / 1024.0
    return values


def cpu_windows(pid: int, seconds: float, window_s: float, during=None) -> list:
    """CPU % of one core in consecutive windows over ``seconds``; ``during()`` is called repeatedly
    meanwhile."""
    percents, end = [], time.monotonic() + seconds
    while time.monotonic() < end:
        wall0, cpu0 = time.monotonic(), cpu_seconds(pid)
        window_end = wall0 + window_s
        while time.monotonic() < window_end:
            if during is None:
                time.sleep(0.05)
            else:
                during()
        percents.append(100.0 * (cpu_seconds(pid) - cpu0) / (time.monotonic() - wall0))
    return percents


def receive_floor_cpu(channel: str, period_s: float, seconds: float) -> float:
    """CPU % (of one core) of RECEIVE_FLOOR_LOOP on ``channel`` over ``seconds``: the frames
    drained every ``period_s``, or one at a time for 0."""
    loop = subprocess.Popen(
        [sys.executable, "-c", RECEIVE_FLOOR_LOOP, channel, str(period_s), str(seconds)],
        stdout=subprocess.PIPE, text=True)
    try:
        output, _ = loop.communicate(timeout=seconds + 60.0)
        cpu_s, wall_s = map(float, output.split())
    except (subprocess.TimeoutExpired, ValueError) as error:
        raise RuntimeError(f"the receive floor's loop gave no figure: {error}") from None
    finally:
        stop_process(loop)
    return 100.0 * cpu_s / wall_s


def p99(values) -> float:
    return float(np.percentile(values, 99))


def wait_future(future, timeout_s: float):
    deadline = time.monotonic() + timeout_s
    while not future.done():
        if time.monotonic() > deadline:
            return None
        time.sleep(0.002)
    return future.result()


def timed_goal(client, goal, timeout_s: float = 10.0):
    """(seconds from the goal's acceptance to its result, the result response), or None."""
    handle = wait_future(client.send_goal_async(goal), 5.0)
    if handle is None or not handle.accepted:
        return None
    accepted = time.monotonic()
    response = wait_future(handle.get_result_async(), timeout_s)
    return None if response is None else (time.monotonic() - accepted, response)


def open_goals(node, states, pairs: int) -> dict:
    """``pairs`` x OPEN_SPACINGS_M: a GripperCommand opening goal and the Grasp action's OPEN to
    the same D2, in turn, each from IDLE (a STOP between)."""
    from action_msgs.msg import GoalStatus
    from control_msgs.action import GripperCommand
    from rclpy.action import ActionClient
    from softgrip_interfaces.action import Grasp
    gripper = ActionClient(node, GripperCommand, "gripper_cmd")
    grasp = ActionClient(node, Grasp, "grasp")
    stops = node.create_publisher(GraspCommand, "grasp_command", 10)
    times = {"gripper": [], "grasp": [], "failed": 0}
    try:
        if not (gripper.wait_for_server(timeout_sec=10.0) and grasp.wait_for_server(
                timeout_sec=10.0)):
            raise RuntimeError("no gripper_cmd or grasp action server")
        for n in range(pairs):
            for spacing in OPEN_SPACINGS_M:
                goal = GripperCommand.Goal()
                goal.command.position = spacing
                for kind, client, request in (
                        ("gripper", gripper, goal),
                        ("grasp", grasp, Grasp.Goal(command=command(
                            GraspCommand.OPEN, f"bench-open-{n}", target_tip_spacing_m=spacing)))):
                    outcome = timed_goal(client, request)
                    ok = outcome is not None and outcome[1].status == GoalStatus.STATUS_SUCCEEDED
                    if ok and kind == "gripper":
                        ok = outcome[1].result.reached_goal
                    if ok:
                        times[kind].append(outcome[0])
                    else:
                        times["failed"] += 1
                    stops.publish(command(GraspCommand.STOP, f"bench-open-stop-{n}"))
                    wait_phase(states, GripperState.IDLE, 5.0)
                    time.sleep(0.3)  # vented
    finally:
        gripper.destroy()
        grasp.destroy()
        node.destroy_publisher(stops)
    return times


def cancel_goals(node, states, watch, count: int, seed: int = 0) -> dict:
    """``count`` GripperCommand opening goals from IDLE, each cancelled a random CANCEL_DELAY_S
    after its first valve frame (the supply open): {"latencies_ms": [...], "hold_stamp_ms":
    [...], "shut_at_request": n, "states": {channel-0 state at the end: count}, "failed": n,
    "why": [...]}. A latency runs from the cancel request to the first valve frame after which
    channel 0 does not open to the supply again within CANCEL_WATCH_S (the opening pulses
    between closed frames, so the first change alone would time the pulses); it is 0 when the
    supply was shut at the request and stayed shut (no frame changes then: the next one is the
    periodic re-send). A hold stamp runs from the request to the stamp of the first
    ``grasp_state`` after it that says the goal was canceled."""
    import random

    from control_msgs.action import GripperCommand
    from rclpy.action import ActionClient
    gripper = ActionClient(node, GripperCommand, "gripper_cmd")
    stops = node.create_publisher(GraspCommand, "grasp_command", 10)
    rng = random.Random(seed)
    out = {"latencies_ms": [], "hold_stamp_ms": [], "shut_at_request": 0, "states": {},
           "failed": 0, "why": []}
    try:
        if not gripper.wait_for_server(timeout_sec=10.0):
            raise RuntimeError("no gripper_cmd action server")
        for n in range(count):
            goal = GripperCommand.Goal()
            goal.command.position = max(OPEN_SPACINGS_M)
            sent = time.time()
            handle = wait_future(gripper.send_goal_async(goal), 5.0)
            started = watch.first_valve_change_after(sent) if handle and handle.accepted else None
            why = ("not accepted" if not (handle and handle.accepted) else
                   "no valve frame of the opening" if started is None else "")
            if not why:
                time.sleep(max(0.0, started + rng.uniform(*CANCEL_DELAY_S) - time.time()))
                cancel_sent = time.time()
                cancelled = handle.cancel_goal_async()
                time.sleep(CANCEL_WATCH_S + 2 * WATCH_PERIOD_S)
                frames = watch.valve_frames(cancel_sent, cancel_sent + CANCEL_WATCH_S)
                supplied = [k for k, (_, state) in enumerate(frames) if state == SUPPLY]
                shut = not supplied and watch.valve_state_at(cancel_sent) != SUPPLY
                settled = supplied[-1] + 1 if supplied else 0
                if settled < len(frames):
                    out["latencies_ms"].append(
                        0.0 if shut else 1e3 * (frames[settled][0] - cancel_sent))
                    out["shut_at_request"] += shut
                    end_state = frames[-1][1]
                    out["states"][end_state] = out["states"].get(end_state, 0) + 1
                else:
                    why = f"still supplied {CANCEL_WATCH_S:g} s after the cancel"
                held = [stamp for stamp in (stamp_seconds(m.header.stamp) for m in list(states)
                                            if "canceled" in m.message) if stamp >= cancel_sent]
                if held:
                    out["hold_stamp_ms"].append(1e3 * (held[0] - cancel_sent))
                wait_future(cancelled, 2.0)
                wait_future(handle.get_result_async(), 5.0)
            if why:
                out["failed"] += 1
                out["why"].append(why)
            stops.publish(command(GraspCommand.STOP, f"bench-cancel-stop-{n}"))
            wait_phase(states, GripperState.IDLE, 5.0)
            time.sleep(0.3)  # vented
    finally:
        gripper.destroy()
        node.destroy_publisher(stops)
    return out


def matched_latencies(watch, samples) -> list:
    """ms from each sample's sensor frame to its publish: ``samples`` [(published, received,
    stamp)]."""
    matched = [(published_s, watch.sensor_frame_before(stamp_s))
               for published_s, _, stamp_s in samples]
    return [1e3 * (published_s - sent_s) for published_s, sent_s in matched if sent_s is not None]


def safety_reactions(node, states, watch, count: int) -> dict:
    """``count`` times: the gripper held open at REACTION_OPEN_M, then every reading biased by
    REACTION_BIAS_PA at the simulated device: {"latencies_ms": [...], "failed": n, "why": [...]}
    from the first sensor frame past the limit to the first venting ValveCommand; then the bias
    is taken off, and a STOP after the safe state's clear time brings the gripper to IDLE."""
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    limit_pa = 50e3 + 5e3  # the default max_gauge_pressure_pa + overpressure_margin_pa
    setter = node.create_client(SetParameters, "/sim_device/set_parameters")
    commands = node.create_publisher(GraspCommand, "grasp_command", 10)
    out = {"latencies_ms": [], "failed": 0, "why": []}

    def set_bias(bias_pa: float) -> bool:
        request = SetParameters.Request(parameters=[
            Parameter("fault.sensor_bias_pa", value=bias_pa).to_parameter_msg()])
        response = wait_future(setter.call_async(request), 5.0)
        return bool(response and response.results and response.results[0].successful)

    statuses = []
    watcher = node.create_subscription(ControllerStatus, "controller/status", statuses.append, 10)

    def stop() -> None:
        # once the safe state's evidence has been gone for its clear time, a STOP clears it; on a
        # busy host the first may come too soon, as the fault matrix's reset finds
        for _ in range(3):
            time.sleep(0.6)
            commands.publish(command(GraspCommand.STOP, "bench-reaction-stop"))
            wait_phase(states, GripperState.IDLE, 5.0)
            time.sleep(0.3)
            if statuses and statuses[-1].mode != FAULT_MODE:
                return

    def held_open(n: int) -> bool:
        for _ in range(3):  # a command just after the safe state cleared may find it still set
            commands.publish(command(GraspCommand.OPEN, f"bench-reaction-{n}",
                                     target_tip_spacing_m=REACTION_OPEN_M))
            if wait_phase(states, GripperState.ENVELOPED, 5.0) is not None:
                return True
            stop()
        return False

    try:
        if not setter.wait_for_service(timeout_sec=10.0):
            raise RuntimeError("no /sim_device/set_parameters service")
        for n in range(count):
            why = ""
            if not held_open(n):
                why = "the opening did not reach ENVELOPED"
            else:
                time.sleep(0.3)  # settled
                watch.kept_sensor_frames = []
                biased_from = time.time()
                if not set_bias(REACTION_BIAS_PA):
                    why = "the device refused the bias"
                else:
                    vented = None
                    past = None
                    deadline = time.monotonic() + 2.0
                    while vented is None and time.monotonic() < deadline:
                        time.sleep(2 * WATCH_PERIOD_S)
                        past = past or watch.first_reading_above(limit_pa, biased_from)
                        if past is not None:
                            vented = next((t for t, state in watch.valve_frames(
                                past - 1e-4, past + 1.0) if state == VENT), None)
                    if past is None or vented is None:
                        why = ("no reading past the limit" if past is None else
                               "no venting ValveCommand within 1 s")
                    else:
                        out["latencies_ms"].append(1e3 * (vented - past))
                watch.kept_sensor_frames = None
                set_bias(0.0)
            if why:
                out["failed"] += 1
                out["why"].append(why)
            stop()
    finally:
        watch.kept_sensor_frames = None
        node.destroy_subscription(watcher)
        node.destroy_client(setter)
        node.destroy_publisher(commands)
    return out


def measure(idle_s: float, grasp_s: float, window_s: float, open_pairs: int, cancels: int,
            reactions: int, controller_env: dict | None = None) -> tuple[dict, dict]:
    """One run; ``controller_env``: the controller's environment (None: this one's)."""
    channel = f"bench-e2e-{uuid.uuid4().hex[:8]}"
    ros_args = [
        "--ros-args", "-p", "can.interface:=softgrip_ipc", "-p", f"can.channel:={channel}",
        "--log-level", "warn"
    ]
    watch = BusWatch(channel)
    device = subprocess.Popen([installed_executable("sim_device"), *ros_args])
    rclpy.init()
    node = Node("softgrip_bench_e2e")
    # poses: (published, received, stamp), matched to their frames once the watch has read them
    states, poses = [], []
    clock_offsets = []

    def on_pose(msg, info):
        received_s = info["received_timestamp"] * 1e-9
        clock_offsets.append(time.time() - received_s)
        poses.append(
            (info["source_timestamp"] * 1e-9, received_s, stamp_seconds(msg.header.stamp)))

    joints = []

    def on_joints(msg, info):
        joints.append((info["source_timestamp"] * 1e-9, 0.0, stamp_seconds(msg.header.stamp)))

    ready_s = []

    def on_state(msg):
        if not ready_s:
            ready_s.append(time.monotonic() - launched_s)
        states.append(msg)

    node.create_subscription(GripperState, "grasp_state", on_state, 100)
    node.create_subscription(PoseWithCovarianceStamped, "tip_pose/left", on_pose, 100)
    publisher = node.create_publisher(GraspCommand, "grasp_command", 10)
    command_latencies = {"ENVELOP_CLAMP": [], "CLAMP": [], "STOP": []}
    cycles = {"done": 0, "failed": 0}

    def send(label, msg):
        sent = time.time()
        publisher.publish(msg)
        changed = watch.first_valve_change_after(sent)
        if changed is not None:
            command_latencies[label].append(1e3 * (changed - sent))

    def one_grasp():
        n = cycles["done"] + cycles["failed"]
        send(
            "ENVELOP_CLAMP",
            command(GraspCommand.ENVELOP_CLAMP, f"bench-{n}", object_diameter_m=0.04,
                    object_mass_kg=0.02))
        ok = wait_phase(states, GripperState.ENVELOPED, 5.0) is not None
        send("CLAMP", command(GraspCommand.CLAMP, f"bench-{n}-clamp"))
        ok = ok and wait_phase(states, GripperState.HOLDING, 5.0) is not None
        time.sleep(0.2)
        send("STOP", command(GraspCommand.STOP, f"bench-{n}-stop"))
        ok = ok and wait_phase(states, GripperState.IDLE, 5.0) is not None
        time.sleep(0.3)  # vented before the next grasp
        cycles["done" if ok else "failed"] += 1

    # the device up first: its start would otherwise share the host with the controller's
    deadline = time.monotonic() + 60.0
    while not watch.sensor_times and device.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    launched_s = time.monotonic()
    controller = subprocess.Popen([installed_executable("controller"), *ros_args],
                                  env=controller_env)
    try:
        with spinning(node, threads=1):
            deadline = time.monotonic() + 60.0
            while not (states and publisher.get_subscription_count() and watch.sensor_times):
                if time.monotonic() > deadline or controller.poll() is not None:
                    raise RuntimeError(
                        "the controller did not come up (no grasp_state or no sensor frames in 60 "
                        "s)"
                    )
                time.sleep(0.05)
            time.sleep(2.0)  # past start-up
            progress(f"idle: CPU over {idle_s:.0f} s")
            idle = cpu_windows(controller.pid, idle_s, window_s)
            progress(f"the floor: a bare receive loop of the same frames, 2 x {idle_s:.0f} s")
            floor = receive_floor_cpu(channel, RECEIVE_FLOOR_PERIOD_S, idle_s)
            floor_per_frame = receive_floor_cpu(channel, 0.0, idle_s)
            progress(f"grasping: ENVELOP_CLAMP 40 mm -> CLAMP -> STOP cycles for {grasp_s:.0f} s")
            poses.clear()
            grasp = cpu_windows(controller.pid, grasp_s, window_s, during=one_grasp)
            grasp_poses = list(poses)  # not the predictions while the device is paused
            memory = memory_mb(controller.pid)
            children_rss = sum(
                memory_mb(p).get("VmRSS", 0.0) for p in process_tree(controller.pid)[1:])
            progress(f"device paused: CPU over {idle_s:.0f} s without bus traffic")
            device.send_signal(signal.SIGSTOP)
            try:
                paused = cpu_windows(controller.pid, idle_s, window_s)
            finally:
                device.send_signal(signal.SIGCONT)
            progress(f"as an arm stack: joint_states subscribed, {open_pairs} x "
                     f"{len(OPEN_SPACINGS_M)} pairs of opening goals, then grasp cycles")
            node.create_subscription(JointState, "joint_states", on_joints, 100)
            time.sleep(1.0)  # the device catches up; discovery of the new subscription
            opens = open_goals(node, states, open_pairs)
            progress(f"{cancels} opening goals cancelled under way")
            cancelled = cancel_goals(node, states, watch, cancels)
            progress(f"{reactions} safety reactions: readings past the limit")
            reacted = safety_reactions(node, states, watch, reactions)
            poses.clear()
            joints.clear()
            arm_end = time.monotonic() + grasp_s / 2
            while time.monotonic() < arm_end:
                one_grasp()
            arm_poses, arm_joints = list(poses), list(joints)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        codes = [stop_process(p, timeout_s=15.0) for p in (controller, device)]
        watch.close()
    if codes[0] != 0:
        raise RuntimeError(f"the controller exited with {codes[0]} (None: killed)")
    all_commands = [v for values in command_latencies.values() for v in values]
    matched = [(published_s, received_s, watch.sensor_frame_before(stamp_s))
               for published_s, received_s, stamp_s in grasp_poses]
    matched = [row for row in matched if row[2] is not None]
    if not all_commands or not matched:
        raise RuntimeError("no latency samples: no valve change or no tip pose was seen")
    if any(published_s <= 0.0 for published_s, _, _ in matched):
        raise RuntimeError("the rmw gave no source timestamp: the publish time cannot be measured")
    to_joints, to_pose_arm = matched_latencies(watch, arm_joints), matched_latencies(
        watch, arm_poses)
    if not (to_joints and to_pose_arm and opens["gripper"] and opens["grasp"]
            and cancelled["latencies_ms"] and cancelled["hold_stamp_ms"]
            and reacted["latencies_ms"]):
        raise RuntimeError(f"as an arm stack: {len(to_joints)} joint_states, {len(to_pose_arm)} "
                           f"poses, opening goals {opens}, cancels {cancelled}, safety "
                           f"reactions {reacted}")
    to_pose = [1e3 * (published_s - sent_s) for published_s, _, sent_s in matched]
    to_received = [1e3 * (received_s - sent_s) for _, received_s, sent_s in matched]
    hops = [1e3 * (received_s - published_s) for published_s, received_s, _ in matched]
    figures = {
        "cmd_to_valve_frame_ms_median": statistics.median(all_commands),
        "cmd_to_valve_frame_ms_p99": p99(all_commands),
        "sensor_to_tip_pose_ms_median": statistics.median(to_pose),
        "sensor_to_tip_pose_ms_p99": p99(to_pose),
        "sensor_to_tip_pose_received_ms_median": statistics.median(to_received),
        "sensor_to_tip_pose_received_ms_p99": p99(to_received),
        "controller_cpu_pct_idle": statistics.median(idle),
        "controller_cpu_pct_grasp": statistics.median(grasp),
        "controller_cpu_pct_device_paused": statistics.median(paused),
        "receive_floor_cpu_pct": floor,
        "receive_floor_cpu_pct_per_frame": floor_per_frame,
        "idle_over_receive_floor": statistics.median(idle) / floor,
        "start_to_ready_s": ready_s[0],
        "controller_rss_mb": memory.get("VmRSS", float("nan")),
        "controller_peak_rss_mb": memory.get("VmHWM", float("nan")),
        "controller_children_rss_mb": children_rss,
        "sensor_to_joint_states_ms_p99": p99(to_joints),
        "sensor_to_tip_pose_arm_ms_p99": p99(to_pose_arm),
        "joint_states_p99_excess_ms": p99(to_joints) - p99(to_pose_arm),
        "gripper_open_s": statistics.median(opens["gripper"]),
        "grasp_open_s": statistics.median(opens["grasp"]),
        "gripper_open_ratio": statistics.median(opens["gripper"]) /
        statistics.median(opens["grasp"]),
        "cancel_to_valve_frame_ms_median": statistics.median(cancelled["latencies_ms"]),
        "cancel_to_valve_frame_ms_p99": p99(cancelled["latencies_ms"]),
        "cancel_to_hold_stamp_ms_median": statistics.median(cancelled["hold_stamp_ms"]),
        "cancel_to_hold_stamp_ms_p99": p99(cancelled["hold_stamp_ms"]),
        "safety_reaction_ms_median": statistics.median(reacted["latencies_ms"]),
        "safety_reaction_ms_p99": p99(reacted["latencies_ms"]),
    }
    details = {
        "cmd_to_valve_frame_ms": {
            k: {
                "n": len(v), "median": statistics.median(v) if v else None,
                "p99": p99(v) if v else None, "max": max(v) if v else None
            }
            for k, v in command_latencies.items()
        },
        "sensor_to_tip_pose_samples": len(to_pose),
        "dds_hop_ms": {"median": statistics.median(hops), "p99": p99(hops), "max": max(hops)},
        "cpu_windows_pct": {"idle": idle, "grasp": grasp, "device_paused": paused},
        "grasp_cycles": cycles,
        "open_goals_s": opens,
        "cancels": cancelled,
        "safety_reactions": reacted,
        "arm_samples": {"joint_states": len(to_joints), "tip_pose": len(to_pose_arm)},
        "reception_clock_offset_ms_median": 1e3 *
        statistics.median(clock_offsets) if clock_offsets else None,
    }
    return figures, details


def against(args) -> int:
    """--against: interleaved pairs, the reference first in each; the table (or --json)."""
    settings = (args.idle_s, args.grasp_s, args.window_s, args.open_pairs, args.cancels,
                args.reactions)
    pairs = {}
    try:
        with reference_checkout(args.against, ROOT) as (commit, environment):
            for run in range(args.runs):
                progress(f"pair {run + 1} of {args.runs}: {args.against} ({commit[:8]})")
                reference, _ = measure(*settings, controller_env=environment)
                progress(f"pair {run + 1} of {args.runs}: this code")
                this, _ = measure(*settings)
                for key in this:
                    pairs.setdefault(key, []).append((reference[key], this[key]))
    except UnknownReference as error:
        print(f"bench_e2e: --against {error}", file=sys.stderr)
        return 2
    if args.json:
        print(strict_json({"against": args.against, "commit": commit, "pairs": pairs}))
    else:
        print(f"{args.runs} interleaved pairs, {args.against} ({commit[:8]}) -> this code "
              f"({machine_line()}):\n")
        print("\n".join(paired_rows(pairs, TARGETS, (args.against, "this code"))))
    return 0


def main(argv=None) -> int:
    parser = benchmark_parser(__doc__, "one short run (2 s idle, 6 s of grasps); writes nothing",
                              load=True)
    parser.add_argument("--idle-s", type=float, default=10.0,
                        help="seconds of idle CPU measurement")
    parser.add_argument("--grasp-s", type=float, default=30.0, help="seconds of grasp cycles")
    parser.add_argument("--window-s", type=float, default=2.0,
                        help="CPU window (median over windows)")
    parser.add_argument("--open-pairs", type=int, default=5,
                        help="pairs of gripper and grasp opening goals per spacing")
    parser.add_argument("--cancels", type=int, default=30,
                        help="opening goals cancelled under way, per run")
    parser.add_argument("--reactions", type=int, default=10,
                        help="safety reactions to readings past the limit, per run")
    parser.add_argument(
        "--runs", type=int, default=3,
        help="whole measurements, each with fresh processes; each figure is the median over them")
    parser.add_argument(
        "--against", metavar="GIT_REF",
        help="A/B: alternate each run of this code with one of the controller at GIT_REF (from "
        "its sources in a temporary git worktree, on this workspace's messages, configuration "
        "and simulated device); prints the pairs, writes nothing")
    args = parser.parse_args(argv)
    if args.quick:
        args.runs, args.idle_s, args.grasp_s, args.window_s, args.open_pairs = 1, 3.0, 6.0, 1.0, 1
        args.cancels, args.reactions = 3, 2
    if args.window_s <= 0 or args.idle_s < 3 * args.window_s or args.grasp_s < 3 * args.window_s:
        parser.error("need --window-s > 0 and at least three windows in --idle-s and --grasp-s")
    if args.runs < 1 or args.open_pairs < 1 or args.cancels < 1 or args.reactions < 1:
        parser.error("need --runs, --open-pairs, --cancels and --reactions >= 1")
    started = time.perf_counter()
    with host_load(args.load):
        if args.against:
            return against(args)
        runs = []
        for run in range(args.runs):
            progress(f"run {run + 1} of {args.runs}")
            runs.append(measure(args.idle_s, args.grasp_s, args.window_s, args.open_pairs,
                                args.cancels, args.reactions))
    # a p99 of one run on a shared 2-core VM moves by a millisecond from run to run: the median of
    # runs
    figures = {key: statistics.median(f[key] for f, _ in runs) for key in runs[0][0]}
    details = {**runs[-1][1], "runs": {key: [f[key] for f, _ in runs] for key in runs[0][0]},
               "load_processes": args.load}
    if args.json or args.quick or args.load:
        print(
            strict_json({**figures, "details": details}) if args.json else "\n".
            join(figure_rows(figures, TARGETS)))
        return 0
    rows = figure_rows(figures, TARGETS)
    per_command = "; ".join(
        f"{k} {v['median']:.2f} ms median, {v['p99']:.2f} ms p99 (n = {v['n']})"
        for k, v in details["cmd_to_valve_frame_ms"].items() if v["n"])
    per_run = "; ".join(f"{key} " + ", ".join(f"{v:.3g}" for v in values)
                        for key, values in details["runs"].items() if key in TARGETS)
    idle_windows = ", ".join(f"{v:.0f}" for v in details["cpu_windows_pct"]["idle"])
    grasp_windows = ", ".join(f"{v:.0f}" for v in details["cpu_windows_pct"]["grasp"])
    notes = (
        f"Each figure is the median over {args.runs} runs (fresh processes each); the runs gave "
        f"{per_run}. "
        "The rest of this section's figures are from the last run.\n\n"
        "**What is measured**\n\n"
        f"- Command to valve frame: {per_command}. From this process over DDS to the grasp "
        "manager, its state "
        "machine, the direct call to the pressure controller (which steps in the calling thread "
        "and sends "
        "the frames at once) and the CAN send.\n"
        f"- Sensor frame to `tip_pose/left`: {details['sensor_to_tip_pose_samples']} poses, "
        "through the frame's "
        "reception, the estimator and kinematics to the publish (the DDS sample's source "
        "timestamp), as the "
        "target is defined; `_received` adds the DDS hop to this process (its reception "
        "timestamp), "
        f"{details['dds_hop_ms']['median']:.2f} ms median and {details['dds_hop_ms']['p99']:.2f} "
        "ms p99 "
        "in the last run. Frames carry their sender's time; this process's bus watch reads them "
        "in batches "
        "every 20 ms and matches poses to frames after the run. The three timestamps come from "
        "this host's one clock.\n"
        "- Until 2026-11-22 `sensor_to_tip_pose_ms` was taken to the reception here, which the "
        "`_received` row now gives; the figures quoted below from before then are that one.\n"
        "- CPU of the controller process (the L2 solver's child included), windows of "
        f"{args.window_s:g} s: "
        f"idle {idle_windows} %; grasping {grasp_windows} %. Grasp cycles: "
        f"{details['grasp_cycles']['done']} "
        f"complete, {details['grasp_cycles']['failed']} not. The simulated device runs in its own "
        "process and "
        "is not counted.\n"
        "- As an arm stack uses it (`joint_states` subscribed too, after the CPU windows): "
        f"`joint_states` p99 {figures['sensor_to_joint_states_ms_p99']:.2f} ms against "
        f"`tip_pose`'s {figures['sensor_to_tip_pose_arm_ms_p99']:.2f} ms from the same estimates "
        f"({details['arm_samples']['joint_states']} and {details['arm_samples']['tip_pose']} "
        "samples; kinematics publishes the joints first). Opening goals from IDLE to 40 and 60 "
        "mm, from acceptance to the result: GripperCommand "
        f"{figures['gripper_open_s']:.3f} s median "
        f"(n = {len(details['open_goals_s']['gripper'])}), "
        f"the Grasp action's OPEN {figures['grasp_open_s']:.3f} s "
        f"(n = {len(details['open_goals_s']['grasp'])}), {details['open_goals_s']['failed']} "
        "failed. The grasp OPEN aims `pressure_tolerance_pa` (1.5 kPa) above the D2's pressure so "
        "that D2 clears an object; the gripper goal aims at it and is judged by "
        "`goal_tolerance_m`.\n"
        f"- Cancels: {len(details['cancels']['latencies_ms'])} opening goals cancelled "
        f"{CANCEL_DELAY_S[0] * 1e3:.0f}-{CANCEL_DELAY_S[1] * 1e3:.0f} ms after their first "
        f"valve frame ({details['cancels']['failed']} failed: "
        f"{'; '.join(details['cancels']['why']) or 'none'}); channel 0 at the end (0 closed, "
        "1 supply, 2 vacuum, 3 vent): "
        + ", ".join(f"{k}: {v}" for k, v in sorted(details["cancels"]["states"].items()))
        + ". From the cancel request sent here over DDS to the action server, the grasp "
        "manager's hold and the CAN send; the opening pulses the supply, so the latency runs "
        "to the frame after its last pulse, and is 0 for the "
        f"{details['cancels']['shut_at_request']} requests that came between pulses and after "
        "which the supply never reopened (the hold closes nothing new then, and the next frame "
        "is only the periodic re-send). The grasp manager's hold was stamped "
        f"{figures['cancel_to_hold_stamp_ms_median']:.1f} ms after the request (median), "
        f"{figures['cancel_to_hold_stamp_ms_p99']:.1f} ms p99, over every cancel.\n"
        f"- Safety reactions: {len(details['safety_reactions']['latencies_ms'])} readings past "
        f"the limit ({details['safety_reactions']['failed']} failed: "
        f"{'; '.join(details['safety_reactions']['why']) or 'none'}): the simulated device's "
        f"readings biased {REACTION_BIAS_PA / 1e3:.0f} kPa while the gripper is held open at "
        f"{REACTION_OPEN_M * 1e3:.0f} mm; from the first frame reading above the limit (55 kPa) "
        "to the first venting ValveCommand, both by their senders' timestamps.\n"
        "- With the device paused (no frames) the controller uses "
        f"{figures['controller_cpu_pct_device_paused']:.0f} %: "
        "the control loop at its 50 Hz rest rate (`rest_rate_hz`) with controller/status at 50 "
        "Hz, the "
        "composed nodes' timer threads, and the estimator's predictions at 50 Hz while no sample "
        "comes. The "
        "rest of the idle figure is the device's ~700 sensor frames a second.\n\n"
        "**On this host, 2026-12-02** (one run each, `--runs 1`)\n\n"
        "- The code of 2026-11-22 (c2c2837), whose committed figures were pose p99 4.14 ms, idle "
        "12.5 %, grasping 32 %, command p99 7.45 ms, ran here at pose p99 11.3 ms, idle 13.0 %, "
        "grasping 40.5 %, command p99 16.9 ms: this host is slower and busier today, and the "
        "latency and CPU targets are missed by the old code too.\n"
        "- The single-fault safety work (#20, fa695e2) in the same session: idle 16.0 %, "
        "grasping 47.8 %, pose p99 12.1 ms. Its monitor checks every reading; its cost is "
        "about 3 % idle and 7 % grasping here (one run each, not interleaved).\n"
        "- The arm-stack interfaces (#22: two more action servers, joint_states) against "
        "fa695e2, 3 interleaved pairs: idle 15.5 -> 17.7, 15.5 -> 16.9, 15.9 -> 15.3 %; "
        "grasping 51.7 -> 54.0, 48.5 -> 52.1, 46.3 -> 47.1 %; device paused 10.0 -> 12.0, "
        "9.0 -> 12.5, 10.0 -> 8.5 %; pose p99 14.7 -> 10.8, 13.5 -> 10.9, 13.6 -> 13.8 ms: "
        "about 1-2 % more CPU, within the host's swing, and no latency change.\n\n"
        "**Doing less at rest** (2026-11-22)\n\n"
        "- The control loop rests at 50 Hz (was 100, `rest_rate_hz`); the estimator fuses a "
        "resting "
        "chamber's samples every 20 ms (was 10, `fusion_window`: every other 10 ms bus batch) and "
        "predicts "
        "such a window in one filter step while the regulator rests too (a fusion took ~320 us of "
        "thread "
        "CPU in the controller: four 5 ms predictions and an update).\n"
        "- Against the code before (02b8aa4), one run each in turn (`--runs 1`), 8 pairs in two "
        "sessions of "
        "4 (medians of each session's 4): idle CPU 14.4 -> 12.5 % and 14.9 -> 13.2 %, lower in "
        "all 8 pairs; "
        "with the device paused 8.5 -> 8.5 % and 9.7 -> 8.0 %; grasping 31.9 -> 33.7 % and 33.2 "
        "-> 33.3 %; "
        "pose p99 4.4 -> 4.9 ms and 4.6 -> 4.4 ms, command-to-valve p99 7.1 -> 7.4 ms and 7.1 -> "
        "7.6 ms: no "
        "difference beyond the host's swing. (The first session ran before the last estimator "
        "commit, "
        "which made a sample fused at once cheaper again.)\n"
        "- Explored first, 3 runs each in sequence: taking the resting batches every 20 ms too "
        "saved a "
        "little more CPU (idle 11.0 %) but raised the pose p99 to 5.7-6.4 ms: ~16 readings then "
        "went "
        "through the estimator before a resting estimate. Traced with temporary timestamps (one "
        "run), 46 of "
        "the 74 slowest poses came from resting batches, whose estimator stage took 2.0 ms "
        "(median of those "
        "74) against 0.26 ms over all poses. Reception stays at 10 ms.\n"
        "- Traced again on the final code (one run, 2506 poses): 53 of the 76 slowest came from "
        "resting "
        "batches; in 33 of them the longest stage was the newest frame's wait for the batch (it "
        "arrives "
        "0-2 ms before the wake; 1.2 ms median in those 76), in 26 the estimator (1.25 ms "
        "median).\n\n"
        "**Where the time goes, and what did not help**\n\n"
        "- Python runs several times slower woken or interleaved with other threads than in a "
        "warm loop: a "
        "frame's decode 5 us in a loop, 11-19 us in the controller; a 20 ms resting batch's "
        "estimator work ~110 us "
        "warm, ~700 us in place. A thread wake costs 45-80 us before any work. So the cost is per "
        "wake and "
        "per call more than per computation, and doing less at rest paid more than faster code.\n"
        "- rclpy's `rcl_publish` keeps the GIL: a DDS publish that blocks (1.5-6 ms seen) stalls "
        "every "
        "thread of the process. The composed nodes therefore pass readings, statuses and "
        "estimates by "
        "direct call and publish a topic only while it has a subscriber.\n"
        "- The L2 solver's child runs 10 above the controller's nice value (`l2_nice_increment`): "
        "in four "
        "pairs of runs the pose p99 was lower with it every time, by 0.05-0.7 ms.\n"
        "- The simulated bus once dropped frames: Unix datagram sockets queue ~10 per receiver, "
        "so a "
        "resting batch that started late lost its newest frames silently. `softgrip_ipc` now runs "
        "on "
        "loopback UDP, which queues hundreds, and counts what a full receiver drops.\n"
        "- Tried and not adopted: a GIL switch interval of 0.1 or 0.5 ms (no change); taking the "
        "resting "
        "batches in the control loop's tick (the same CPU); `gc.freeze()` after start-up (no "
        "change to the pose p99; since adopted in run_node against full collections that "
        "stopped the controller for 92 ms, see CHANGELOG); a "
        "50 ms fusion window (it changes the estimator's lag rule); refilling two preallocated "
        "pose "
        "messages instead of building them (77 against 80 us per pose, warm: not worth a shared "
        "message "
        "and its lock); ending each resting batch on a frame that has just arrived (a second wake "
        "per "
        "batch; 3 pairs: pose p99 3.96 -> 4.12, 4.63 -> 4.69, 4.56 -> 4.17 ms, idle CPU no lower, "
        "paused "
        "+1 %); timing each resting wake to just after the fastest sensor stream's next frame "
        "(its period "
        "and phase learnt from the timestamps; no extra wake): the newest reading's wait for its "
        "batch "
        "fell from 0.66 to 0.41 ms median and 1.66 to 0.75 ms p90 (one traced run each), but in 3 "
        "pairs "
        "the pose p99 went 3.61 -> 3.63, 3.93 -> 3.23, 3.89 -> 4.19 ms and the idle CPU did not "
        "move; "
        "the estimator's silence check sleeping until the silence deadline it knows, instead of "
        "waking "
        "every 20 ms while samples flow: its thread woke 34 instead of 53 times a second (0.53 "
        "against "
        "0.60 % of a core, one run each), but in 8 pairs the idle CPU (mean of the windows) was "
        "higher "
        "with it in 6, by up to 1.2 %.")
    update_section(
        "bench_e2e", "## End to end, the installed controller (`scripts/bench_e2e.py`)\n\n"
        f"Command: `python scripts/bench_e2e.py` ({machine_line()}; {args.idle_s:g} s idle, "
        f"{args.grasp_s:g} s of grasp cycles, {args.runs} runs; latencies as median and p99 over "
        "every "
        f"sample of a run, each figure the median over the runs)\n\n" + "\n".join(rows) + "\n\n" +
        notes)
    print("\n".join(rows))
    print(notes)
    progress(f"done in {time.perf_counter() - started:.0f} s; wrote docs/benchmarks.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())

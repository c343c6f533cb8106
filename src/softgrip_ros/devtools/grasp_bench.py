"""The grasp benchmark (scripts/bench_grasp.py): grasps commanded through the real suite (the
composed ``controller`` with the physics world), judged by what happens to the object.

**Each grasp.** The object is presented (its weight borne) below the gripper, level with the tip
chambers of the fingers opened to clear it (the placement the clamp force law assumes,
:mod:`softgrip_ros.model.force_law`); a sheet hangs between the closed tips. Through the
product's :class:`~softgrip_ros.client.GripperClient`, as a user would: ENVELOP_CLAMP, and once
ENVELOPED the arm comes down around the object, then CLAMP; or PINCH. Once HOLDING, the object's
weight is let go (0.5 s), and the arm lifts 0.2 m at 1 g, shakes +-0.5 g sideways (across the
fingers) for 2 s and holds still for 2 s; then RELEASE. The world's truth
(``sim/grasp_truth``) judges it: held (in the hand throughout, drifting less than
``SLIP_LIMIT_M``), slipped (in the hand, drifted more), dropped; or refused at the command, or
failed (no HOLDING).

**Offline** (the world alone, stepped faster than real time at the clamp pressure a planner
chose, through the same moves): the hold margin, the largest extra mass held, by bisection; and
planners compared at the grasp level (the one-number law with L0 or L1 contact, the L2 tables of
the L0 and L1 laws, the 3-D FE's table of the FE-calibrated model).
"""
from __future__ import annotations

import contextlib
import dataclasses
import enum
import math
import pathlib
import subprocess
import threading
import time
import uuid

import numpy as np
import yaml

from softgrip_ros.estimation.grasp_sensing import ObjectStatus
from softgrip_ros.model.force_law import (ENVELOP_MARGIN_M, PRESSURE_TOLERANCE_PA, ObjectKind,
                                          ROD_ELEMENTS)

SLIP_LIMIT_M = 0.005
OBJECT_HEIGHT_M = 0.2  # the object is presented this far above the floor
APPROACH_M = 0.15  # the gripper starts this far above its grasp height
MOVES = ("settle", "lift", "shake", "hold")
SHAPES = ("cylinder", "sphere", "box", "sheet")


class Outcome(enum.Enum):
    HELD = "held"
    SLIPPED = "slipped"
    DROPPED = "dropped"
    REFUSED = "refused"
    FAILED = "failed"


@dataclasses.dataclass(frozen=True)
class GraspCase:
    shape: str
    size_m: float
    mass_kg: float
    friction: float

    @property
    def mode(self) -> str:
        return "PINCH" if self.shape == "sheet" else "ENVELOP_CLAMP"

    @property
    def kind(self) -> ObjectKind:
        return ObjectKind.FLAT if self.shape == "sheet" else ObjectKind.ROUND

    @property
    def object_class(self) -> str:
        if self.shape == "sheet":
            return "sheet 0.1 mm"
        return f"{self.shape} {self.size_m * 1e3:.0f} mm"


@dataclasses.dataclass
class GraspRecord:
    case: GraspCase
    outcome: Outcome
    message: str = ""
    slip_distance_m: float = math.nan
    cycle_s: float = math.nan
    clamp_pressure_pa: float = math.nan
    rated_mass_kg: float = math.nan
    false_holding_reports: int = 0
    hold_margin_kg: float = math.nan

    @property
    def within_rating(self) -> bool:
        return self.case.mass_kg <= self.rated_mass_kg and self.case.friction >= 0.5

    def as_dict(self) -> dict:
        return {"shape": self.case.shape, "size_m": self.case.size_m,
                "mass_kg": self.case.mass_kg, "friction": self.case.friction,
                "mode": self.case.mode, "object_class": self.case.object_class,
                "outcome": self.outcome.value, "within_rating": self.within_rating,
                "rated_mass_kg": self.rated_mass_kg, "slip_distance_m": self.slip_distance_m,
                "cycle_s": self.cycle_s, "clamp_pressure_pa": self.clamp_pressure_pa,
                "false_holding_reports": self.false_holding_reports,
                "hold_margin_kg": self.hold_margin_kg, "message": self.message}


def verdict_correct(status: ObjectStatus, object_present: bool) -> bool:
    """Whether a closing's verdict agrees with the world: an object found (CONTACT_CLOSING or
    HELD) when one is in the hand, NO_OBJECT when none is; UNKNOWN is never correct."""
    if object_present:
        return status in (ObjectStatus.CONTACT_CLOSING, ObjectStatus.HELD)
    return status == ObjectStatus.NO_OBJECT


@dataclasses.dataclass
class SensedClosing:
    """A closing judged through the suite: its verdict (an ObjectStatus), the felt size (m,
    NaN: none), whether the world had the object in the hand then, the evidence (or why the
    closing failed), and how long after the task's end the verdict came (a goal ends without it
    after the grasp manager's sensing_wait)."""

    case: GraspCase
    status: ObjectStatus
    size_m: float
    object_present: bool
    evidence: str
    verdict_after_task_s: float = 0.0

    @property
    def correct(self) -> bool:
        return verdict_correct(self.status, self.object_present)


# a closing's verdict is waited for this long after the task's end (MOVING_NO_CONTACT until it
# comes); past it the closing counts UNKNOWN
VERDICT_WAIT_S = 10.0

FULL_SIZES_M = (0.005, 0.01, 0.02, 0.04, 0.06, 0.08)
FULL_MASSES_KG = (0.02, 0.05, 0.1, 0.2)
FULL_FRICTIONS = (0.3, 0.5, 0.8)


def grasp_grid(quick: bool = False) -> list:
    """The cases: cylinders and spheres of FULL_SIZES_M, a 30 mm cube and the 0.1 mm sheet, each at
    every mass and friction (quick: the demo's 20 mm rubber cylinder, and an overweight cylinder
    that must be refused)."""
    if quick:
        return [GraspCase("cylinder", 0.02, 0.02, 0.8), GraspCase("cylinder", 0.04, 0.5, 0.5)]
    objects = [(shape, size) for shape in ("cylinder", "sphere") for size in FULL_SIZES_M]
    objects += [("box", 0.03), ("sheet", 1e-4)]
    masses = {shape: ((0.005,) + FULL_MASSES_KG[:2] if shape == "sheet" else FULL_MASSES_KG)
              for shape in SHAPES}
    return [GraspCase(shape, size, mass, mu) for shape, size in objects
            for mass in masses[shape] for mu in FULL_FRICTIONS]


# ---- the scene of a case -----------------------------------------------------------------------
class Placement:
    """Where the benchmark puts the gripper and the object, from the gripper model's kinematics
    and L2 rod (the force law's own placement)."""

    def __init__(self, gripper_model: str = "type_II", bending: str = "l0"):
        from softgrip_ros.model import gripper_models
        from softgrip_ros.model.kinematics import GripperKinematics
        from softgrip_ros.model.rod import RodFinger
        geometry, calibration = gripper_models.resolve(gripper_model)
        self.kinematics = GripperKinematics(geometry, calibration, model=bending)
        self.rod = RodFinger(geometry, calibration, bending=bending,
                             elements_per_segment=ROD_ELEMENTS)

    def opening_pa(self, case: GraspCase) -> float:
        if case.kind == ObjectKind.FLAT:
            return 0.0
        return min(self.kinematics.pressure_for_tip_spacing(case.size_m + ENVELOP_MARGIN_M) +
                   PRESSURE_TOLERANCE_PA, self.kinematics.max_pressure_pa)

    def tip_chamber_depth_m(self, case: GraspCase) -> float:
        """How far below the base the object's centre sits (m)."""
        return float(self.rod.chamber_face_point_m(self.opening_pa(case), 4)[1])

    def scene(self, case: GraspCase) -> dict:
        depth = self.tip_chamber_depth_m(case)
        grasp_z = OBJECT_HEIGHT_M + depth
        envelop = case.kind == ObjectKind.ROUND
        start_z = grasp_z + (APPROACH_M if envelop else 0.0)
        obj = {"shape": case.shape, "mass_kg": case.mass_kg, "friction": case.friction,
               "position_m": [0.0, 0.0, OBJECT_HEIGHT_M], "held_until": "settle"}
        if case.shape in ("cylinder", "sphere"):
            obj["diameter_m"] = case.size_m
        elif case.shape == "box":
            obj["size_m"] = [case.size_m] * 3
        else:
            obj["size_m"] = [0.06, 0.08]
        moves = {"settle": [{"wait_s": 0.5}],
                 "lift": [{"to_m": [0.0, 0.0, grasp_z + 0.2], "accel_m_s2": 9.81}],
                 "shake": [{"shake": {"axis": "x", "accel_m_s2": 4.9, "frequency_hz": 2.0,
                                      "duration_s": 2.0}}],
                 "hold": [{"wait_s": 2.0}]}
        if envelop:
            moves["approach"] = [{"to_m": [0.0, 0.0, grasp_z], "accel_m_s2": 3.0,
                                  "max_speed_m_s": 0.4}]
        return {"format": "softgrip_scene/1",
                "name": f"{case.object_class} {case.mass_kg * 1e3:g} g mu {case.friction:g}",
                "object": obj, "arm": {"start_m": [0.0, 0.0, start_z], "moves": moves}}


def write_scene(document: dict, directory) -> pathlib.Path:
    path = pathlib.Path(directory) / f"scene_{abs(hash(document['name'])):x}.yaml"
    path.write_text(yaml.safe_dump(document, sort_keys=False))
    return path


# ---- through the suite --------------------------------------------------------------------------
class SuiteRig:
    """The composed controller with the physics world in its own process, and this process's
    client: the product's GripperClient, and the ground truth's subscriptions and services."""

    def __init__(self, first_scene: pathlib.Path, channel: str, log_path: pathlib.Path,
                 gripper_model: str = "type_II", parameters: tuple = (),
                 device_apart: bool = False):
        """``parameters``: more ``name:=value`` settings of the controller's nodes;
        ``device_apart``: the simulated device and its world in a ``sim_device`` process of their
        own, on a softgrip_ipc bus (as a real device has its own processor), not in the
        controller's."""
        import rclpy
        from rclpy.node import Node

        from softgrip_interfaces.msg import GraspTruth, GripperState
        from softgrip_interfaces.srv import LoadScene, PlayArmMove
        from softgrip_ros.client import GripperClient
        from softgrip_ros.devtools.processes import installed_executable
        from softgrip_ros.nodes.common import spinning

        self.log = open(log_path, "w+")  # the caller's directory: it goes when that does
        world = ("-p", f"world.scene:={first_scene}")
        bus = ("-p", f"can.channel:={channel}") + (
            ("-p", "can.interface:=softgrip_ipc") if device_apart else ())
        self.device_process = subprocess.Popen(
            [installed_executable("sim_device"), "--ros-args", *bus, *world],
            stdout=self.log, stderr=subprocess.STDOUT, text=True) if device_apart else None
        self.process = subprocess.Popen(
            [installed_executable("controller"), "--ros-args", *bus,
             *(() if device_apart else world), "-p", f"gripper_model:={gripper_model}",
             *(word for setting in parameters for word in ("-p", setting))],
            stdout=self.log, stderr=subprocess.STDOUT, text=True)
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = Node("bench_grasp", context=self.context)
        self.client = GripperClient(context=self.context)
        self._lock = threading.Lock()
        self.truth = None
        self.states = []  # (phase, truth state) pairs since the last mark
        self.node.create_subscription(GraspTruth, "sim/grasp_truth", self._on_truth, 50)
        self.node.create_subscription(GripperState, "grasp_state", self._on_state, 50)
        self.play_client = self.node.create_client(PlayArmMove, "sim/play_arm_move")
        self.load_client = self.node.create_client(LoadScene, "sim/load_scene")
        # the package's spinner stops its loop before the executor shuts down: executor.spin in
        # a thread raced with shutdown() (InvalidHandle on its guard condition, seen in CI)
        self._spinning = contextlib.ExitStack()
        self._spinning.enter_context(spinning(self.node, context=self.context, threads=1))
        self.GripperState, self.GraspTruth = GripperState, GraspTruth
        self.LoadScene, self.PlayArmMove = LoadScene, PlayArmMove

    def _on_truth(self, message) -> None:
        with self._lock:
            self.truth = message

    def _on_state(self, message) -> None:
        with self._lock:
            truth = self.truth
            self.states.append((message.phase, truth.state if truth is not None else None))

    def wait_ready(self, timeout_s: float = 30.0) -> None:
        if not self.client.wait_until_ready(timeout_s=timeout_s):
            raise RuntimeError(f"the controller did not come up in {timeout_s:.0f} s; the "
                               f"end of its log:\n{self.log_tail()}")
        for service in (self.play_client, self.load_client):
            if not service.wait_for_service(timeout_sec=timeout_s):
                raise RuntimeError("the simulated device serves no world (sim/ services)")
        self._wait(lambda: self.truth is not None, 5.0)

    def log_tail(self, lines: int = 30) -> str:
        """The last ``lines`` lines the controller wrote."""
        self.log.flush()
        return "\n".join(pathlib.Path(self.log.name).read_text().splitlines()[-lines:])

    def close(self) -> None:
        from softgrip_ros.devtools.processes import stop_process
        import rclpy
        try:
            self.client.close()
            self._spinning.close()
            self.node.destroy_node()
        finally:
            rclpy.try_shutdown(context=self.context)
            stop_process(self.process)
            if self.device_process is not None:
                stop_process(self.device_process)
            self.log.close()

    @staticmethod
    def _wait(condition, timeout_s: float, period_s: float = 0.01) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if condition():
                return True
            time.sleep(period_s)
        return False

    def _call(self, client, request, timeout_s: float = 10.0):
        future = client.call_async(request)
        if not self._wait(future.done, timeout_s):
            raise RuntimeError(f"no answer from {client.srv_name} in {timeout_s:.0f} s")
        return future.result()

    def load(self, scene_path: pathlib.Path) -> None:
        answer = self._call(self.load_client, self.LoadScene.Request(scene_file=str(scene_path)))
        if not answer.accepted:
            raise RuntimeError(f"sim/load_scene refused {scene_path}: {answer.message}")
        self._wait(lambda: self.truth is not None and self.truth.world_time_s < 0.5, 5.0)

    def play(self, move: str) -> None:
        answer = self._call(self.play_client, self.PlayArmMove.Request(move=move))
        if not answer.accepted:
            raise RuntimeError(f"sim/play_arm_move refused {move!r}: {answer.message}")

    def play_through(self, *moves: str, timeout_s: float = 30.0) -> None:
        """Play ``moves`` and wait until the arm has played them all (seen moving, then at
        rest)."""
        for move in moves:
            self.play(move)
        if not self._wait(lambda: self.truth.arm_move != "", 2.0):
            raise TimeoutError(f"the arm did not start {moves[0]!r}")
        if not self._wait(self.arm_idle, timeout_s):
            raise TimeoutError(f"the arm did not finish {moves}")

    def phase(self) -> int | None:
        state = self.client.state()
        return None if state is None else state.phase

    def arm_idle(self) -> bool:
        return self.truth is not None and self.truth.arm_move == ""

    def _close_around(self, case: GraspCase) -> None:
        """After an ENVELOP_CLAMP: ENVELOPED, the arm's approach, then CLAMP (a PINCH: nothing);
        TimeoutError when the gripper does not follow."""
        S = self.GripperState
        if case.mode != "PINCH":
            if not self._wait(lambda: self.phase() == S.ENVELOPED, 8.0):
                raise TimeoutError(f"no ENVELOPED (phase {self.phase()})")
            self.play_through("approach")
            if not self.client.clamp():
                raise TimeoutError("CLAMP refused")

    def run(self, case: GraspCase, scene_path: pathlib.Path, rated_mass_kg: float) -> GraspRecord:
        """One grasp (see the module docstring); the gripper is vented and IDLE afterwards."""
        S = self.GripperState
        self.load(scene_path)
        record = GraspRecord(case, Outcome.FAILED, rated_mass_kg=rated_mass_kg)
        started = time.monotonic()
        with self._lock:
            self.states = []
        mu = {"friction_coefficient": case.friction}
        command_id = f"bench-{uuid.uuid4().hex[:8]}"
        if case.mode == "PINCH":
            sent = self.client.pinch(case.size_m, case.mass_kg, command_id=command_id, **mu)
        else:
            sent = self.client.envelop_clamp(case.size_m, case.mass_kg, command_id=command_id,
                                             **mu)

        def answered():
            state = self.client.state()
            return state is not None and state.command_id == command_id and (
                state.command_rejected or state.phase != S.IDLE)

        if not sent or not self._wait(answered, 5.0) or self.client.state().command_rejected:
            record.outcome = Outcome.REFUSED
            record.message = self.client.state().message if self.client.state() else ""
            record.cycle_s = time.monotonic() - started
            return record
        try:
            self._close_around(case)
            if not self._wait(lambda: self.phase() in (S.HOLDING, S.FAULT), 8.0) or \
                    self.phase() != S.HOLDING:
                raise TimeoutError(f"no HOLDING (phase {self.phase()}: "
                                   f"{self.client.state().message})")
            record.clamp_pressure_pa = self.client.state().target_gauge_pressure_pa
            with self._lock:
                self.states = []
            self.play_through(*MOVES)
            time.sleep(0.1)
            truth = self.truth
            record.slip_distance_m = truth.slip_distance_m
            if truth.dropped or not truth.object_in_hand:
                record.outcome = Outcome.DROPPED
            elif truth.slip_distance_m > SLIP_LIMIT_M:
                record.outcome = Outcome.SLIPPED
            else:
                record.outcome = Outcome.HELD
            with self._lock:
                record.false_holding_reports = sum(
                    1 for phase, world in self.states
                    if phase == S.HOLDING and world == self.GraspTruth.DROPPED)
            record.message = self.client.state().message
        except (TimeoutError, RuntimeError) as error:
            record.outcome, record.message = Outcome.FAILED, str(error)
        finally:
            self.client.release()
            self._wait(lambda: self.phase() == S.IDLE, 8.0)
            record.cycle_s = time.monotonic() - started
            self.client.stop()
            self._wait(lambda: self.phase() == S.IDLE, 5.0)
            time.sleep(0.3)  # vented: the next world starts from rest
        return record

    def sense_closing(self, case: GraspCase, scene_path: pathlib.Path) -> SensedClosing:
        """One closing with the grasp manager's object sensing on (see :class:`SuiteRig`'s
        ``parameters``): ``case``'s grasp in the scene at ``scene_path`` (which may hold no
        object), its verdict (waited for up to VERDICT_WAIT_S after the task's end; UNKNOWN
        when none came) against the world's truth; the gripper is vented and IDLE afterwards."""
        S = self.GripperState
        self.load(scene_path)
        command_id = f"sense-{uuid.uuid4().hex[:8]}"
        sent = (self.client.pinch(case.size_m, case.mass_kg, command_id=command_id)
                if case.mode == "PINCH" else
                self.client.envelop_clamp(case.size_m, case.mass_kg, command_id=command_id,
                                          friction_coefficient=case.friction))
        closing = SensedClosing(case, ObjectStatus.UNKNOWN, math.nan, False, "")
        try:
            if not sent:
                raise RuntimeError("the grasp was not accepted")
            self._close_around(case)
            if not self._wait(self.client.is_task_complete, 12.0):
                raise TimeoutError(f"the task did not end (phase {self.phase()})")
            ended = time.monotonic()
            # the goal waits sensing_wait for the closing's verdict, then ends without it: on
            # a loaded host the judgement comes later, and it is the verdict that is benched
            judged = self._wait(lambda: self.client.object_status()[0] !=
                                ObjectStatus.MOVING_NO_CONTACT, VERDICT_WAIT_S)
            status, size = self.client.object_status()
            truth = self.truth
            closing = SensedClosing(case, status, size, bool(truth.object_in_hand),
                                    self.client.state().message, time.monotonic() - ended)
            if not judged:
                closing.status = ObjectStatus.UNKNOWN
                closing.evidence = (f"no verdict {VERDICT_WAIT_S:.0f} s after the task ended "
                                    f"({closing.evidence})")
        except (TimeoutError, RuntimeError) as error:
            closing.evidence = f"failed: {error}"
        finally:
            self.client.release()
            self._wait(lambda: self.phase() == S.IDLE, 8.0)
            self.client.stop()
            self._wait(lambda: self.phase() == S.IDLE, 5.0)
            time.sleep(0.3)
        return closing

    def product_sim_subscribers(self) -> list:
        """The subscriptions to the ground-truth topics of any node but this benchmark's: none
        may exist (the product never reads the world)."""
        others = []
        for topic in ("sim/object_pose", "sim/contacts", "sim/grasp_truth"):
            for info in self.node.get_subscriptions_info_by_topic(topic):
                if info.node_name != self.node.get_name():
                    others.append(f"{info.node_namespace.rstrip('/')}/{info.node_name} on {topic}")
        return others

    def world_load(self) -> tuple[float, float]:
        truth = self.truth
        return (truth.world_cpu_s, truth.world_time_s) if truth is not None else (0.0, 0.0)


# ---- offline: the world alone ------------------------------------------------------------------
def hold_in_world(finger, scene_document: dict, opening_pa: float, clamp_pa: float,
                  mass_kg: float | None = None) -> tuple[Outcome, float, float]:
    """(outcome, slip distance m, world CPU s per simulated s) of the case's scene held at
    ``clamp_pa``: the fingers start opened at ``opening_pa`` around the object (the approach
    done), close to the clamp over 0.3 s, settle 0.3 s, then the moves. ``mass_kg`` replaces the
    object's mass. FAILED: the object does not fit between the opened fingers where it is
    placed."""
    from softgrip_ros.model.world.scene import scene_from_document
    from softgrip_ros.model.world.world import GraspTruthState, GripperWorld

    document = yaml.safe_load(yaml.safe_dump(scene_document))
    if mass_kg is not None:
        document["object"]["mass_kg"] = float(mass_kg)
    moves = document["arm"]["moves"]
    if "approach" in moves:
        document["arm"]["start_m"] = moves["approach"][0]["to_m"]
    from softgrip_ros.model.world.scene import SceneError
    try:
        world = GripperWorld(scene_from_document(document), finger, start_pressure_pa=opening_pa)
    except SceneError:
        return Outcome.FAILED, math.nan, math.nan
    for fraction in np.linspace(0.0, 1.0, 300):
        world.set_pressure(opening_pa + fraction * (clamp_pa - opening_pa))
        world.advance_to(world.time_s + 1e-3)
    world.advance_to(world.time_s + 0.3)
    if not world.in_hand():
        return Outcome.DROPPED, math.nan, world.cpu_s / max(world.time_s, 1e-9)
    for move in MOVES:
        world.play(move)
    while world.arm.moving:
        world.advance_to(world.time_s + 0.05)
    truth = world.truth()
    rate = world.cpu_s / max(world.time_s, 1e-9)
    if truth.state in (GraspTruthState.DROPPED, GraspTruthState.FREE) or not all(truth.touching):
        return Outcome.DROPPED, truth.slip_distance_m, rate
    if truth.slip_distance_m > SLIP_LIMIT_M:
        return Outcome.SLIPPED, truth.slip_distance_m, rate
    return Outcome.HELD, truth.slip_distance_m, rate


def hold_margin_kg(finger, scene_document: dict, opening_pa: float, clamp_pa: float,
                   mass_kg: float, iterations: int = 6) -> float:
    """The largest extra mass (kg) the clamp at ``clamp_pa`` holds through the moves, by
    bisection in the world between ``mass_kg`` and the first failing doubling; NaN when
    ``mass_kg`` itself is not held."""
    def holds(mass):
        return hold_in_world(finger, scene_document, opening_pa, clamp_pa, mass)[0] == \
            Outcome.HELD

    if not holds(mass_kg):
        return math.nan
    low, high = mass_kg, 2.0 * mass_kg
    while holds(high):
        low, high = high, 2.0 * high
        if high > 20.0:
            return high - mass_kg
    for _ in range(iterations):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if holds(middle) else (low, middle)
    return low - mass_kg


# ---- planners at the grasp level ----------------------------------------------------------------
class Planner:
    """A clamp pressure for a case, or None when the planner refuses it (too heavy)."""

    def __init__(self, name: str, plan, min_gauge_pa: float = -60e3):
        self.name, self._plan, self.min_gauge_pa = name, plan, min_gauge_pa

    def clamp_pa(self, case: GraspCase) -> float | None:
        pressure = self._plan(case)
        if pressure is None or not math.isfinite(pressure) or pressure < self.min_gauge_pa:
            return None
        return pressure


def planners(gripper_model: str = "type_II") -> list:
    """The grasp-level planners compared: the paper's one-number law with the L0 or L1 contact
    pressure, the tabulated L2 law of the L0 and L1 bending laws, and the 3-D FE's table of the
    FE-calibrated model."""
    from softgrip_ros.model.calibration import build_kinematics
    from softgrip_ros.model.force_law import ClampForceLaw, load_table
    from softgrip_ros.model.grasp import OneNumberClampLaw

    result = []
    one_number = OneNumberClampLaw()
    for law in ("l0", "l1"):
        kinematics = build_kinematics(law, gripper_model)

        def contact(case, kinematics=kinematics):
            low, _ = kinematics.tip_spacing_range_m()
            return (kinematics.contact_pressure_pa if case.size_m <= low else
                    kinematics.pressure_for_tip_spacing(case.size_m))

        result.append(Planner(f"one-number law, {law.upper()} contact",
                              lambda case, contact=contact: one_number.clamp_pressure_pa(
                                  case.mass_kg, contact(case), case.friction)))
    for model, law, name in ((gripper_model, "l0", "L2 table (L0 law)"),
                             (gripper_model, "l1", "L2 table (L1 law)"),
                             ("type_II_fe", "l0", "the FE's table (type_II_fe)")):
        clamp_law = ClampForceLaw(load_table(model, law))

        def plan(case, clamp_law=clamp_law):
            return clamp_law.clamp_pressure_pa(case.mass_kg, case.size_m, case.kind,
                                               case.friction)

        result.append(Planner(name, plan))
    return result


def rated_mass_kg(clamp_law, case: GraspCase, min_gauge_pa: float = -60e3) -> float:
    """The most the law plans to hold of the case's object at the pressure limit, with the
    case's friction and the law's safety factor (NaN: out of its reach)."""
    force = clamp_law.normal_force_n(min_gauge_pa, case.size_m, case.kind)
    if not math.isfinite(force):
        return math.nan
    return clamp_law.mass_held_kg(force, case.friction)


def free_bending_max_err_mm(gripper_model: str = "type_II", bending: str = "l0") -> float:
    """The world's free fingers against the kinematics, -60 to +50 kPa: the largest tip or D2
    error (mm)."""
    from softgrip_ros.model import gripper_models
    from softgrip_ros.model.calibration import build_kinematics
    from softgrip_ros.model.world.fingers import PseudoRigidFinger
    from softgrip_ros.model.world.scene import scene_from_document
    from softgrip_ros.model.world.world import GripperWorld

    finger = PseudoRigidFinger(*gripper_models.resolve(gripper_model), bending=bending)
    world = GripperWorld(scene_from_document({"name": "free", "arm": {"start_m": [0, 0, 0.3]}}),
                         finger, fingers_collide=False)
    kinematics = build_kinematics(bending, gripper_model)
    worst = 0.0
    for pressure in np.linspace(-60e3, 50e3, 12):
        start = world.pressure_pa
        for fraction in np.linspace(0.0, 1.0, 200):
            world.set_pressure(start + fraction * (pressure - start))
            world.advance_to(world.time_s + 1e-3)
        world.advance_to(world.time_s + 0.5)
        tip, d2 = kinematics.free_shape(float(pressure))
        tips = world.in_gripper_frame(world.tip_points_m())
        faces = world.in_gripper_frame(world.face_points_m())
        worst = max(worst, math.hypot(tips[0, 0] - tip[0], tips[0, 1] - tip[1]),
                    abs(faces[1, 4, 0] - faces[0, 4, 0] - d2))
    return 1e3 * worst

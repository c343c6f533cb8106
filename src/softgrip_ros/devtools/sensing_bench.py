"""Grasp sensing judged in the physics world, offline (scripts/bench_grasp.py's sensing part and
the tests): the product's grasp state machine, its link to the sensing and the pressure
controller, closed around the plant and the world without CAN or ROS; the sensors read with the
simulated device's noise and rates (and its faults, when a trial injects one); the state
machine fed the estimator's estimate. Nothing the product reads comes from the world.

A trial: an ENVELOP_CLAMP (the gripper opens above the object, the arm comes down around it,
CLAMP) or a PINCH of the case's object, or of nothing; once HOLDING has been judged the object's
weight is let go and the trial's events run: arm moves, a force pulling the object out, a fault.
The world's truth says whether and when the object left the hand (moved ``LOSS_DISTANCE_M``
from where the fingers held it once its weight was let go, or out of both fingers from some
instant to the trial's end).
"""
from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from softgrip_ros.canbus.sim_device import DEFAULT_SENSORS
from softgrip_ros.control.grasp_fsm import (GraspConfig, GraspMode, GraspRequest,
                                            GraspStateMachine, Phase)
from softgrip_ros.control.faults import fault_text
from softgrip_ros.control.object_sensing import ObjectSensingLink
from softgrip_ros.control.pressure import PressureControlConfig, PressureController
from softgrip_ros.devtools.grasp_bench import GraspCase, Placement, verdict_correct
from softgrip_ros.estimation.estimator import PressureEstimator
from softgrip_ros.estimation.grasp_sensing import (ContactModel, GraspSensing, ObjectStatus,
                                                   SensorNoise, judge_motion)
from softgrip_ros.model.pneumatics import P_ATM_PA, PlantInputs, PneumaticPlant, Valve

STEP_S = 1.0e-3
CONTROL_PERIOD_STEPS = 2  # 500 Hz
REGULATOR_REPORT_STEPS = 10
FSM_PERIOD_STEPS = 5
COMMAND_REPEAT_S = 0.2
LOSS_DISTANCE_M = 0.005
TIMEOUT_S = 8.0  # a grasp that has not reached HOLDING by then failed
START_S = 0.3  # the estimator has settled: the grasp is commanded
SETTLE_S = 0.5  # the object's weight let go: its place in the hand is the reference after

# a single fault of the simulated device's kinds, as the offline trial injects it
FAULTS = {
    "bias_plus_20kPa": {"bias_pa": 20e3},
    "bias_minus_20kPa": {"bias_pa": -20e3},
    "bias_plus_1kPa": {"bias_pa": 1e3},
    "chamber_a_stuck_present": {"stuck": "chamber_a"},
    "chamber_b_stuck_present": {"stuck": "chamber_b"},
    "chamber_a_stuck_high": {"stuck": "chamber_a", "stuck_at": 40e3},
    "chamber_b_stuck_low": {"stuck": "chamber_b", "stuck_at": -40e3},
    "dropout_chamber_a": {"dropout": "chamber_a"},
    "noise_x10": {"noise_scale": 10.0},
    "valve_stuck_open": {"valve_stuck_open": True},
    "regulator_overshoot": {"overshoot_pa": 100e3},
}


@dataclasses.dataclass(frozen=True)
class Trial:
    """One grasp to run. ``case`` None: nothing, the gripper opened as for ``opened_for`` (None:
    a pinch). ``clamp_pa``: the clamp pressure override (NaN: the force law's plan). After the
    hold is judged: ``moves`` (the scene's arm moves, in turn), a downward pull on the object
    ramping at ``pull_n_per_s`` up to ``pull_max_n``, ``fault`` (a key of FAULTS) injected
    ``fault_after_s`` in, and the trial ends ``hold_s`` after the hold began."""

    case: GraspCase | None
    opened_for: GraspCase | None = None
    clamp_pa: float = math.nan
    moves: tuple = ()
    pull_n_per_s: float = 0.0
    pull_max_n: float = 0.0
    fault: str = ""
    fault_after_s: float = 0.5
    hold_s: float = 0.3
    seed: int = 0
    label: str = ""

    @property
    def name(self) -> str:
        if self.label:
            return self.label
        if self.case is not None:
            return self.case.object_class
        return (f"nothing, opened for {self.opened_for.object_class}" if self.opened_for
                else "nothing, pinch")


@dataclasses.dataclass
class TrialResult:
    """What happened: the closing's verdict and the final one; whether the world had the object
    when the hold was judged; when it left the hand (s, NaN: never) and when LOST was first
    reported (s, NaN: never); the LOST reports while the object was still held; the CPU spent
    judging motions (s)."""

    trial: Trial
    reached_hold: bool
    closing_status: ObjectStatus
    closing_size_m: float
    final_status: ObjectStatus
    object_present: bool
    loss_time_s: float
    lost_report_s: float
    false_lost: int
    judge_cpu_s: float
    evidence: str
    message: str

    @property
    def true_size_m(self) -> float:
        return self.trial.case.size_m if self.trial.case is not None else 0.0

    @property
    def closing_correct(self) -> bool:
        """The closing's verdict agrees with the world (see verdict_correct)."""
        return verdict_correct(self.closing_status, self.object_present)


def sensor_noise() -> dict:
    """The simulated device's sensors as the sensing sees them."""
    return {s.name: SensorNoise(s.noise_std_pa, s.rate_hz) for s in DEFAULT_SENSORS}


def run_trial(model: ContactModel, trial: Trial, placement: Placement | None = None,
              config: GraspConfig | None = None) -> TrialResult:
    """Run ``trial`` (see the module); ValueError for an unknown fault."""
    from softgrip_ros.model import gripper_models
    from softgrip_ros.model.kinematics import GripperKinematics
    from softgrip_ros.model.world.fingers import PseudoRigidFinger
    from softgrip_ros.model.world.scene import scene_from_document
    from softgrip_ros.model.world.world import GripperWorld

    if trial.fault and trial.fault not in FAULTS:
        raise ValueError(f"unknown fault {trial.fault!r}; known: {', '.join(FAULTS)}")
    placement = placement or Placement()
    shaped = trial.case or trial.opened_for
    if shaped is not None:
        document = placement.scene(shaped)
    else:
        document = {"name": "empty pinch", "arm": {"start_m": [0.0, 0.0, 0.3]},
                    "object": None}
    if trial.case is None:
        document.pop("object", None)
    envelop = shaped is not None and shaped.mode == "ENVELOP_CLAMP"
    geometry, calibration = gripper_models.resolve("type_II")
    finger = PseudoRigidFinger(geometry, calibration, bending="l0")
    world = GripperWorld(scene_from_document(document), finger, plant=model.plant)
    plant = PneumaticPlant(model.plant)
    state = plant.initial_state(0.0)
    controller = PressureController(PressureControlConfig())
    controller.active = True
    estimator = PressureEstimator(plant=PneumaticPlant(model.plant))
    fsm = GraspStateMachine(GripperKinematics(geometry, calibration, model="l0"),
                            config or GraspConfig(hold_air="trap"))
    sensing = GraspSensing(model, sensor_noise())
    judge_cpu = [0.0]

    def run(job, done):
        started = time.process_time()
        result = judge_motion(model, job)
        judge_cpu[0] += time.process_time() - started
        done(result)

    link = ObjectSensingLink(fsm, sensing, run)
    rng = np.random.default_rng(trial.seed)
    periods = [max(1, round(1.0 / (s.rate_hz * STEP_S))) for s in DEFAULT_SENSORS]
    inputs = PlantInputs(0.0, True, (Valve.CLOSED,))
    fault: dict = {}
    stuck_values: dict = {}
    sent_request, last_sent_s, sent_inputs = None, -math.inf, None
    size = shaped.size_m if shaped is not None else 1e-4
    mass = trial.case.mass_kg if trial.case is not None else 0.02
    friction = trial.case.friction if trial.case is not None else 0.8
    if envelop:
        first = GraspRequest(GraspMode.ENVELOP_CLAMP, object_diameter_m=size,
                             object_mass_kg=mass, friction_coefficient=friction,
                             clamp_pressure_pa=trial.clamp_pa)
    else:
        first = GraspRequest(GraspMode.PINCH, object_diameter_m=min(size, 1e-4),
                             object_mass_kg=mass, friction_coefficient=friction,
                             clamp_pressure_pa=trial.clamp_pa)
    stage, hold_start, pull_start, clamp_sent = "start", math.nan, math.nan, False
    dropped_since = math.nan
    gauge_estimate = math.nan
    moves = list(trial.moves)
    loss_time = lost_report = math.nan
    false_lost, reached_hold, present = 0, False, False
    closing_status, closing_size = ObjectStatus.UNKNOWN, math.nan
    hold_reference = None
    end_s, i = TIMEOUT_S, 0
    while True:
        i += 1
        now = i * STEP_S
        if now > end_s:
            break
        phase = fsm.state.phase
        # ---- the arm, as a user's program would run it; every command followed by the link
        if stage == "start" and now >= START_S:
            fsm.command(first, now)
            link.after(now, gauge_estimate)
            stage = "grasp"
        elif stage == "grasp":
            if envelop and phase == Phase.ENVELOPED and not clamp_sent:
                world.play("approach")
                clamp_sent = True
                stage = "approach"
            elif phase == Phase.HOLDING:
                stage = "judge"
        elif stage == "approach" and not world.arm.moving:
            fsm.command(GraspRequest(GraspMode.CLAMP), now)
            link.after(now, gauge_estimate)
            stage = "grasp"
        elif stage == "judge" and fsm._closing_judged:
            reached_hold = True
            closing_status, closing_size = fsm.state.object_status, fsm.state.object_size_m
            present = trial.case is not None and world.in_hand()
            hold_start, stage = now, "hold"
            end_s = now + trial.hold_s
            if world.scene.object is not None:
                world.play("settle")
        elif stage == "hold":
            if moves and not world.arm.moving and now - hold_start > SETTLE_S:
                world.play(moves.pop(0))
            if trial.pull_max_n > 0.0 and now - hold_start > SETTLE_S + 0.1:
                if math.isnan(pull_start):
                    pull_start = now
                force = min(trial.pull_max_n, trial.pull_n_per_s * (now - pull_start))
                world.push_object((0.0, 0.0, -force))
            if trial.fault and not fault and now - hold_start >= trial.fault_after_s:
                fault = dict(FAULTS[trial.fault])
            if present and hold_reference is None and now - hold_start >= SETTLE_S:
                hold_reference = world.object_in_hand_m()
            if present and math.isnan(loss_time) and i % 5 == 0:
                moved = (np.linalg.norm(world.object_in_hand_m() - hold_reference)
                         if hold_reference is not None else 0.0)
                dropped = world.truth().state.name == "DROPPED"
                dropped_since = (now if dropped and math.isnan(dropped_since) else
                                 dropped_since if dropped else math.nan)
                if moved > LOSS_DISTANCE_M:
                    loss_time = now
        # ---- sensors
        gauge = state.chamber_pa[0] - P_ATM_PA
        for sensor, period in zip(DEFAULT_SENSORS, periods):
            if i % period or fault.get("dropout") == sensor.name:
                continue
            if fault.get("stuck") == sensor.name:
                reading = fault.get("stuck_at", stuck_values.get(sensor.name, gauge))
            else:
                reading = (gauge + fault.get("bias_pa", 0.0) + fault.get("noise_scale", 1.0) *
                           sensor.noise_std_pa * rng.standard_normal())
                stuck_values[sensor.name] = reading
            controller.update_sensor(sensor.name, reading, now)
            estimator.add_measurement(sensor.name, reading, now)
            link.reading(sensor.name, now, reading)
        if i % REGULATOR_REPORT_STEPS == 0:
            controller.update_regulator_status(state.regulator_gauge_pa, 0)
        # ---- the state machine and the controller
        if i % CONTROL_PERIOD_STEPS == 0:
            request = fsm.request
            if request != sent_request or now - last_sent_s > COMMAND_REPEAT_S:
                controller.command(request.target_gauge_pa, request.source, math.nan, now)
                sent_request, last_sent_s = request, now
            out = controller.step(now)
            valves = (Valve.SUPPLY,) if fault.get("valve_stuck_open") else out.valves
            inputs = PlantInputs(out.regulator_setpoint_gauge_pa, out.regulator_enabled, valves,
                                 fault.get("overshoot_pa", 0.0))
            key = (out.regulator_setpoint_gauge_pa, out.regulator_enabled, out.valves)
            if key != sent_inputs:
                sent_inputs = key
                link.controller_outputs(now, out.regulator_setpoint_gauge_pa,
                                        out.regulator_enabled, int(out.valves[0]))
                estimator.set_inputs(out.regulator_setpoint_gauge_pa, out.regulator_enabled,
                                     int(out.valves[0]), now)
        if i % FSM_PERIOD_STEPS == 0:
            estimate = estimator.estimate(now) if estimator.initialised else None
            gauge_estimate = estimate.gauge_pa if estimate is not None else math.nan
            fault_now = fault_text(int(out.fault_flags))
            fsm.update(now, gauge_estimate, controller_fault=fault_now)
            link.after(now, gauge_estimate, fault_now)
            status = fsm.state.object_status
            if stage == "hold" and status == ObjectStatus.LOST and math.isnan(lost_report):
                lost_report = now
                if math.isnan(loss_time):
                    false_lost += 1
        # ---- the air and the world
        state = plant.advance(state, inputs, STEP_S)
        world.set_pressure(float(state.chamber_pa[0] - P_ATM_PA))
        if world.advance_to(now):
            state = plant.with_volume_offset(state, [world.volume_offset_m3()])
    if math.isnan(loss_time) and math.isfinite(dropped_since):
        loss_time = dropped_since  # out of the hand at the end, and since then
    return TrialResult(trial, reached_hold, closing_status, closing_size,
                       fsm.state.object_status, present, loss_time, lost_report,
                       false_lost, judge_cpu[0], fsm.state.object_evidence, fsm.state.message)



"""Grasp sensing judged in the physics world, offline (scripts/bench_grasp_sensing.py and the
tests): the pressure controller closed around the plant and the world, without CAN or ROS, the
sensors read with the simulated device's noise and rates, and the closing's verdict
(:mod:`softgrip_ros.estimation.grasp_sensing`) set against what the world says happened.

Each trial starts steady, opened as the grasp would open for its object (a sheet or a pinch:
at 0 Pa), the object presented level with the tip chambers (its weight borne); then the clamp
is commanded and the air is recorded until ``settle_s`` after it. Nothing the detector reads
comes from the world: only the sensor readings and the controller's outputs.
"""
from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from softgrip_ros.canbus.sim_device import DEFAULT_SENSORS
from softgrip_ros.control.pressure import PressureControlConfig, PressureController, Source
from softgrip_ros.devtools.grasp_bench import GraspCase, Placement
from softgrip_ros.estimation.grasp_sensing import (AirRecord, ContactModel, Detection,
                                                   ObjectStatus, fit_contact, judge_closing)
from softgrip_ros.model.pneumatics import P_ATM_PA, PlantInputs, PneumaticPlant, Valve

STEP_S = 1.0e-3
CONTROL_PERIOD_STEPS = 2  # 500 Hz
REGULATOR_REPORT_STEPS = 10
START_S = 0.3  # steady at the opening before the clamp


@dataclasses.dataclass(frozen=True)
class SensingTrial:
    """One closing: the case (None: nothing between the fingers, opened as for
    ``opened_for``), whether the world had the object in both fingers at the end, its size (m),
    the verdict, and the fit's CPU time (s)."""

    label: str
    object_present: bool
    true_size_m: float
    detection: Detection
    fit_cpu_s: float


def closing_trial(model: ContactModel, case: GraspCase | None, seed: int = 0,
                  clamp_pa: float = -30e3, settle_s: float = 0.5,
                  opened_for: GraspCase | None = None, noise_scale: float = 1.0,
                  placement: Placement | None = None) -> SensingTrial:
    """Run one closing (see the module) and judge it. ``case`` None: the hand is empty, opened
    as for ``opened_for`` (None: a pinch from 0 Pa)."""
    from softgrip_ros.model import gripper_models
    from softgrip_ros.model.world.fingers import PseudoRigidFinger
    from softgrip_ros.model.world.scene import scene_from_document
    from softgrip_ros.model.world.world import GripperWorld

    placement = placement or Placement()
    shaped = case or opened_for
    if shaped is not None:
        document = placement.scene(shaped)
        opening = placement.opening_pa(shaped)
        moves = document["arm"]["moves"]
        if "approach" in moves:
            document["arm"]["start_m"] = moves["approach"][0]["to_m"]
    else:
        document = {"name": "empty pinch", "arm": {"start_m": [0.0, 0.0, 0.3]}}
        opening = 0.0
    if case is None:
        document.pop("object", None)
    finger = PseudoRigidFinger(*gripper_models.resolve("type_II"), bending="l0")
    world = GripperWorld(scene_from_document(document), finger, start_pressure_pa=opening,
                         plant=model.plant)
    plant = PneumaticPlant(model.plant)
    state = plant.initial_state(opening)
    state.regulator_gauge_pa = opening
    controller = PressureController(PressureControlConfig())
    controller.active = True
    controller.command(opening, Source.SUPPLY, math.nan, 0.0)
    rng = np.random.default_rng(seed)
    inputs = PlantInputs(opening, True, (Valve.SUPPLY,))
    periods = [max(1, round(1.0 / (sensor.rate_hz * STEP_S))) for sensor in DEFAULT_SENSORS]
    record, sent = None, None
    end_s = START_S + settle_s
    for i in range(int(round(end_s / STEP_S))):
        now = (i + 1) * STEP_S
        if record is None and now >= START_S - 0.5 * STEP_S:
            controller.command(clamp_pa, Source.VACUUM if clamp_pa < 0 else Source.SUPPLY,
                               math.nan, now)
            record = AirRecord(now, opening)
        gauge = state.chamber_pa[0] - P_ATM_PA
        for sensor, period in zip(DEFAULT_SENSORS, periods):
            if i % period == 0:
                std = noise_scale * sensor.noise_std_pa
                reading = gauge + std * rng.standard_normal()
                controller.update_sensor(sensor.name, reading, now)
                if record is not None:
                    record.add_sample(now, reading, max(std, 1.0))
        if i % REGULATOR_REPORT_STEPS == 0:
            controller.update_regulator_status(state.regulator_gauge_pa, 0)
        if i % CONTROL_PERIOD_STEPS == 0:
            out = controller.step(now)
            inputs = PlantInputs(out.regulator_setpoint_gauge_pa, out.regulator_enabled,
                                 out.valves)
            key = (inputs.regulator_setpoint_gauge_pa, inputs.regulator_enabled, inputs.valves)
            if record is not None and key != sent:
                record.add_inputs(now, inputs)
                sent = key
        state = plant.advance(state, inputs, STEP_S)
        world.set_pressure(float(state.chamber_pa[0] - P_ATM_PA))
        if world.advance_to(now):
            state = plant.with_volume_offset(state, [world.volume_offset_m3()])
    started = time.process_time()
    fit = fit_contact(record, model, end_s, clamp_pa, max(opening, 1e3))
    expected = case.size_m if case is not None else (
        opened_for.size_m if opened_for is not None else math.nan)
    detection = judge_closing(fit, model, end_s, expected)
    cpu = time.process_time() - started
    present = case is not None and world.in_hand()
    label = case.object_class if case is not None else (
        f"nothing, opened for {opened_for.object_class}" if opened_for else "nothing, pinch")
    return SensingTrial(label, present, case.size_m if case is not None else 0.0, detection,
                        cpu)


def correct(trial: SensingTrial) -> bool:
    """The verdict agrees with the world: an object held and CONTACT_CLOSING, or nothing and
    NO_OBJECT (UNKNOWN is not correct)."""
    if trial.object_present:
        return trial.detection.status == ObjectStatus.CONTACT_CLOSING
    return trial.detection.status == ObjectStatus.NO_OBJECT

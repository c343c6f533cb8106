"""The control core closed around a pneumatic plant, without CAN or ROS: step responses for the
tests and the benchmarks (the controller's model and the plant it runs on may differ)."""
import math

import numpy as np

from softgrip_ros.control.pressure import PressureControlConfig, PressureController, Source
from softgrip_ros.model.pneumatics import P_ATM_PA, PlantInputs, PneumaticPlant, Valve

PLANT_DT = 1e-3


def step_response(target_gauge_pa, duration_s=1.0, noise_pa=300.0, seed=0, config=None,
                  control_hz=500, plant=None, time_optimal=False, overshoot_fault_pa=0.0,
                  sensor_until_s=math.inf, model=None):
    """Times (s), true chamber gauge pressures (Pa) and controller outputs of one step on
    ``plant``; the controller's own model is ``model`` (default: the shipped assumptions)."""
    rng = np.random.default_rng(seed)
    plant = plant or PneumaticPlant()
    state = plant.initial_state()
    controller = PressureController(config or PressureControlConfig(), model)
    controller.active = True
    source = Source.SUPPLY if target_gauge_pa >= 0 else Source.VACUUM
    controller.command(target_gauge_pa, source, math.nan, 0.0)
    period = max(1, int(round(1.0 / (control_hz * PLANT_DT))))
    inputs = PlantInputs(valves=(Valve.CLOSED,))
    times, pressures, outputs = [], [], []
    for i in range(int(round(duration_s / PLANT_DT))):
        now = (i + 1) * PLANT_DT
        gauge = state.chamber_pa[0] - P_ATM_PA
        if i % 2 == 0 and now < sensor_until_s:
            controller.update_sensor("sensor1", gauge + noise_pa * rng.standard_normal(), now)
        if i % 10 == 0:
            controller.update_regulator_status(state.regulator_gauge_pa, 0)
        if i % period == 0:
            if time_optimal:
                inputs = PlantInputs(regulator_setpoint_gauge_pa=plant.parameters.supply_gauge_pa,
                                     valves=(Valve.SUPPLY,))
            else:
                out = controller.step(now)
                outputs.append(out)
                inputs = PlantInputs(regulator_setpoint_gauge_pa=out.regulator_setpoint_gauge_pa,
                                     regulator_enabled=out.regulator_enabled, valves=out.valves,
                                     regulator_overshoot_pa=overshoot_fault_pa)
        state = plant.step(state, inputs, PLANT_DT)
        times.append(now)
        pressures.append(state.chamber_pa[0] - P_ATM_PA)
    return np.array(times), np.array(pressures), outputs


def rise_time_s(times, pressures, target):
    """10-90 % rise time of a step from 0 to target."""
    above = (lambda level: pressures >= level) if target > 0 else (
        lambda level: pressures <= level)
    return times[np.argmax(above(0.9 * target))] - times[np.argmax(above(0.1 * target))]


def step_figures(target_gauge_pa: float, plant, model=None, seed: int = 0) -> dict:
    """rise_time_ratio (10-90 % rise against the valve fully open to the supply, on ``plant``),
    overshoot_pct (of the step) and steady_state_error_kpa (the last 0.2 s) of one step."""
    times, pressures, _ = step_response(target_gauge_pa, seed=seed, plant=plant, model=model)
    optimal_t, optimal_p, _ = step_response(target_gauge_pa, plant=plant, time_optimal=True)
    return {
        "rise_time_ratio": rise_time_s(times, pressures, target_gauge_pa) /
        rise_time_s(optimal_t, optimal_p, target_gauge_pa),
        "overshoot_pct": max(0.0, 100.0 * (pressures.max() - target_gauge_pa) / target_gauge_pa),
        "steady_state_error_kpa": abs(float(pressures[-200:].mean()) - target_gauge_pa) / 1e3,
    }

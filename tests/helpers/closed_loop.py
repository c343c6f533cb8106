"""The control core closed around the pneumatic plant, without CAN or ROS: a fast test bench."""
import math

import numpy as np

from softgrip_ros.control.pressure import PressureControlConfig, PressureController, Source
from softgrip_ros.model.pneumatics import P_ATM_PA, PlantInputs, PneumaticPlant, Valve

PLANT_DT = 1e-3


def step_response(target_gauge_pa, duration_s=1.0, noise_pa=300.0, seed=0, config=None, control_hz=500,
                  plant=None, time_optimal=False, overshoot_fault_pa=0.0, sensor_until_s=math.inf):
    """Times (s), true chamber gauge pressures (Pa) and controller outputs of one step."""
    rng = np.random.default_rng(seed)
    plant = plant or PneumaticPlant()
    state = plant.initial_state()
    controller = PressureController(config or PressureControlConfig())
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
                inputs = PlantInputs(regulator_setpoint_gauge_pa=plant.parameters.supply_gauge_pa, valves=(Valve.SUPPLY,))
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
    above = (lambda level: pressures >= level) if target > 0 else (lambda level: pressures <= level)
    return times[np.argmax(above(0.9 * target))] - times[np.argmax(above(0.1 * target))]

"""The control core closed around the pneumatic plant, without CAN or ROS: a fast test bench."""
import math

import numpy as np

from softgrip_ros.control.pressure import PressureControlConfig, PressureController, Source
from softgrip_ros.model.pneumatics import P_ATM_PA, PlantInputs, PneumaticPlant, Valve

PLANT_DT = 1e-3


def step_response(target_gauge_pa, duration_s=1.0, noise_pa=300.0, seed=0, config=None,
                  control_hz=500, plant=None, time_optimal=False, overshoot_fault_pa=0.0,
                  sensor_until_s=math.inf):
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


class FaultyLoop:
    """The control core on the plant in simulated time, with one fault at a time injected: two
    sensors (chamber_a 300 Pa at 500 Hz, chamber_b 150 Pa at 200 Hz) and the regulator's report
    at 100 Hz, as the simulated device sends them. ``true`` holds every plant step's pressure,
    which is what the limits are judged on.

    Faults (attributes, changeable between runs): ``bias_pa`` on both sensors,
    ``bias_rate_pa_per_s`` (a drift), ``stuck`` {sensor: None (at its reading) or a value},
    ``noise_scale``, ``valve_stuck`` (the valves keep their state), ``valve_stuck_open`` (SUPPLY),
    ``overshoot_pa``."""

    SENSORS = {"chamber_a": (300.0, 2), "chamber_b": (150.0, 5)}  # noise Pa, period in ms

    def __init__(self, config=None, seed=0, plant=None):
        self.plant = plant or PneumaticPlant()
        self.controller = PressureController(
            config, sensor_noise_pa={n: s
                                     for n, (s, _) in self.SENSORS.items()})
        self.controller.active = True
        self.rng = np.random.default_rng(seed)
        self.state = self.plant.initial_state()
        self.inputs = PlantInputs(valves=(Valve.CLOSED,))
        self.tick = 0
        self.bias_pa = self.bias_rate_pa_per_s = 0.0
        self.noise_scale, self.overshoot_pa = 1.0, 0.0
        self.stuck, self._frozen = {}, {}
        self.valve_stuck = self.valve_stuck_open = False
        self.true, self.outputs = [], []

    @property
    def now(self) -> float:
        return self.tick * 1e-3

    def gauge(self) -> float:
        return float(self.state.chamber_pa[0] - P_ATM_PA)

    def command(self, target_gauge_pa, source=None, rate=math.nan):
        if source is None:
            source = Source.SUPPLY if target_gauge_pa >= 0.0 else Source.VACUUM
        return self.controller.command(target_gauge_pa, source, rate, self.now)

    def reading(self, name):
        noise, _ = self.SENSORS[name]
        value = self.gauge() + self.bias_pa + self.noise_scale * noise * self.rng.standard_normal()
        if name in self.stuck:
            if name not in self._frozen:
                self._frozen[name] = value if self.stuck[name] is None else self.stuck[name]
            return self._frozen[name]
        self._frozen.pop(name, None)
        return value

    def run_for(self, seconds):
        for _ in range(int(round(seconds / 1e-3))):
            self.tick += 1
            self.bias_pa += self.bias_rate_pa_per_s * 1e-3
            for name, (_, period_ms) in self.SENSORS.items():
                if self.tick % period_ms == 0:
                    self.controller.update_sensor(name, self.reading(name), self.now)
            if self.tick % 10 == 0:
                self.controller.update_regulator_status(self.state.regulator_gauge_pa, 0, self.now)
            if self.tick % 2 == 0:
                out = self.controller.step(self.now)
                self.outputs.append((self.now, out))
                valves = ((Valve.SUPPLY,) if self.valve_stuck_open else
                          self.inputs.valves if self.valve_stuck else out.valves)
                self.inputs = PlantInputs(out.regulator_setpoint_gauge_pa, out.regulator_enabled,
                                          valves, regulator_overshoot_pa=self.overshoot_pa)
            self.state = self.plant.step(self.state, self.inputs, 1e-3)
            self.true.append((self.now, self.gauge()))
        return self

    def true_extremes(self, since=0.0):
        values = [p for t, p in self.true if t >= since]
        return min(values), max(values)

    def first_fault(self, since=0.0):
        """(time, output) of the first safe-state output since ``since``, or None."""
        return next(((t, o) for t, o in self.outputs if t >= since and o.mode.name == "FAULT"),
                    None)

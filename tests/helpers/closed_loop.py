"""The control core closed around the pneumatic plant, without CAN or ROS, with faults injected
(the step responses are softgrip_ros.devtools.closed_loop's)."""
import math

import numpy as np

from softgrip_ros.control.pressure import PressureController, Source
from softgrip_ros.model.pneumatics import P_ATM_PA, PlantInputs, PneumaticPlant, Valve


class FaultyLoop:
    """The control core on the plant in simulated time, with one fault at a time injected: two
    sensors (chamber_a 300 Pa at 500 Hz, chamber_b 150 Pa at 200 Hz) and the regulator's report
    at 100 Hz, as the simulated device sends them. ``true`` holds every plant step's pressure,
    which is what the limits are judged on.

    Faults (attributes, changeable between runs): ``bias_pa`` on both sensors,
    ``bias_rate_pa_per_s`` (a drift), ``stuck`` {sensor: None (at its reading) or a value},
    ``noise_scale``, ``valve_stuck`` (the valves keep their state), ``valve_stuck_open`` (SUPPLY),
    ``overshoot_pa``. ``step_period_ms`` (2) spaces the controller's steps, and
    ``reading_delay_ms`` (0) delays each reading's arrival, stamped when it was sampled, and
    ``reading_burst_ms`` (0) holds them until the next multiple of it (a reception thread that
    runs in bursts): a loaded host."""

    SENSORS = {"chamber_a": (300.0, 2), "chamber_b": (150.0, 5)}  # noise Pa, period in ms

    def __init__(self, config=None, seed=0, plant=None):
        self.plant = plant or PneumaticPlant()
        # the controller's model is the plant (what an identification gives)
        self.controller = PressureController(
            config, self.plant, sensor_noise_pa={n: s
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
        self.step_period_ms = 2
        self.reading_delay_ms = self.reading_burst_ms = 0
        self._in_flight = []  # (arrival tick, name, reading, stamp)
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
                    arrival, burst = self.tick + self.reading_delay_ms, self.reading_burst_ms
                    if burst:
                        arrival = -(-arrival // burst) * burst
                    self._in_flight.append((arrival, name, self.reading(name), self.now))
            arrived = [r for r in self._in_flight if r[0] <= self.tick]
            self._in_flight = [r for r in self._in_flight if r[0] > self.tick]
            for _, name, value, stamp in arrived:
                self.controller.update_sensor(name, value, stamp)
            if self.tick % 10 == 0:
                self.controller.update_regulator_status(self.state.regulator_gauge_pa, 0, self.now)
            if self.tick % self.step_period_ms == 0:
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

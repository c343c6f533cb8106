"""The grasp state machine closed around the pressure controller and the plant, in simulated
time."""
import math

import numpy as np

from softgrip_ros.control.faults import HALTING_FAULTS, TRANSIENT_FAULTS, fault_text
from softgrip_ros.control.grasp_fsm import GraspStateMachine
from softgrip_ros.control.pressure import PressureController
from softgrip_ros.model.pneumatics import P_ATM_PA, PlantInputs, PneumaticPlant, Valve

PLANT_DT = 1e-3


class GraspLoop:
    """1 kHz plant, 500 Hz controller on a 300 Pa sensor, FSM updated at 100 Hz on the true
    pressure plus 100 Pa noise (the estimator's accuracy). ``valve_stuck`` keeps the valves
    closed."""

    def __init__(self, kinematics, config=None, valve_stuck=False, seed=0, scene_model=None):
        self.fsm = GraspStateMachine(kinematics, config, scene_model=scene_model)
        self.plant = PneumaticPlant()
        self.state = self.plant.initial_state()
        self.controller = PressureController()
        self.controller.active = True
        self.rng = np.random.default_rng(seed)
        self.now, self.valve_stuck = 0.0, valve_stuck
        self.controller_fault, self.overshoot_pa = "", 0.0
        self.inputs = PlantInputs(valves=(Valve.CLOSED,))
        self.phase_log, self.history = [], []
        self.spacing_at_enveloped = math.nan
        self._sent = None
        self.reported_fault = ""
        self.blind = False
        self.controller_blind = False  # whether an injected controller_fault is the blind kind

    def command(self, request):
        reason = self.fsm.command(request, self.now, self.controller_fault)
        self._forward()
        return reason

    def _forward(self):
        if self.fsm.request != self._sent:
            self._sent = self.fsm.request
            self.controller.command(self._sent.target_gauge_pa, self._sent.source, math.nan,
                                    self.now)
        if not self.phase_log or self.phase_log[-1][1] != self.fsm.state.phase:
            self.phase_log.append((self.now, self.fsm.state.phase))

    def gauge(self):
        return self.state.chamber_pa[0] - P_ATM_PA

    def step(self):
        i = int(round(self.now / PLANT_DT))
        self.now = (i + 1) * PLANT_DT
        if i % 2 == 0:
            self.controller.update_sensor("sensor1",
                                          self.gauge() + 300.0 * self.rng.standard_normal(),
                                          self.now)
            out = self.controller.step(self.now)
            self.reported_fault = fault_text(out.fault_flags)
            self.blind = not (out.fault_flags & HALTING_FAULTS & ~TRANSIENT_FAULTS)
            valves = (Valve.CLOSED,) if self.valve_stuck else out.valves
            self.inputs = PlantInputs(out.regulator_setpoint_gauge_pa, out.regulator_enabled,
                                      valves, regulator_overshoot_pa=self.overshoot_pa)
        if i % 10 == 0:
            self.controller.update_regulator_status(self.state.regulator_gauge_pa, 0)
            before = self.fsm.state.phase
            self.fsm.update(
                self.now,
                self.gauge() + 100.0 * self.rng.standard_normal(), 100.0, self.controller_fault or
                self.reported_fault,
                controller_blind=self.controller_blind if self.controller_fault else self.blind)
            if self.fsm.state.phase != before and self.fsm.state.phase.name == "ENVELOPED":
                self.spacing_at_enveloped = self.fsm.state.tip_spacing_m
            self._forward()
        self.state = self.plant.step(self.state, self.inputs, PLANT_DT)
        self.history.append((self.now, self.gauge()))

    def run_for(self, seconds):
        end = self.now + seconds
        while self.now < end - 1e-9:
            self.step()

    def run_until(self, condition, timeout):
        end = self.now + timeout
        while not condition(self.fsm.state):
            if self.now >= end:
                raise AssertionError(
                    f"timed out in {self.fsm.state.phase.name}: {self.fsm.state.message}; "
                    f"phases {[(round(t, 3), p.name) for t, p in self.phase_log]}")
            self.step()

    def pressures_since(self, t0):
        return [p for t, p in self.history if t >= t0]

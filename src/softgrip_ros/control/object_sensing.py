"""The grasp state machine and the air's verdict on the object, joined (no ROS): which phase
starts and ends a motion to judge, when a hold's air is trapped, and the verdicts fed back to
the state machine (:meth:`~softgrip_ros.control.grasp_fsm.GraspStateMachine.sensed`).

The owner calls :meth:`ObjectSensingLink.controller_outputs` and
:meth:`ObjectSensingLink.reading` as the controller's outputs and the sensors' readings arrive,
and :meth:`ObjectSensingLink.after` after every command and update of the state machine, all
under one lock. A motion's judgement is CPU-heavy: ``run(job, done)`` judges the
:class:`~softgrip_ros.estimation.grasp_sensing.MotionJob` ``job`` where the owner likes
(:func:`~softgrip_ros.estimation.grasp_sensing.judge_motion` with the sensing's model, in a child
process: in a thread it holds the GIL the control path needs) and must call ``done(result)``
back under the owner's lock, ``result`` the verdict or the exception raised; None judges it at
once.
"""
from __future__ import annotations

import math

from softgrip_ros.control.grasp_fsm import GraspMode, GraspStateMachine, Phase
from softgrip_ros.estimation.grasp_sensing import (Detection, GraspSensing, MotionJob,
                                                   ObjectStatus, judge_motion)
from softgrip_ros.model.pneumatics import PlantInputs, Valve

# phases in which the fingers move towards a pressure the motion's judgement starts from
_MOVING = (Phase.OPENING, Phase.CLAMPING)


class ObjectSensingLink:
    """See the module. ``fsm``: the grasp state machine (its ``sensing_enabled`` is set);
    ``sensing``: the :class:`~softgrip_ros.estimation.grasp_sensing.GraspSensing`."""

    def __init__(self, fsm: GraspStateMachine, sensing: GraspSensing, run=None):
        self.fsm, self.sensing = fsm, sensing
        self.run = run or (lambda job, done: done(judge_motion(sensing.model, job)))
        fsm.sensing_enabled = True
        self._phase = fsm.state.phase
        self._trapped = None
        self._motion = 0  # counts motions: a late judgement of an older one is dropped
        self._last = None
        self._outputs = None

    def controller_outputs(self, stamp_s: float, regulator_command_gauge_pa: float,
                           regulator_enabled: bool, valve: int) -> None:
        """The controller's outputs in force from ``stamp_s`` (s): its regulator command (Pa
        gauge), enable and channel 0's valve (a Valve value); repeats, a NaN command or an unknown
        valve change nothing."""
        key = (regulator_command_gauge_pa, bool(regulator_enabled), valve)
        if key == self._outputs or not math.isfinite(regulator_command_gauge_pa):
            return
        try:
            valve_state = Valve(valve)
        except ValueError:
            return
        self._outputs = key
        self.sensing.inputs(stamp_s, PlantInputs(regulator_command_gauge_pa,
                                                 bool(regulator_enabled), (valve_state,)))

    def reading(self, name: str, stamp_s: float, gauge_pa: float) -> None:
        self.sensing.reading(name, stamp_s, gauge_pa)

    def after(self, now: float, estimate_gauge_pa: float, controller_fault: str = "") -> None:
        """Follow the state machine's phase (see the module) and give it the verdict now."""
        fsm = self.fsm
        phase = fsm.state.phase
        if phase != self._phase:
            self._transition(self._phase, phase, now, estimate_gauge_pa)
            self._phase = phase
        trapped = fsm.air_trapped_since
        if trapped != self._trapped:
            self._trapped = trapped
            self.sensing.air_trapped(math.nan if trapped is None else trapped)
        verdict = self.sensing.status(now, controller_fault)
        key = (verdict.status, verdict.evidence)
        if key != self._last:
            self._last = key
            fsm.sensed(verdict, now)

    def _transition(self, old: Phase, new: Phase, now: float, estimate: float) -> None:
        fsm, sensing = self.fsm, self.sensing
        self._motion += 1
        if new in _MOVING and old != new:
            grasp = fsm.grasp
            expected = (grasp.object_diameter_m if grasp is not None and
                        GraspMode(grasp.mode) != GraspMode.OPEN else math.nan)
            sensing.motion_started(now, estimate, fsm.request.target_gauge_pa, expected)
        elif old in _MOVING and new in (Phase.ENVELOPED, Phase.HOLDING):
            job = sensing.settle_motion(now)
            if job is not None:
                motion, hold_pa = self._motion, fsm.request.target_gauge_pa
                self.run(job,
                         lambda verdict: self._judged(motion, job, verdict, hold_pa))
        elif new not in (Phase.ENVELOPED, Phase.HOLDING) or old == Phase.HOLDING:
            sensing.released(now, "no grasp: " + fsm.state.message)

    def _judged(self, motion: int, job: MotionJob, verdict, hold_pa: float) -> None:
        """A judgement is back (under the owner's lock): the verdict, or what the work raised."""
        if motion != self._motion:
            return  # the grasp moved on meanwhile
        if isinstance(verdict, BaseException):
            verdict = Detection(ObjectStatus.UNKNOWN, 0.0,
                                f"the motion could not be judged: {verdict}", job.stamp_s)
        self.sensing.accept(job, verdict)
        if not job.opening and verdict.status == ObjectStatus.CONTACT_CLOSING and \
                self.fsm.state.phase == Phase.HOLDING:
            self.sensing.holding(verdict.stamp_s, hold_pa)
            if self._trapped is not None:
                self.sensing.air_trapped(self._trapped)
        now = self.fsm.now_s
        current = self.sensing.status(now)
        self._last = (current.status, current.evidence)
        self.fsm.sensed(current, now)

"""The grasp-mode state machine (no ROS): commands in, pressure requests and a state out.

Phases: IDLE -> OPENING -> ENVELOPED -> CLAMPING -> HOLDING -> RELEASING -> IDLE, and FAULT.

- PINCH (object up to ``pinch_max_diameter_m``, down to a 0.1 mm sheet): negative pressure
  only, straight to CLAMPING at the clamp pressure, then HOLDING.
- ENVELOP_CLAMP: OPENING at the pressure whose modelled tip spacing D2 is the object plus
  ``envelop_margin_m`` (the inverse model, plus the pressure tolerance so that D2 still clears
  the object at the low edge of it), or the ``open_pressure_pa`` override. ENVELOPED once the
  estimate has settled there and the modelled D2 clears the object; it waits for the arm: a
  CLAMP command, or the automatic clamp after ``auto_clamp_delay_s`` (negative: never). Then
  CLAMPING at the pressure of :class:`~softgrip_ros.model.force_law.ClampForceLaw` (or the
  ``clamp_pressure_pa`` override) and HOLDING once settled.
- OPEN: OPENING to ``target_tip_spacing_m``, then ENVELOPED (held open; CLAMP may follow).
- RELEASE: RELEASING vents until the chamber is near 0, then opens to the object plus margin
  (or ``release_tip_spacing_m``), then IDLE with the valves holding.
- STOP: vent now, whatever runs: RELEASING until the chamber is near 0, then IDLE ("stopped:
  vented"). Neither RELEASE nor STOP reports success before the pressure says so.
- CLAMP: clamp now; only from ENVELOPED.

Every phase that waits has a timeout; a timeout, a controller fault or a HOLDING pressure that
drifts off its target gives FAULT, which vents. A controller that cannot see the chamber (a
sensor timeout or a silent bus that outlasts the grace) gives FAULT too, but with the valves
held closed, as the pressure controller itself does then: nothing could confirm a vent.
A rejected command changes nothing and says why: an invalid number, and also a command that
cannot do what its mode means (an opening pressure that is not positive, a clamp pressure
that is, an override a mode never uses).
"""
from __future__ import annotations

import dataclasses
import enum
import math

from softgrip_ros.checks import require_positive
from softgrip_ros.control.faults import (HALTING_FAULTS, SAFETY_FAULTS, TRANSIENT_FAULTS, Fault,
                                         fault_text)
from softgrip_ros.control.pressure import Source
from softgrip_ros.estimation.grasp_sensing import Detection, ObjectStatus
from softgrip_ros.model.fidelity import FREE, Scene, cylinder_scene
from softgrip_ros.model.force_law import ClampForceLaw, ObjectKind, load_table
from softgrip_ros.model.rod import Sheet
from softgrip_ros.settings import check_settings, setting

HOLD_AIR = ("trap", "regulate")
ON_OBJECT_LOST = ("hold", "release", "fault")
# the sensed statuses that mean an object is between the fingers
HOLDING_STATUSES = (ObjectStatus.HELD, ObjectStatus.CONTACT_CLOSING)


class Phase(enum.IntEnum):
    """GripperState phases."""

    IDLE = 0
    OPENING = 1
    ENVELOPED = 2
    CLAMPING = 3
    HOLDING = 4
    RELEASING = 5
    FAULT = 6


class GraspMode(enum.IntEnum):
    """GraspCommand modes."""

    PINCH = 0
    ENVELOP_CLAMP = 1
    OPEN = 2
    RELEASE = 3
    STOP = 4
    CLAMP = 5


class ReleaseStep(enum.Enum):
    """Where a RELEASING phase stands: STOP vents to IDLE; a RELEASE vents (VENT), then opens
    past the object (OPEN) to IDLE."""

    NONE = enum.auto()
    STOP = enum.auto()
    VENT = enum.auto()
    OPEN = enum.auto()


class GoalOutcome(enum.Enum):
    """How a command's goal stands (:meth:`GraspStateMachine.outcome`)."""

    RUNNING = "running"
    SUCCEEDED = "succeeded"
    FAILED = "failed"  # FAULT, or closed on nothing
    SUPERSEDED = "superseded"  # another command started a task of its own
    CANCELED = "canceled"  # by its client (the action servers' outcome)

    @property
    def ended(self) -> bool:
        return self is not GoalOutcome.RUNNING


@dataclasses.dataclass(frozen=True)
class Rejection:
    """A command refused, and why (for a person: it goes into grasp_state.message); nothing
    moved."""

    reason: str

    def __str__(self) -> str:
        return self.reason


@dataclasses.dataclass(frozen=True)
class GraspRequest:
    """One command; NaN means "not given" (automatic)."""

    mode: int
    object_diameter_m: float = math.nan
    object_mass_kg: float = math.nan
    target_tip_spacing_m: float = math.nan
    friction_coefficient: float = math.nan
    open_pressure_pa: float = math.nan
    clamp_pressure_pa: float = math.nan
    command_id: str = ""


@dataclasses.dataclass(frozen=True)
class PressureRequest:
    """What the pressure controller is asked for (gauge Pa)."""

    target_gauge_pa: float
    source: Source


@dataclasses.dataclass(frozen=True)
class Plan:
    """What an accepted command does: the phase it enters with its pressure request, and the
    grasp it starts or goes on with (None: the running one stays) with its pressures (None:
    unchanged). ``new_task``: false for a CLAMP, which goes on with the task it clamps."""

    phase: Phase
    pressure: "PressureRequest"
    message: str
    new_task: bool = True
    grasp: GraspRequest | None = None
    open_pa: float | None = None
    clamp_pa: float | None = None
    contact_pa: float | None = None
    release_step: ReleaseStep = ReleaseStep.NONE
    # the object the clamp force law reports the force on: (size m, ObjectKind)
    held: tuple | None = None


@dataclasses.dataclass(frozen=True)
class GraspConfig:
    """Pressures gauge Pa, lengths m, times s."""

    max_gauge_pa: float = setting(50e3, "highest pressure a command may ask for", "Pa", 1e3,
                                  100e3)
    min_gauge_pa: float = setting(-60e3, "lowest pressure a command may ask for", "Pa", -100e3,
                                  -1e3)
    envelop_margin_m: float = setting(0.01, "D2 beyond the object before ENVELOPED", "m", 1e-4,
                                      0.1)
    pinch_max_diameter_m: float = setting(0.005, "largest object for PINCH", "m", 1e-4, 0.02)
    release_tip_spacing_m: float = setting(0.02, "least opening after RELEASE", "m", 1e-3, 0.15)
    pressure_tolerance_pa: float = setting(
        1.5e3, "a phase's pressure counts as reached within this", "Pa", 100.0, 20e3)
    settle_s: float = setting(0.1, "time within tolerance before a phase completes", "s", 0.01,
                              5.0)
    auto_clamp_delay_s: float = setting(
        -1.0, "ENVELOPED to CLAMPING on its own after this; < 0: wait for CLAMP", "s", -1.0, 600.0)
    opening_timeout_s: float = setting(3.0, "OPENING longer than this: FAULT", "s", 0.1, 60.0)
    clamping_timeout_s: float = setting(3.0, "CLAMPING longer than this: FAULT", "s", 0.1, 60.0)
    releasing_timeout_s: float = setting(3.0, "RELEASING longer than this: FAULT", "s", 0.1,
                                         60.0)
    vented_below_pa: float = 1.5e3
    hold_error_limit_pa: float = setting(
        5e3, "HOLDING pressure off target by more than this ...", "Pa", 500.0, 50e3)
    hold_error_time_s: float = setting(0.3, "... for this long: FAULT", "s", 0.01, 10.0)
    hold_air: str = setting(
        "regulate", "HOLDING once settled: trap (valves closed, topped up past "
        "pressure_tolerance_pa; a lost object shows in the pressure) or regulate (the regulated "
        "line open; a loss is not sensed)", choices=HOLD_AIR)
    on_object_lost: str = setting(
        "hold", "a loss sensed in HOLDING: hold (report it), release, or fault (vent)",
        choices=ON_OBJECT_LOST)
    sensing_wait_s: float = setting(
        2.0, "a HOLDING goal waits this long for the closing's sensed verdict", "s", 0.0, 10.0)

    def __post_init__(self):
        check_settings(self)
        if not self.min_gauge_pa < 0.0 < self.max_gauge_pa:
            raise ValueError("need min_gauge_pa < 0 < max_gauge_pa")
        require_positive(self, "vented_below_pa")


@dataclasses.dataclass
class GraspState:
    """Everything GripperState reports, in SI units. The geometry (alpha, D2, D1) is the free
    model's at the estimate, except that while an object is between the fingers (clamped, held or
    being released) D2 is at least its size: free bending closes the tips through the object,
    which they rest on (see :meth:`GraspStateMachine.held_object_m`)."""

    phase: Phase = Phase.IDLE
    mode: int = GraspMode.STOP
    command_id: str = ""
    command_rejected: bool = False
    target_gauge_pa: float = 0.0
    estimated_gauge_pa: float = math.nan
    estimated_std_pa: float = math.nan
    included_angle_rad: float = math.nan
    tip_spacing_m: float = math.nan
    root_spacing_m: float = math.nan
    clamp_force_n: float = 0.0
    model_fidelity: str = ""
    in_validated_range: bool = True
    message: str = "idle"
    # the air's verdict on the object (estimation.grasp_sensing), and its size as felt (m)
    object_status: ObjectStatus = ObjectStatus.UNKNOWN
    object_size_m: float = math.nan
    object_evidence: str = "no grasp yet"


class ControllerFeedback:
    """What the grasp sees of the pressure controller: the pressure (the estimate while fresher
    than ``estimate_timeout_s``, else the controller's own measurement) and the fault that stops
    a grasp (the controller's halting faults, or its silence for ``status_timeout_s``).

    Before the first status a grasp waits up to ``status_timeout_s`` for it, as for a late one:
    a command sent while the suite is still starting (the pressure controller not yet active)
    is not a fault.

    A sensor timeout or a silent bus stops a grasp only once it has lasted ``transient_grace_s``:
    the controller already holds the valves closed meanwhile and resumes by itself, and a loaded
    machine can delay frames by tens of milliseconds (a dropout that lasts still faults)."""

    def __init__(self, estimate_timeout_s: float, status_timeout_s: float,
                 transient_grace_s: float = 0.3):
        self.estimate_timeout_s, self.status_timeout_s = estimate_timeout_s, status_timeout_s
        self.transient_grace_s = transient_grace_s
        self._estimate = (math.nan, math.nan, -math.inf)  # gauge, std, arrival
        # (fault flags, measured gauge, arrival)
        self._status = None
        # the controller's own words on its fault
        self._message = ""
        # first non-idle ask before any status
        self._awaited_since = None
        # since when TRANSIENT_FAULTS are reported
        self._transient_since = None

    def on_estimate(self, gauge_pa: float, std_pa: float, now: float) -> None:
        self._estimate = (gauge_pa, std_pa, now)

    def on_status(self, fault_flags: int, measured_gauge_pa: float, now: float,
                  message: str = "") -> None:
        self._status = (fault_flags, measured_gauge_pa, now)
        self._message = message
        if not fault_flags & TRANSIENT_FAULTS:
            self._transient_since = None
        elif self._transient_since is None:
            self._transient_since = now

    def pressure(self, now: float) -> tuple[float, float]:
        """(gauge Pa, std Pa; NaN when unknown)."""
        gauge, std, stamp = self._estimate
        if now - stamp <= self.estimate_timeout_s:
            return gauge, std
        return (self._status[1] if self._status is not None else math.nan), math.nan

    def fault(self, now: float, idle: bool) -> str:
        if self._status is None:
            if idle:
                return ""
            if self._awaited_since is None:
                self._awaited_since = now
            waited = now - self._awaited_since
            return f"no controller/status in {waited:.1f} s: is the pressure controller up?" \
                if waited > self.status_timeout_s else ""
        flags, _, stamp = self._status
        if now - stamp > self.status_timeout_s:
            return f"no controller/status for {now - stamp:.1f} s"
        if (self._transient_since is not None and
                now - self._transient_since < self.transient_grace_s):
            flags &= ~TRANSIENT_FAULTS
        text = fault_text(flags)
        if text and Fault(flags) & SAFETY_FAULTS and self._message:
            text = f"{text} ({self._message})"
        return text

    def safe_state(self, now: float) -> bool:
        """Whether the controller's fresh status reports a safety fault (it vents, regulator
        off)."""
        if self._status is None or now - self._status[2] > self.status_timeout_s:
            return False
        return bool(Fault(self._status[0]) & SAFETY_FAULTS)

    def blind(self, now: float) -> bool:
        """Whether the fault that stops a grasp is the controller being unable to see the chamber
        (a sensor timeout or a silent bus past the grace, or no status at all) and nothing else:
        the controller holds the valves closed then, and a vent could not be confirmed."""
        if self._status is None:
            return True
        flags, _, stamp = self._status
        return now - stamp > self.status_timeout_s or not Fault(
            flags) & HALTING_FAULTS & ~TRANSIENT_FAULTS


TERMINAL = {
    GraspMode.ENVELOP_CLAMP: (Phase.HOLDING,), GraspMode.PINCH: (Phase.HOLDING,),
    GraspMode.OPEN: (Phase.ENVELOPED,), GraspMode.RELEASE: (Phase.IDLE,),
    GraspMode.STOP: (Phase.IDLE,), GraspMode.CLAMP: (Phase.HOLDING,)
}


class GraspStateMachine:
    """Feed it commands (:meth:`command`) and estimates (:meth:`update`); read :attr:`state` and
    :attr:`request`. ``kinematics`` is a :class:`~softgrip_ros.model.kinematics.GripperKinematics`.
    ``scene_model`` (a :class:`~softgrip_ros.model.fidelity.SceneModel`, optional): :meth:`scene`
    then names the object being clamped, and the state's ``model_fidelity`` is the model its
    selector picks for that scene (the kinematics node's choice, with the same settings)."""

    def __init__(self, kinematics, config: GraspConfig | None = None,
                 force_law: ClampForceLaw | None = None, scene_model=None):
        self.kinematics = kinematics
        self.scene_model = scene_model
        self._scenes = {}
        self.config = config or GraspConfig()
        self.force_law = force_law or ClampForceLaw(load_table(kinematics.geometry.name,
                                                               kinematics.model))
        self.state = GraspState(model_fidelity=kinematics.model)
        self.request = PressureRequest(0.0, Source.VENT)
        self.changes = 0  # counts every phase or request change
        self.accepted = 0  # counts accepted commands
        # the running task: a new one per command but a CLAMP that goes on
        self.task = 0
        self._request: GraspRequest | None = None
        self._phase_start = 0.0
        self._settled_since = None
        self._off_target_since = None
        self._contact_pa = 0.0
        self._held = (0.0, ObjectKind.FLAT)
        self._open_pa = 0.0
        self._clamp_pa = 0.0
        self._release_step = ReleaseStep.NONE
        # the hold's air: trapped since (s; None while the regulated line is open)
        self.air_trapped_since: float | None = None
        self.top_ups = 0
        # sensing: None when nothing judges the object (the verdicts never come)
        self.sensing_enabled = False
        self._closing_judged = False
        self._last_now = 0.0  # the latest time update() or command() was given

    @property
    def grasp(self) -> GraspRequest | None:
        """The command whose grasp runs (None when none does)."""
        return self._request

    @property
    def now_s(self) -> float:
        """The latest time :meth:`update` or :meth:`command` was given (s)."""
        return self._last_now

    # ---- commands -----------------------------------------------------------------------------
    def command(self, request: GraspRequest, now: float,
                controller_fault: str = "") -> Rejection | None:
        """Accept ``request`` (None returned) or reject it (its Rejection returned); nothing
        moves on a rejection. Each mode has a planner that checks the command and works out what
        it does."""
        self._last_now = now
        try:
            mode = GraspMode(request.mode)
        except ValueError:
            return self._reject(request, f"unknown mode {request.mode}")
        if controller_fault and mode != GraspMode.STOP:
            return self._reject(request,
                                f"the pressure controller reports a fault: {controller_fault}")
        return self._accept(request, self._planners[mode](request), now)

    def close_on(self, diameter_m: float, force_n: float, now: float, command_id: str = "",
                 controller_fault: str = "") -> Rejection | None:
        """Close until the fingers press an object ``diameter_m`` wide with ``force_n`` each (the
        clamp force law inverted: the clamp pressure is the one at which that force comes out),
        from any phase but FAULT; CLAMPING, then HOLDING. The gripper actions' closing goal: None
        or why it is refused."""
        request = GraspRequest(GraspMode.PINCH if diameter_m <= self.config.pinch_max_diameter_m
                               else GraspMode.CLAMP, object_diameter_m=diameter_m,
                               command_id=command_id)
        if controller_fault:
            return self._reject(request,
                                f"the pressure controller reports a fault: {controller_fault}")
        return self._accept(request, self._plan_close(diameter_m, force_n), now)

    def _plan_close(self, diameter_m: float, force_n: float) -> "Plan | str":
        c = self.config
        high = self.kinematics.tip_spacing_range_m()[1]
        if not (math.isfinite(diameter_m) and 0.0 <= diameter_m <= high):
            return (f"the opening must lie in [0, {high * 1e3:.1f}] mm, got "
                    f"{diameter_m * 1e3:.1f} mm")
        if not (math.isfinite(force_n) and force_n >= 0.0):
            return f"the force must be finite and >= 0 N, got {force_n}"
        kind = ObjectKind.FLAT if diameter_m <= c.pinch_max_diameter_m else ObjectKind.ROUND
        law = self.force_law
        contact = law.contact_pressure_pa(diameter_m, kind)
        if math.isnan(contact):
            return self._out_of_reach(diameter_m)
        most_n = law.normal_force_n(c.min_gauge_pa, diameter_m, kind)
        if force_n > most_n:
            return (f"an effort of {force_n:.2f} N needs more vacuum than the limit "
                    f"{c.min_gauge_pa / 1e3:.0f} kPa allows at {diameter_m * 1e3:.1f} mm "
                    f"(at most {most_n:.2f} N)")
        clamp = max(law.pressure_for_force(force_n, diameter_m, kind), c.min_gauge_pa)
        grasp = GraspRequest(GraspMode.PINCH if diameter_m <= c.pinch_max_diameter_m
                             else GraspMode.CLAMP, object_diameter_m=diameter_m)
        return Plan(Phase.CLAMPING, self._pressure(clamp), f"closing to {diameter_m * 1e3:.1f} mm",
                    grasp=grasp, clamp_pa=clamp, contact_pa=contact, held=(diameter_m, kind))

    def hold_here(self, now: float, message: str) -> None:
        """Keep the present pressure, valves closed (a canceled gripper goal, as the
        ros2_controllers gripper controllers stop where they are): held open (ENVELOPED) at a
        positive pressure, held closed (HOLDING) at a negative one. A new task: whatever ran is
        over. STOP still vents."""
        estimate = self.state.estimated_gauge_pa
        target = estimate if math.isfinite(estimate) else self.request.target_gauge_pa
        self.task += 1
        phase = Phase.HOLDING if target < 0.0 else Phase.ENVELOPED
        if phase == Phase.HOLDING:
            self._clamp_pa = target
        self._enter(phase, PressureRequest(target, Source.HOLD), now, message)

    def _accept(self, request: GraspRequest, plan: "Plan | str",
                now: float) -> Rejection | None:
        if isinstance(plan, str):
            return self._reject(request, plan)
        self.state.command_rejected = False
        self.state.command_id, self.state.mode = request.command_id, request.mode
        self.accepted += 1
        if plan.new_task:
            self.task += 1
        if plan.grasp is not None:
            self._request = plan.grasp
        self._open_pa = plan.open_pa if plan.open_pa is not None else self._open_pa
        self._clamp_pa = plan.clamp_pa if plan.clamp_pa is not None else self._clamp_pa
        self._contact_pa = plan.contact_pa if plan.contact_pa is not None else self._contact_pa
        self._held = plan.held if plan.held is not None else self._held
        self._release_step = plan.release_step
        self._enter(plan.phase, plan.pressure, now, plan.message)
        return None

    def refuse(self, command_id: str, reason: str) -> Rejection:
        """Say in the state why a command from elsewhere (a gripper goal) was refused, changing
        nothing else, as a rejected GraspCommand does."""
        return self._reject(GraspRequest(GraspMode.STOP, command_id=command_id), reason)

    def _reject(self, request: GraspRequest, reason: str) -> Rejection:
        self.state.command_rejected, self.state.message = True, f"rejected: {reason}"
        self.state.command_id = request.command_id
        self.changes += 1
        return Rejection(reason)

    @property
    def _planners(self) -> dict:
        return {
            GraspMode.STOP: self._plan_stop, GraspMode.RELEASE: self._plan_release,
            GraspMode.CLAMP: self._plan_clamp, GraspMode.OPEN: self._plan_open,
            GraspMode.PINCH: self._plan_grasp, GraspMode.ENVELOP_CLAMP: self._plan_grasp
        }

    def _plan_stop(self, r: GraspRequest) -> "Plan":
        return Plan(Phase.RELEASING, PressureRequest(0.0, Source.VENT), "stopping: venting",
                    release_step=ReleaseStep.STOP)

    def _plan_release(self, r: GraspRequest) -> "Plan":
        return Plan(Phase.RELEASING, PressureRequest(0.0, Source.VENT), "releasing: venting",
                    release_step=ReleaseStep.VENT)

    def _plan_clamp(self, r: GraspRequest) -> "Plan | str":
        """CLAMP goes on with the grasp the gripper holds open (ENVELOP_CLAMP, or OPEN with the
        object named here): the same task, so that its goal ends at HOLDING rather than being
        superseded."""
        running = self._request
        if self.state.phase != Phase.ENVELOPED or running is None:
            return f"CLAMP needs the ENVELOPED phase, the gripper is {self.state.phase.name}"
        contradiction = self._overrides(GraspMode.CLAMP, r)
        if contradiction:
            return contradiction
        if GraspMode(running.mode) == GraspMode.ENVELOP_CLAMP:
            clamp = self._clamp_pa if math.isnan(r.clamp_pressure_pa) else r.clamp_pressure_pa
            if clamp >= self._contact_pa:
                return (f"clamp_pressure_pa {clamp:.0f} Pa does not squeeze: contact is at "
                        f"{self._contact_pa:.0f} Pa")
            return Plan(Phase.CLAMPING, self._pressure(clamp), "clamping", new_task=False,
                        clamp_pa=clamp)
        # held open by OPEN: this CLAMP must say what it holds, or how hard
        if math.isnan(r.clamp_pressure_pa) and (math.isnan(r.object_diameter_m) or
                                                math.isnan(r.object_mass_kg)):
            return ("CLAMP after OPEN needs object_diameter_m and object_mass_kg, or "
                    "clamp_pressure_pa: nothing else "
                    "says how hard to squeeze")
        held = (None if math.isnan(r.object_diameter_m) else self._object_plan(
            r, margin_m=0.0, check_size=False))
        if isinstance(held, str):
            return held
        spacing = max(self.state.tip_spacing_m, self.kinematics.tip_spacing_range_m()[0])
        contact = (held.contact_pa
                   if held is not None else self.kinematics.pressure_for_tip_spacing(spacing))
        clamp = held.clamp_pa if held is not None else r.clamp_pressure_pa
        if clamp >= contact:
            return (f"clamp_pressure_pa {clamp:.0f} Pa does not squeeze: contact is at "
                    f"{contact:.0f} Pa")
        grasp = dataclasses.replace(running, object_diameter_m=r.object_diameter_m,
                                    object_mass_kg=r.object_mass_kg)
        return Plan(Phase.CLAMPING, self._pressure(clamp), "clamping", new_task=False, grasp=grasp,
                    clamp_pa=clamp, contact_pa=contact,
                    held=held.held if held is not None else (spacing, ObjectKind.ROUND))

    def _plan_open(self, r: GraspRequest) -> "Plan | str":
        problem = self._overrides(GraspMode.OPEN, r)
        if problem:
            return problem
        high = self.kinematics.tip_spacing_range_m()[1]
        # NaN: fully open
        spacing = high if math.isnan(r.target_tip_spacing_m) else r.target_tip_spacing_m
        if not math.isfinite(spacing) or spacing < 0.0:
            return ("OPEN needs a finite, non-negative target_tip_spacing_m (NaN: fully open), "
                    f"got {spacing}")
        if spacing > high:
            return (f"target_tip_spacing_m {spacing * 1e3:.1f} mm is wider than the gripper opens "
                    f"({high * 1e3:.1f} mm)")
        if not math.isnan(r.open_pressure_pa) and self.kinematics.pose(
                r.open_pressure_pa).tip_spacing_m < spacing:
            return (
                f"open_pressure_pa {r.open_pressure_pa:.0f} Pa opens the tips to "
                f"{self.kinematics.pose(r.open_pressure_pa).tip_spacing_m * 1e3:.1f} mm, short of "
                f"target_tip_spacing_m {spacing * 1e3:.1f} mm")
        open_pa = self._open_pressure(spacing, r.open_pressure_pa)
        return Plan(Phase.OPENING, self._pressure(open_pa), "opening",
                    grasp=dataclasses.replace(r, target_tip_spacing_m=spacing), open_pa=open_pa)

    def _plan_grasp(self, r: GraspRequest) -> "Plan | str":
        """PINCH (the tips close on the object) and ENVELOP_CLAMP (opened around it, then
        clamped)."""
        mode = GraspMode(r.mode)
        problem = self._overrides(mode, r)
        if problem:
            return problem
        c = self.config
        if mode == GraspMode.PINCH and math.isfinite(
                r.object_diameter_m) and r.object_diameter_m > c.pinch_max_diameter_m:
            return (f"PINCH takes objects up to {c.pinch_max_diameter_m * 1e3:.1f} mm, got "
                    f"{r.object_diameter_m * 1e3:.1f} mm: use ENVELOP_CLAMP")
        plan = self._object_plan(
            r, margin_m=c.envelop_margin_m if mode == GraspMode.ENVELOP_CLAMP else 0.0)
        if isinstance(plan, str) or mode == GraspMode.PINCH:
            return plan
        needed = r.object_diameter_m + c.envelop_margin_m
        if not math.isnan(r.open_pressure_pa) and self.kinematics.pose(
                r.open_pressure_pa).tip_spacing_m < needed:
            return (
                f"open_pressure_pa {r.open_pressure_pa:.0f} Pa opens the tips to "
                f"{self.kinematics.pose(r.open_pressure_pa).tip_spacing_m * 1e3:.1f} mm, short of "
                "the object plus margin")
        open_pa = self._open_pressure(needed, r.open_pressure_pa)
        return dataclasses.replace(plan, phase=Phase.OPENING, pressure=self._pressure(open_pa),
                                   message="opening", open_pa=open_pa)

    def _object_plan(self, r: GraspRequest, margin_m: float,
                     check_size: bool = True) -> "Plan | str":
        """The object's checks and its clamp: PINCH's plan, which ENVELOP_CLAMP starts with an
        opening."""
        c = self.config
        if not math.isfinite(r.object_diameter_m) or r.object_diameter_m < 0.0:
            return f"object_diameter_m must be finite and >= 0, got {r.object_diameter_m}"
        if not math.isfinite(r.object_mass_kg) or r.object_mass_kg < 0.0:
            return f"object_mass_kg must be finite and >= 0, got {r.object_mass_kg}"
        mu = r.friction_coefficient
        if not math.isnan(mu) and not (math.isfinite(mu) and 0.0 < mu <= 2.0):
            return ("friction_coefficient must lie in (0, 2] (NaN: the default "
                    f"{self.force_law.friction_coefficient}), got {mu}")
        high = self.kinematics.tip_spacing_range_m()[1]
        if check_size and r.object_diameter_m + margin_m > high:
            return (f"the object ({r.object_diameter_m * 1e3:.1f} mm plus {margin_m * 1e3:.0f} mm "
                    "margin) is wider "
                    f"than the gripper opens ({high * 1e3:.1f} mm)")
        kind = ObjectKind.FLAT if GraspMode(r.mode) == GraspMode.PINCH else ObjectKind.ROUND
        law = self.force_law
        contact = law.contact_pressure_pa(r.object_diameter_m, kind)
        if math.isnan(contact):
            return self._out_of_reach(r.object_diameter_m)
        mu = None if math.isnan(mu) else mu
        clamp = (r.clamp_pressure_pa if not math.isnan(r.clamp_pressure_pa) else
                 law.clamp_pressure_pa(r.object_mass_kg, r.object_diameter_m, kind, mu))
        if clamp < c.min_gauge_pa:
            most_kg = law.mass_held_kg(
                law.normal_force_n(c.min_gauge_pa, r.object_diameter_m, kind), mu)
            return (
                f"holding {r.object_mass_kg:.3g} kg needs {max(clamp, -1e9) / 1e3:.1f} kPa, "
                f"below the limit {c.min_gauge_pa / 1e3:.0f} kPa: too heavy for this gripper (at "
                f"most {most_kg:.3g} kg at {r.object_diameter_m * 1e3:.1f} mm with friction "
                f"{law.friction_coefficient if mu is None else mu:g} and safety factor "
                f"{law.safety_factor:g})")
        if clamp >= contact:
            return (f"clamp_pressure_pa {clamp:.0f} Pa does not squeeze: contact is at "
                    f"{contact:.0f} Pa")
        return Plan(Phase.CLAMPING, self._pressure(clamp), "pinching", grasp=r, clamp_pa=clamp,
                    contact_pa=contact, held=(r.object_diameter_m, kind))

    def _out_of_reach(self, diameter_m: float) -> str:
        return (f"the clamp force law has no force for a {diameter_m * 1e3:.1f} mm object: the "
                "opened fingers cannot take it level with their tip chambers")

    def _overrides(self, mode: GraspMode, r: GraspRequest) -> str:
        """The pressure overrides within the limits, and none that contradicts the mode."""
        c = self.config
        for name in ("open_pressure_pa", "clamp_pressure_pa"):
            value = getattr(r, name)
            if not math.isnan(value) and not (math.isfinite(value) and
                                              c.min_gauge_pa <= value <= c.max_gauge_pa):
                return (f"{name} {value} Pa is beyond the pressure limits [{c.min_gauge_pa:.0f}, "
                        f"{c.max_gauge_pa:.0f}] Pa")
        return self._contradiction(mode, r)

    @staticmethod
    def _contradiction(mode: GraspMode, r: GraspRequest) -> str:
        """Why an override contradicts its mode ('' when none does): positive pressure opens and
        negative pressure clamps, and a mode that never opens or never clamps takes no such
        override (it could only mean that the sender wanted another mode)."""
        opens, clamps = mode in (GraspMode.ENVELOP_CLAMP,
                                 GraspMode.OPEN), mode in (GraspMode.ENVELOP_CLAMP,
                                                           GraspMode.PINCH, GraspMode.CLAMP)
        if not math.isnan(r.open_pressure_pa):
            if not opens:
                return (f"{mode.name} does not open: open_pressure_pa must be NaN, got "
                        f"{r.open_pressure_pa:.0f} Pa")
            if r.open_pressure_pa <= 0.0:
                return (
                    "open_pressure_pa must be > 0 (positive pressure opens the fingers; negative "
                    "closes them), "
                    f"got {r.open_pressure_pa:.0f} Pa")
        if not math.isnan(r.clamp_pressure_pa):
            if not clamps:
                return (f"{mode.name} does not clamp: clamp_pressure_pa must be NaN, got "
                        f"{r.clamp_pressure_pa:.0f} Pa")
            if r.clamp_pressure_pa > 0.0:
                return (
                    f"clamp_pressure_pa must be <= 0 (negative pressure clamps; positive opens), "
                    f"got {r.clamp_pressure_pa:.0f} Pa")
        return ""

    def _open_pressure(self, tip_spacing_m: float, override_pa: float) -> float:
        if not math.isnan(override_pa):
            return override_pa
        return min(
            self.kinematics.pressure_for_tip_spacing(tip_spacing_m) +
            self.config.pressure_tolerance_pa, self.config.max_gauge_pa)

    # ---- time ---------------------------------------------------------------------------------
    def update(self, now: float, estimate_gauge_pa: float, estimate_std_pa: float = math.nan,
               controller_fault: str = "", controller_blind: bool = False,
               controller_safe_state: bool = False) -> GraspState:
        """Advance on a new estimate (NaN when none) and the controller's fault ('' when none).
        ``controller_blind``: that fault is only the controller not seeing the chamber (see
        :meth:`ControllerFeedback.blind`): FAULT then holds the valves closed instead of venting.
        ``controller_safe_state``: the controller vents on a safety fault. That gives FAULT from
        IDLE too (a fault found just after a release ends, for one): grasp_state then says why
        the next grasp is refused, and IDLE's hold is not asked for again."""
        s, c = self.state, self.config
        self._last_now = now
        s.estimated_gauge_pa, s.estimated_std_pa = estimate_gauge_pa, estimate_std_pa
        self._model(estimate_gauge_pa)
        idle_and_safe = s.phase == Phase.IDLE and controller_safe_state
        if controller_fault and (s.phase not in (Phase.IDLE, Phase.FAULT) or idle_and_safe):
            if controller_blind:
                self._enter(
                    Phase.FAULT, PressureRequest(self.request.target_gauge_pa, Source.HOLD), now,
                    f"fault: {controller_fault}: the pressure controller holds the valves closed "
                    f"(nothing can confirm a vent while it cannot see the chamber)")
            else:
                self._enter(Phase.FAULT, PressureRequest(0.0, Source.VENT), now,
                            f"fault: {controller_fault}; venting")
            return s
        settled = self._settled(now, estimate_gauge_pa)
        elapsed = now - self._phase_start
        if s.phase == Phase.OPENING:
            clears = s.tip_spacing_m >= self._required_spacing() - 1e-9
            if settled and clears:
                self._enter(Phase.ENVELOPED, self.request, now,
                            f"enveloped: D2 {s.tip_spacing_m * 1e3:.1f} mm")
            elif elapsed > c.opening_timeout_s:
                self._timeout(now, "opening")
        elif s.phase == Phase.ENVELOPED:
            if (self._request is not None and
                    GraspMode(self._request.mode) == GraspMode.ENVELOP_CLAMP and
                    c.auto_clamp_delay_s >= 0.0 and elapsed >= c.auto_clamp_delay_s):
                self._enter(Phase.CLAMPING, self._pressure(self._clamp_pa), now,
                            "clamping (automatic)")
        elif s.phase == Phase.HOLDING:
            self._check_hold(now, estimate_gauge_pa)
            if s.phase == Phase.HOLDING and c.hold_air == "trap":
                self._trap_air(now, estimate_gauge_pa, settled)
        elif s.phase == Phase.CLAMPING:
            if settled:
                self._enter(Phase.HOLDING, self.request, now, "holding")
                if c.hold_air == "trap":  # settled already: the air is trapped at once
                    self._trap_air(now, estimate_gauge_pa, True)
            elif elapsed > c.clamping_timeout_s:
                self._timeout(now, "clamping")
        elif s.phase == Phase.RELEASING:
            vented = (math.isfinite(estimate_gauge_pa) and
                      abs(estimate_gauge_pa) < c.vented_below_pa)
            if self._release_step == ReleaseStep.STOP and vented:
                self._request = None
                self._enter(Phase.IDLE, PressureRequest(0.0, Source.VENT), now,
                            f"stopped: vented ({estimate_gauge_pa / 1e3:.1f} kPa)")
            elif self._release_step == ReleaseStep.STOP and elapsed > c.releasing_timeout_s:
                self._timeout(now, "stopping (the vent)")
            elif self._release_step == ReleaseStep.VENT and vented:
                self._release_step = ReleaseStep.OPEN
                spacing = c.release_tip_spacing_m
                if self._request is not None and math.isfinite(self._request.object_diameter_m):
                    spacing = max(spacing, self._request.object_diameter_m + c.envelop_margin_m)
                self._enter(Phase.RELEASING, self._pressure(self._open_pressure(spacing,
                                                                                math.nan)), now,
                            "releasing: opening")
            elif self._release_step == ReleaseStep.OPEN and settled:
                self._request = None
                self._enter(Phase.IDLE, PressureRequest(self.request.target_gauge_pa, Source.HOLD),
                            now, "released")
            elif elapsed > c.releasing_timeout_s:
                self._timeout(now, "releasing")
        # a clamp whose pressure is unknown for a tick (a starved host: the estimate and the
        # sensors both stale) has a force nobody knows, not none
        holding = s.phase in (Phase.CLAMPING, Phase.HOLDING)
        s.clamp_force_n = (0.0 if not holding else math.nan if not math.isfinite(estimate_gauge_pa)
                           else self.force_law.normal_force_n(estimate_gauge_pa, *self._held))
        return s

    def _check_hold(self, now: float, estimate: float) -> None:
        """HOLDING lost: the pressure off its target by more than hold_error_limit_pa for
        hold_error_time_s."""
        c = self.config
        if not math.isfinite(estimate) or abs(
                estimate - self.request.target_gauge_pa) <= c.hold_error_limit_pa:
            self._off_target_since = None
            return
        if self._off_target_since is None:
            self._off_target_since = now
        elif now - self._off_target_since >= c.hold_error_time_s:
            self._enter(
                Phase.FAULT, PressureRequest(0.0, Source.VENT), now,
                f"fault: holding lost, {estimate:.0f} Pa against a target of "
                f"{self.request.target_gauge_pa:.0f} Pa; venting")

    def _trap_air(self, now: float, estimate: float, settled: bool) -> None:
        """HOLDING with trapped air: close the valves once settled at the target (at once on
        entering HOLDING, which the clamp reached settled); top up (regulate again) when the
        pressure drifts past the tolerance, and close them again once settled."""
        c, target = self.config, self.request.target_gauge_pa
        if self.request.source in (Source.SUPPLY, Source.VACUUM):
            if settled:
                self.request = PressureRequest(target, Source.HOLD)
                self.air_trapped_since = now
                self.changes += 1
        elif (self.request.source == Source.HOLD and math.isfinite(estimate) and
              abs(estimate - target) > c.pressure_tolerance_pa):
            self.request = self._pressure(target)
            self.air_trapped_since = None
            self._settled_since = None
            self.top_ups += 1
            self.changes += 1

    def sensed(self, detection: Detection, now: float) -> None:
        """The air's verdict on the object (see :mod:`softgrip_ros.estimation.grasp_sensing`).
        In HOLDING: NO_OBJECT ends the grasp's goal as failed ("closed on nothing"), the fingers
        still closed; LOST does what ``on_object_lost`` says."""
        s, c = self.state, self.config
        previous = s.object_status
        s.object_status, s.object_evidence = detection.status, detection.evidence
        s.object_size_m = detection.object_size_m
        if detection.status in (ObjectStatus.CONTACT_CLOSING, ObjectStatus.NO_OBJECT,
                                ObjectStatus.HELD) or (
                detection.status == ObjectStatus.UNKNOWN and s.phase == Phase.HOLDING):
            self._closing_judged = True
        if detection.status != previous:
            self.changes += 1
        if s.phase != Phase.HOLDING or detection.status == previous:
            return
        if detection.status == ObjectStatus.NO_OBJECT:
            s.message = f"closed on nothing: {detection.evidence}"
        elif detection.status == ObjectStatus.LOST:
            if c.on_object_lost == "fault":
                self._enter(Phase.FAULT, PressureRequest(0.0, Source.VENT), now,
                            f"fault: object lost ({detection.evidence}); venting")
            elif c.on_object_lost == "release":
                self._release_step = ReleaseStep.VENT
                self._enter(Phase.RELEASING, PressureRequest(0.0, Source.VENT), now,
                            f"object lost, releasing: {detection.evidence}")
            else:
                s.message = f"object lost: {detection.evidence}"

    def _required_spacing(self) -> float:
        r = self._request
        if r is None:
            return 0.0
        if GraspMode(r.mode) == GraspMode.OPEN:
            return r.target_tip_spacing_m
        # an override was checked against the object when accepted; the estimate's tolerance then
        # rules
        return (r.object_diameter_m +
                self.config.envelop_margin_m if math.isnan(r.open_pressure_pa) else 0.0)

    def _settled(self, now: float, estimate: float) -> bool:
        near = math.isfinite(estimate) and abs(
            estimate - self.request.target_gauge_pa) <= self.config.pressure_tolerance_pa
        if not near or self.request.source in (Source.VENT, Source.HOLD):
            self._settled_since = None
            return False
        if self._settled_since is None:
            self._settled_since = now
        return now - self._settled_since >= self.config.settle_s

    def held_object_m(self) -> float:
        """The size of the commanded object while it is between the fingers: CLAMPING, HOLDING, or
        RELEASING it until the fingers open past it (a cylinder's diameter, or for PINCH a sheet's
        thickness); 0 otherwise. The tips rest on it: for 20 and 40 mm cylinders held at the clamp
        pressure the L2 rod puts the tip-chamber faces within 0.5 mm of the diameter, where free
        bending gives 0 (tests/test_model_fidelity.py)."""
        r = self._request
        if (r is None or
                self.state.phase not in (Phase.CLAMPING, Phase.HOLDING, Phase.RELEASING) or
                not math.isfinite(r.object_diameter_m)):
            return 0.0
        return r.object_diameter_m

    def scene(self) -> Scene:
        """What the fingers meet: the commanded object while it is between them (see
        :meth:`held_object_m`; a cylinder level with the tip chambers at the opening pressure, or
        for PINCH a sheet), else free bending."""
        r = self._request
        if self.scene_model is None or self.held_object_m() <= 0.0:
            return FREE
        key = (GraspMode(r.mode), r.object_diameter_m, self._open_pa)
        if key not in self._scenes:
            self._scenes = {
                key: Scene(Sheet(r.object_diameter_m), 0.0) if key[0] == GraspMode.PINCH else
                cylinder_scene(self.scene_model.rod, r.object_diameter_m, self._open_pa)
            }
        return self._scenes[key]

    def _model(self, estimate: float) -> None:
        s = self.state
        if not math.isfinite(estimate):
            return
        if self.scene_model is not None:
            s.model_fidelity = self.scene_model.selector.choose(estimate, self.scene()).model
        k = self.kinematics
        pose = k.pose(min(max(estimate, k.MODEL_MIN_PRESSURE_PA), k.MODEL_MAX_PRESSURE_PA))
        s.included_angle_rad, s.root_spacing_m = pose.included_angle_rad, pose.root_spacing_m
        s.tip_spacing_m = max(pose.tip_spacing_m, self.held_object_m())
        s.in_validated_range = bool(
            pose.in_validated_range) and estimate <= k.MODEL_MAX_PRESSURE_PA

    def _pressure(self, target: float) -> PressureRequest:
        return PressureRequest(target, Source.SUPPLY if target >= 0.0 else Source.VACUUM)

    def _timeout(self, now: float, what: str) -> None:
        self._enter(
            Phase.FAULT, PressureRequest(0.0, Source.VENT), now,
            f"fault: {what} timed out at {self.state.estimated_gauge_pa:.0f} Pa "
            f"(target {self.request.target_gauge_pa:.0f} Pa); venting")

    def _enter(self, phase: Phase, request: PressureRequest, now: float, message: str) -> None:
        self.state.phase, self.state.message = phase, message
        self.state.target_gauge_pa = (request.target_gauge_pa
                                      if request.source != Source.VENT else 0.0)
        self.request = request
        self._phase_start, self._settled_since, self._off_target_since = now, None, None
        self.air_trapped_since = None
        if phase == Phase.CLAMPING:
            self._closing_judged = False
        self.changes += 1

    def done(self, mode: int) -> bool:
        """Whether a command of ``mode`` has finished (or failed)."""
        return (self.state.phase == Phase.FAULT or
                self.state.phase in TERMINAL.get(GraspMode(mode), ()))

    def outcome(self, task: int, mode: int) -> GoalOutcome:
        """How a goal stands: the command of ``mode`` that started or went on with ``task``.
        RUNNING until SUCCEEDED at its mode's end (HOLDING for ENVELOP_CLAMP, PINCH and CLAMP;
        ENVELOPED for OPEN; IDLE for RELEASE and STOP), FAILED in FAULT or on nothing, SUPERSEDED
        once another command started a task of its own (a CLAMP that goes on with it does not)."""
        if self.task != task:
            return GoalOutcome.SUPERSEDED
        if self.state.phase == Phase.FAULT:
            return GoalOutcome.FAILED
        if self.state.phase not in TERMINAL.get(GraspMode(mode), ()):
            return GoalOutcome.RUNNING
        if self.state.phase == Phase.HOLDING and self.sensing_enabled:
            if self.state.object_status == ObjectStatus.NO_OBJECT:
                return GoalOutcome.FAILED
            if self.sensing_pending():
                return GoalOutcome.RUNNING
        return GoalOutcome.SUCCEEDED

    def sensing_pending(self) -> bool:
        """HOLDING, and the air's verdict on the closing is still to come (for at most
        ``sensing_wait_s``)."""
        return (self.state.phase == Phase.HOLDING and self.sensing_enabled and
                not self._closing_judged and
                self._last_now - self._phase_start < self.config.sensing_wait_s)

    def object_held(self) -> bool:
        """Whether the air says an object is between the fingers (HELD or found by the closing,
        in HOLDING). Without sensing nothing says so: False, whatever the phase."""
        return (self.sensing_enabled and self.state.phase == Phase.HOLDING and
                self.state.object_status in HOLDING_STATUSES)

"""Sensing the grasp from the air: whether the fingers met an object, how large it felt, and
whether it is still held (no ROS; no new hardware).

**The physics it rests on.** A finger held back by an object cannot bend as far as the pressure
asks, so its chambers' volume stops following the free fingers' V(p): the bending's share of the
chambers' compliance (``bending_volume_share`` of dV/dp, the FE's figure, the rest being the walls
ballooning, which a blocked finger still does) is held at its value at contact. Closing under
vacuum from a contact pressure p_c, the chambers hold ``B(p_c) - B(p)`` more air volume than free
fingers would, B(p) = share x dV/dp x p (gauge). Fingers that close on nothing meet each other at
``meet_pressure_pa`` and are held back from there. The pressure the sensors read depends on that
volume only through the air's mass balance while air flows: at a steady regulated pressure the
chamber sits at the regulator's output whatever its volume.

- **Contact while closing** (:func:`fit_contact`): the plant is simulated from a steady start
  through the recorded regulator commands and valve states, once per contact-pressure hypothesis
  (vectorised), and the hypothesis whose pressure trace best explains every sensor reading
  (weighted least squares, i.e. maximum likelihood under Gaussian noise) gives p_c, its standard
  error from the curvature, and the object's size as the fingers felt it, D2(p_c) of the
  kinematics (:func:`judge_closing`: the commanded object against nothing, by their odds).
  The readings' stamps are first aligned on the motion's start (:func:`readings_lead_s`): the
  fit is as sensitive to the outputs' timing as to contact.
- **Loss during a hold** (:class:`LossDetector`): with the valves closed on the hold's air, an
  object leaving the hand lets the fingers close onto each other, the chambers' volume drops by
  ``B(p_c) - B(p_meet)`` within the fingers' response time, and at the air's fixed mass the
  pressure steps by ``p |dV| / (V + p dV/dp)`` and stays (with the regulated line open, the line
  absorbs it within ms). A step of the expected sign and size, on every live sensor, is a loss
  (one biased or stuck sensor is a sensor fault, the safety monitor's to name).

**What it cannot tell apart.** An object thinner than the fingers' closing resolution (a 0.1 mm
sheet in a pinch: the fingers meet it where they would meet each other) from nothing; a very
soft object, which lets the fingers close almost as if free, from nothing; a loss of a small
object (the fingers close by little, the volume hardly changes) from noise. Each case ends
``UNKNOWN`` rather than a guess. The figures that bound it are in docs/grasp_sensing.md.
"""
from __future__ import annotations

import dataclasses
import enum
import math

import numpy as np

from softgrip_ros.checks import require_positive
from softgrip_ros.model.geometry import CHAMBER_COUNT
from softgrip_ros.model.pneumatics import (P_ATM_PA, PlantInputs, PlantState,
                                           PneumaticParameters, PneumaticPlant, Valve,
                                           orifice_flow_and_slope)

# the fit's simulation step (s): its linearly implicit Euler is within 30 Pa of the plant's truth
# integrator over a clamp (tests/test_grasp_sensing.py)
FIT_STEP_S = 2.5e-4
# contact-pressure hypotheses per fit, before the parabolic refinement
FIT_HYPOTHESES = 48


class ObjectStatus(enum.IntEnum):
    """GripperState.object_status (in the style of Robotiq's gOBJ)."""

    UNKNOWN = 0
    MOVING_NO_CONTACT = 1
    CONTACT_OPENING = 2
    CONTACT_CLOSING = 3
    HELD = 4
    NO_OBJECT = 5
    LOST = 6


@dataclasses.dataclass(frozen=True)
class Detection:
    """One finding of the grasp sensing: its status, a confidence in [0, 1], the evidence in
    words, when (s), and what was measured (NaN when not): the object's size as the fingers felt
    it (m), the contact pressure (Pa gauge) and the instant of contact (s)."""

    status: ObjectStatus
    confidence: float
    evidence: str
    stamp_s: float
    object_size_m: float = math.nan
    contact_pressure_pa: float = math.nan
    contact_time_s: float = math.nan


class FingerDynamics:
    """How a free finger's shape follows a changing pressure: its hinge chain, M q'' + D q' +
    K q = K h(p), h(p) the free bending's hinge angles (rad), M the chain's mass matrix (kg m^2),
    K and D its hinges' stiffness (N m/rad) and damping (N m s/rad). The shape is read back as
    the pressure whose free shape moves the tip as far (each hinge's turn weighted by its
    ``lever_arms_m`` to the tip chamber), so that contact is judged with the static kinematics.

    ``hinge_angles``: h, a gauge pressure (Pa) -> (n,) rad; ``pressure_range_pa``: where h is
    tabulated. ValueError on mismatched shapes or a non-positive stiffness."""

    def __init__(self, mass, stiffness, damping, hinge_angles, lever_arms_m,
                 pressure_range_pa: tuple = (-100e3, 60e3), table_step_pa: float = 250.0):
        self.mass = np.asarray(mass, dtype=float)
        self.stiffness = np.asarray(stiffness, dtype=float)
        self.damping = np.asarray(damping, dtype=float)
        n = self.stiffness.size
        if self.mass.shape != (n, n) or self.damping.shape != (n,):
            raise ValueError("mass must be (n, n) and damping (n,) for n hinge stiffnesses")
        if not np.all(self.stiffness > 0.0):
            raise ValueError("every hinge stiffness must be positive")
        low, high = pressure_range_pa
        self.table_pa = np.arange(low, high + 0.5 * table_step_pa, table_step_pa)
        self.table_angles = np.array([hinge_angles(p) for p in self.table_pa])
        self.weights = np.asarray(lever_arms_m, dtype=float)
        if self.weights.shape != (n,):
            raise ValueError("lever_arms_m must be (n,)")
        self.table_projection = self.table_angles @ self.weights
        if not np.all(np.diff(self.table_projection) > 0.0):
            raise ValueError("the free bending must turn the fingers monotonically with pressure")

    def shape_pressures(self, gauge_pa: np.ndarray, step_s: float) -> np.ndarray:
        """The pressure whose free shape the finger has (Pa gauge), per sample of ``gauge_pa``
        (T,) taken every ``step_s`` (s), from rest at ``gauge_pa[0]``; backward Euler."""
        gauge = np.asarray(gauge_pa, dtype=float)
        angles = np.array([np.interp(gauge, self.table_pa, self.table_angles[:, j])
                           for j in range(self.stiffness.size)]).T  # (T, n)
        system = (self.mass + step_s * np.diag(self.damping) +
                  step_s * step_s * np.diag(self.stiffness))
        solve = np.linalg.inv(system)
        q, v = angles[0].copy(), np.zeros(self.stiffness.size)
        shapes = np.empty(gauge.size)
        for k in range(gauge.size):
            v = solve @ (self.mass @ v + step_s * self.stiffness * (angles[k] - q))
            q = q + step_s * v
            shapes[k] = q @ self.weights
        return np.interp(shapes, self.table_projection, self.table_pa)


@dataclasses.dataclass(frozen=True)
class ContactModel:
    """The fingers' air model of contact. ``plant``: the pneumatics (the plant file's);
    ``bending_volume_share``: the share of dV/dp that the bending makes (dimensionless, in
    (0, 1)); ``meet_pressure_pa``: the gauge pressure at which free fingers meet each other;
    ``tip_spacing_m``: D2 (m) of a gauge pressure (Pa), the kinematics' free bending, and
    ``pressure_for_tip_spacing``: its inverse (Pa of m); ``dynamics``: how the fingers' shape
    lags a changing pressure; ``finger_mode_rad_s``: their first mode (rad/s), with whose
    2 / omega_1 the held-back volume follows; ``share_identified``: the share was measured on
    this gripper (softgrip_identify's known-object step), not the model's prediction."""

    plant: PneumaticParameters
    bending_volume_share: float
    meet_pressure_pa: float
    tip_spacing_m: object
    pressure_for_tip_spacing: object
    dynamics: FingerDynamics
    finger_mode_rad_s: float
    share_identified: bool = False

    def __post_init__(self):
        if not 0.0 < self.bending_volume_share < 1.0:
            raise ValueError("bending_volume_share must lie in (0, 1), got "
                             f"{self.bending_volume_share}")
        if not math.isfinite(self.meet_pressure_pa):
            raise ValueError("meet_pressure_pa must be finite")
        if not (math.isfinite(self.finger_mode_rad_s) and 1.0 <= self.finger_mode_rad_s <= 1e4):
            raise ValueError("finger_mode_rad_s must lie in [1, 10000] rad/s, got "
                             f"{self.finger_mode_rad_s}")

    def bending_volume_m3(self, gauge_pa):
        """B(p): the chambers' volume change (m^3) from 0 Pa that the free fingers' bending makes
        at ``gauge_pa`` (arrays allowed)."""
        gauge = np.asarray(gauge_pa, dtype=float)
        compliance = np.where(gauge >= 0.0, self.plant.chamber_compliance_m3_per_pa,
                              self.plant.vacuum_compliance_m3_per_pa)
        return self.bending_volume_share * compliance * gauge

    def held_back_m3(self, gauge_pa, contact_pa):
        """The air volume (m^3) fingers blocked since ``contact_pa`` hold beyond free ones at
        ``gauge_pa`` while closing (positive below the contact; zero above it)."""
        gauge = np.asarray(gauge_pa, dtype=float)
        contact = np.asarray(contact_pa, dtype=float)
        return np.where(gauge < contact,
                        self.bending_volume_m3(contact) - self.bending_volume_m3(gauge), 0.0)

    def loss_volume_m3(self, contact_pa: float) -> float:
        """How much the chambers' volume drops (m^3, positive) when an object that stopped the
        closing at ``contact_pa`` leaves and the fingers close onto each other."""
        return float(self.bending_volume_m3(contact_pa) -
                     self.bending_volume_m3(self.meet_pressure_pa))


def contact_model_for(gripper_model: str = "type_II", bending: str = "l0",
                      plant: PneumaticParameters | None = None,
                      bending_volume_share: float | None = None) -> ContactModel:
    """The built-in model's :class:`ContactModel`: the bending share (``bending_volume_share``,
    identified on this gripper, or None: the FE's prediction), the fingers' meeting pressure, D2
    of the kinematics and the fingers' first mode of the pseudo-rigid chain (their masses against
    their hinges' stiffness; MuJoCo computes the chain's mass matrix). ``plant``: the default
    plant's when None. RuntimeError when MuJoCo is missing; ValueError for a share outside
    (0, 1)."""
    from softgrip_ros.model import gripper_models
    from softgrip_ros.model.kinematics import GripperKinematics
    from softgrip_ros.model.world.fingers import FE_BENDING_VOLUME_SHARE, PseudoRigidFinger
    from softgrip_ros.model.world.scene import scene_from_document
    from softgrip_ros.model.world.world import GripperWorld

    geometry, calibration = gripper_models.resolve(gripper_model)
    kinematics = GripperKinematics(geometry, calibration, model=bending)
    finger = PseudoRigidFinger(geometry, calibration, bending=bending)
    bare = GripperWorld(scene_from_document({"name": "bare", "arm": {"start_m": [0, 0, 0.3]}}),
                        finger)
    tip_chamber_m = (CHAMBER_COUNT - 0.5) * geometry.segment_length_m
    levers = np.array([max(tip_chamber_m - arc.start_m, 0.0) for arc in finger.sub_arcs])
    dynamics = FingerDynamics(bare.hinge_mass_matrix(), finger.hinge_stiffness_nm_per_rad,
                              bare.hinge_damping(), finger.hinge_angles, levers)
    identified = bending_volume_share is not None
    return ContactModel(plant or PneumaticParameters(),
                        bending_volume_share if identified else FE_BENDING_VOLUME_SHARE,
                        float(finger.contact_pressure_pa),
                        lambda gauge_pa: float(kinematics.pose(gauge_pa).tip_spacing_m),
                        kinematics.pressure_for_tip_spacing, dynamics, bare.first_mode_rad_s,
                        identified)


# ---- what the fit reads ------------------------------------------------------------------------
@dataclasses.dataclass
class AirRecord:
    """What the air did since a steady start: the inputs in force from each stamp (regulator
    command Pa gauge, enabled, valve) and each sensor reading (stamp s, gauge Pa, its noise std
    Pa). ``start_gauge_pa``: the chamber's steady pressure at ``start_s``, which is also the
    regulator's output then."""

    start_s: float
    start_gauge_pa: float
    inputs: list = dataclasses.field(default_factory=list)  # [(stamp, PlantInputs)]
    samples: list = dataclasses.field(default_factory=list)  # [(stamp, gauge, std)]

    def add_inputs(self, stamp_s: float, inputs: PlantInputs) -> None:
        self.inputs.append((float(stamp_s), inputs))

    def add_sample(self, stamp_s: float, gauge_pa: float, std_pa: float) -> None:
        if math.isfinite(gauge_pa) and std_pa > 0.0:
            self.samples.append((float(stamp_s), float(gauge_pa), float(std_pa)))


@dataclasses.dataclass(frozen=True)
class ContactFit:
    """The closing's contact, fitted: ``contact_pa`` (Pa gauge) and its standard error, the
    instant the pressure crossed it (s; NaN when never), D2 there (m), ``z`` = how many
    standard errors the contact lies above the fingers' meeting pressure, and the fit's
    reduced chi-square (about 1 when the model explains the readings)."""

    contact_pa: float
    contact_std_pa: float
    contact_time_s: float
    object_size_m: float
    z: float
    reduced_chi2: float
    samples: int
    grid_pa: tuple = ()
    costs: tuple = ()

    def cost_at(self, contact_pa: float) -> float:
        """The fit's chi-square for the hypothesis ``contact_pa`` (Pa; interpolated on the
        grid; NaN outside it)."""
        if not self.grid_pa or not self.grid_pa[0] <= contact_pa <= self.grid_pa[-1]:
            return math.nan
        return float(np.interp(contact_pa, self.grid_pa, self.costs))


def simulate_hypotheses(record: AirRecord, model: ContactModel, contacts_pa: np.ndarray,
                        until_s: float, step_s: float = FIT_STEP_S,
                        block_steps=None) -> tuple:
    """The chamber's gauge pressure (Pa) from ``record.start_s`` to ``until_s`` for each contact
    hypothesis (K,): (times (T,), pressures (T, K)).

    Hypothesis k: the fingers stop where their free shape is that of ``contacts_pa[k]``. Their
    shape lags the pressure (``model.dynamics``, on the free fingers' pressure trace: until it
    stops them every hypothesis has that trace), so a fast closing meets an object at a lower
    pressure than its size says; once stopped they
    hold back ``B(contact) - B(p)`` of volume, followed with their response time ``2 / omega_1``
    (a contact's impulse does not move the walls at once). The air by linearly implicit Euler on
    its p V at a fixed volume over each step; the regulator exactly as the plant.
    ``block_steps``: the step at which each hypothesis stops the fingers (None: from
    :func:`contact_steps`)."""
    contacts = np.asarray(contacts_pa, dtype=float)
    steps = max(1, int(math.ceil((until_s - record.start_s) / step_s)))
    if block_steps is None:
        block_steps = contact_steps(record, model, contacts, steps, step_s)
    return _simulate(record, model, contacts, steps, step_s, block_steps)


def free_trace(record: AirRecord, model: ContactModel, steps: int, step_s: float,
               opening: bool = False) -> np.ndarray:
    """The chamber's gauge pressure (Pa) of free fingers through ``record``, per step (steps,)."""
    never = np.array([math.inf if opening else -math.inf])
    return _simulate(record, model, never, steps, step_s, None)[1][:, 0]


def contact_steps(record: AirRecord, model: ContactModel, contacts_pa: np.ndarray, steps: int,
                  step_s: float, opening: bool = False, free: np.ndarray | None = None
                  ) -> np.ndarray:
    """The step at which free fingers, closing (``opening``: opening) through ``record``, reach
    the shape of each of ``contacts_pa`` (``steps`` when they never do). ``free``: their
    pressure trace, when already simulated."""
    if free is None:
        free = free_trace(record, model, steps, step_s, opening)
    shapes = model.dynamics.shape_pressures(np.concatenate([[record.start_gauge_pa], free]),
                                            step_s)[1:]
    contacts = np.asarray(contacts_pa, dtype=float)[None, :]
    reached = shapes[:, None] >= contacts if opening else shapes[:, None] <= contacts
    return np.where(reached.any(axis=0), reached.argmax(axis=0), steps)


def _simulate(record: AirRecord, model: ContactModel, contacts: np.ndarray, steps: int,
              step_s: float, block_steps, share_scale=None) -> tuple:
    """simulate_hypotheses' air: hypothesis k blocked from step ``block_steps[k]`` (None:
    never), with the model's bending share times ``share_scale[k]`` (None: 1)."""
    plant = PneumaticPlant(model.plant)
    par = model.plant
    rt = par.gas_constant_times_temperature
    follow = 1.0 - math.exp(-0.5 * model.finger_mode_rad_s * step_s)
    p = np.full(contacts.shape, P_ATM_PA + record.start_gauge_pa)
    offset = np.zeros(contacts.shape)
    v, _ = plant.volume_and_swelling(p, offset)
    pv = p * v
    regulator = record.start_gauge_pa
    inputs_list = record.inputs
    times = record.start_s + step_s * np.arange(1, steps + 1)
    out = np.empty((steps, contacts.size))
    index, inputs = 0, PlantInputs(record.start_gauge_pa, True, (Valve.CLOSED,))
    while index < len(inputs_list) and inputs_list[index][0] <= record.start_s:
        inputs = inputs_list[index][1]
        index += 1
    blocked_at = (np.full(contacts.shape, steps) if block_steps is None
                  else np.asarray(block_steps))
    held_at_contact = model.bending_volume_m3(np.where(np.isfinite(contacts), contacts, 0.0))
    scale = 1.0 if share_scale is None else np.asarray(share_scale, dtype=float)
    for k, now in enumerate(times):
        while index < len(inputs_list) and inputs_list[index][0] < now:
            inputs = inputs_list[index][1]
            index += 1
        regulator = plant.regulator_step(regulator, inputs, step_s)[0]
        valve = Valve(inputs.valves[0])
        source_pa, conductance = plant.source(valve, regulator, inputs.regulator_enabled)
        if conductance > 0.0:
            flow, slope = orifice_flow_and_slope(source_pa, p, conductance, par.path(valve)[1],
                                                 par.temperature_k)
            v, dv = plant.volume_and_swelling(p, offset)
            # p V rises by R T m_dot: linearly implicit in the chamber's pressure
            pv = pv + step_s * rt * flow / (1.0 - step_s * rt * slope / (v + p * dv))
        gauge = p - P_ATM_PA
        target = np.where(blocked_at <= k,
                          scale * (held_at_contact - model.bending_volume_m3(gauge)), 0.0)
        offset = offset + follow * (target - offset)
        for _ in range(2):  # Newton on p (V(p) + offset) = pv
            v, dv = plant.volume_and_swelling(p, offset)
            p = np.maximum(p - (p * v - pv) / (v + p * dv), 1e3)
        out[k] = p - P_ATM_PA
    return times, out


# how far the readings' stamps may lead or lag the controller's outputs' (s), and the share of the
# motion's pressure change whose readings align them (the fingers cannot reach an object the
# opening cleared by the margin before the pressure has gone this far)
MAX_READING_LEAD_S = 0.025
ALIGNING_SHARE = 0.4


def readings_lead_s(record: AirRecord, times: np.ndarray, free: np.ndarray,
                    until_s: float) -> float:
    """How far the readings' stamps lead the outputs' (s, within +-MAX_READING_LEAD_S): the
    shift that best fits the free fingers' trace to the readings of the motion's first
    ``ALIGNING_SHARE`` (weighted least squares on a 0.5 ms grid). Readings are stamped when the
    device measured them and the outputs when their frames went out, through two clock
    mappings: a few ms apart is the rule, and a fit of contact would read them as air."""
    start, end = record.start_gauge_pa, float(free[-1])
    span = end - start
    if abs(span) < 1e3:
        return 0.0
    early = [(t, v, sd) for t, v, sd in record.samples
             if record.start_s - MAX_READING_LEAD_S < t <= until_s and
             (v - start) / span < ALIGNING_SHARE]
    if len(early) < 5:
        return 0.0
    stamps = np.array([t for t, _, _ in early])
    values = np.array([v for _, v, _ in early])
    weights = 1.0 / np.array([sd for _, _, sd in early]) ** 2
    before = np.concatenate([[record.start_s], times])
    trace = np.concatenate([[start], free])
    shifts = np.arange(-MAX_READING_LEAD_S, MAX_READING_LEAD_S + 1e-9, 5e-4)
    costs = [float(np.sum(weights * (values - np.interp(stamps - shift, before, trace)) ** 2))
             for shift in shifts]
    return float(shifts[int(np.argmin(costs))])


def fit_contact(record: AirRecord, model: ContactModel, until_s: float,
                low_pa: float, high_pa: float, hypotheses: int = FIT_HYPOTHESES,
                opening: bool = False) -> ContactFit:
    """The contact pressure within [``low_pa``, ``high_pa``] (Pa gauge) that best explains
    ``record``'s readings up to ``until_s`` (see the module). Closing, ``z`` is taken against
    the fingers meeting each other; ``opening``, against the fingers never stopped (``high_pa``,
    the opening's end), positive when they stopped before it. ValueError when the record holds
    no readings or the range is empty."""
    if not high_pa > low_pa:
        raise ValueError(f"need low_pa < high_pa, got {low_pa} and {high_pa}")
    grid = np.linspace(low_pa, high_pa, hypotheses)
    cost, blocks, steps, samples = _chi_square(record, model, until_s, grid, opening)
    best = int(np.argmin(cost))
    spacing = grid[1] - grid[0]
    contact, curvature = grid[best], math.nan
    if 0 < best < grid.size - 1:
        c_minus, c_0, c_plus = cost[best - 1], cost[best], cost[best + 1]
        curvature = (c_plus - 2.0 * c_0 + c_minus) / spacing**2
        if curvature > 0.0:
            contact = grid[best] - 0.5 * spacing * (c_plus - c_minus) / (c_plus - 2 * c_0 +
                                                                       c_minus)
    else:
        neighbour = 1 if best == 0 else best - 1
        curvature = 2.0 * abs(cost[neighbour] - cost[best]) / spacing**2
    # cost is chi-square: its second derivative is 2 / variance
    std = math.sqrt(2.0 / curvature) if curvature > 0.0 else math.inf
    # "nothing stopped them": how much worse that hypothesis explains the readings
    reference = high_pa if opening else model.meet_pressure_pa
    away = reference - contact if opening else contact - reference
    reference_cost = (float(np.interp(reference, grid, cost)) if low_pa <= reference <= high_pa
                      else math.nan)
    z = (math.copysign(math.sqrt(max(reference_cost - float(cost[best]), 0.0)), away)
         if math.isfinite(reference_cost) else away / std)
    meet = model.meet_pressure_pa
    block = float(np.interp(contact, grid, blocks))
    contact_time = (record.start_s + (block + 1) * FIT_STEP_S) if block < steps else math.nan
    size = model.tip_spacing_m(contact) if contact > meet else 0.0
    return ContactFit(float(contact), float(std), contact_time, float(max(size, 0.0)), float(z),
                      float(cost[best]) / max(samples - 1, 1), samples,
                      tuple(float(g) for g in grid), tuple(float(c) for c in cost))


def share_chi_square(record: AirRecord, model: ContactModel, until_s: float,
                     contact_pa: float, shares) -> np.ndarray:
    """The chi-square of ``record``'s closing readings up to ``until_s`` with the fingers stopped
    at ``contact_pa`` (Pa gauge), under each bending share of ``shares`` ((K,), dimensionless),
    weighed as :func:`fit_contact` weighs them; ValueError when the record holds fewer than 3
    readings."""
    shares = np.atleast_1d(np.asarray(shares, dtype=float))
    return _chi_square(record, model, until_s, np.full(shares.shape, float(contact_pa)), False,
                       shares / model.bending_volume_share)[0]


def _chi_square(record: AirRecord, model: ContactModel, until_s: float, contacts: np.ndarray,
                opening: bool, share_scale=None) -> tuple:
    """(chi-square per hypothesis, the step each stops the fingers, the steps simulated, the
    readings counted)."""
    steps = max(1, int(math.ceil((until_s - record.start_s) / FIT_STEP_S)))
    free = free_trace(record, model, steps, FIT_STEP_S, opening)
    times = record.start_s + FIT_STEP_S * np.arange(1, steps + 1)
    shift = readings_lead_s(record, times, free, until_s)
    samples = [(t - shift, v, sd) for t, v, sd in record.samples
               if record.start_s < t - shift <= until_s]
    if len(samples) < 3:
        raise ValueError("the record holds fewer than 3 readings to fit")
    stamps = np.array([s[0] for s in samples])
    values = np.array([s[1] for s in samples])
    weights = 1.0 / np.array([s[2] for s in samples]) ** 2
    blocks = contact_steps(record, model, contacts, steps, FIT_STEP_S, opening, free)
    times, traces = _simulate(record, model, contacts, steps, FIT_STEP_S, blocks, share_scale)
    predicted = np.stack([np.interp(stamps, times, traces[:, j]) for j in range(contacts.size)])
    cost = ((predicted - values[None, :]) ** 2 * weights[None, :]).sum(axis=1)
    return cost, blocks, steps, len(samples)


# how many standard errors above the fingers' meeting the contact must lie to be an object, and
# below which it is nothing (between them: unknown), when no size is expected
Z_OBJECT = 5.0
Z_NOTHING = 3.0
# with an expected size: the log-likelihood ratio, object of that size against nothing, that
# decides either way (odds of 100 to 1)
DECIDING_LOG_RATIO = math.log(100.0)


def judge_closing(fit: ContactFit, model: ContactModel, stamp_s: float,
                  expected_size_m: float = math.nan) -> Detection:
    """The closing's verdict from its fit.

    With an ``expected_size_m`` (m; the command's object): the readings' likelihood under "the
    fingers stopped at that object" against "they met each other", a simple test between two
    hypotheses: CONTACT_CLOSING (sized by the fit) or NO_OBJECT once the odds pass 100 to 1,
    else UNKNOWN, e.g. for a 0.1 mm sheet, which the fingers meet where they would meet each
    other. Without one: CONTACT_CLOSING when the contact lies ``Z_OBJECT`` standard errors above
    the fingers' meeting, else UNKNOWN."""
    size_mm = fit.object_size_m * 1e3
    meet = model.meet_pressure_pa
    found = (f"the air's volume stopped following the fingers at {fit.contact_pa / 1e3:.1f} kPa"
             f" of their shape: an object of {size_mm:.0f} mm")
    if math.isfinite(expected_size_m) and expected_size_m > 0.0:
        expected_pa = float(model.pressure_for_tip_spacing(expected_size_m))
        log_ratio = 0.5 * (fit.cost_at(meet) - fit.cost_at(expected_pa))
        if not math.isfinite(log_ratio):
            return Detection(ObjectStatus.UNKNOWN, 0.0, "the closing's range does not span "
                             "the object and the fingers' meeting", stamp_s)
        odds = f"odds {math.exp(min(abs(log_ratio), 700.0)):.3g} to 1{_provenance(model)}"
        if log_ratio >= DECIDING_LOG_RATIO:
            return Detection(
                ObjectStatus.CONTACT_CLOSING, 1.0 - math.exp(-log_ratio),
                f"{found}; the {expected_size_m * 1e3:.0f} mm object against nothing: {odds}",
                stamp_s, fit.object_size_m, fit.contact_pa, fit.contact_time_s)
        if log_ratio <= -DECIDING_LOG_RATIO:
            return Detection(
                ObjectStatus.NO_OBJECT, 1.0 - math.exp(log_ratio),
                f"the fingers closed as if on nothing: nothing against the "
                f"{expected_size_m * 1e3:.0f} mm object, {odds}", stamp_s, 0.0, fit.contact_pa,
                fit.contact_time_s)
        return Detection(
            ObjectStatus.UNKNOWN, 0.0,
            f"the air cannot tell the {expected_size_m * 1e3:.1f} mm object from nothing "
            f"(log odds {log_ratio:+.1f})", stamp_s, math.nan, fit.contact_pa,
            fit.contact_time_s)
    if math.isfinite(fit.z) and fit.z >= Z_OBJECT:
        return Detection(
            ObjectStatus.CONTACT_CLOSING, float(_normal_cdf(fit.z - Z_NOTHING)),
            f"{found}, {fit.z:.1f} standard errors before the fingers could meet each other",
            stamp_s, fit.object_size_m, fit.contact_pa, fit.contact_time_s)
    return Detection(
        ObjectStatus.UNKNOWN, 0.0,
        f"no object expected, and no contact clear of the fingers' meeting "
        f"({fit.z:.1f} standard errors)", stamp_s, math.nan, fit.contact_pa, fit.contact_time_s)


def _provenance(model: ContactModel) -> str:
    """What the verdict's contact model rests on, for its evidence."""
    if model.share_identified:
        return " (contact identified on this gripper)"
    return " (the contact model's prediction: not identified on this gripper)"


def _normal_cdf(x: float) -> float:
    return 0.5 * (1.0 + math.erf(x / math.sqrt(2.0)))


# ---- the hold ----------------------------------------------------------------------------------
def loss_step_pa(model: ContactModel, hold_gauge_pa: float, contact_pa: float) -> float:
    """How far the trapped air's pressure moves (Pa, signed) when an object that stopped the
    fingers at ``contact_pa`` leaves a hold at ``hold_gauge_pa`` with the valves closed: the
    chambers' volume drops by :meth:`ContactModel.loss_volume_m3` at a fixed mass of air."""
    before = model.held_back_m3(hold_gauge_pa, contact_pa)
    after = model.held_back_m3(hold_gauge_pa, model.meet_pressure_pa)
    plant = PneumaticPlant(model.plant)
    held = PlantState(0.0, np.array([P_ATM_PA + hold_gauge_pa]), np.array([float(before)]))
    return float(plant.with_volume_offset(held, [float(after)]).chamber_pa[0] -
                 P_ATM_PA - hold_gauge_pa)


@dataclasses.dataclass(frozen=True)
class LossConfig:
    """The loss test's windows (s), thresholds (multiples of the expected step, and standard
    errors) and the sensors it needs. See :class:`LossDetector`."""

    settle_s: float = 0.1
    reference_s: float = 0.2
    gap_s: float = 0.08
    test_s: float = 0.06
    min_fraction: float = 0.4
    max_fraction: float = 3.0
    z_min: float = 5.0
    flat_fraction: float = 0.35
    min_sensors: int = 2
    check_period_s: float = 0.02

    def __post_init__(self):
        require_positive(self, "settle_s", "reference_s", "gap_s", "test_s", "z_min",
                         "flat_fraction", "check_period_s")
        if not 0.0 < self.min_fraction < 1.0 < self.max_fraction:
            raise ValueError("need 0 < min_fraction < 1 < max_fraction")
        if self.min_sensors < 1:
            raise ValueError("min_sensors must be at least 1")

    @property
    def history_s(self) -> float:
        return self.reference_s + self.gap_s + self.test_s


def _window_stats(readings, start_s: float, end_s: float) -> tuple:
    """(mean, standard error, count) of the readings with start < stamp <= end; the spread is
    the larger of the rated noise and the readings' own."""
    values = [(v, s) for t, v, s in readings if start_s < t <= end_s]
    if len(values) < 3:
        return math.nan, math.nan, len(values)
    data = np.array([v for v, _ in values])
    rated = max(s for _, s in values)
    spread = max(rated, float(np.std(data, ddof=1)))
    return float(np.mean(data)), spread / math.sqrt(data.size), data.size


class LossDetector:
    """An object leaving a hold whose air is trapped (valves closed): the fingers close onto each
    other, the chambers' volume drops, and the pressure steps by :func:`loss_step_pa` within the
    fingers' response time, then stays (the air's mass has not changed). With the regulated line
    open instead, the line absorbs the step within milliseconds (its orifice conducts without
    bound near equilibrium): nothing to see, so the loss is judged only while the air is trapped.

    Each live sensor is tested on its own: the mean of its last ``test_s`` against that of a
    reference window ``reference_s`` long, ``gap_s`` earlier (so the test starts ``settle_s`` +
    ``history_s`` after the trap: a loss before that is not seen). A loss needs, on
    every live sensor (at least ``min_sensors``), a step of the expected sign between
    ``min_fraction`` and ``max_fraction`` of the expected size, ``z_min`` standard errors clear
    of the noise, a flat test window (a step that has ended, not a ramp: a valve stuck open or
    a leak keeps moving) and a flat reference. A step on one sensor alone is a sensor's fault,
    a step far larger than a loss can make is not a loss: the safety monitor names those. Once
    found, a loss stays until :meth:`reset`."""

    def __init__(self, expected_step_pa: float, config: LossConfig | None = None):
        if not math.isfinite(expected_step_pa) or expected_step_pa == 0.0:
            raise ValueError(f"expected_step_pa must be finite and non-zero, got "
                             f"{expected_step_pa}")
        self.expected_step_pa = float(expected_step_pa)
        self.config = config or LossConfig()
        self.readings = {}  # name -> [(stamp, gauge, std)]
        self.trapped_since = math.nan
        self.lost: Detection | None = None
        self._checked_s = -math.inf

    def reset(self) -> None:
        self.readings.clear()
        self.trapped_since = math.nan
        self.lost = None

    def trapped(self, since_s: float) -> None:
        """The valves closed on the hold at ``since_s`` (s); math.nan: they opened (a top-up)."""
        if math.isnan(since_s) or math.isnan(self.trapped_since):
            self.readings.clear()
        self.trapped_since = since_s

    def reading(self, name: str, stamp_s: float, gauge_pa: float, std_pa: float) -> None:
        if math.isnan(self.trapped_since) or not math.isfinite(gauge_pa):
            return
        if stamp_s < self.trapped_since + self.config.settle_s:
            return
        kept = self.readings.setdefault(name, [])
        kept.append((stamp_s, gauge_pa, std_pa))
        horizon = stamp_s - self.config.history_s - 0.05
        while kept and kept[0][0] < horizon:
            kept.pop(0)

    def check(self, now_s: float) -> Detection | None:
        """The loss found by ``now_s`` (s), or None. Undecided windows give None; the windows
        are tested at most every ``check_period_s``."""
        if self.lost is not None:
            return self.lost
        c = self.config
        if math.isnan(self.trapped_since) or now_s < (self.trapped_since + c.settle_s +
                                                      c.history_s):
            return None
        if now_s - self._checked_s < c.check_period_s:
            return None
        self._checked_s = now_s
        expected = self.expected_step_pa
        test_start = now_s - c.test_s
        reference_end = test_start - c.gap_s
        evidence = []
        for name, readings in sorted(self.readings.items()):
            test, test_se, n_test = _window_stats(readings, test_start, now_s)
            if n_test < 3:
                continue  # not live
            reference_start = reference_end - c.reference_s
            reference, reference_se, _ = _window_stats(readings, reference_start, reference_end)
            middle = 0.5 * (reference_start + reference_end)
            before, _, _ = _window_stats(readings, reference_start, middle)
            after, before_se, _ = _window_stats(readings, middle, reference_end)
            first, _, _ = _window_stats(readings, test_start, now_s - 0.5 * c.test_s)
            second, half_se, _ = _window_stats(readings, now_s - 0.5 * c.test_s, now_s)
            if not all(math.isfinite(x) for x in (reference, first, second, before, after)):
                return None
            step = test - reference
            z = step / math.hypot(test_se, reference_se)
            fraction = step / expected
            # the step has ended (the test window is flat) and came on a steady hold (so did
            # the reference): a ramp, a valve stuck open or a fast leak, is neither
            flat = (abs(second - first) <= max(c.flat_fraction * abs(expected),
                                               3.0 * math.sqrt(2.0) * half_se) and
                    abs(after - before) <= max(c.flat_fraction * abs(expected),
                                               3.0 * math.sqrt(2.0) * before_se))
            if not (c.min_fraction <= fraction <= c.max_fraction and abs(z) >= c.z_min and
                    flat):
                return None
            evidence.append((name, step, z))
        if len(evidence) < c.min_sensors:
            return None
        words = ", ".join(f"{name} {step:+.0f} Pa ({abs(z):.0f} sigma)"
                          for name, step, z in evidence)
        confidence = _normal_cdf(min(abs(z) for _, _, z in evidence) - c.z_min)
        self.lost = Detection(
            ObjectStatus.LOST, float(confidence),
            f"the trapped air stepped as the object's leaving would ({expected:+.0f} Pa "
            f"expected): {words}", now_s)
        return self.lost

    def resolvable(self, noise_pa: dict, rates_hz: dict) -> bool:
        """Whether a step of the expected size would clear ``z_min`` on every sensor of
        ``noise_pa`` (rated std, Pa) read at ``rates_hz`` (Hz) in 97.7 % of losses (2 standard
        errors to spare)."""
        c = self.config
        for name, std in noise_pa.items():
            n_test = max(rates_hz[name] * c.test_s, 1.0)
            n_reference = max(rates_hz[name] * c.reference_s, 1.0)
            se = std * math.sqrt(1.0 / n_test + 1.0 / n_reference)
            if abs(self.expected_step_pa) < (c.z_min + 2.0) * se:
                return False
        return True


# ---- the grasp, phase by phase -----------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class SensorNoise:
    """A pressure sensor as the sensing sees it: its rated noise (Pa, 1 sigma) and rate (Hz)."""

    std_pa: float
    rate_hz: float


class GraspSensing:
    """The grasp's object status from the air, driven by its owner (the grasp manager):

    - :meth:`inputs` and :meth:`reading`: every input change of the controller (regulator
      command, enable, valve) and every sensor reading, stamped;
    - :meth:`motion_started` when a phase starts to open or close the fingers from a steady
      pressure, :meth:`motion_settled` when it has arrived (fits the motion: CONTACT_OPENING or
      MOVING_NO_CONTACT; CONTACT_CLOSING, NO_OBJECT or UNKNOWN), :meth:`holding` and
      :meth:`air_trapped` through a hold, :meth:`released` when the grasp ends.

    :meth:`status` is the verdict now; UNKNOWN while the controller reports a fault (the safety
    monitor names it). Not thread-safe; :meth:`motion_settled` is CPU-heavy (owners
    with a latency budget run it on a worker)."""

    def __init__(self, model: ContactModel, sensors: dict, loss: LossConfig | None = None):
        self.model = model
        self.sensors = dict(sensors)
        self.loss_config = loss or LossConfig()
        self._record: AirRecord | None = None
        self._inputs: tuple = (-math.inf, PlantInputs())
        self._motion = None  # (opening, expected size m, end gauge Pa)
        self._verdict = Detection(ObjectStatus.UNKNOWN, 0.0, "no grasp yet", -math.inf)
        self._closing: Detection | None = None
        self._loss: LossDetector | None = None

    # ---- what the air did ----------------------------------------------------------------------
    def inputs(self, stamp_s: float, inputs: PlantInputs) -> None:
        self._inputs = (stamp_s, inputs)
        if self._record is not None:
            self._record.add_inputs(stamp_s, inputs)

    def reading(self, name: str, stamp_s: float, gauge_pa: float) -> None:
        sensor = self.sensors.get(name)
        if sensor is None:
            return
        if self._record is not None:
            self._record.add_sample(stamp_s, gauge_pa, sensor.std_pa)
        if self._loss is not None:
            self._loss.reading(name, stamp_s, gauge_pa, sensor.std_pa)

    # ---- the phases ----------------------------------------------------------------------------
    def motion_started(self, stamp_s: float, start_gauge_pa: float, end_gauge_pa: float,
                       expected_size_m: float = math.nan) -> None:
        """The fingers start to move from a steady ``start_gauge_pa`` towards ``end_gauge_pa``
        (Pa gauge): opening when it is higher."""
        self._loss = None
        if not (math.isfinite(start_gauge_pa) and math.isfinite(end_gauge_pa)):
            self._record, self._motion = None, None
            return
        self._record = AirRecord(stamp_s, start_gauge_pa)
        self._record.add_inputs(*self._inputs)
        self._motion = (end_gauge_pa > start_gauge_pa, expected_size_m, end_gauge_pa)
        self._verdict = Detection(ObjectStatus.MOVING_NO_CONTACT, 0.0,
                                  "the fingers are moving; the air is judged when they arrive",
                                  stamp_s)

    def motion_settled(self, stamp_s: float) -> Detection:
        """Judge the motion that has arrived (see the class); its verdict from now on."""
        job = self.settle_motion(stamp_s)
        return self.accept(job, judge_motion(self.model, job)) if job else self._verdict

    def settle_motion(self, stamp_s: float) -> "MotionJob | None":
        """The arrived motion's record, detached (nothing more is added to it), to judge with
        :func:`judge_motion` (on any thread) and give back to :meth:`accept`; None when no motion
        was recorded."""
        record, motion = self._record, self._motion
        self._record = self._motion = None
        if record is None or motion is None:
            return None
        return MotionJob(record, *motion, stamp_s)

    def accept(self, job: "MotionJob", verdict: Detection) -> Detection:
        """The verdict :func:`judge_motion` gave on ``job``: the status from now on."""
        if not job.opening:
            self._closing = verdict
        self._verdict = verdict
        return verdict

    def holding(self, stamp_s: float, hold_gauge_pa: float) -> None:
        """A hold at ``hold_gauge_pa`` begins: its losses are watched while its air is trapped,
        when the closing found an object whose loss the sensors resolve."""
        closing = self._closing
        self._loss = None
        if closing is None or closing.status != ObjectStatus.CONTACT_CLOSING:
            return
        step = loss_step_pa(self.model, hold_gauge_pa, closing.contact_pressure_pa)
        detector = LossDetector(step, self.loss_config)
        note = ""
        if detector.resolvable({n: s.std_pa for n, s in self.sensors.items()},
                               {n: s.rate_hz for n, s in self.sensors.items()}):
            self._loss = detector
        else:
            note = (f"; its loss ({step:+.0f} Pa of trapped air) would be below what the sensors "
                    "resolve: a loss is not sensed")
        self._verdict = Detection(
            ObjectStatus.HELD, closing.confidence, f"held: {closing.evidence}{note}", stamp_s,
            closing.object_size_m, closing.contact_pressure_pa, closing.contact_time_s)

    def air_trapped(self, since_s: float) -> None:
        """The hold's valves closed at ``since_s`` (s); math.nan: they opened (a top-up)."""
        if self._loss is not None:
            self._loss.trapped(since_s)

    def released(self, stamp_s: float, why: str = "released") -> None:
        """The grasp ended (released, stopped, faulted): UNKNOWN from now, but a loss stays
        reported until the next motion starts."""
        self._record, self._motion, self._loss, self._closing = None, None, None, None
        if self._verdict.status != ObjectStatus.LOST:
            self._verdict = Detection(ObjectStatus.UNKNOWN, 0.0, why, stamp_s)

    # ---- the verdict ---------------------------------------------------------------------------
    def status(self, now_s: float, controller_fault: str = "") -> Detection:
        """The object status now; UNKNOWN while ``controller_fault`` is set (a found loss stays:
        it was judged before the fault)."""
        if self._loss is not None and self._loss.lost is None and not controller_fault:
            lost = self._loss.check(now_s)
            if lost is not None:
                closing = self._closing
                self._verdict = dataclasses.replace(
                    lost, object_size_m=closing.object_size_m if closing else math.nan)
        if controller_fault and self._verdict.status != ObjectStatus.LOST:
            return Detection(ObjectStatus.UNKNOWN, 0.0,
                             f"the pressure controller reports {controller_fault}: the air "
                             "says nothing of the object meanwhile", now_s)
        return self._verdict


@dataclasses.dataclass(frozen=True)
class MotionJob:
    """An arrived motion to judge: its record, whether it opened, the size the command expected
    (m, NaN: none), the pressure it went to (Pa gauge) and when it arrived (s)."""

    record: AirRecord
    opening: bool
    expected_size_m: float
    end_gauge_pa: float
    stamp_s: float


def judge_motion(model: ContactModel, job: MotionJob) -> Detection:
    """The verdict on one motion (pure: any thread): CONTACT_OPENING, MOVING_NO_CONTACT or
    UNKNOWN for an opening; CONTACT_CLOSING, NO_OBJECT or UNKNOWN for a closing."""
    record, end, stamp = job.record, job.end_gauge_pa, job.stamp_s
    start = record.start_gauge_pa
    try:
        if job.opening:
            fit = fit_contact(record, model, stamp, start, end, opening=True)
            return _judge_opening(fit, stamp)
        fit = fit_contact(record, model, stamp, *closing_range_pa(model, job))
        return judge_closing(fit, model, stamp, job.expected_size_m)
    except ValueError as error:
        return Detection(ObjectStatus.UNKNOWN, 0.0, f"the motion cannot be judged: {error}",
                         stamp)


def closing_range_pa(model: ContactModel, job: MotionJob) -> tuple:
    """The contact pressures (Pa gauge) a closing's fit spans: from below its end or the
    fingers' meeting, up to its start."""
    low = min(job.end_gauge_pa, model.meet_pressure_pa) - 1e3
    return low, max(job.record.start_gauge_pa, low + 1e3)


def _judge_opening(fit: ContactFit, stamp_s: float) -> Detection:
    if math.isfinite(fit.z) and fit.z >= Z_OBJECT:
        return Detection(
            ObjectStatus.CONTACT_OPENING, _normal_cdf(fit.z - Z_NOTHING),
            f"the opening fingers stopped at {fit.contact_pa / 1e3:.1f} kPa, {fit.z:.1f} "
            f"standard errors short of their target: something at {fit.object_size_m * 1e3:.0f} "
            "mm", stamp_s, fit.object_size_m, fit.contact_pa, fit.contact_time_s)
    if math.isfinite(fit.z) and fit.z < Z_NOTHING:
        return Detection(ObjectStatus.MOVING_NO_CONTACT, _normal_cdf(Z_NOTHING - fit.z),
                         "the fingers opened freely", stamp_s)
    return Detection(ObjectStatus.UNKNOWN, 0.0, "the opening's air does not say whether the "
                     "fingers met anything", stamp_s)

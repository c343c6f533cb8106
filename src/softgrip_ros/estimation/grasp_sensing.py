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
  kinematics. The fingers met *something* before they could meet each other when p_c lies
  ``decision_sigma`` standard errors above ``meet_pressure_pa``.
- **Loss during a hold** (:class:`LossDetector`): an object leaving the hand lets the fingers close
  onto each other, the chambers' volume drops by ``B(p_c) - B(p_meet)`` within the fingers'
  response time, and at the air's fixed mass the pressure jumps by ``p |dV| / (V + p dV/dp)``,
  then decays as the regulated line refills the chamber. A generalised likelihood-ratio test
  looks for that signature, of the expected sign and size, in every sensor's readings; a loss is
  reported only when each live sensor shows it (one biased or stuck sensor is a sensor fault,
  the safety monitor's to name, not a loss).

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

from softgrip_ros.model.geometry import CHAMBER_COUNT
from softgrip_ros.model.pneumatics import (P_ATM_PA, RHO0_KG_PER_M3, T0_K, PlantInputs,
                                           PneumaticParameters, PneumaticPlant, Valve)

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
    2 / omega_1 the held-back volume follows."""

    plant: PneumaticParameters
    bending_volume_share: float
    meet_pressure_pa: float
    tip_spacing_m: object
    pressure_for_tip_spacing: object
    dynamics: FingerDynamics
    finger_mode_rad_s: float

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
                      plant: PneumaticParameters | None = None) -> ContactModel:
    """The built-in model's :class:`ContactModel`: the FE's bending share, the fingers' meeting
    pressure, D2 of the kinematics and the fingers' first mode of the pseudo-rigid chain (their
    masses against their hinges' stiffness; MuJoCo computes the chain's mass matrix). ``plant``:
    the default plant's when None. RuntimeError when MuJoCo is missing."""
    from softgrip_ros.model import gripper_models
    from softgrip_ros.model.kinematics import GripperKinematics
    from softgrip_ros.model.world.fingers import FE_BENDING_VOLUME_SHARE, PseudoRigidFinger
    from softgrip_ros.model.world.scene import scene_from_document
    from softgrip_ros.model.world.world import GripperWorld

    geometry, calibration = gripper_models.resolve(gripper_model)
    kinematics = GripperKinematics(geometry, calibration, model=bending)
    finger = PseudoRigidFinger(geometry, calibration, bending=bending)
    import mujoco

    bare = GripperWorld(scene_from_document({"name": "bare", "arm": {"start_m": [0, 0, 0.3]}}),
                        finger)
    full = np.zeros((bare.model.nv, bare.model.nv))
    mujoco.mj_fullM(bare.model, bare.data, full)
    dofs = bare._hinge_dof[0]
    tip_chamber_m = (CHAMBER_COUNT - 0.5) * geometry.segment_length_m
    levers = np.array([max(tip_chamber_m - arc.start_m, 0.0) for arc in finger.sub_arcs])
    dynamics = FingerDynamics(full[np.ix_(dofs, dofs)], finger.hinge_stiffness_nm_per_rad,
                              bare.model.dof_damping[dofs], finger.hinge_angles, levers)
    return ContactModel(plant or PneumaticParameters(), FE_BENDING_VOLUME_SHARE,
                        float(finger.contact_pressure_pa),
                        lambda gauge_pa: float(kinematics.pose(gauge_pa).tip_spacing_m),
                        kinematics.pressure_for_tip_spacing, dynamics, bare.first_mode_rad_s)


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


def _flow(gain: float, source_pa: float, chamber_pa: np.ndarray, critical_ratio: float):
    """R T m_dot into the chambers (J/s) and its slope by the chamber pressure, vectorised."""
    inflow = source_pa >= chamber_pa
    upstream = np.where(inflow, source_pa, chamber_pa)
    downstream = np.where(inflow, chamber_pa, source_pa)
    ratio = downstream / upstream
    s = np.clip((ratio - critical_ratio) / (1.0 - critical_ratio), 0.0, 1.0)
    phi = np.sqrt(np.maximum(1.0 - s * s, 1e-12))
    dphi = np.where(ratio > critical_ratio, -s / (phi * (1.0 - critical_ratio)), 0.0)
    flow = np.where(inflow, gain * upstream * phi, -gain * upstream * phi)
    slope = np.where(inflow, gain * dphi, -gain * (phi - ratio * dphi))
    return flow, slope


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


def contact_steps(record: AirRecord, model: ContactModel, contacts_pa: np.ndarray, steps: int,
                  step_s: float) -> np.ndarray:
    """The step at which free fingers, closing through ``record``, reach the shape of each of
    ``contacts_pa`` (``steps`` when they never do)."""
    free = _simulate(record, model, np.array([-math.inf]), steps, step_s, None)[1][:, 0]
    shapes = model.dynamics.shape_pressures(np.concatenate([[record.start_gauge_pa], free]),
                                            step_s)[1:]
    below = shapes[:, None] <= np.asarray(contacts_pa, dtype=float)[None, :]
    return np.where(below.any(axis=0), below.argmax(axis=0), steps)


def _simulate(record: AirRecord, model: ContactModel, contacts: np.ndarray, steps: int,
              step_s: float, block_steps) -> tuple:
    """simulate_hypotheses' air: hypothesis k blocked from step ``block_steps[k]`` (None:
    never)."""
    plant = PneumaticPlant(model.plant)
    par = model.plant
    gain = (RHO0_KG_PER_M3 * math.sqrt(T0_K / par.temperature_k) *
            par.gas_constant_times_temperature)
    omega = model.finger_mode_rad_s
    follow = 1.0 - math.exp(-0.5 * omega * step_s)
    p = np.full(contacts.shape, P_ATM_PA + record.start_gauge_pa)
    offset = np.zeros(contacts.shape)

    def volume(p_abs):
        gauge = p_abs - P_ATM_PA
        compliance = np.where(gauge >= 0.0, par.chamber_compliance_m3_per_pa,
                              par.vacuum_compliance_m3_per_pa)
        v = par.chamber_volume_m3 + compliance * gauge + offset
        return np.maximum(v, par.min_chamber_volume_m3), np.where(
            v > par.min_chamber_volume_m3, compliance, 0.0)

    v, _ = volume(p)
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
    for k, now in enumerate(times):
        while index < len(inputs_list) and inputs_list[index][0] < now:
            inputs = inputs_list[index][1]
            index += 1
        regulator = plant.regulator_step(regulator, inputs, step_s)[0]
        valve = Valve(inputs.valves[0])
        source_pa, conductance = plant.source(valve, regulator, inputs.regulator_enabled)
        if conductance > 0.0:
            flow, slope = _flow(gain * conductance, source_pa, p, par.path(valve)[1])
            v, dv = volume(p)
            pv = pv + step_s * flow / (1.0 - step_s * slope / (v + p * dv))
        gauge = p - P_ATM_PA
        target = np.where(blocked_at <= k, held_at_contact - model.bending_volume_m3(gauge), 0.0)
        offset = offset + follow * (target - offset)
        for _ in range(2):  # Newton on p (V(p) + offset) = pv
            v, dv = volume(p)
            p = np.maximum(p - (p * v - pv) / (v + p * dv), 1e3)
        out[k] = p - P_ATM_PA
    return times, out


def fit_contact(record: AirRecord, model: ContactModel, until_s: float,
                low_pa: float, high_pa: float, hypotheses: int = FIT_HYPOTHESES) -> ContactFit:
    """The contact pressure within [``low_pa``, ``high_pa``] (Pa gauge) that best explains
    ``record``'s readings up to ``until_s`` (see the module). ValueError when the record holds
    no readings or the range is empty."""
    if not high_pa > low_pa:
        raise ValueError(f"need low_pa < high_pa, got {low_pa} and {high_pa}")
    samples = [s for s in record.samples if record.start_s < s[0] <= until_s]
    if len(samples) < 3:
        raise ValueError("the record holds fewer than 3 readings to fit")
    stamps = np.array([s[0] for s in samples])
    values = np.array([s[1] for s in samples])
    weights = 1.0 / np.array([s[2] for s in samples]) ** 2
    grid = np.linspace(low_pa, high_pa, hypotheses)
    steps = max(1, int(math.ceil((until_s - record.start_s) / FIT_STEP_S)))
    blocks = contact_steps(record, model, grid, steps, FIT_STEP_S)
    times, traces = simulate_hypotheses(record, model, grid, until_s, block_steps=blocks)
    predicted = np.stack([np.interp(stamps, times, traces[:, j]) for j in range(grid.size)])
    cost = ((predicted - values[None, :]) ** 2 * weights[None, :]).sum(axis=1)
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
    meet = model.meet_pressure_pa
    # the fingers' meeting: how much worse the hypothesis "they met nothing first" explains
    meet_cost = float(np.interp(meet, grid, cost)) if low_pa <= meet <= high_pa else math.nan
    z = math.copysign(math.sqrt(max(meet_cost - float(cost[best]), 0.0)), contact - meet) \
        if math.isfinite(meet_cost) else (contact - meet) / std
    block = float(np.interp(contact, grid, blocks))
    contact_time = (record.start_s + (block + 1) * FIT_STEP_S) if block < steps else math.nan
    size = model.tip_spacing_m(contact) if contact > meet else 0.0
    return ContactFit(float(contact), float(std), contact_time, float(max(size, 0.0)), float(z),
                      float(cost[best]) / max(len(samples) - 1, 1), len(samples))


# how many standard errors above the fingers' meeting the contact must lie to be an object, and
# below which it is nothing (between them: unknown)
Z_OBJECT = 5.0
Z_NOTHING = 3.0


def judge_closing(fit: ContactFit, model: ContactModel, stamp_s: float,
                  expected_size_m: float = math.nan) -> Detection:
    """The closing's verdict from its fit: CONTACT_CLOSING (an object of ``fit.object_size_m``)
    when the contact lies ``Z_OBJECT`` standard errors above the fingers' meeting; NO_OBJECT
    when it lies within ``Z_NOTHING`` of it and an object of ``expected_size_m`` (m; NaN: the
    smallest the fit resolves) would have been seen; UNKNOWN otherwise, e.g. a 0.1 mm sheet,
    which the fingers meet where they would meet each other."""
    size_mm = fit.object_size_m * 1e3
    if not math.isfinite(fit.z) or not math.isfinite(fit.contact_std_pa):
        return Detection(ObjectStatus.UNKNOWN, 0.0, "the closing's readings fix no contact",
                         stamp_s)
    if fit.z >= Z_OBJECT:
        confidence = float(_normal_cdf(fit.z - Z_NOTHING))
        return Detection(
            ObjectStatus.CONTACT_CLOSING, confidence,
            f"the air's volume stopped following the fingers at {fit.contact_pa / 1e3:.1f} kPa, "
            f"{fit.z:.1f} standard errors before they could meet each other: an object of "
            f"{size_mm:.0f} mm", stamp_s, fit.object_size_m, fit.contact_pa, fit.contact_time_s)
    if fit.z < Z_NOTHING:
        if math.isfinite(expected_size_m) and expected_size_m > 0.0:
            expected_pa = float(model.pressure_for_tip_spacing(expected_size_m))
        else:
            expected_pa = model.meet_pressure_pa + Z_OBJECT * fit.contact_std_pa
        expected_z = (expected_pa - model.meet_pressure_pa) / fit.contact_std_pa
        if expected_z >= Z_OBJECT + Z_NOTHING:
            return Detection(
                ObjectStatus.NO_OBJECT, float(_normal_cdf(expected_z - Z_OBJECT)),
                f"the fingers closed to {fit.contact_pa / 1e3:.1f} kPa as if free, within "
                f"{Z_NOTHING:g} standard errors of meeting each other; an object of "
                f"{expected_pa / 1e3:.1f} kPa's size would lie {expected_z:.0f} above",
                stamp_s, 0.0, fit.contact_pa, fit.contact_time_s)
        what = (f"an object of {expected_size_m * 1e3:.1f} mm" if math.isfinite(expected_size_m)
                else "an object the fit can resolve")
        return Detection(
            ObjectStatus.UNKNOWN, 0.0,
            f"the fingers closed as if on nothing, but {what} would close them the same: the "
            "air cannot tell", stamp_s, math.nan, fit.contact_pa, fit.contact_time_s)
    return Detection(
        ObjectStatus.UNKNOWN, 0.0,
        f"a contact at {fit.contact_pa / 1e3:.1f} kPa, only {fit.z:.1f} standard errors before "
        "the fingers would meet each other", stamp_s, math.nan, fit.contact_pa, fit.contact_time_s)


def _normal_cdf(x: float) -> float:
    return 0.5 * (1.0 + math.erf(x / math.sqrt(2.0)))

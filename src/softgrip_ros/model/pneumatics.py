"""Pneumatic plant: regulator, valve block, vacuum source and compliant chambers.

The simulated device runs this in real time, and the estimator uses it as its process
model. All pressures inside are **absolute** (Pa) unless a name says gauge.

Orifice flow, ISO 6358, with sonic conductance C and critical pressure ratio b; for
r = p_down / p_up::

    m_dot = C rho0 p_up sqrt(T0/T)                                  r <= b (choked)
    m_dot = C rho0 p_up sqrt(T0/T) sqrt(1 - ((r - b)/(1 - b))^2)    r >  b (subsonic)

Chamber (ideal gas, isothermal: the paper's Assumption 2), with a volume that swells
with pressure, V(p) = V0 + k (p - p_atm), k the positive-pressure compliance above p_atm and the
vacuum compliance below (a chamber that balloons out need not collapse alike)::

    dp/dt = R T m_dot / (V + p dV/dp)

The paper assumes every orifice is choked; near equilibrium (r -> 1) that is false and a
choked-only model never settles. The subsonic branch has an infinite slope at r = 1,
which makes the ODE stiff there: a fixed-step explicit Euler cannot settle (it chatters
with an amplitude that grows with dt^2, and beyond a step size it runs away).
:meth:`PneumaticPlant.step` therefore integrates each chamber by backward Euler, solved per step by
a bracketed Newton iteration; the backward-Euler map is monotone, so it never overshoots the source
and settles exactly at equilibrium for any step.

The regulator follows its setpoint with a first-order lag and a rate limit, integrated
exactly (stable for any step). Its flow demand is not modelled: it is assumed large
enough to hold its output.

Disabling the regulator (``PlantInputs.regulator_enabled`` false, the CAN RegulatorSetpoint's
Enable = 0) is the device's safe state: the regulator's inlet is cut, so its output goes to
0 Pa gauge whatever its setpoint or fault, and the vacuum source is isolated from the valve
block, its line vented. No valve state can then pump, not even a valve stuck open.
"""
from __future__ import annotations

import dataclasses
import enum
import math

import numpy as np

from softgrip_ros.checks import require_positive

P_ATM_PA = 101_325.0
R_AIR_J_PER_KG_K = 287.05
RHO0_KG_PER_M3 = 1.185  # ISO 6358 reference density
T0_K = 293.15  # ISO 6358 reference temperature
# a simulated truth's longest step (PneumaticPlant.advance, extrapolated backward Euler): within
# 5 Pa of the law on the benchmark truths' fills, vents and evacuations (most within 1 Pa), where
# backward Euler itself lagged up to 48 Pa at 0.2 ms steps (five solves per ms, against three)
TRUTH_STEP_S = 1e-3


def regulator_after(value_pa: float, target_pa: float, dt: float, tau_s: float,
                    rate_limit_pa_per_s: float) -> tuple[float, float]:
    """The regulator's output after ``dt`` at a fixed target, and its derivative by ``value_pa``:
    d value/dt = (target - value) / tau, limited to +-rate_limit, solved exactly. The output slews
    at the limit while the gap exceeds rate_limit * tau, then relaxes with tau. Exact, so that
    one step of 20 ms (the identification between two regulator reports) gives what twenty of
    1 ms give (the simulated device): a step that clamps its whole lag step to rate_limit * dt
    does not, and the identification's rate limit came out 6 % low."""
    gap = target_pa - value_pa
    knee = rate_limit_pa_per_s * tau_s  # the gap below which the lag is slower than the limit
    slewing_s = max(abs(gap) - knee, 0.0) / rate_limit_pa_per_s
    if dt <= slewing_s:
        return value_pa + math.copysign(rate_limit_pa_per_s * dt, gap), 1.0
    decay = math.exp(-(dt - slewing_s) / tau_s)
    return target_pa - math.copysign(min(abs(gap), knee), gap) * decay, decay


class Valve(enum.IntEnum):
    """Valve-block state of one channel (the CAN ValveCommand values)."""

    CLOSED = 0
    SUPPLY = 1  # chamber <-> regulator output
    VACUUM = 2  # chamber <-> vacuum source (fast evacuation)
    VENT = 3  # chamber <-> atmosphere


# open to a source: the states a device closes when a ValveCommand's OpenLifetime runs out
SOURCE_VALVES = (Valve.SUPPLY, Valve.VACUUM)

@dataclasses.dataclass(frozen=True)
class PneumaticParameters:
    """Every default of the plant, in one place. These are documented assumptions, not
    measurements: the paper gives no pneumatic data. Orders of magnitude follow physics.md.

    chamber_volume_m3: V0, the air in one channel at 0 Pa gauge (five chambers of two
        fingers plus tubing).
    chamber_compliance_m3_per_pa: k = dV/dp above 0 Pa gauge, the chambers' swelling (+5 mL
        at 50 kPa).
    vacuum_compliance_m3_per_pa: dV/dp below 0 Pa gauge (the chambers drawn in).
    min_chamber_volume_m3: the volume cannot shrink below this under vacuum.
    supply_conductance, vacuum_conductance, vent_conductance: C of each valve path,
        m^3/(s Pa).
    supply_critical_ratio, vacuum_critical_ratio, vent_critical_ratio: b of each path.
    temperature_k: the gas temperature (isothermal).
    supply_gauge_pa: the regulator's inlet; its output cannot exceed it.
    vacuum_source_gauge_pa: the vacuum pump's level.
    regulator_time_constant_s, regulator_rate_limit_pa_per_s: the regulator's dynamics.
    """

    channels: int = 1
    chamber_volume_m3: float = 20e-6
    chamber_compliance_m3_per_pa: float = 1e-10
    vacuum_compliance_m3_per_pa: float = 1e-10
    min_chamber_volume_m3: float = 2e-6
    supply_conductance: float = 1.0e-9
    vacuum_conductance: float = 1.0e-9
    vent_conductance: float = 1.5e-9
    supply_critical_ratio: float = 0.3
    vacuum_critical_ratio: float = 0.3
    vent_critical_ratio: float = 0.3
    temperature_k: float = 293.15
    supply_gauge_pa: float = 150e3
    vacuum_source_gauge_pa: float = -80e3
    regulator_time_constant_s: float = 0.03
    regulator_rate_limit_pa_per_s: float = 2.0e6

    def __post_init__(self):
        require_positive(self, "chamber_volume_m3", "min_chamber_volume_m3", "supply_conductance",
                         "vacuum_conductance", "vent_conductance", "temperature_k",
                         "regulator_time_constant_s", "regulator_rate_limit_pa_per_s")
        if not 1 <= self.channels <= 4:
            raise ValueError(
                f"channels must lie in 1..4 (the ValveCommand frame has 4), got {self.channels}")
        for name in ("supply_critical_ratio", "vacuum_critical_ratio", "vent_critical_ratio"):
            if not 0.0 < getattr(self, name) < 1.0:
                raise ValueError(f"{name} b must lie in (0, 1), got {getattr(self, name)}")
        for name in ("chamber_compliance_m3_per_pa", "vacuum_compliance_m3_per_pa"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0.0):
                raise ValueError(f"{name} must be >= 0 and finite")
        if not -P_ATM_PA < self.vacuum_source_gauge_pa < 0.0 < self.supply_gauge_pa:
            raise ValueError("need -101325 < vacuum_source_gauge_pa < 0 < supply_gauge_pa")

    @property
    def gas_constant_times_temperature(self) -> float:
        return R_AIR_J_PER_KG_K * self.temperature_k

    def compliance_at(self, chamber_pa: float) -> float:
        """dV/dp at an absolute chamber pressure: the positive or the vacuum compliance."""
        return (self.chamber_compliance_m3_per_pa if chamber_pa >= P_ATM_PA else
                self.vacuum_compliance_m3_per_pa)

    def path(self, valve: "Valve") -> tuple[float, float]:
        """(C, b) of the valve path ``valve`` opens; (0, b of the vent) for CLOSED."""
        if valve == Valve.SUPPLY:
            return self.supply_conductance, self.supply_critical_ratio
        if valve == Valve.VACUUM:
            return self.vacuum_conductance, self.vacuum_critical_ratio
        if valve == Valve.VENT:
            return self.vent_conductance, self.vent_critical_ratio
        return 0.0, self.vent_critical_ratio


def orifice_mass_flow(p_from_pa, p_to_pa, conductance: float, critical_ratio: float,
                      temperature_k: float):
    """Signed ISO 6358 mass flow (kg/s) from the ``p_from`` side to the ``p_to`` side; arrays
    allowed."""
    result = orifice_flow_and_slope(p_from_pa, p_to_pa, conductance, critical_ratio,
                                    temperature_k)[0]
    return float(result) if result.ndim == 0 else result


def orifice_flow_and_slope(p_from_pa, p_to_pa, conductance: float, critical_ratio: float,
                           temperature_k: float) -> tuple:
    """:func:`orifice_mass_flow` (kg/s, arrays) and its derivative by ``p_to`` (kg/(s Pa)), the
    chamber's side: what an implicit step of a chamber needs. At r -> 1 the subsonic branch's
    slope is infinite; it is capped, as in :meth:`PneumaticPlant.flow_and_slopes`."""
    p_from = np.asarray(p_from_pa, dtype=float)
    p_to = np.asarray(p_to_pa, dtype=float)
    inflow = p_from >= p_to
    upstream = np.maximum(p_from, p_to)
    downstream = np.minimum(p_from, p_to)
    ratio = downstream / upstream
    subsonic = np.clip((ratio - critical_ratio) / (1.0 - critical_ratio), 0.0, 1.0)
    phi = np.sqrt(np.maximum(1.0 - subsonic**2, 0.0))
    dphi = np.where(ratio > critical_ratio,
                    -subsonic / (np.maximum(phi, 1e-9) * (1.0 - critical_ratio)), 0.0)
    gain = conductance * RHO0_KG_PER_M3 * math.sqrt(T0_K / temperature_k)
    flow = np.where(inflow, gain * upstream * phi, -gain * upstream * phi)
    # d/dp_to: inflow, p_to is downstream (d ratio = 1 / upstream); outflow, it is upstream
    slope = np.where(inflow, gain * dphi, -gain * (phi - ratio * dphi))
    return flow, slope


@dataclasses.dataclass
class PlantState:
    """regulator_gauge_pa: the regulator output; chamber_pa: absolute pressure per channel;
    volume_offset_m3: per channel, air volume beyond V(p) (None: none), e.g. fingers held back by
    an object hold less air than free ones at the same pressure (the physics world sets it, through
    :meth:`PneumaticPlant.with_volume_offset`)."""

    regulator_gauge_pa: float
    chamber_pa: np.ndarray
    volume_offset_m3: np.ndarray | None = None

    def copy(self) -> "PlantState":
        return PlantState(self.regulator_gauge_pa, self.chamber_pa.copy(),
                          None if self.volume_offset_m3 is None else self.volume_offset_m3.copy())

    def offset(self, channel: int) -> float:
        return 0.0 if self.volume_offset_m3 is None else float(self.volume_offset_m3[channel])


@dataclasses.dataclass
class PlantInputs:
    """regulator_setpoint_gauge_pa (clamped to the sources), regulator_enabled (false: both sources
    cut, see the module docstring), valves per channel, regulator_overshoot_pa (a fault: the output
    settles this far above its setpoint while enabled)."""

    regulator_setpoint_gauge_pa: float = 0.0
    regulator_enabled: bool = True
    valves: tuple = (Valve.CLOSED,)
    regulator_overshoot_pa: float = 0.0


class PneumaticPlant:
    """The plant of :class:`PneumaticParameters`, integrated by :meth:`step`."""

    def __init__(self, parameters: PneumaticParameters | None = None):
        self.parameters = parameters or PneumaticParameters()

    def initial_state(self, chamber_gauge_pa: float = 0.0) -> PlantState:
        return PlantState(0.0, np.full(self.parameters.channels, P_ATM_PA + chamber_gauge_pa))

    # ---- the model ----------------------------------------------------------------------------
    def _compliance(self, chamber_pa):
        par = self.parameters
        return np.where(np.asarray(chamber_pa) >= P_ATM_PA, par.chamber_compliance_m3_per_pa,
                        par.vacuum_compliance_m3_per_pa)

    def volume_and_swelling(self, chamber_pa, volume_offset_m3=0.0) -> tuple:
        """(V, dV/dp) at an absolute chamber pressure (arrays allowed): V(p) plus
        ``volume_offset_m3``, held at the floor, where it no longer swells. :meth:`air_terms` is
        the same law for one scalar, on the filters' hot path."""
        par = self.parameters
        compliance = self._compliance(chamber_pa)
        volume = (par.chamber_volume_m3 + compliance * (np.asarray(chamber_pa) - P_ATM_PA) +
                  volume_offset_m3)
        return (np.maximum(volume, par.min_chamber_volume_m3),
                np.where(volume > par.min_chamber_volume_m3, compliance, 0.0))

    def volume_m3(self, chamber_pa):
        return self.volume_and_swelling(chamber_pa)[0]

    def capacitance(self, chamber_pa):
        """V + p dV/dp (m^3): the chamber's isothermal capacitance times R T."""
        volume, swelling = self.volume_and_swelling(chamber_pa)
        return volume + np.asarray(chamber_pa) * swelling

    def source(self, valve: Valve, regulator_gauge_pa: float,
               sources_live: bool = True) -> tuple[float, float]:
        """(absolute pressure, conductance) a valve state connects the chamber to; conductance 0 =
        closed. ``sources_live`` false (the regulator disabled): the vacuum line is isolated and
        vented. The path's critical ratio: ``parameters.path(valve)``."""
        par = self.parameters
        conductance = par.path(valve)[0]
        if valve == Valve.SUPPLY:
            return P_ATM_PA + regulator_gauge_pa, conductance
        if valve == Valve.VACUUM:
            return P_ATM_PA + (par.vacuum_source_gauge_pa if sources_live else 0.0), conductance
        return P_ATM_PA, conductance

    def chamber_mass_flow(self, chamber_pa: float, valve: Valve,
                          regulator_gauge_pa: float) -> float:
        """Mass flow into one chamber (kg/s)."""
        source_pa, conductance = self.source(valve, regulator_gauge_pa)
        if conductance == 0.0:
            return 0.0
        return orifice_mass_flow(source_pa, chamber_pa, conductance,
                                 self.parameters.path(valve)[1], self.parameters.temperature_k)

    def chamber_rate(self, chamber_pa: float, valve: Valve, regulator_gauge_pa: float,
                     sources_live: bool = True) -> float:
        """dp/dt of one chamber (Pa/s)."""
        source_pa, conductance = self.source(valve, regulator_gauge_pa, sources_live)
        return self.rate_and_slopes(float(chamber_pa), source_pa, conductance,
                                    self.parameters.path(valve)[1])[0]

    def rate_and_slopes(self, chamber_pa: float, source_pa: float, conductance: float,
                        critical_ratio: float | None = None) -> tuple[float, float, float]:
        """(dp/dt, its partial derivative by the chamber pressure, by the source pressure) of one
        chamber joined to a source through ``conductance`` with ``critical_ratio`` (None: the
        supply path's); scalar, plain floats (the filters' hot path).

        At r -> 1 the subsonic branch's slope is infinite; it is capped at a finite large value
        so that the implicit-step Jacobian stays defined (it then tends to the exact limit)."""
        if conductance == 0.0:
            return 0.0, 0.0, 0.0
        flow, flow_p, flow_s = self.flow_and_slopes(chamber_pa, source_pa, conductance,
                                                    critical_ratio)
        _, capacitance, swelling = self.air_terms(chamber_pa)
        rate = flow / capacitance
        return (rate, (flow_p - flow * 2.0 * swelling / capacitance) / capacitance,
                flow_s / capacitance)

    def flow_and_slopes(self, chamber_pa: float, source_pa: float, conductance: float,
                        critical_ratio: float | None = None) -> tuple[float, float, float]:
        """(R T m_dot, the rate of p V into the chamber; its partial derivatives by the chamber
        and by the source pressure) of one chamber joined to a source (see
        :meth:`rate_and_slopes`); zeros through a closed path."""
        par = self.parameters
        if conductance == 0.0:
            return 0.0, 0.0, 0.0
        inflow = source_pa >= chamber_pa
        upstream, downstream = (source_pa, chamber_pa) if inflow else (chamber_pa, source_pa)
        ratio = downstream / upstream
        b = par.supply_critical_ratio if critical_ratio is None else critical_ratio
        if ratio <= b:
            phi, dphi = 1.0, 0.0
        else:
            s = (ratio - b) / (1.0 - b)
            phi = math.sqrt(max(1.0 - s * s, 0.0))
            dphi = -s / (max(phi, 1e-9) * (1.0 - b))
        gain = (conductance * RHO0_KG_PER_M3 * math.sqrt(T0_K / par.temperature_k) *
                par.gas_constant_times_temperature)
        if inflow:
            flow, flow_p, flow_s = gain * upstream * phi, gain * dphi, gain * (phi - ratio * dphi)
        else:
            flow, flow_p, flow_s = (-gain * upstream * phi, -gain * (phi - ratio * dphi),
                                    -gain * dphi)
        return flow, flow_p, flow_s

    def air_terms(self, chamber_pa: float,
                  volume_offset_m3: float = 0.0) -> tuple[float, float, float]:
        """(p V, R T times the air's mass; the capacitance d(pV)/dp = V + p dV/dp; dV/dp) of one
        chamber at an absolute pressure, its volume ``volume_offset_m3`` beyond V(p); scalar,
        plain floats (the filters' and the simulated device's hot path: :meth:`chamber_mass_kg`
        and :meth:`capacitance` are the same law on arrays, several times slower per call on a
        scalar)."""
        par = self.parameters
        compliance = (par.chamber_compliance_m3_per_pa if chamber_pa >= P_ATM_PA else
                      par.vacuum_compliance_m3_per_pa)
        volume = par.chamber_volume_m3 + compliance * (chamber_pa - P_ATM_PA) + volume_offset_m3
        swelling = compliance if volume > par.min_chamber_volume_m3 else 0.0
        held = max(volume, par.min_chamber_volume_m3)
        return chamber_pa * held, held + chamber_pa * swelling, swelling

    def regulator_target_gauge_pa(self, inputs: PlantInputs) -> float:
        par = self.parameters
        if not inputs.regulator_enabled:
            # the inlet cut: no setpoint or fault can raise the output
            return 0.0
        target = min(max(inputs.regulator_setpoint_gauge_pa, par.vacuum_source_gauge_pa),
                     par.supply_gauge_pa)
        return min(target + inputs.regulator_overshoot_pa, par.supply_gauge_pa)

    def chamber_mass_kg(self, chamber_pa):
        return np.asarray(chamber_pa) * self.volume_m3(
            chamber_pa) / self.parameters.gas_constant_times_temperature

    # ---- integration --------------------------------------------------------------------------
    def step(self, state: PlantState, inputs: PlantInputs, dt: float) -> PlantState:
        """Advance by dt (s): the regulator exactly, each chamber by backward Euler."""
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"dt must be positive and finite, got {dt}")
        regulator = self.regulator_step(state.regulator_gauge_pa, inputs, dt)[0]
        chambers = np.array([
            self.chamber_step(p, valve, regulator, dt, inputs.regulator_enabled,
                              state.offset(i))[0]
            for i, (p, valve) in enumerate(zip(state.chamber_pa, self._valves(inputs)))
        ])
        return PlantState(regulator, chambers, state.volume_offset_m3)

    def with_volume_offset(self, state: PlantState, volume_offset_m3) -> PlantState:
        """``state`` with each channel's volume offset changed to ``volume_offset_m3`` (m^3) at a
        fixed mass of air (isothermal): a chamber whose fingers were held back lost volume, and
        its pressure rose. The volume stays at its floor or above."""
        offsets = np.asarray(volume_offset_m3, dtype=float).reshape(self.parameters.channels)
        chambers = state.chamber_pa.copy()
        for i, p_n in enumerate(state.chamber_pa):
            target = self.air_terms(float(p_n), state.offset(i))[0]
            p = float(p_n)
            for _ in range(50):  # Newton on p V(p) = const: pV rises strictly with p
                pv, capacitance, _ = self.air_terms(p, float(offsets[i]))
                step = (pv - target) / capacitance
                p = max(p - step, 0.5 * p)
                if abs(step) <= 1e-9 * p:
                    break
            chambers[i] = p
        return PlantState(state.regulator_gauge_pa, chambers, offsets)

    def advance(self, state: PlantState, inputs: PlantInputs, dt: float,
                max_step_s: float = TRUTH_STEP_S) -> PlantState:
        """Advance by dt (s) in equal :meth:`extrapolated_step` s of at most ``max_step_s``: the
        plant as a truth close to the continuous law whatever its caller's step (the simulated
        device, the identification's offline recordings). Backward Euler alone strays from the law
        by up to half a step's worth of the response (1 ms: up to 210 Pa in a fill of a small
        chamber; 0.2 ms: 48 Pa), and an identification on such a truth fitted that: its 95 %
        intervals held the truth in as few as 67 % of seeded fits. With every chamber closed, or
        vented and at atmosphere, one step is exact (the regulator's law is solved exactly, and
        such a chamber does not move): the simulated device's idle chamber costs a third."""
        if all(valve == Valve.CLOSED or (valve == Valve.VENT and p == P_ATM_PA)
               for p, valve in zip(state.chamber_pa, self._valves(inputs))):
            return self.step(state, inputs, dt)
        count = max(1, math.ceil(dt / max_step_s - 1e-9))
        for _ in range(count):
            state = self.extrapolated_step(state, inputs, dt / count)
        return state

    def extrapolated_step(self, state: PlantState, inputs: PlantInputs, dt: float) -> PlantState:
        """Advance by dt (s) to second order: backward Euler over dt and twice over dt/2, combined
        as 2 x halves - whole (Richardson), which cancels backward Euler's first-order error.

        Near the source the combination may step past it, which backward Euler never does (its
        map is monotone): a chamber is then put at its source, where the law would settle it. The
        combination's amplification on a linear stiff mode, 2/(1 + x/2)^2 - 1/(1 + x) with
        x = dt/tau, lies in (-0.04, 1] and tends to 0: stable for any step."""
        whole = self.step(state, inputs, dt)
        halves = self.step(self.step(state, inputs, 0.5 * dt), inputs, 0.5 * dt)
        chambers = 2.0 * halves.chamber_pa - whole.chamber_pa
        for i, valve in enumerate(self._valves(inputs)):
            source_pa = self.source(valve, halves.regulator_gauge_pa,
                                    inputs.regulator_enabled)[0]
            if np.sign(chambers[i] - source_pa) != np.sign(halves.chamber_pa[i] - source_pa):
                chambers[i] = source_pa
        return PlantState(halves.regulator_gauge_pa, chambers, state.volume_offset_m3)

    def chamber_step(self, chamber_pa: float, valve: Valve, regulator_gauge_pa: float, dt: float,
                     sources_live: bool = True,
                     volume_offset_m3: float = 0.0) -> tuple[float, float, float]:
        """One backward-Euler step of one chamber's air: (p_next, dp_next/dp, dp_next/d regulator).

        The step is taken on the air's mass (R T m = p V(p), :meth:`air_terms`), not on p: p_next
        solves g(p) = p V(p) - p_n V(p_n) - dt R T m_dot(p) = 0. Where the two compliances differ,
        the capacitance d(pV)/dp = V + p dV/dp jumps at atmosphere and so does dp/dt, but the mass
        flow does not: a step on p across atmosphere took one side's law for the whole step, which
        put the simulated device's fill from vacuum 21 Pa off the law ever after (and the
        identification's model, which steps the same way, 12 Pa on slow_large; a sigma of a fit's
        values). g rises strictly from p_n to the source (p V rises with p, the inflow falls), so
        a Newton iteration kept inside that bracket (bisection when it leaves) converges. The
        derivatives follow from the implicit function theorem: C(p_n)/g'(p_next) and
        dt R T m_dot_s/g'(p_next), with C = d(pV)/dp, g' = C - dt R T m_dot_p, and m_dot_s = 0
        unless the valve joins the regulator."""
        source_pa, conductance = self.source(valve, regulator_gauge_pa, sources_live)
        b = self.parameters.path(valve)[1]
        p_n = float(chamber_pa)
        if conductance == 0.0 or source_pa == p_n:
            return p_n, 1.0, 0.0
        low, high = (p_n, source_pa) if source_pa > p_n else (source_pa, p_n)
        pv_n, capacitance_n, _ = self.air_terms(p_n, volume_offset_m3)
        p = self._first_guess(p_n, source_pa, conductance, dt, b)
        for _ in range(100):
            flow, flow_p, _ = self.flow_and_slopes(p, source_pa, conductance, b)
            pv, capacitance, _ = self.air_terms(p, volume_offset_m3)
            residual = pv - pv_n - dt * flow
            step = residual / (capacitance - dt * flow_p)
            if abs(step) <= 1e-9 + 4e-16 * abs(p):
                p -= step
                break
            if residual > 0.0:
                high = p
            else:
                low = p
            p = p - step if low < p - step < high else 0.5 * (low + high)
            if high - low <= 1e-9:
                break
        _, flow_p, flow_s = self.flow_and_slopes(p, source_pa, conductance, b)
        slope = self.air_terms(p, volume_offset_m3)[1] - dt * flow_p
        return (p, capacitance_n / slope, (dt * flow_s / slope if valve == Valve.SUPPLY else 0.0))

    def _first_guess(self, p_n: float, source_pa: float, conductance: float, dt: float,
                     critical_ratio: float) -> float:
        """Newton's start for :meth:`chamber_step`: the step that a flow growing as the square root
        of the gap to the source (the subsonic law near r = 1, fitted at p_n) would make.

        From p_n itself, Newton creeps towards the source where the flow's slope is infinite
        (a chamber resting at its source took 11-20 flow evaluations a step; now 2-4). With
        rate = k sqrt(gap), backward Euler's gap g solves g + dt k sqrt(g) = gap_n."""
        gap_n = abs(source_pa - p_n)
        k_dt = dt * abs(self.rate_and_slopes(p_n, source_pa, conductance,
                                             critical_ratio)[0]) / math.sqrt(gap_n)
        root_gap = 0.5 * (math.sqrt(k_dt * k_dt + 4.0 * gap_n) - k_dt)
        return source_pa - math.copysign(root_gap * root_gap, source_pa - p_n)

    def regulator_step(self, regulator_gauge_pa: float, inputs: PlantInputs,
                       dt: float) -> tuple[float, float]:
        """The regulator after dt, exactly (lag and rate limit), and its derivative by the start
        value."""
        par = self.parameters
        return regulator_after(regulator_gauge_pa, self.regulator_target_gauge_pa(inputs), dt,
                               par.regulator_time_constant_s, par.regulator_rate_limit_pa_per_s)

    def _valves(self, inputs: PlantInputs) -> tuple:
        valves = tuple(Valve(v) for v in inputs.valves)
        if len(valves) == 1 and self.parameters.channels > 1:
            valves = valves * self.parameters.channels
        if len(valves) != self.parameters.channels:
            raise ValueError(f"need {self.parameters.channels} valve states, got {len(valves)}")
        return valves

    def explicit_euler_step(self, state: PlantState, inputs: PlantInputs, dt: float) -> PlantState:
        """The naive scheme, kept to show where it fails (tests and the integrator benchmark)."""
        regulator = self.regulator_step(state.regulator_gauge_pa, inputs, dt)[0]
        chambers = np.array([
            p +
            dt * self.chamber_rate(p, valve, state.regulator_gauge_pa, inputs.regulator_enabled)
            for p, valve in zip(state.chamber_pa, self._valves(inputs))
        ])
        return PlantState(regulator, chambers)

    def derivative(self, state_vector: np.ndarray, inputs: PlantInputs) -> np.ndarray:
        """d/dt of [regulator gauge, chamber abs...] for scipy's solve_ivp (rate limit
        included)."""
        par = self.parameters
        regulator, chambers = state_vector[0], state_vector[1:]
        target = self.regulator_target_gauge_pa(inputs)
        regulator_rate = min(
            max((target - regulator) / par.regulator_time_constant_s,
                -par.regulator_rate_limit_pa_per_s), par.regulator_rate_limit_pa_per_s)
        rates = [
            self.chamber_rate(p, valve, regulator, inputs.regulator_enabled)
            for p, valve in zip(chambers, self._valves(inputs))
        ]
        return np.array([regulator_rate, *rates])

    # ---- closed forms
    # ----------------------------------------------------------------------------
    def choked_fill_time_s(self, source_pa: float, from_pa: float, to_pa: float,
                           conductance: float) -> float:
        """Time to fill from ``from_pa`` to ``to_pa`` from a constant source while the flow stays
        choked.

        The flow is constant, m = C rho0 p_s sqrt(T0/T); integrating dp (V0 + k(2p - p_atm)) = R T
        m dt (with V(p) above its floor) gives t = [V0 (p1 - p0) + k (p1^2 - p0^2 - p_atm (p1 -
        p0))] / (R T m).
        """
        par = self.parameters
        if to_pa > par.supply_critical_ratio * source_pa:
            raise ValueError(
                "the flow is not choked all the way: to_pa must stay below b * source_pa")
        flow = conductance * RHO0_KG_PER_M3 * source_pa * math.sqrt(T0_K / par.temperature_k)
        k, v0 = par.chamber_compliance_m3_per_pa, par.chamber_volume_m3
        return ((v0 * (to_pa - from_pa) + k * (to_pa**2 - from_pa**2 - P_ATM_PA *
                                               (to_pa - from_pa))) /
                (par.gas_constant_times_temperature * flow))

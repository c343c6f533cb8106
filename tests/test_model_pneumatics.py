"""The pneumatic plant: conservation, equilibrium, the choked-fill closed form, and integrator
stability."""
import functools
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from softgrip_ros.model.pneumatics import (P_ATM_PA, PlantInputs, PlantState, PneumaticParameters,
                                           PneumaticPlant, Valve, orifice_mass_flow)

pytestmark = pytest.mark.cpu  # computation only: scripts/test.sh runs it beside another

PLANT = PneumaticPlant()
SMALL = PneumaticPlant(
    PneumaticParameters(chamber_volume_m3=1e-6, min_chamber_volume_m3=0.2e-6,
                        chamber_compliance_m3_per_pa=0.0))
FILL_30KPA = PlantInputs(regulator_setpoint_gauge_pa=30e3, valves=(Valve.SUPPLY,))


def simulate(plant, stepper, inputs, dt, duration, state=None):
    state = state or PlantState(inputs.regulator_setpoint_gauge_pa, np.array([P_ATM_PA]))
    history = []
    with np.errstate(all="ignore"):
        for _ in range(int(round(duration / dt))):
            state = stepper(state, inputs, dt)
            history.append(state.chamber_pa[0] - P_ATM_PA)
    return np.array(history)


def test_iso6358_flow_has_both_branches_and_is_continuous():
    b, c, t = 0.3, 1e-9, 293.15
    choked = orifice_mass_flow(300e3, 50e3, c, b, t)
    assert choked == pytest.approx(c * 1.185 * 300e3)
    # still choked at r < b
    assert orifice_mass_flow(300e3, 80e3, c, b, t) == pytest.approx(choked)
    assert orifice_mass_flow(300e3, 0.3 * 300e3 * (1 + 1e-12), c, b,
                             t) == pytest.approx(choked, rel=1e-9)
    assert orifice_mass_flow(300e3, 200e3, c, b, t) < choked  # subsonic
    assert orifice_mass_flow(300e3, 300e3, c, b, t) == 0.0  # no flow at r = 1
    assert orifice_mass_flow(200e3, 300e3, c, b, t) == -orifice_mass_flow(300e3, 200e3, c, b, t)


def test_closed_valves_conserve_mass_exactly():
    state = PlantState(40e3, np.array([P_ATM_PA + 25e3]))
    inputs = PlantInputs(regulator_setpoint_gauge_pa=40e3, valves=(Valve.CLOSED,))
    mass = PLANT.chamber_mass_kg(state.chamber_pa)
    for _ in range(1000):
        state = PLANT.step(state, inputs, 1e-3)
    assert state.chamber_pa[0] == P_ATM_PA + 25e3
    assert PLANT.chamber_mass_kg(state.chamber_pa) == mass


def test_fill_mass_balance():
    """Mass gained = the integral of the inflow: exactly per step without swelling, to 1e-4 with
    it."""
    for plant, tolerance in ((PneumaticPlant(
            PneumaticParameters(chamber_compliance_m3_per_pa=0.0)), 1e-12), (PLANT, 1e-4)):
        state, dt, inflow = PlantState(30e3, np.array([P_ATM_PA])), 1e-4, 0.0
        start = plant.chamber_mass_kg(state.chamber_pa)[0]
        for _ in range(2000):
            state = plant.step(state, FILL_30KPA, dt)
            inflow += dt * plant.chamber_mass_flow(state.chamber_pa[0], Valve.SUPPLY,
                                                   state.regulator_gauge_pa)
        gained = plant.chamber_mass_kg(state.chamber_pa)[0] - start
        assert gained == pytest.approx(inflow, rel=tolerance)


def test_settles_exactly_at_the_supply_pressure():
    history = simulate(PLANT, PLANT.step, FILL_30KPA, 1e-3, 1.0)
    assert history[-1] == pytest.approx(30e3, abs=1e-3)
    assert history.max() <= 30e3 + 1e-6, "backward Euler must never overshoot its source"
    assert np.all(np.diff(history) >= -1e-9), "the fill must be monotone"


def test_regulator_lag_and_rate_limit():
    state = PLANT.initial_state()
    inputs = PlantInputs(regulator_setpoint_gauge_pa=100e3, valves=(Valve.CLOSED,))
    state = PLANT.step(state, inputs, 1e-3)
    assert state.regulator_gauge_pa == pytest.approx(2.0e3)  # rate-limited: 2 MPa/s for 1 ms
    for _ in range(300):
        state = PLANT.step(state, inputs, 1e-3)
    assert state.regulator_gauge_pa == pytest.approx(100e3, rel=1e-3)
    off = PlantInputs(regulator_setpoint_gauge_pa=100e3, regulator_enabled=False,
                      valves=(Valve.CLOSED,))
    for _ in range(400):
        state = PLANT.step(state, off, 1e-3)
    assert abs(state.regulator_gauge_pa) < 100.0  # disabled: back to 0 gauge


@pytest.mark.parametrize("start_pa, target_pa", [(0.0, 100e3), (60e3, -50e3), (10e3, 11e3)])
def test_the_regulator_step_is_exact_at_any_step_size(start_pa, target_pa):
    """One step of 20 ms or 0.1 s lands where a tight ODE solve of the lag with its rate limit
    does, and where many small steps do: the identification steps between reports 20 ms apart,
    the device at its tick. (A step that clamps its whole lag step to rate * dt does not: the
    identification's rate limit came out 4-6 % low.) Its derivative by the start value is the
    finite difference's."""
    tau, rate = 0.03, 3e5
    params = PneumaticParameters(regulator_time_constant_s=tau, regulator_rate_limit_pa_per_s=rate)
    plant = PneumaticPlant(params)
    inputs = PlantInputs(regulator_setpoint_gauge_pa=target_pa, valves=(Valve.CLOSED,))
    reference = solve_ivp(lambda t, x: plant.derivative(np.array([x[0], P_ATM_PA]), inputs)[:1],
                          (0.0, 0.5), [start_pa], method="LSODA", rtol=1e-11, atol=1e-6,
                          dense_output=True, max_step=1e-4)
    for dt in (0.001, 0.02, 0.1):
        value, t = start_pa, 0.0
        while t < 0.5 - 1e-12:
            value, t = plant.regulator_step(value, inputs, dt)[0], t + dt
            assert value == pytest.approx(reference.sol(t)[0], abs=0.05), (dt, t)
    value, slope = plant.regulator_step(start_pa, inputs, 0.05)
    shifted = plant.regulator_step(start_pa + 1.0, inputs, 0.05)[0]
    assert slope == pytest.approx(shifted - value, rel=1e-6, abs=1e-9)


def test_choked_fill_time_matches_the_closed_form():
    plant = PneumaticPlant(PneumaticParameters(supply_gauge_pa=500e3))
    source = P_ATM_PA + 500e3
    target = 0.29 * source  # stays choked (b = 0.3)
    inputs = PlantInputs(regulator_setpoint_gauge_pa=500e3, valves=(Valve.SUPPLY,))
    state, dt, elapsed = PlantState(500e3, np.array([P_ATM_PA])), 1e-5, 0.0
    while state.chamber_pa[0] < target:
        previous = state.chamber_pa[0]
        state = plant.step(state, inputs, dt)
        elapsed += dt
    elapsed -= dt * (state.chamber_pa[0] - target) / (state.chamber_pa[0] - previous)
    closed_form = plant.choked_fill_time_s(source, P_ATM_PA, target,
                                           plant.parameters.supply_conductance)
    assert elapsed == pytest.approx(closed_form, rel=0.02)
    with pytest.raises(ValueError, match="not choked"):
        plant.choked_fill_time_s(source, P_ATM_PA, 0.5 * source, 1e-9)


def test_step_agrees_with_an_lsoda_reference():
    inputs = PlantInputs(regulator_setpoint_gauge_pa=25e3, valves=(Valve.SUPPLY,))
    reference = solve_ivp(lambda t, y: PLANT.derivative(y, inputs), (0.0, 0.3), [0.0, P_ATM_PA],
                          method="LSODA", rtol=1e-10, atol=1e-6, t_eval=np.arange(1, 301) * 1e-3)
    ours = simulate(PLANT, PLANT.step, inputs, 1e-4, 0.3,
                    state=PlantState(0.0, np.array([P_ATM_PA])))[9::10]
    assert np.max(np.abs(ours - (reference.y[1] - P_ATM_PA))) < 150.0  # Pa, over a 25 kPa step
    assert ours[-1] == pytest.approx(reference.y[1][-1] - P_ATM_PA, abs=1.0)


@pytest.mark.parametrize("chunk_s", [1e-3, 5e-3])
def test_advance_follows_the_law_however_its_caller_chops_the_time(chunk_s):
    """A simulated device advances its truth by whatever time its ticks took (1 ms, or 5 ms on a
    loaded host). In one backward-Euler step each, the fill lagged LSODA by 67 and 285 Pa: the
    truth moved with the host's load, and live identification fitted that. ``advance`` takes
    extrapolated steps of at most TRUTH_STEP_S: within 5 Pa either way (2.6 Pa; backward Euler
    sub-stepped at 0.2 ms, as it was, 14 Pa)."""
    inputs = PlantInputs(regulator_setpoint_gauge_pa=25e3, valves=(Valve.SUPPLY,))
    reference = solve_ivp(lambda t, y: PLANT.derivative(y, inputs), (0.0, 0.3), [0.0, P_ATM_PA],
                          method="LSODA", rtol=1e-10, atol=1e-6,
                          t_eval=np.arange(1, 301) * 1e-3).y[1] - P_ATM_PA
    every = int(round(chunk_s / 1e-3))
    for stepper, low, high in ((PLANT.advance, 0.0, 5.0), (PLANT.step, 60.0, math.inf)):
        ours = simulate(PLANT, stepper, inputs, chunk_s, 0.3,
                        state=PlantState(0.0, np.array([P_ATM_PA])))
        worst = np.max(np.abs(ours - reference[every - 1::every]))
        assert low < worst < high, (stepper.__name__, worst)


TRANSIENTS = {  # (regulator gauge, chamber gauge) at the start, the inputs
    "fill as the regulator ramps": ((0.0, 0.0), PlantInputs(40e3, True, (Valve.SUPPLY,))),
    "vent from 40 kPa": ((40e3, 40e3), PlantInputs(40e3, True, (Valve.VENT,))),
    "evacuation": ((0.0, 0.0), PlantInputs(0.0, True, (Valve.VACUUM,))),
    "vent from -50 kPa": ((0.0, -50e3), PlantInputs(0.0, True, (Valve.VENT,))),
}


@pytest.mark.parametrize("truth", ["slow_large", "drawn_1", "drawn_2"])
@pytest.mark.parametrize("transient", list(TRANSIENTS))
def test_the_truth_follows_the_law_on_the_identification_truths(truth, transient):
    """The identification's truths (the simulated user's hardware) within 6 Pa of the law over
    0.6 s of each transient the excitation drives, in the simulated device's 1 ms ticks: a
    sensor's noise is 150-250 Pa, and an error of tens of Pa repeated over every transient skewed
    the fitted conductances by about their own interval (backward Euler at 0.2 ms: 7-48 Pa, and
    the fits' 95 % intervals held the truth in 67-83 %). Largest now: 4.6 Pa, a fill as the
    regulator's rate limit lets go. The law: the same steps at a tenth of the length, second
    order so a hundredth of the error (LSODA's chatter near a source made it a minute a case; on
    the fill above the two agree to 0.003 Pa)."""
    from softgrip_ros.devtools.identification_sim import truth as benchmark_truth
    plant = PneumaticPlant(benchmark_truth(truth).parameters)
    (regulator_pa, chamber_pa), inputs = TRANSIENTS[transient]
    start = PlantState(regulator_pa, np.array([P_ATM_PA + chamber_pa]))
    law = simulate(plant, lambda *args: plant.advance(*args, max_step_s=1e-4), inputs, 1e-3, 0.6,
                   state=start)
    ours = simulate(plant, plant.advance, inputs, 1e-3, 0.6, state=start)
    assert np.max(np.abs(ours - law)) < 6.0


# a chamber that balloons out five times as readily as it is drawn in: its capacitance
# V + p dV/dp jumps by 20 % at atmosphere, and so does dp/dt
TWO_SIDED = PneumaticPlant(PneumaticParameters(chamber_compliance_m3_per_pa=2.5e-10,
                                               vacuum_compliance_m3_per_pa=0.5e-10))


def law_across(plant, inputs, start, duration_s, level_pa=P_ATM_PA):
    """(times, gauge Pa, when it reached ``level_pa``): LSODA on the law, every 1 ms, stopped
    where the chamber reaches that level (where the law has a kink: atmosphere, the volume's
    floor) and restarted there on the far side's law."""
    times = np.arange(1, int(round(duration_s / 1e-3)) + 1) * 1e-3
    rising = start[1] < level_pa

    def at_level(t, y):
        return y[1] - level_pa
    at_level.terminal = True
    near = solve_ivp(lambda t, y: plant.derivative(y, inputs), (0.0, duration_s), start,
                     method="LSODA", rtol=1e-10, atol=1e-6, events=at_level,
                     dense_output=True)
    assert near.status == 1, "the chamber never reached the level"
    crossed_s = float(near.t_events[0][0])
    there = near.y_events[0][0].copy()
    there[1] = level_pa + (1e-9 if rising else -1e-9)
    far = solve_ivp(lambda t, y: plant.derivative(y, inputs), (crossed_s, duration_s), there,
                    method="LSODA", rtol=1e-10, atol=1e-6, dense_output=True)
    gauge = np.where(times < crossed_s, near.sol(np.minimum(times, crossed_s))[1],
                     far.sol(np.maximum(times, crossed_s))[1]) - P_ATM_PA
    return times, gauge, crossed_s


@pytest.mark.parametrize("start_gauge_pa, inputs", [
    (-50e3, PlantInputs(40e3, True, (Valve.SUPPLY,))),
    (40e3, PlantInputs(0.0, True, (Valve.VACUUM,)))], ids=["fill from vacuum", "evacuation"])
def test_a_chamber_crosses_atmosphere_as_the_law_does_where_its_compliance_changes(
        start_gauge_pa, inputs):
    """Where the two compliances differ, dp/dt jumps at atmosphere. Steps on p took one side's
    law for the whole step across it: the simulated device's fill from vacuum 21 Pa and its
    evacuation from 40 kPa 39 Pa off the law ever after (on the identification's slow_large,
    2.8 Pa: enough to move a fit's values by a sigma). On the air's mass, whose rate (the flow)
    does not jump: within 1 Pa of LSODA stopped and restarted there (0.05 and 0.15 Pa)."""
    start = np.array([inputs.regulator_setpoint_gauge_pa, P_ATM_PA + start_gauge_pa])
    times, law, crossed_s = law_across(TWO_SIDED, inputs, start, 0.4)
    assert 0.05 < crossed_s < 0.35  # the crossing lies well inside the run
    ours = simulate(TWO_SIDED, TWO_SIDED.advance, inputs, 1e-3, 0.4,
                    state=PlantState(start[0], start[1:].copy()))
    assert np.max(np.abs(ours - law)) < 1.0, np.max(np.abs(ours - law))


# drawn in so far under vacuum that its volume reaches the floor at -45 kPa
FLOORED = PneumaticPlant(PneumaticParameters(vacuum_compliance_m3_per_pa=4e-10))
FLOOR_GAUGE_PA = -(FLOORED.parameters.chamber_volume_m3 -
                   FLOORED.parameters.min_chamber_volume_m3) / 4e-10


@pytest.mark.parametrize("start_gauge_pa, inputs, duration_s", [
    (-30e3, PlantInputs(0.0, True, (Valve.VACUUM,)), 0.1),
    (-60e3, PlantInputs(-10e3, True, (Valve.SUPPLY,)), 0.1)], ids=["evacuation", "refill"])
def test_a_chamber_reaches_its_volume_floor_as_the_law_does(start_gauge_pa, inputs, duration_s):
    """Drawn in far enough, a chamber's volume stops at min_chamber_volume_m3: its capacitance
    drops from V + p dV/dp to V there (12 times here), a kink like atmosphere's. Stepped on the
    air's mass, the plant follows LSODA stopped and restarted at the floor, both ways across it
    (0.73 and 0.10 Pa; stepped on p, as before the air's mass, 271 and 34 Pa). At 0.25 ms
    steps: the collapsed chamber is so fast that at the device's 1 ms its fall is 9 Pa off the
    law whether or not a step crosses the floor (started past it: 9.5 Pa; second order, 2.2 Pa
    at 0.5 ms), which would hide an error of the crossing itself. The runs end short of the
    vacuum source, where LSODA crawls (the flow's square root)."""
    start = np.array([inputs.regulator_setpoint_gauge_pa, P_ATM_PA + start_gauge_pa])
    level = P_ATM_PA + FLOOR_GAUGE_PA
    times, law, crossed_s = law_across(FLOORED, inputs, start, duration_s, level)
    assert 0.002 < crossed_s < duration_s - 0.02, crossed_s  # the floor is crossed in the run
    ours = simulate(FLOORED, functools.partial(FLOORED.advance, max_step_s=2.5e-4), inputs,
                    1e-3, duration_s, state=PlantState(start[0], start[1:].copy()))
    assert np.max(np.abs(ours - law)) < 1.0, np.max(np.abs(ours - law))


@pytest.mark.parametrize("valve, regulator_gauge_pa, chamber_gauge_pa", [
    (Valve.SUPPLY, 40e3, -150.0), (Valve.SUPPLY, 40e3, -3e3), (Valve.SUPPLY, -40e3, 200.0),
    (Valve.VACUUM, 0.0, 150.0), (Valve.VACUUM, 0.0, 5e3)])
def test_a_step_near_atmosphere_has_the_derivatives_of_its_result(
        valve, regulator_gauge_pa, chamber_gauge_pa):
    """The estimator linearises the step (filters.plant_step): its derivatives by the chamber and
    by the regulator are those of the step's result, on a chamber whose compliance changes at
    atmosphere, where the step crosses it (the first three cases) and where it ends short of it
    (the last two), to 1e-4 relative."""
    p_n = P_ATM_PA + chamber_gauge_pa
    p_next, d_chamber, d_regulator = TWO_SIDED.chamber_step(p_n, valve, regulator_gauge_pa, 1e-3)
    crossed = (p_next - P_ATM_PA) * (p_n - P_ATM_PA) < 0.0
    assert crossed == (abs(chamber_gauge_pa) < 1e3)
    h = 1e-3
    by_chamber = (TWO_SIDED.chamber_step(p_n + h, valve, regulator_gauge_pa, 1e-3)[0] -
                  TWO_SIDED.chamber_step(p_n - h, valve, regulator_gauge_pa, 1e-3)[0]) / (2 * h)
    by_regulator = (TWO_SIDED.chamber_step(p_n, valve, regulator_gauge_pa + h, 1e-3)[0] -
                    TWO_SIDED.chamber_step(p_n, valve, regulator_gauge_pa - h, 1e-3)[0]) / (2 * h)
    assert d_chamber == pytest.approx(by_chamber, rel=1e-4)
    assert d_regulator == pytest.approx(by_regulator, rel=1e-4, abs=1e-9)


@pytest.mark.parametrize("valve, regulator_gauge_pa, source_gauge_pa",
                         [(Valve.VENT, 0.0, 0.0), (Valve.SUPPLY, 30e3, 30e3),
                          (Valve.VACUUM, 0.0, PLANT.parameters.vacuum_source_gauge_pa)])
@pytest.mark.parametrize("gap_pa", [-5e3, -1.0, -1e-3, 1e-3, 1.0, 5e3])
@pytest.mark.parametrize("dt", [1e-4, 1e-3, 2e-2])
def test_an_extrapolated_step_never_passes_the_source(valve, regulator_gauge_pa, source_gauge_pa,
                                                      gap_pa, dt):
    """Backward Euler's map is monotone: it approaches its source and never passes it. The
    extrapolation (2 x halves - whole) would pass it near the source, where backward Euler's
    error is not smooth (the flow's square root); the step then puts the chamber at the source."""
    source_pa = P_ATM_PA + source_gauge_pa
    inputs = PlantInputs(regulator_gauge_pa, True, (valve,))
    state = PlantState(regulator_gauge_pa, np.array([source_pa + gap_pa]))
    for _ in range(5):
        after = SMALL.extrapolated_step(state, inputs, dt).chamber_pa[0]
        assert (after - source_pa) * gap_pa >= 0.0
        assert abs(after - source_pa) <= abs(state.chamber_pa[0] - source_pa)
        state = PlantState(regulator_gauge_pa, np.array([after]))


@pytest.mark.parametrize("setpoint_pa, valve, chamber_gauge_pa",
                         [(0.0, Valve.CLOSED, 20e3), (45e3, Valve.CLOSED, 20e3),
                          (-30e3, Valve.CLOSED, -20e3), (0.0, Valve.VENT, 0.0)])
def test_advance_with_the_chambers_at_rest_is_one_exact_step(setpoint_pa, valve, chamber_gauge_pa,
                                                               monkeypatch):
    """The regulator's law is solved exactly and a closed chamber keeps its air (a vented one at
    atmosphere stays there): ``advance`` takes one step (a fifth of an idle simulated device's
    plant time), the same as its sub-steps to 1e-6 Pa."""
    inputs = PlantInputs(regulator_setpoint_gauge_pa=setpoint_pa, valves=(valve,))
    start = PlantState(50e3, np.array([P_ATM_PA + chamber_gauge_pa]))
    substeps = start
    for _ in range(69):
        substeps = PLANT.step(substeps, inputs, 0.0137 / 69)
    steps = []
    step = PLANT.step
    monkeypatch.setattr(PLANT, "step", lambda *args: steps.append(args[2]) or step(*args))
    once = PLANT.advance(start, inputs, 0.0137)
    assert steps == [0.0137]
    assert once.regulator_gauge_pa == pytest.approx(substeps.regulator_gauge_pa, abs=1e-6)
    assert once.chamber_pa[0] == start.chamber_pa[0] == substeps.chamber_pa[0]
    assert abs(once.regulator_gauge_pa - 50e3) > 1e3  # the regulator did move


@pytest.mark.parametrize("valve, regulator_gauge_pa, source_gauge_pa",
                         [(Valve.VENT, 0.0, 0.0), (Valve.SUPPLY, 30e3, 30e3),
                          (Valve.VACUUM, 0.0, PLANT.parameters.vacuum_source_gauge_pa)])
@pytest.mark.parametrize("gap_pa", [-5e4, -1e3, -1.0, -1e-3, 1e-3, 1.0, 1e3, 5e4])
@pytest.mark.parametrize("dt", [1e-4, 1e-3, 2e-2])
def test_backward_euler_step_solves_its_equation_in_few_flow_evaluations(
        valve, regulator_gauge_pa, source_gauge_pa, gap_pa, dt):
    """The implicit step's root, to 1e-9 Pa, against brentq on the same equation (on the air's
    mass: p V(p) - p_n V(p_n) = dt R T m_dot(p)); from a start on the square-root law, at most 6
    flow evaluations (with the Jacobian's), where starting at p_n took up to 20 near the source,
    at the singular slope (the state of every idle chamber)."""
    from scipy.optimize import brentq
    p_n = P_ATM_PA + source_gauge_pa + gap_pa
    plant, calls = PneumaticPlant(), []
    flow_and_slopes = plant.flow_and_slopes
    plant.flow_and_slopes = lambda *args: calls.append(args) or flow_and_slopes(*args)
    p_next, slope, _ = plant.chamber_step(p_n, valve, regulator_gauge_pa, dt)
    source_pa, conductance = PLANT.source(valve, regulator_gauge_pa)

    def residual(p):
        return (PLANT.air_terms(p)[0] - PLANT.air_terms(p_n)[0] -
                dt * PLANT.flow_and_slopes(p, source_pa, conductance)[0])

    reference = brentq(residual, min(p_n, source_pa), max(p_n, source_pa), xtol=1e-12, rtol=1e-15)
    assert p_next == pytest.approx(reference, abs=1e-9)
    assert len(calls) <= 6, f"{len(calls)} flow evaluations"
    assert 0.0 < slope <= 1.0


def explicit_euler_ripple(dt):
    history = simulate(SMALL, SMALL.explicit_euler_step, FILL_30KPA, dt, 0.5)
    tail = history[int(0.8 * history.size):]
    return float(np.max(np.abs(tail - 30e3)))


def test_explicit_euler_fails_near_r_equals_one_and_ours_does_not():
    """Pin the failure: near r -> 1 the subsonic flow ~ sqrt(1 - r) has an infinite slope, so
    explicit Euler chatters around equilibrium with an amplitude ~ dt^2 and never settles; the
    critical step for a 0.2 kPa ripple (the controller's steady-state spec) on a 1 mL chamber lies
    near 0.5 ms, below the device's 1 kHz step. Backward Euler settles exactly at every step
    size."""
    ripple_small, ripple_large = explicit_euler_ripple(1e-4), explicit_euler_ripple(1e-3)
    assert ripple_large / ripple_small == pytest.approx(100.0, rel=0.1)  # ~ dt^2
    # bisect the 200 Pa point
    low, high = 1e-4, 2e-3
    for _ in range(12):
        middle = math.sqrt(low * high)
        low, high = (middle, high) if explicit_euler_ripple(middle) < 200.0 else (low, middle)
    assert 3e-4 < high < 7e-4, f"critical step moved: {high:.3g} s"
    for dt in (high, 1e-3, 1e-2, 5e-2):
        history = simulate(SMALL, SMALL.step, FILL_30KPA, dt, 1.0)
        assert abs(history[-1] - 30e3) < 1e-3 and history.max() <= 30e3 + 1e-6, dt


def test_explicit_euler_leaves_the_physical_range_at_large_steps():
    history = simulate(SMALL, SMALL.explicit_euler_step, FILL_30KPA, 2e-2, 1.0)
    assert np.nanmin(
        history) < -P_ATM_PA, "naive Euler reaches a negative absolute pressure while filling"
    ours = simulate(SMALL, SMALL.step, FILL_30KPA, 2e-2, 1.0)
    assert 0.0 <= ours.min() and ours.max() <= 30e3 + 1e-6


@pytest.mark.parametrize("changes, message",
                         [({"chamber_volume_m3": 0.0}, "chamber_volume_m3"),
                          ({"vent_critical_ratio": 1.2}, "vent_critical_ratio"),
                          ({"vacuum_compliance_m3_per_pa": -1.0}, "vacuum_compliance"),
                          ({"channels": 5}, "channels"),
                          ({"vacuum_source_gauge_pa": 10e3}, "vacuum_source_gauge_pa"),
                          ({"supply_conductance": float("nan")}, "supply_conductance")])
def test_bad_parameters_are_rejected(changes, message):
    with pytest.raises(ValueError, match=message):
        PneumaticParameters(**changes)


def test_bad_step_is_rejected():
    with pytest.raises(ValueError, match="dt must be positive"):
        PLANT.step(PLANT.initial_state(), FILL_30KPA, 0.0)
    with pytest.raises(ValueError, match="valve states"):
        PneumaticPlant(PneumaticParameters(channels=2)).step(
            PneumaticPlant(PneumaticParameters(channels=2)).initial_state(),
            PlantInputs(valves=(Valve.SUPPLY, Valve.VENT, Valve.VENT)), 1e-3)


def test_a_disabled_regulator_cuts_both_sources():
    """Enable = 0 is the device's safe state: the regulator's output goes to 0 whatever its fault,
    and the vacuum valve path leads to a vented line, so no valve state can pump."""
    plant = PneumaticPlant()
    disabled = PlantInputs(regulator_setpoint_gauge_pa=40e3, regulator_enabled=False,
                           valves=(Valve.VACUUM,), regulator_overshoot_pa=100e3)
    assert plant.regulator_target_gauge_pa(disabled) == 0.0
    state = plant.initial_state(-30e3)
    for _ in range(500):
        state = plant.step(state, disabled, 2e-3)
    assert abs(state.chamber_pa[0] - P_ATM_PA) < 100.0 and abs(state.regulator_gauge_pa) < 100.0
    live = PlantInputs(regulator_enabled=True, valves=(Valve.VACUUM,))
    assert (plant.chamber_rate(P_ATM_PA, Valve.VACUUM, 0.0) < 0.0 == plant.chamber_rate(
        P_ATM_PA, Valve.VACUUM, 0.0, False))
    assert plant.step(plant.initial_state(), live, 0.01).chamber_pa[0] < P_ATM_PA - 1e3


@pytest.mark.parametrize("gauge_pa, offset_m3", [(30e3, -1e-6), (-40e3, 2e-6), (0.0, -0.5e-6)])
def test_a_volume_offset_keeps_the_air_and_moves_the_pressure(gauge_pa, offset_m3):
    """Fingers held back by an object take volume from the chamber at a fixed mass of air: p V is
    unchanged, and the pressure rises for less volume, falls for more."""
    plant = PneumaticPlant(PneumaticParameters(vacuum_compliance_m3_per_pa=2e-10))
    state = plant.initial_state(gauge_pa)
    moved = plant.with_volume_offset(state, [offset_m3])
    before = plant.air_terms(float(state.chamber_pa[0]))[0]
    after = plant.air_terms(float(moved.chamber_pa[0]), offset_m3)[0]
    assert after == pytest.approx(before, rel=1e-12)
    assert np.sign(moved.chamber_pa[0] - state.chamber_pa[0]) == -np.sign(offset_m3)
    back = plant.with_volume_offset(moved, [0.0])
    assert back.chamber_pa[0] == pytest.approx(state.chamber_pa[0], rel=1e-12)
    # a step with the offset conserves the air through a closed valve
    held = plant.step(moved, PlantInputs(valves=(Valve.CLOSED,)), 1e-3)
    assert held.chamber_pa[0] == moved.chamber_pa[0]


def test_the_array_orifice_slope_is_the_scalar_plants_and_the_flows_derivative():
    """orifice_flow_and_slope (the grasp sensing's vectorised step) against the plant's scalar
    flow_and_slopes (R T m_dot) and a central difference, choked, subsonic, in and out."""
    from softgrip_ros.model.pneumatics import orifice_flow_and_slope
    plant = PneumaticPlant()
    par = plant.parameters
    c, b, t = par.supply_conductance, par.supply_critical_ratio, par.temperature_k
    chambers = np.array([40e3, 90e3, 120e3, 160e3, 240e3])
    source = 150e3
    flow, slope = orifice_flow_and_slope(source, chambers, c, b, t)
    rt = par.gas_constant_times_temperature
    for chamber, f, d in zip(chambers, flow, slope):
        scalar = plant.flow_and_slopes(float(chamber), source, c, b)
        assert rt * f == pytest.approx(scalar[0], rel=1e-12)
        assert rt * d == pytest.approx(scalar[1], rel=1e-9)
        h = 1.0
        numeric = (orifice_mass_flow(source, chamber + h, c, b, t) -
                   orifice_mass_flow(source, chamber - h, c, b, t)) / (2 * h)
        assert d == pytest.approx(numeric, rel=1e-4, abs=1e-15)

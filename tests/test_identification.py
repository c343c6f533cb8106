"""Pneumatic identification without ROS: the vectorised plant against the suite's, what pressure
data can and cannot determine, and the fit recovering perturbed truths from an excitation run
on them (softgrip_ros.devtools.identification_sim)."""
import collections
import copy
import dataclasses
import math

import numpy as np
import pytest

from softgrip_ros.devtools import identification_sim
from softgrip_ros.estimation import identification
from softgrip_ros.model import plant_file
from softgrip_ros.model.pneumatics import (P_ATM_PA, PlantInputs, PlantState,
                                           PneumaticParameters, PneumaticPlant, Valve)

pytestmark = pytest.mark.cpu  # computation only: scripts/test.sh runs it beside another


def _par(parameters: PneumaticParameters) -> dict:
    par = {"temperature_k": np.array(parameters.temperature_k),
           "kpos": np.array(parameters.chamber_compliance_m3_per_pa),
           "kneg": np.array(parameters.vacuum_compliance_m3_per_pa),
           "v0": np.array(parameters.chamber_volume_m3),
           "vmin": np.array(parameters.min_chamber_volume_m3)}
    par["rt"] = 287.05 * par["temperature_k"]
    return par


def _two_sided_chambers(count: int, seed: int):
    """(parameters, plant, rng, absolute chamber pressures): compliances that differ, and a
    quarter of the chambers within a step's reach of atmosphere, where dp/dt jumps."""
    parameters = dataclasses.replace(PneumaticParameters(), vent_critical_ratio=0.4,
                                     vacuum_compliance_m3_per_pa=0.5e-10)
    rng = np.random.default_rng(seed)
    chambers = P_ATM_PA + np.where(np.arange(count) % 4 == 0,
                                   rng.uniform(-400.0, 400.0, count),
                                   rng.uniform(-55e3, 45e3, count))
    return parameters, PneumaticPlant(parameters), rng, chambers



@pytest.mark.parametrize("valve, regulator_gauge_pa", [(Valve.VACUUM, 0.0),
                                                        (Valve.SUPPLY, -10e3)])
def test_the_vectorised_step_is_the_plants_across_the_volume_floor(valve, regulator_gauge_pa):
    """A chamber drawn in to min_chamber_volume_m3 (here at -45 kPa) has a second kink in its
    capacitance: the fit's step and its p V inverse agree with the plant there too, and steps
    cross the floor both ways."""
    parameters = dataclasses.replace(PneumaticParameters(), vacuum_compliance_m3_per_pa=4e-10)
    plant, par = PneumaticPlant(parameters), _par(parameters)
    floor_pa = P_ATM_PA - 45e3
    chambers = floor_pa + np.random.default_rng(3).uniform(-4e3, 4e3, 200)
    assert np.allclose(identification.pressure_of_pv(identification.air_pv(chambers, par), par),
                       chambers, rtol=0.0, atol=1e-6)
    source, conductance = plant.source(valve, regulator_gauge_pa)
    b = parameters.path(valve)[1]
    ours = identification.chamber_steps(chambers, np.full(200, source),
                                        np.full(200, conductance), np.full(200, b), par, 2e-3)
    theirs = np.array([plant.chamber_step(p, valve, regulator_gauge_pa, 2e-3)[0]
                       for p in chambers])
    assert np.max(np.abs(ours - theirs)) < 1e-6
    assert np.sum((theirs - floor_pa) * (chambers - floor_pa) < 0.0) >= 5

@pytest.mark.parametrize("valve", [Valve.SUPPLY, Valve.VACUUM, Valve.VENT])
def test_the_vectorised_step_is_the_plants_backward_euler_step(valve):
    parameters, plant, rng, chambers = _two_sided_chambers(200, seed=1)
    regulator = rng.uniform(-30e3, 45e3, 200)
    conductance, b = parameters.path(valve)
    sources = np.array([plant.source(valve, r)[0] for r in regulator])
    ours = identification.chamber_steps(chambers, sources, np.full(200, conductance),
                                        np.full(200, b), _par(parameters), 1e-3)
    theirs = np.array([plant.chamber_step(p, valve, r, 1e-3)[0]
                       for p, r in zip(chambers, regulator)])
    assert np.max(np.abs(ours - theirs)) < 1e-6
    if valve != Valve.VENT:  # a vent's source is atmosphere: nothing crosses it
        assert np.sum((theirs - P_ATM_PA) * (chambers - P_ATM_PA) < 0.0) >= 5
    # Newton started from a guess (the simulation's extrapolated trajectory) ends at the same
    # root, wherever the guess lies: near it, at it, past the source, at p_n or the source, NaN
    kinds = np.arange(200) % 6
    guess = np.select([kinds == 0, kinds == 1, kinds == 2, kinds == 3, kinds == 4],
                      [theirs + rng.normal(0.0, 30.0, 200), theirs,
                       2.0 * sources - chambers, chambers, sources], np.nan)
    guessed = identification.chamber_steps(chambers, sources, np.full(200, conductance),
                                           np.full(200, b), _par(parameters), 1e-3, guess=guess)
    assert np.max(np.abs(guessed - theirs)) < 1e-6


@pytest.mark.parametrize("valve", [Valve.SUPPLY, Valve.VACUUM, Valve.VENT])
def test_the_grids_step_after_an_input_change_is_the_plants_extrapolated_step(valve):
    """The fit takes the step after an input change as the simulated device takes each of its
    steps: the same chambers, the regulator slewing to its target, give the same pressures to
    1e-5 Pa, across atmosphere (where the compliances differ) too."""
    parameters, plant, rng, chambers = _two_sided_chambers(60, seed=2)
    regulator, target = rng.uniform(-30e3, 45e3, 60), rng.uniform(-30e3, 45e3, 60)
    theirs, middles, ends = [], [], []
    for p, r, t in zip(chambers, regulator, target):
        inputs = PlantInputs(t, True, (valve,))
        theirs.append(plant.extrapolated_step(PlantState(r, np.array([p])), inputs,
                                              1e-3).chamber_pa[0])
        middles.append(plant.source(valve, plant.regulator_step(r, inputs, 5e-4)[0])[0])
        ends.append(plant.source(valve, plant.regulator_step(r, inputs, 1e-3)[0])[0])
    conductance, b = np.full(60, parameters.path(valve)[0]), np.full(60, parameters.path(valve)[1])
    par = {key: np.full(60, value) for key, value in _par(parameters).items()}
    whole = identification.chamber_steps(chambers, np.array(ends), conductance, b, par, 1e-3)
    ours = identification._Grid._extrapolated(chambers, np.array(middles), np.array(ends),
                                              conductance, b, par, whole)
    assert np.max(np.abs(ours - np.array(theirs))) < 1e-5
    if valve != Valve.VENT:
        assert np.sum((ours - P_ATM_PA) * (chambers - P_ATM_PA) < 0.0) >= 3


def test_volume_and_conductances_cannot_be_told_apart_by_pressure_alone():
    """Every volume term and every conductance scaled by one factor: the same pressures to
    1e-9 relative. Hence V0 is measured or inherited, never fitted."""
    truth = plant_file.default_description()
    steps, _ = identification.excitation(quick=True)
    recording = identification_sim.record(truth, steps[:12], seed=0)
    scaled = dataclasses.replace(truth.parameters, **{
        name: getattr(truth.parameters, name) * 1.7 for name in identification.VOLUME_SCALED})
    rests = identification.vented_rests(recording)
    biases = {name: 0.0 for name in recording.sensors}
    episodes = identification.episodes_of(recording, biases, rests)
    grid = identification._Grid(recording, episodes, lambda t: np.zeros(len(t)), biases,
                                {name: 1.0 for name in recording.sensors})
    both = grid.simulate([truth.parameters, scaled])
    assert np.max(np.abs(both[0] - both[1])) <= 1e-9 * P_ATM_PA


def _quick_drawn_2():
    """(truth, recording, biases, weights, episodes): drawn_2 run through the quick excitation,
    without biases, each reading weighed alike."""
    truth = identification_sim.drawn(2)
    steps, _ = identification.excitation(quick=True)
    recording = identification_sim.record(truth, steps, seed=0)
    biases = {name: 0.0 for name in recording.sensors}
    weights = {name: 1.0 for name in recording.sensors}
    return truth, recording, biases, weights, identification.episodes_of(recording, biases)


def test_episodes_stepped_together_predict_what_each_predicts_alone():
    """The grid steps its episodes longest first, each only as far as its readings need (13 %
    less time per simulation of the full excitation): together, under two parameter sets and
    with the sensors' readings dated apart, each episode's readings come out as they do alone."""
    truth, recording, biases, weights, episodes = _quick_drawn_2()
    lengths = [e.end_s - e.start_s for e in episodes]
    assert len(episodes) >= 8 and max(lengths) > 1.5 * min(lengths)
    sets = [truth.parameters, dataclasses.replace(truth.parameters, vent_critical_ratio=0.45,
                                                  supply_conductance=2e-9)]
    delays = {name: delay for name, delay in zip(recording.sensors, (4e-4, -3e-4))}

    def grid(of):
        built = identification._Grid(recording, of, lambda t: np.full(len(t), 20e3), biases,
                                     weights)
        built.set_delays(delays)
        return built

    together = grid(episodes)
    both = together.simulate(sets)
    for e, episode in enumerate(episodes):
        alone = grid([episode]).simulate(sets)
        assert np.max(np.abs(both[:, together.episode == e] - alone)) < 1e-6, e


def test_grids_stacked_into_one_simulation_predict_what_each_predicts_alone():
    """The timings' sensitivities simulate the recording with each batch of valve switches moved,
    and with the sensors' readings dated older, all as one grid: a simulation's time goes to its
    steps, hardly to its width (a live slow_large recording, under a profiler: 9 simulations,
    2.6 s, per pass before)."""
    truth, recording, biases, weights, episodes = _quick_drawn_2()
    later = recording.moved({i: 4e-4 for i in range(1, len(recording.inputs), 3)})
    grids = [identification._Grid(of, episodes, lambda t: np.full(len(t), 20e3), biases, weights)
             for of in (recording, later, recording)]
    grids[2].set_delays({name: 3e-4 for name in recording.sensors})
    stacked = identification._Grid.stacked(grids)
    assert len(stacked.measured) == sum(len(g.measured) for g in grids)
    together = np.split(stacked.simulate([truth.parameters])[0],
                        np.cumsum([len(g.measured) for g in grids[:-1]]))
    for grid, predicted in zip(grids, together):
        assert np.max(np.abs(predicted - grid.simulate([truth.parameters])[0])) < 1e-6
    # and the three differ: the moves and the delays reach the predictions
    assert np.max(np.abs(together[1] - together[0])) > 100.0
    assert np.max(np.abs(together[2] - together[0])) > 100.0


def _fit_model_error(truth: PneumaticParameters, plan: list, law_step_s: float):
    """(times, the fit's 1 ms simulation of ``plan`` [(seconds, valve, regulator setpoint)] minus
    the law's: PneumaticPlant.advance at ``law_step_s``), from rest at atmosphere."""
    plant = PneumaticPlant(truth)
    inputs, now = [], 0.0
    state, times, reference = plant.initial_state(), [], []
    for duration, valve, setpoint_pa in plan:
        inputs.append(identification.InputChange(now, int(valve), setpoint_pa, True))
        for _ in range(int(round(duration / 1e-3))):
            state = plant.advance(state, PlantInputs(setpoint_pa, True, (valve,)), 1e-3,
                                  law_step_s)
            now += 1e-3
            times.append(now)
            reference.append(state.chamber_pa[0] - P_ATM_PA)
    times, reference = np.array(times), np.array(reference)
    recording = identification.Recording({"s": (times, reference)}, (times, reference), inputs)

    def regulator_at(at):
        return identification.regulator_trajectory(
            at, inputs, truth.regulator_time_constant_s, truth.regulator_rate_limit_pa_per_s,
            truth.vacuum_source_gauge_pa, truth.supply_gauge_pa)

    grid = identification._Grid(recording, [identification.Episode(0.0, now, 0.0)],
                                regulator_at, {"s": 0.0}, {"s": 1.0})
    return grid.times, grid.simulate([truth])[0] - grid.measured


def test_the_fits_simulation_follows_the_law_at_its_1_ms_steps():
    """A real chamber (and the simulated device, PneumaticPlant.advance) follows the continuous
    law. One backward-Euler step per millisecond strayed from it by up to 216 Pa in this fast
    plant's fill, vent, evacuation and refill (a sensor's noise: 150-300 Pa): against such a
    truth the fit put drawn_1's supply critical ratio 17 % off. The grid's steps are BDF2, from
    a backward-Euler step wherever the inputs change: within 60 Pa."""
    truth = identification_sim.drawn(1).parameters
    plan = [(0.05, Valve.CLOSED, 42750.0), (0.6, Valve.SUPPLY, 42750.0), (0.9, Valve.VENT, 0.0),
            (0.25, Valve.VACUUM, 0.0), (0.9, Valve.VENT, 0.0), (0.8, Valve.SUPPLY, 20000.0)]
    error = _fit_model_error(truth, plan, 1e-5)[1]
    assert np.max(np.abs(error)) < 60.0, np.max(np.abs(error))
    assert np.sqrt(np.mean(error**2)) < 15.0


def test_the_fits_simulation_crosses_atmosphere_as_the_law_does():
    """slow_large's chamber balloons out twice as readily as it is drawn in, so dp/dt jumps at
    atmosphere. BDF2 on p took that jump inside a step and into the next one's formula: each
    fill from vacuum and each evacuation from a positive level 12 Pa off the law (4.1 Pa rms),
    weighed over every reading after it (the simulated device was 2.8 Pa off, the other way: the
    fits' values moved by up to a sigma). On the air's mass, whose rate does not jump, and with
    the step after an input change taken as the device takes its own: within 2 Pa (0.34 Pa).
    Detecting the crossing and taking that step otherwise was tried: the finite differences of
    the fit's Jacobian then saw the switch, and intervals came out up to 9 times too narrow."""
    truth = identification_sim.truth("slow_large").parameters
    assert truth.chamber_compliance_m3_per_pa > 1.5 * truth.vacuum_compliance_m3_per_pa
    plan = [(0.05, Valve.CLOSED, 42750.0), (0.3, Valve.VACUUM, 42750.0),
            (0.6, Valve.SUPPLY, 42750.0), (0.4, Valve.VACUUM, 0.0), (0.5, Valve.SUPPLY, 20000.0),
            (0.3, Valve.VACUUM, 0.0)]
    times, error = _fit_model_error(truth, plan, 5e-5)
    assert np.max(np.abs(error)) < 2.0, np.max(np.abs(error))
    assert np.sqrt(np.mean(error**2)) < 0.5


def test_the_fits_step_after_an_input_change_is_the_devices():
    """A fill from a rest as the regulator steps up: its first step starts where the flow's
    square root is singular, with the regulator slewing. Backward Euler there (BDF2's start, first
    order) left slow_large's fills 12 Pa off the law (3.4 Pa rms); taken as the simulated device
    takes every step (backward Euler over the step and its halves, combined), 1.7 Pa (0.74)."""
    truth = identification_sim.truth("slow_large").parameters
    plan = [(0.05, Valve.CLOSED, 0.0), (0.6, Valve.SUPPLY, 42750.0), (0.6, Valve.VENT, 0.0),
            (0.5, Valve.SUPPLY, 20000.0)]
    error = _fit_model_error(truth, plan, 5e-5)[1]
    assert np.max(np.abs(error)) < 3.0, np.max(np.abs(error))
    assert np.sqrt(np.mean(error**2)) < 1.0


@pytest.mark.parametrize("quick", [False, True])
def test_the_excitation_fits_its_budget_in_short_segments_within_the_limits(quick):
    """At most 60 s of gripper time, every level inside the limits, and every fitted segment
    under 1.2 s: the fit simulates all of them for as long as the longest takes (one 2.8 s PRBS
    made every fit 2.8x slower, up to 72 s of its 60 s budget). The full excitation vents four
    times from the top and four from the bottom, and refills from the bottom four times: the vent
    path's critical ratio shows only in the curvature of those decays (drawn_1: +-15 % with one
    of each, +-13 % with four), the supply's mostly in those refills."""
    steps, held_out = identification.excitation(quick=quick)
    assert sum(step.duration_s for step in steps) <= 60.0
    assert all(-55e3 <= step.target_pa <= 45e3 for step in steps
               if math.isfinite(step.target_pa))
    vents_from = collections.Counter(
        (before.source, before.target_pa) for before, hold, vent in zip(steps, steps[1:],
                                                                        steps[2:])
        if vent.source == "VENT" and hold.source == "HOLD" and before.source != "HOLD")
    refills = sum(1 for before, hold, fill in zip(steps, steps[1:], steps[2:])
                  if (before.source, before.target_pa, hold.source, fill.source, fill.target_pa)
                  == ("VACUUM", 0.95 * -55e3, "HOLD", "SUPPLY", 0.95 * 45e3))
    if not quick:
        assert vents_from[("SUPPLY", 0.95 * 45e3)] >= 4, vents_from
        assert vents_from[("VACUUM", 0.95 * -55e3)] >= 4, vents_from
        assert refills >= 4, refills
    recording = identification_sim.record(plant_file.default_description(), steps, held_out)
    episodes = identification.episodes_of(recording, {name: 0.0 for name in recording.sensors})
    fitted = [e.end_s - e.start_s for e in episodes if e.start_s < held_out]
    assert len(fitted) >= (8 if quick else 20) and max(fitted) < 1.2, fitted


def test_a_segment_fits_only_the_start_of_a_closed_hold_and_the_whole_of_a_vent():
    """A hold with the valves closed repeats one level, which the next segment starts from:
    fitted whole, it weighed that level (and a valve's timing error, live ~1 ms on a 40 ms
    evacuation) hundreds of times over. A vent's decay is the vent path's response: fitted
    whole."""
    truth = plant_file.default_description()
    steps = [identification.Step("VENT", 0.0, 1.0), identification.Step("VACUUM", -30e3, 0.8),
             identification.Step("HOLD", math.nan, 0.5), identification.Step("SUPPLY", 20e3, 0.4),
             identification.Step("VENT", 0.0, 1.0)]
    recording = identification_sim.record(truth, steps, seed=0)
    rests = identification.vented_rests(recording)
    biases = {name: 0.0 for name in recording.sensors}
    episodes = identification.episodes_of(recording, biases, rests)
    changes = recording.inputs
    closes = [c.time_s for before, c in zip(changes, changes[1:])
              if before.valve == Valve.VACUUM and c.valve == Valve.CLOSED]
    assert len(closes) == 1 and len(episodes) == 2
    # the evacuation's segment: from the first vent's tail to 50 ms into the closed hold
    assert episodes[0].end_s == pytest.approx(closes[0] + identification.HOLD_FITTED_S, abs=1e-9)
    # the fill's: from the hold's tail through the whole final vent
    fill = next(c.time_s for c in changes if c.valve == Valve.SUPPLY)
    assert episodes[1].start_s == pytest.approx(fill - identification.REST_TAIL_S, abs=1e-9)
    assert episodes[1].end_s == pytest.approx(recording.end_s, abs=1e-9)


MAY_BE_FLAGGED = identification_sim.MAY_BE_FLAGGED
# the targets; each sensor's noise is checked on its own
TOLERANCES = {name: target for name, target in identification_sim.RECOVERY_TARGETS.items()
              if "." not in name}


def _assert_recovered(result, truth: PneumaticParameters) -> None:
    """Each value within its TOLERANCES, or flagged (MAY_BE_FLAGGED only) with an interval that
    says how little is known: it holds the truth."""
    for name, tolerance in TOLERANCES.items():
        estimate, true = result.estimates[name], getattr(truth, name)
        if estimate.flag:
            assert name in MAY_BE_FLAGGED, (name, estimate.flag)
            assert any(f.startswith(name) for f in result.flags)
            assert estimate.ci95[0] <= true <= estimate.ci95[1], (name, estimate, true)
        else:
            assert estimate.value == pytest.approx(true, rel=tolerance), name


def test_the_spread_over_seeded_fits_counts_targets_and_intervals():
    """recovery_spread (bench_identify_spread's table): per value, the share within its target,
    the median and largest |error|, the share of intervals holding the truth, over the fits
    that have the value; and the errors' spread over the unflagged intervals' sigma."""
    def fit(error, half_width, covered, flagged=False):
        return {"vent_critical_ratio": {"rel_err": error, "rel_half_width": half_width,
                                        "covered": covered, "flagged": flagged,
                                        "reach": abs(error) / half_width}}
    fits = [{"values": fit(0.04, 0.05, True)}, {"values": fit(-0.12, 0.10, False)},
            {"values": fit(0.09, 0.08, False, flagged=True)}, {"values": fit(-0.02, 0.30, True)}]
    fits.append({"values": {}})  # a fit without the value does not count
    spread = identification_sim.recovery_spread(fits, {"vent_critical_ratio": 0.10,
                                                       "supply_conductance": 0.05})
    assert set(spread) == {"vent_critical_ratio"}
    row = spread["vent_critical_ratio"]
    assert row["fits"] == 4 and row["target"] == 0.10
    assert row["within_target"] == pytest.approx(0.75)
    assert row["median_abs_err"] == pytest.approx(0.065)
    assert row["max_abs_err"] == pytest.approx(0.12)
    assert row["covered"] == pytest.approx(0.5)
    assert row["median_half_width"] == pytest.approx(0.09)
    assert row["flagged"] == pytest.approx(0.25)
    # reaches 0.8, 1.2 and 1/15 (the flagged one left out)
    assert row["spread_over_interval"] == pytest.approx(
        1.96 * math.sqrt((0.8**2 + 1.2**2 + (1 / 15)**2) / 3))
    widthless = {"vent_critical_ratio": {"rel_err": 0.0, "rel_half_width": 0.0, "covered": None,
                                         "flagged": False, "reach": None}}
    alone = identification_sim.recovery_spread([{"values": widthless}],
                                               {"vent_critical_ratio": 0.10})
    assert math.isnan(alone["vent_critical_ratio"]["spread_over_interval"])
    # an interval without width is not judged: the share is over the others
    assert math.isnan(alone["vent_critical_ratio"]["covered"])
    mixed = identification_sim.recovery_spread([{"values": widthless}, fits[0]],
                                               {"vent_critical_ratio": 0.10})
    assert mixed["vent_critical_ratio"]["covered"] == 1.0



def test_each_truth_of_a_spread_draws_its_noise_from_seeds_of_its_own():
    """One seed gives every truth the same noise (the same excitation, drawn reading by
    reading): the spread's truths take disjoint blocks of seeds, so that their fits are
    independent draws."""
    seeds = identification_sim.spread_seeds(["slow_large", "drawn_1", "drawn_2"], 10, 20)
    assert seeds == {"slow_large": list(range(20, 30)), "drawn_1": list(range(30, 40)),
                     "drawn_2": list(range(40, 50))}
    one = identification_sim.spread_seeds(["slow_large"], 2, 20)
    assert one == {"slow_large": [20, 21]}
    with pytest.raises(ValueError, match="count must be at least 1"):
        identification_sim.spread_seeds(["slow_large"], 0, 20)

def test_a_benchmark_truth_is_named_or_a_file_or_refused(tmp_path):
    assert identification_sim.truth("drawn_2").parameters == (
        identification_sim.drawn(2).parameters)
    assert identification_sim.truth("slow_large").parameters.supply_conductance == pytest.approx(
        0.6 * plant_file.default_description().parameters.supply_conductance)
    with pytest.raises(ValueError, match="unknown truth 'drawn_x'"):
        identification_sim.truth("drawn_x")
    path = plant_file.save(identification_sim.drawn(4), tmp_path / "mine.yaml")
    assert dataclasses.asdict(identification_sim.truth(str(path)).parameters) == pytest.approx(
        dataclasses.asdict(identification_sim.drawn(4).parameters))


@pytest.fixture(scope="module")
def drawn_1_fitted():
    """drawn_1 recorded (seed 5) and fitted with the exact switch times: (truth, recording,
    fit), shared by the tests that start from it (each fit takes tens of seconds)."""
    truth = identification_sim.drawn(1)
    steps, held_out = identification.excitation()
    recording = identification_sim.record(truth, steps, held_out, seed=5)
    fit = identification.fit(copy.deepcopy(recording),
                             plant_file.default_description().parameters,
                             volume_m3=truth.parameters.chamber_volume_m3)
    return truth, recording, fit


@pytest.mark.slow
@pytest.mark.parametrize("case", ["slow_large", "drawn_1"])
def test_the_fit_recovers_a_perturbed_plant_within_the_targets(case, request):
    """The issue's case (a slower supply path and a larger chamber), and a seeded draw whose
    conductances and compliances are off by factors near 2 (a one-pass fit ended in a local
    minimum there, its critical ratios 65-94 % off); the volume measured, as the tool's
    --volume-m3 takes it. Conductances within 5 %, critical ratios, compliances and the
    regulator's lag within 10 %, noise within 20 %, or flagged where the limits leave a value
    unexcited; the held-out excitation predicted within 1.5x the noise."""
    if case == "slow_large":
        truth = identification_sim.scaled(identification_sim.SLOW_LARGE, (800.0, -400.0))
        steps, held_out = identification.excitation()
        recording = identification_sim.record(truth, steps, held_out, seed=3)
        result = identification.fit(recording, plant_file.default_description().parameters,
                                    volume_m3=truth.parameters.chamber_volume_m3)
    else:
        truth, _, result = request.getfixturevalue("drawn_1_fitted")
    sensors = truth.sensors
    _assert_recovered(result, truth.parameters)
    for name, model in sensors.items():
        assert result.sensor_noise_pa[name] == pytest.approx(model.noise_std_pa, rel=0.2)
        assert result.sensor_bias_pa[name] == pytest.approx(model.bias_pa, abs=60.0)
    assert result.validation_rmse_over_noise <= 1.5
    # and near 1, the law being the truth's: each reading over its own sensor's noise (the pooled
    # RMSE over the noises' RMS gave 1.11 here, as the faster sensor is the noisier)
    assert 0.95 <= result.validation_rmse_over_noise <= 1.05
    assert result.estimates["chamber_volume_m3"].source == "measured"
    # the residuals are white at the right model
    assert all(abs(w) < identification.WHITENESS_LIMIT for w in result.whiteness.values())


@pytest.mark.slow
def test_a_measured_pump_level_is_held_and_the_vacuum_ratio_is_then_identified():
    """Fitted, the pump's level and the vacuum path's critical ratio trade off within the limits
    (both flagged in the test above, the ratio 50 % off here) and drag the values beside them.
    Given as measured (softgrip_identify --vacuum-source-pa), the level is held, exactly, and
    the ratio comes out unflagged within its target; nothing is flagged, and every chamber value's
    interval holds the truth."""
    truth = identification_sim.scaled(identification_sim.SLOW_LARGE, (800.0, -400.0))
    steps, held_out = identification.excitation()
    recording = identification_sim.record(truth, steps, held_out, seed=3)
    level = truth.parameters.vacuum_source_gauge_pa
    result = identification.fit(recording, plant_file.default_description().parameters,
                                volume_m3=truth.parameters.chamber_volume_m3,
                                vacuum_source_pa=level)
    source = result.estimates["vacuum_source_gauge_pa"]
    assert (source.value, source.ci95, source.source, source.flag) == (
        level, (level, level), "measured", "")
    assert result.parameters.vacuum_source_gauge_pa == level
    ratio = result.estimates["vacuum_critical_ratio"]
    assert not ratio.flag
    assert ratio.value == pytest.approx(truth.parameters.vacuum_critical_ratio, rel=0.10)
    # the cost rises more slowly above the ratio than below it (the curved trade-off with the
    # vacuum conductance and the compliances): its interval follows the cost's profile, lopsided
    # (here -9.9 / +11.8 % of the value; -10.4 / +15.4 %, and 1.2 asked, while the model strayed
    # 12 Pa from the law where the chamber crosses atmosphere, which skewed the profile)
    below, above = ratio.value - ratio.ci95[0], ratio.ci95[1] - ratio.value
    assert above > 1.15 * below
    for name in identification.STAGE3[:8]:
        low, high = result.estimates[name].ci95
        assert low <= getattr(truth.parameters, name) <= high, name
    assert result.flags == []
    _assert_recovered(result, truth.parameters)
    assert 0.95 <= result.validation_rmse_over_noise <= 1.05


@pytest.mark.slow
def test_valve_switches_dated_tenths_of_a_millisecond_off_are_re_timed_by_the_fit(
        drawn_1_fitted):
    """Live, a valve switch is dated to a few tenths of a ms (a solenoid valve's to a ms or
    more), and a small chamber's fill moves 600 Pa in one. Here every recorded switch is moved by
    N(0, 0.3 ms) after the run, as if dated that badly. Fitted with the recorded times alone,
    drawn_1's vent critical ratio came out +27 % (outside its +-10 % interval). The fit now
    dates each switch from the readings about it, and recovers the values within the targets.
    A vent's opening starts a transient, and is dated to within 0.12 ms rms of where it was; a
    supply valve closing on a chamber already at the regulator's level tells nothing, and is
    left where it was recorded. The conductances come within 0.5 % of the truth, and every
    chamber value within a quarter of its interval of what the exact times give: the vent ratio
    -2.9 % against -1.8 %, inside +-13 % (without the re-dating +15.7 %, the vacuum conductance
    +1.4 % against +0.1 %). How far either fit is from the truth is the noise's draw; a bound of
    2.5 % from the truth on the vent ratio held on the draw of the 0.2 ms truth (-0.4 %) and not
    on this one."""
    truth, recording, exact = drawn_1_fitted
    recording = copy.deepcopy(recording)
    rng = np.random.default_rng(11)
    errors = 3e-4 * rng.standard_normal(len(recording.inputs))
    recording.inputs = [dataclasses.replace(c, time_s=c.time_s + error)
                        for c, error in zip(recording.inputs, errors)]
    result = identification.fit(recording, plant_file.default_description().parameters,
                                volume_m3=truth.parameters.chamber_volume_m3)
    shifts, changes = result.switch_shifts_s, recording.inputs
    assert len(shifts) >= 30
    # a vent opening recorded late is moved earlier by about as much
    vents = [i for i in shifts if (changes[i - 1].valve, changes[i].valve) == (Valve.CLOSED,
                                                                               Valve.VENT)]
    misses = np.array([shifts[i] + errors[i] for i in vents])
    assert len(vents) >= 10 and np.sqrt(np.mean(misses**2)) < 1.2e-4, misses
    untold = [shifts[i] for i in shifts if (changes[i - 1].valve, changes[i].valve) == (
        Valve.SUPPLY, Valve.CLOSED) and changes[i].time_s - changes[i - 1].time_s > 0.5]
    assert len(untold) >= 4 and max(map(abs, untold)) < 1e-5, untold
    _assert_recovered(result, truth.parameters)
    fitted, true = result.parameters, truth.parameters
    for name in identification.STAGE3:
        estimate, reference = result.estimates[name], exact.estimates[name]
        if not (estimate.flag or reference.flag):
            half_width = 0.5 * (reference.ci95[1] - reference.ci95[0])
            assert abs(estimate.value - reference.value) < 0.25 * half_width, name
    for name in ("supply_conductance", "vent_conductance"):
        assert getattr(fitted, name) == pytest.approx(getattr(true, name), rel=0.005), name
    assert result.validation_rmse_over_noise <= 1.1


def test_a_switch_is_never_re_dated_past_a_change_beside_it():
    """Live, a step that moves the regulator and switches the valves reports the regulator's
    command 0.1 ms before the switch (its frame went out first), each change carrying the whole
    output. A switch the fit dated 0.3 ms earlier came before that command, and the recording
    then switched the valves back: the live fit ran off to residuals of 3.5 kPa. The switch
    stops just after the change before it, and the order and what each change says stay."""
    Change = identification.InputChange
    inputs = [Change(0.0, Valve.CLOSED, 0.0, True), Change(1.0, Valve.CLOSED, 40e3, True),
              Change(1.0001, Valve.SUPPLY, 40e3, True), Change(1.6, Valve.CLOSED, 40e3, True)]
    recording = identification.Recording({"s": ([0.0], [0.0])}, ([0.0], [0.0]), inputs)
    moved = recording.moved({2: -3e-4, 3: 2e-4})
    assert [(c.valve, c.regulator_setpoint_pa) for c in moved.inputs] == [
        (c.valve, c.regulator_setpoint_pa) for c in inputs]
    assert moved.inputs[2].time_s == pytest.approx(1.0 + identification.MOVE_GAP_S, abs=1e-12)
    assert moved.inputs[3].time_s == pytest.approx(1.6002, abs=1e-12)  # free to move
    assert moved.inputs[1].time_s == 1.0


def test_the_joint_passes_stop_once_one_no_longer_lowers_the_cost(monkeypatch):
    """A pass that re-dates the switches but lowers the cost by less than REDATE_GAIN is the last:
    live (slow_large) such passes walked along a valley the data do not resolve, the vent ratio
    from +8 % to +17 %. Here the timings never count as settled, and the third pass gains 0.5."""
    truth = identification_sim.drawn(1)
    steps, held_out = identification.excitation(quick=True)
    recording = identification_sim.record(truth, steps, held_out, seed=5)
    real_pass, costs, passes = identification._joint_pass, [5000.0, 4990.0, 4989.5, 4000.0], []

    def joint_pass(*args):
        result, moved = real_pass(*args)
        result.cost = costs[len(passes)]
        passes.append(result.cost)
        return result, moved

    monkeypatch.setattr(identification, "_joint_pass", joint_pass)
    monkeypatch.setattr(identification, "REDATE_SETTLED_MS", 0.0)
    result = identification.fit(recording, plant_file.default_description().parameters,
                                volume_m3=truth.parameters.chamber_volume_m3)
    assert passes == costs[:3]
    assert identification.REDATE_PASSES >= 4
    # no budget by default: the passes end on the cost alone, and nothing says otherwise
    assert not any("re-dating" in flag for flag in result.flags)


def test_the_re_dating_stops_early_and_says_so_when_the_fit_would_overrun_its_budget(
        monkeypatch):
    """softgrip_identify's fit has FIT_BUDGET_S; live drawn_1 once took 82 s, its four re-dating
    passes all used. The re-dating starts no pass it expects to end past REDATE_SHARE of the
    budget (each pass taken to last as long as the one before), and flags the result when its
    timings had not settled. Here the clock moves only while a pass runs, 10 s a pass, and the
    passes never settle: a 40 s budget leaves room for two (20 s, then 30 s > 24 s). (Without a
    budget nothing stops them: the test above.)"""
    truth = identification_sim.drawn(1)
    steps, held_out = identification.excitation(quick=True)
    recording = identification_sim.record(truth, steps, held_out, seed=5)
    real_pass, clock, passes = identification._joint_pass, [0.0], []

    def joint_pass(*args):
        clock[0] += 10.0
        passes.append(clock[0])
        return real_pass(*args)

    monkeypatch.setattr(identification, "_joint_pass", joint_pass)
    monkeypatch.setattr(identification.time, "perf_counter", lambda: clock[0])
    monkeypatch.setattr(identification, "REDATE_SETTLED_MS", 0.0)
    monkeypatch.setattr(identification, "REDATE_GAIN", -math.inf)
    result = identification.fit(recording, plant_file.default_description().parameters,
                                volume_m3=truth.parameters.chamber_volume_m3, budget_s=40.0)
    assert passes == [10.0, 20.0] and identification.REDATE_PASSES > 2
    stopped = [flag for flag in result.flags if "re-dating" in flag]
    assert len(stopped) == 1 and "after 2 of 4 passes" in stopped[0], result.flags
    assert "40 s budget" in stopped[0]


def test_readings_older_than_their_stamps_are_dated_by_the_fit(drawn_1_fitted):
    """A reading is the chamber some time before its stamp: a sensor's filter, or (live) the
    simulated device's readings up to 0.2 ms. drawn_1 with every reading 0.2 ms stale, fitted
    with the stamps as they are: supply critical ratio -11.6 %. The fit dates each sensor's
    latency with the valve switches, finds 0.1-0.3 ms, and recovers the values within the
    targets (the supply ratio within 5 %)."""
    truth, recording, _ = drawn_1_fitted
    recording = copy.deepcopy(recording)
    recording.sensors = {name: (times + 2e-4, values)
                         for name, (times, values) in recording.sensors.items()}
    result = identification.fit(recording, plant_file.default_description().parameters,
                                volume_m3=truth.parameters.chamber_volume_m3)
    assert set(result.sensor_delay_s) == set(recording.sensors)
    for name, delay in result.sensor_delay_s.items():
        assert 1e-4 <= delay <= 3e-4, (name, delay)
    _assert_recovered(result, truth.parameters)
    assert result.parameters.supply_critical_ratio == pytest.approx(
        truth.parameters.supply_critical_ratio, rel=0.05)


def test_a_recording_without_rests_or_readings_is_refused_with_the_reason():
    truth = plant_file.default_description()
    steps = [identification.Step("SUPPLY", 20e3, 0.5), identification.Step("HOLD", math.nan, 0.2)]
    recording = identification_sim.record(truth, steps, seed=0)
    with pytest.raises(ValueError, match="vented rest"):
        identification.fit(recording, truth.parameters)
    recording.sensors["chamber_b"] = (np.array([]), np.array([]))
    with pytest.raises(ValueError, match="too few readings"):
        identification.fit(recording, truth.parameters)


def test_intervals_keep_their_coverage_when_the_residuals_are_correlated():
    """Live, the model misses part of the response and the residuals stay correlated over tens of
    readings; the Gauss-Newton intervals then came out far too narrow (a critical ratio 211 % off
    inside +-2 %). On a straight line with AR(1) errors (rho 0.9, two series of 400), the
    sandwich covariance's 95 % intervals cover the slope in 168 of 200 seeds (84 %: the Bartlett
    kernel is known to under-cover somewhat at such correlation), Gauss-Newton's in 61 (30 %)."""
    times = np.linspace(0.0, 1.0, 400)
    jacobian = np.column_stack([np.ones(800), np.tile(times, 2)])
    series = [np.arange(400), np.arange(400, 800)]
    covered = {"gauss_newton": 0, "robust": 0}
    for seed in range(200):
        rng = np.random.default_rng(seed)
        errors = np.empty(800)
        for rows in series:
            noise = rng.standard_normal(400)
            for k in range(1, 400):
                noise[k] += 0.9 * noise[k - 1]
            errors[rows] = noise
        data = 1.0 + 2.0 * np.tile(times, 2) + errors
        solution, *_ = np.linalg.lstsq(jacobian, data, rcond=None)
        residuals = jacobian @ solution - data
        for name, covariance in (
                ("gauss_newton", identification._covariance(jacobian, residuals)),
                ("robust", identification._robust_covariance(jacobian, residuals, series))):
            half = 1.96 * math.sqrt(covariance[1, 1])
            covered[name] += abs(solution[1] - 2.0) <= half
    assert covered["robust"] >= 150 and covered["gauss_newton"] <= 90, covered


def _parabolic_valley(points):
    """Weighted residuals of two values (u, v) whose cost's valley is the parabola
    v = ((u + 1/2)^2 - 1/4) / 2, the optimum at (0, 0): v traded off with u along a curve."""
    u, v = points[:, 0], points[:, 1]
    return np.stack([u, v - 0.5 * ((u + 0.5)**2 - 0.25)], axis=1)


def _exact_profile_halves(index: int) -> list:
    """Below and above the optimum: where the cost, minimised over the other value, rises by
    1.92 (the 95 % chi-square of one value, halved)."""
    from scipy.optimize import brentq, minimize_scalar

    def profile(t):
        def cost(other):
            point = [other, t] if index == 1 else [t, other]
            residual = _parabolic_valley(np.array([point]))[0]
            return 0.5 * float(residual @ residual)
        return minimize_scalar(cost, bracket=(-1.0, 1.0)).fun
    return [brentq(lambda t: profile(sign * t) - 1.92, 1e-3, 50.0) for sign in (-1.0, 1.0)]


def test_intervals_follow_the_cost_along_a_curved_trade_off():
    """Seeded, slow_large's vacuum path traded off along a curved valley, and its values spread
    1.3-3.7 times as far as their linearised intervals said. On the parabolic valley, v's
    profile rises to 1.92 at 2.04 below and 3.30 above, where the linearised interval says 2.19
    either side (33 % short above); the profiled half width is within 0.5 % above (two trials
    per side, as before the third, came within 1.1 %: 3.26), and below,
    where the profile is steeper than the linearised cost, the linearised one (_side_end keeps
    that width there, for caution). u's profile is quadratic, so its profiled interval is the
    linearised one (1.96) to 1 %, and scaled with it: given intervals twice as wide (the
    sandwich's, say), 3.92."""
    jacobian = np.array([[1.0, 0.0], [-0.5, 1.0]])  # at the optimum
    information = jacobian.T @ jacobian
    linear = 1.96 * np.sqrt(np.diag(np.linalg.inv(information)))
    wide = (np.full(2, -100.0), np.full(2, 100.0))
    steps = np.full(2, 1e-6)
    profiled = identification._profiled_halves(_parabolic_valley, np.zeros(2), wide, linear,
                                               information, steps)
    below, above = _exact_profile_halves(1)
    assert (below, above) == pytest.approx((2.04, 3.30), abs=0.01)
    assert linear[1] == pytest.approx(2.19, abs=0.01)
    assert profiled[1, 1] == pytest.approx(above, rel=0.005)
    assert profiled[1, 0] == pytest.approx(linear[1], rel=1e-9) and below < linear[1]
    assert _exact_profile_halves(0) == pytest.approx([1.96, 1.96], abs=0.01)
    assert profiled[0] == pytest.approx([1.96, 1.96], rel=0.01)
    doubled = identification._profiled_halves(_parabolic_valley, np.zeros(2), wide, 2.0 * linear,
                                              information, steps)
    assert doubled[0] == pytest.approx([3.92, 3.92], rel=0.01)
    # never past the fit's range: v's range ending at 2.5 ends its interval there
    near = (np.full(2, -100.0), np.array([100.0, 2.5]))
    capped = identification._profiled_halves(_parabolic_valley, np.zeros(2), near, linear,
                                             information, steps)
    assert capped[1, 1] <= 2.5 and capped[1, 1] == pytest.approx(2.5, rel=0.01)


def _two_wells(points):
    """Weighted residuals of (u, v) whose cost is zero at v = 0 and again at v = -1.96, the
    linearised half width: between them the profile is flat, beyond it rises. So a trial at the
    linearised end finds no rise at all, as one of slow_large's compliances did (seed 25, its
    cost there 0.01 under the optimum's)."""
    u, v = points[:, 0], points[:, 1]
    return np.stack([u, v * (v + 1.96) / 1.96], axis=1)


def test_a_profile_flat_at_its_first_trial_is_followed_outwards_not_to_the_range_end():
    """v's profile reaches 1.92 (q = 1.96) at 3.17 below the optimum. The first trial, at the
    linearised 1.96, lies at the second zero, q = 0. The second trial went to the range's end
    (99.9 away, q about 5000), and the side, interpolated across that, ended at 2.00: 37 % short.
    Doubled instead, it ends within 8 % (2.94), and never past where the profile rises. Above,
    where the profile rises faster than the linearised cost, the side keeps its linearised
    width."""
    information = np.eye(2)
    linear = np.full(2, 1.96)
    wide = (np.full(2, -100.0), np.full(2, 100.0))
    profiled = identification._profiled_halves(_two_wells, np.zeros(2), wide, linear,
                                               information, np.full(2, 1e-6))
    exact_below = (1.96 + math.sqrt(1.96**2 + 4 * 1.96**2)) / 2  # v (v + 1.96) = 1.96^2
    assert exact_below == pytest.approx(3.17, abs=0.01)
    assert profiled[1, 0] == pytest.approx(exact_below, rel=0.08)
    assert profiled[1, 0] <= exact_below
    assert profiled[1, 1] == pytest.approx(1.96, rel=1e-9)
    assert profiled[0] == pytest.approx([1.96, 1.96], rel=0.01)


@pytest.mark.parametrize("trials, end", [
    ([(1.0, 0.25), (2.0, 0.5)], 4.0),  # both inside: past the farther, along their secant
    ([(1.0, 0.5), (4.0, 2.0)], 2.0),  # one each side: between them
    # both beyond, the cost rising more slowly than the linearised: between the optimum and
    # the nearer, past the linearised end
    ([(2.0, 1.5), (1.5, 1.2)], 1.25),
    # both beyond, rising faster than the linearised: kept at the linearised end (caution)
    ([(1.0, 3.0), (0.5, 2.0)], 1.0),
    # the nearer trial over the target and over the farther one: the secant
    # through both ended at 1.4, past the farther, already over the target
    ([(1.0, 1.2), (0.8, 1.3)], 1.0),
    # a trial inside lies inside, whatever a nearer one stopped at: not short of it
    ([(1.5, 2.0), (2.0, 0.8)], 2.0),
])
def test_a_profiled_side_ends_where_its_trials_say(trials, end):
    """The linearised half width (the target) 1; each trial's q as far as it is from the optimum
    on a quadratic cost."""
    assert identification._side_end(trials, 1.0, 10.0) == pytest.approx(end, rel=1e-9)
    assert identification._side_end(trials, 1.0, 0.9) == 0.9  # never past the fit's range


def test_a_profiled_side_never_ends_short_of_a_trial_inside_or_the_linearised_end():
    rng = np.random.default_rng(7)
    for _ in range(500):
        trials = [(float(d), float(q)) for d, q in rng.uniform(0.01, 3.0, size=(2, 2))]
        room = float(rng.uniform(0.5, 5.0))
        end = identification._side_end(trials, 1.0, room)
        inside = [d for d, q in trials if q < 1.0]
        assert end <= room, (trials, room)
        assert end >= min(max(inside + [1.0]), room), (trials, room)


@pytest.mark.parametrize("into_step", [0.1, 0.5, 0.9])
def test_a_valve_that_opens_and_closes_inside_a_step_acts_for_that_part_of_it(into_step):
    """The device takes a frame at its arrival, splitting its plant step there; the fit's 1 ms
    grid gave the whole step to whichever valve held its middle. Live (bench_identify, drawn_2)
    one 80 ms evacuation followed by a 1 s hold then cost the truth's own parameters 1660 (of
    the fit's 5300): the pulse's edges off by up to half a step, its error held over every
    reading of the hold. The grid now opens a valve for its part of the step."""
    parameters = PneumaticParameters()
    plant = PneumaticPlant(parameters)
    opens, closes = 0.010 + into_step * 1e-3, 0.090 + into_step * 1e-3
    inputs = [identification.InputChange(0.0, int(Valve.CLOSED), 0.0, True),
              identification.InputChange(opens, int(Valve.VACUUM), 0.0, True),
              identification.InputChange(closes, int(Valve.CLOSED), 0.0, True)]
    times = np.arange(0.0, 0.2, 2e-3)
    recording = identification.Recording({"s": (times, np.zeros_like(times))},
                                         (times, np.zeros_like(times)), inputs)
    episode = identification.Episode(0.0, 0.2, 0.0)
    grid = identification._Grid(recording, [episode], lambda t: np.zeros_like(t), {"s": 0.0},
                                {"s": 1.0})
    fitted = grid.simulate([parameters])[0][times > 0.1]
    # the plant, its steps split at each change as the device splits them
    state, now = plant.initial_state(), 0.0
    for until, valve in ((opens, Valve.CLOSED), (closes, Valve.VACUUM)):
        while now < until - 1e-12:
            dt = min(1e-3, until - now)
            state = plant.step(state, PlantInputs(0.0, True, (valve,)), dt)
            now += dt
    held = float(state.chamber_pa[0] - P_ATM_PA)
    assert held < -20e3
    # backward Euler on another grid: within 0.3 % of the fall; the old grid, off by 0.4 ms at
    # each edge (into_step 0.1 and 0.9), failed this
    assert np.all(np.abs(fitted - held) < 0.003 * abs(held)), (fitted[:3], held)


def test_an_evacuation_choked_nearly_all_along_cannot_tell_the_ratio_from_the_pump():
    """Choked flow is C rho p_upstream whatever the critical ratio and the pump's level, so only
    an evacuation's subsonic part tells them apart. Live drawn_2 fitted 0.92 and -55 kPa (truth
    0.3 and -80 kPa, subsonic over 39 % of the evacuations' readings): subsonic over 5 % of
    them, inside +-15 % and +-7 % intervals. Below SUBSONIC_LIMIT the fit flags the pair."""
    truth = plant_file.default_description()
    steps = [identification.Step("VENT", 0.0, 1.0), identification.Step("VACUUM", -52e3, 0.9),
             identification.Step("HOLD", math.nan, 0.3), identification.Step("VENT", 0.0, 1.0)]
    recording = identification_sim.record(truth, steps, seed=0)
    biases = {name: truth.sensor(name).bias_pa for name in recording.sensors}
    grid = identification._Grid(recording, identification.episodes_of(recording, biases),
                                lambda t: np.zeros(len(t)), biases,
                                {name: 1.0 for name in recording.sensors})
    share = identification.vacuum_subsonic_share
    assert share(recording, grid, truth.parameters) > 0.3
    valley = dataclasses.replace(truth.parameters, vacuum_critical_ratio=0.92,
                                 vacuum_source_gauge_pa=-55.2e3)
    assert share(recording, grid, valley) < 0.1 < identification.SUBSONIC_LIMIT


def test_a_value_left_at_the_edge_of_the_range_and_its_partner_are_flagged():
    """Live drawn_2: the vacuum path's critical ratio ended at the range's 0.95 (truth 0.3) with
    the source at -54.5 kPa (truth -80), both inside +-1 % intervals and flagged by nothing."""
    inside = identification._stage3_vector(plant_file.default_description().parameters)
    names = identification.STAGE3
    ratio, source = names.index("vacuum_critical_ratio"), names.index("vacuum_source_gauge_pa")
    covariance = np.eye(len(inside))
    covariance[ratio, source] = covariance[source, ratio] = 0.96
    assert identification._pinned(inside, covariance) == {}
    pinned = inside.copy()
    pinned[ratio] = identification.STAGE3_BOUNDS[1][ratio]
    reasons = identification._pinned(pinned, covariance)
    assert set(reasons) == {ratio, source}
    assert "edge of the fit's range" in reasons[ratio]
    assert "trades off with vacuum_critical_ratio" in reasons[source]
    # a value the data hardly determine (flagged +-37 %, offline drawn_1) takes its partner
    # along (the source was -25 % off inside +-14 %), and keeps its own reason ('')
    assert identification._pinned(inside, covariance, weak=[ratio]) == {
        ratio: "", source: "trades off with vacuum_critical_ratio, which the data do not "
        "determine: the data do not determine it (its interval is the range)"}
    # weakly coupled: only the value at the edge
    covariance[ratio, source] = covariance[source, ratio] = 0.5
    assert set(identification._pinned(pinned, covariance)) == {ratio}
    assert set(identification._pinned(inside, covariance, weak=[ratio])) == {ratio}
    # a value the fit does not depend on (its variance 0; live drawn_2, choked all the way) has
    # no partner: its zero variance once made every value "trade off" with it
    covariance[ratio, :] = covariance[:, ratio] = 0.0
    assert identification._pinned(inside, covariance, weak=[ratio]) == {ratio: ""}

"""The pressure control core: step responses on the plant, limits and every safety rule."""
import math

import numpy as np
import pytest

from softgrip_ros.control.faults import Fault
from softgrip_ros.control.pressure import (PressureMode, PressureControlConfig, PressureController,
                                           RegulationPhase, Source)
from softgrip_ros.model.pneumatics import PneumaticPlant, Valve
from softgrip_ros.devtools.closed_loop import rise_time_s, step_figures, step_response
from softgrip_ros.devtools.identification_sim import SLOW_LARGE, drawn, scaled
from tests.helpers.closed_loop import FaultyLoop

pytestmark = pytest.mark.cpu  # computation only: scripts/test.sh runs it beside another


@pytest.mark.parametrize("seed", range(3))
def test_step_to_25_kpa_is_near_time_optimal(seed):
    """Tolerances: rise <= 1.3x the valve-fully-open rise, overshoot <= 3 %, steady state within
    0.2 kPa."""
    times, pressures, _ = step_response(25e3, seed=seed)
    optimal_times, optimal_pressures, _ = step_response(25e3, time_optimal=True)
    ratio = rise_time_s(times, pressures, 25e3) / rise_time_s(optimal_times, optimal_pressures,
                                                              25e3)
    assert ratio <= 1.3
    assert pressures.max() <= 25e3 * 1.03
    assert abs(pressures[-200:].mean() - 25e3) <= 200.0


@pytest.mark.parametrize("truth", ["slow_large", 1, 2, 3, 4])
def test_step_to_25_kpa_is_near_time_optimal_on_other_plants_given_their_model(truth):
    """#23: the same targets on perturbed plants, the controller's model the plant itself (what an
    identification gives). slow_large rose 1.44x: the boost's fixed ceiling (the one for a step to
    the limit) and a settle that held the chamber 12 % short of the target for up to 0.2 s while
    the regulator came down from the boost."""
    description = scaled(SLOW_LARGE) if truth == "slow_large" else drawn(truth)
    plant = PneumaticPlant(description.parameters)
    for seed in range(2):
        figures = step_figures(25e3, plant, plant, seed=seed)
        assert figures["rise_time_ratio"] <= 1.3, figures
        assert figures["overshoot_pct"] <= 3.0, figures
        assert figures["steady_state_error_kpa"] <= 0.2, figures


@pytest.mark.parametrize("target", [-20e3, -50e3])
def test_vacuum_steps(target):
    """Tolerances: overshoot <= 3 % of the step, steady state within 0.2 kPa, 90 % within 0.2 s."""
    times, pressures, outputs = step_response(target)
    assert pressures.min() >= target * 1.03
    assert abs(pressures[-200:].mean() - target) <= 200.0
    assert rise_time_s(times, pressures, target) < 0.2
    assert all(out.regulator_source == Source.VACUUM for out in outputs[50:])


@pytest.mark.parametrize("target, delay_ms, burst_ms", [(25e3, 20, 0), (25e3, 0, 30),
                                                         (45e3, 30, 0), (-20e3, 30, 0)])
def test_readings_that_reach_a_loaded_controller_late_do_not_overshoot_the_step(
        target, delay_ms, burst_ms):
    """Readings stamped when sampled and taken ``delay_ms`` later, or in bursts every ``burst_ms``
    (a starved reception thread): the crossing is predicted from the feedback carried to the
    step's time at its rate over its stamps. Judged on the steps' times, the boost overshot 25 kPa
    by 8.7 kPa at 20 ms and 8.4 kPa in 30 ms bursts, and 45 kPa into OVERPRESSURE at 30 ms; the
    evacuation to -20 kPa by 6.7 kPa at 30 ms. Tolerance: 10 % of the step, no fault, settled."""
    loop = FaultyLoop()
    loop.reading_delay_ms, loop.reading_burst_ms = delay_ms, burst_ms
    loop.command(target)
    loop.run_for(1.0)
    low, high = loop.true_extremes()
    assert (high - target if target > 0 else target - low) <= 0.1 * abs(target)
    assert loop.first_fault() is None, loop.first_fault()[1].message
    assert abs(loop.true[-1][1] - target) <= 1e3


def test_small_steps_overshoot_less_than_a_kilopascal():
    for target in (3e3, 10e3, 40e3):
        _, pressures, _ = step_response(target)
        assert pressures.max() - target <= 1e3, target
        assert abs(pressures[-200:].mean() - target) <= 200.0, target


def test_vent_returns_to_atmosphere():
    controller = PressureController()
    controller.active = True
    controller.update_sensor("s", 30e3, 0.0)
    controller.command(0.0, Source.VENT, math.nan, 0.0)
    out = controller.step(0.001)
    assert out.mode == PressureMode.VENT and out.valves == (Valve.VENT,)


def active(config=None, pressure=0.0, now=0.0):
    controller = PressureController(config or PressureControlConfig())
    controller.active = True
    controller.update_sensor("s", pressure, now)
    return controller


def test_inactive_controller_outputs_nothing():
    controller = PressureController()
    out = controller.step(0.0)
    assert out.mode == PressureMode.INACTIVE and out.valves == (
        Valve.CLOSED,) and not out.regulator_enabled


def test_a_refused_command_is_reported_by_a_step_even_when_the_next_command_came_first():
    """A refusal is flagged until a command applies; one that applies before any step ran (the
    grasp manager's refresh between the refusal and the loop's step) no longer hides it: the
    next step reports it, with its reason, and the one after does not."""
    controller = active()
    controller.command(0.0, Source.VENT, math.nan, 0.0)
    controller.reject_command("pressure command stamped 30 s in the future")
    out = controller.step(0.01)
    assert Fault.COMMAND_REJECTED in out.fault_flags and "in the future" in out.message
    assert Fault.COMMAND_REJECTED in controller.step(0.012).fault_flags  # until one applies
    controller.command(0.0, Source.VENT, math.nan, 0.014)
    assert Fault.COMMAND_REJECTED not in controller.step(0.016).fault_flags
    controller.reject_command("pressure command stamped 30 s in the future")
    controller.command(0.0, Source.VENT, math.nan, 0.018)  # before any step
    out = controller.step(0.02)
    assert Fault.COMMAND_REJECTED in out.fault_flags and "in the future" in out.message
    assert Fault.COMMAND_REJECTED not in controller.step(0.022).fault_flags
    controller.active = False  # an inactive controller reports it too
    controller.reject_command("pressure command stamped 30 s in the future")
    controller.command(0.0, Source.VENT, math.nan, 0.024)
    assert Fault.COMMAND_REJECTED in controller.step(0.026).fault_flags
    assert Fault.COMMAND_REJECTED not in controller.step(0.028).fault_flags


def test_setpoint_above_the_limit_is_clamped_and_reported():
    controller = active()
    note = controller.command(80e3, Source.SUPPLY, math.nan, 0.0)
    assert "clamped to 50000 Pa" in note
    out = controller.step(0.01)
    assert Fault.SETPOINT_CLAMPED in out.fault_flags
    for i in range(200):
        out = controller.step(0.01 + i * 0.002)
        controller.update_sensor("s", 0.0, 0.01 + i * 0.002)
    assert out.setpoint_gauge_pa == 50e3
    controller.command(20e3, Source.SUPPLY, math.nan, 1.0)
    assert Fault.SETPOINT_CLAMPED not in controller.step(1.001).fault_flags
    controller.command(-90e3, Source.VACUUM, math.nan, 2.0)
    assert controller._target == -60e3


def test_overpressure_vents_and_latches_until_a_new_command_once_the_evidence_is_gone():
    """The safe state holds until a command comes after the evidence has been gone for
    safety.clear_time_s (0.5 s); the readings here fall as the vent makes them."""
    controller = active(pressure=56e3)
    controller.command(40e3, Source.SUPPLY, math.nan, 0.0)
    out = controller.step(0.001)
    assert out.mode == PressureMode.FAULT and out.valves == (
        Valve.VENT,) and not out.regulator_enabled
    assert Fault.OVERPRESSURE in out.fault_flags
    rng, now = np.random.default_rng(0), 0.001

    def vent_for(seconds):  # readings as a vent makes them
        nonlocal now
        for _ in range(int(seconds / 0.002)):
            now += 0.002
            controller.update_sensor("s",
                                     56e3 * math.exp(-now / 0.08) + 300.0 * rng.standard_normal(),
                                     now)
            # pressure back, but no new command
            assert controller.step(now).mode == PressureMode.FAULT

    vent_for(0.1)
    assert "still in the safe state" in controller.command(20e3, Source.SUPPLY, math.nan, now)
    # too soon after the evidence
    assert controller.step(now + 0.001).mode == PressureMode.FAULT
    vent_for(controller.config.safety.clear_time_s)
    assert controller.command(20e3, Source.SUPPLY, math.nan, now) == ""
    out = controller.step(now + 0.001)
    assert out.mode == PressureMode.REGULATE and Fault.OVERPRESSURE not in out.fault_flags


def test_regulator_overshoot_fault_never_exceeds_limit_plus_margin():
    config = PressureControlConfig()
    _, pressures, outputs = step_response(45e3, duration_s=1.5, overshoot_fault_pa=30e3)
    assert any(out.mode == PressureMode.FAULT for out in outputs)
    # + one control period
    assert pressures.max() <= config.max_gauge_pa + config.overpressure_margin_pa + 1e3
    assert outputs[-1].valves == (Valve.VENT,)


def test_sensor_timeout_holds_then_recovers():
    times, pressures, outputs = step_response(20e3, duration_s=0.6, sensor_until_s=0.3)
    after = [o for t, o in zip(np.arange(len(outputs)) * 0.002, outputs) if t > 0.36]
    assert after and all(o.mode == PressureMode.HOLD and o.valves == (Valve.CLOSED,)
                         for o in after)
    assert all(Fault.SENSOR_TIMEOUT in o.fault_flags for o in after)
    held = pressures[int(0.36 / 1e-3):]
    # valves closed: the air stays in
    assert np.ptp(held) < 1.0
    controller = active()
    controller.command(10e3, Source.SUPPLY, math.nan, 0.0)
    assert controller.step(1.0).mode == PressureMode.HOLD
    controller.update_sensor("s", 9e3, 1.001)
    out = controller.step(1.002)
    assert out.mode == PressureMode.REGULATE and Fault.SENSOR_TIMEOUT not in out.fault_flags


@pytest.mark.parametrize("action, mode, valve", [("hold", PressureMode.HOLD, Valve.CLOSED),
                                                 ("vent", PressureMode.VENT, Valve.VENT)])
def test_command_timeout_takes_the_safe_action(action, mode, valve):
    controller = active(
        PressureControlConfig(command_timeout_s=0.5, command_timeout_action=action), pressure=9e3)
    controller.command(10e3, Source.SUPPLY, math.nan, 0.0)
    rng = np.random.default_rng(1)
    for i in range(260):  # 20 ms past the timeout (a chamber that does not vent is
        now = i * 0.002  # the response check's fault some 0.1 s later)
        controller.update_sensor("s", 9e3 + 300.0 * rng.standard_normal(), now)
        out = controller.step(now)
    assert out.mode == mode and out.valves == (valve,) and Fault.COMMAND_TIMEOUT in out.fault_flags
    controller.command(10e3, Source.SUPPLY, math.nan, 0.8)
    controller.update_sensor("s", 9e3, 0.8)
    assert controller.step(0.801).mode == PressureMode.REGULATE


def test_hold_keeps_valves_closed_without_timing_out():
    controller = active()
    controller.command(0.0, Source.HOLD, math.nan, 0.0)
    for i in range(3000):
        controller.update_sensor("s", 5e3, i * 0.002)
        out = controller.step(i * 0.002)
    assert out.mode == PressureMode.HOLD and Fault.COMMAND_TIMEOUT not in out.fault_flags


def test_bad_commands_and_config_are_rejected():
    with pytest.raises(ValueError, match="finite"):
        active().command(math.nan, Source.SUPPLY, math.nan, 0.0)
    with pytest.raises(ValueError):
        active().command(1.0, 9, math.nan, 0.0)
    with pytest.raises(ValueError, match="command_timeout_action"):
        PressureControlConfig(command_timeout_action="explode")
    with pytest.raises(ValueError, match="max_gauge_pa"):
        PressureControlConfig(max_gauge_pa=-1.0)
    with pytest.raises(ValueError, match="finite"):
        PressureControlConfig(kp=math.nan)


def test_nan_sensor_readings_are_ignored():
    controller = active(pressure=1e3)
    controller.update_sensor("s", math.nan, 0.001)
    assert controller.measured(0.002) == 1e3


def test_severity_of_outputs():
    from softgrip_ros.control.reports import severity
    from softgrip_ros.health import Health

    controller = active(pressure=1e3)
    controller.command(5e3, Source.SUPPLY, math.nan, 0.0)
    assert severity(controller.step(0.001)) == Health.OK
    controller.command(90e3, Source.SUPPLY, math.nan, 0.002)
    assert severity(controller.step(0.003)) == Health.WARN  # clamped setpoint
    assert severity(controller.step(1.0)) == Health.ERROR  # no sensor: blind
    controller.update_sensor("s", 70e3, 1.001)
    assert severity(controller.step(1.002)) == Health.ERROR  # overpressure


def test_a_clamp_during_the_settle_after_a_boost_evacuates_at_once():
    """After a boosted fill the valve stays closed while the regulator comes down from its maximum
    (the settle). A negative target arriving then must not wait for that: the vacuum pump's valve
    needs no settled regulator. (The installed controller's CLAMP waited ~100 ms here in 3 of 30
    benchmark cycles.)"""
    controller = active(pressure=0.0)
    controller.update_regulator_status(0.0, 0)
    controller.command(30e3, Source.SUPPLY, math.nan, 0.0)
    assert controller.step(0.002).valves == (Valve.SUPPLY,)  # boost
    now = 0.002
    # a fast rise near the target
    for pressure in np.linspace(2e3, 29.5e3, 20):
        now += 0.002
        controller.update_sensor("s", pressure, now)
        out = controller.step(now)
    controller.update_regulator_status(controller.config.regulator_max_gauge_pa, 0)  # still high
    now += 0.002
    controller.update_sensor("s", 29.8e3, now)
    out = controller.step(now)
    assert controller.regulation_phase is RegulationPhase.SETTLE and out.message == "settle"
    assert out.valves == (Valve.CLOSED,)
    controller.command(-20e3, Source.VACUUM, math.nan, now)
    valves = []
    for _ in range(10):  # 20 ms at 500 Hz
        now += 0.002
        controller.update_sensor("s", 29.8e3, now)
        valves.append(controller.step(now).valves[0])
    # the setpoint 5 ms ahead is already far below
    assert valves[0] == Valve.VACUUM, valves


@pytest.mark.parametrize("rate_pa_per_s, first_vacuum_tick", [(math.nan, 0), (1e6, 0), (50e3, 47)])
def test_a_fast_clamp_opens_the_pump_at_once_and_a_slow_ramp_when_its_setpoint_is_a_band_below(
        rate_pa_per_s, first_vacuum_tick):
    """From a vented chamber to -20 kPa: at the default slew (1 MPa/s) the pump's valve opens on
    the first step, not after the 5 ms the setpoint takes to slew the 5 kPa band (the CLAMP
    command's latency in bench_e2e); a 50 kPa/s ramp is followed on the regulated line until its
    setpoint lies the band (less the 250 Pa it slews in boost_lead_s) below the chamber."""
    controller = active(pressure=0.0)
    controller.step(0.0)  # running: the slew starts from here
    controller.command(-20e3, Source.VACUUM, rate_pa_per_s, 0.0)
    valves = []
    for tick in range(1, 60):
        controller.update_sensor("s", 0.0, 0.002 * tick)
        valves.append(controller.step(0.002 * tick).valves[0])
    assert valves.index(Valve.VACUUM) == first_vacuum_tick, valves
    assert set(valves[:first_vacuum_tick]) <= {Valve.SUPPLY}


def _identifying(pressure=0.0):
    controller = active(pressure=pressure)
    controller.identification = True
    return controller


def test_identification_mode_opens_the_commanded_valve_with_the_regulator_at_the_target():
    controller = _identifying()
    controller.command(30e3, Source.SUPPLY, math.nan, 0.0)
    out = controller.step(0.001)
    # no boost, no trim: the regulator at the target, the valve open to it
    assert out.mode == PressureMode.IDENTIFY and out.valves == (Valve.SUPPLY,)
    assert out.regulator_setpoint_gauge_pa == 30e3 and out.regulator_enabled
    # the regulator alone, valves closed (HOLD with a target)
    controller.update_sensor("s", 0.0, 0.002)
    controller.command(-40e3, Source.HOLD, math.nan, 0.002)
    out = controller.step(0.003)
    assert out.valves == (Valve.CLOSED,) and out.regulator_setpoint_gauge_pa == -40e3
    assert out.mode == PressureMode.IDENTIFY


def test_a_hold_sets_the_regulator_to_atmosphere_except_in_identification():
    """HOLD closes the valves with the regulator at 0 gauge (a valve stuck open then shows);
    identification's plain HOLD keeps the regulator at its last target, so that the refill after
    it measures the valve, not the regulator's lag."""
    for identifying, regulator_pa in ((False, 0.0), (True, 30e3)):
        controller = _identifying() if identifying else active()
        controller.command(30e3, Source.SUPPLY, math.nan, 0.0)
        controller.step(0.001)
        controller.update_sensor("s", 30e3, 0.5)
        controller.command(math.nan, Source.HOLD, math.nan, 0.5)
        out = controller.step(0.501)
        assert out.valves == (Valve.CLOSED,) and out.mode == PressureMode.HOLD
        assert out.regulator_setpoint_gauge_pa == regulator_pa and out.regulator_enabled


def test_identification_mode_evacuates_to_the_target_and_closes_there():
    controller = _identifying()
    controller.command(-30e3, Source.VACUUM, math.nan, 0.0)
    assert controller.step(0.001).valves == (Valve.VACUUM,)
    # falling 200 kPa/s: 50 ms from the target
    controller.update_sensor("s", -20e3, 0.05)
    assert controller.step(0.051).valves == (Valve.VACUUM,)
    controller.update_sensor("s", -30.1e3, 0.1)
    out = controller.step(0.101)
    assert out.valves == (Valve.CLOSED,) and "evacuated" in out.message
    controller.update_sensor("s", -30.1e3, 0.102)
    assert controller.step(0.103).valves == (Valve.CLOSED,)


def test_identification_mode_closes_the_pump_before_its_predicted_crossing():
    """A small chamber falls some 550 kPa/s near the bottom: closing on the first reading past
    the target ran on by the reading's age, the period and the valve's lag (live, 2-4 kPa). The
    valve closes ``boost_lead_s`` before the predicted crossing, as the closed loop's does."""
    controller = _identifying()
    lead_s, rate_pa_per_s, target_pa = controller.config.boost_lead_s, -550e3, -30e3
    controller.command(target_pa, Source.VACUUM, math.nan, 0.0)
    closed_at = None
    # readings every 2 ms, each reaching a step 1 ms after it was measured
    for tick in range(1, 60):
        measured_at = 0.002 * tick
        controller.update_sensor("s", rate_pa_per_s * measured_at, measured_at)
        now = measured_at + 0.001
        if controller.step(now).valves == (Valve.CLOSED,):
            closed_at = now
            break
    assert closed_at is not None
    chamber_pa = rate_pa_per_s * closed_at
    # before the crossing, by the lead and at most one more period (and the rate's filter lag)
    assert target_pa < chamber_pa <= target_pa - rate_pa_per_s * (lead_s + 0.002), chamber_pa
    controller.update_sensor("s", chamber_pa, closed_at + 0.001)
    assert controller.step(closed_at + 0.002).valves == (Valve.CLOSED,)


def test_identification_mode_keeps_the_limits_and_clamps_targets():
    controller = _identifying()
    note = controller.command(90e3, Source.SUPPLY, math.nan, 0.0)
    out = controller.step(0.001)
    assert "clamped" in note and out.regulator_setpoint_gauge_pa == 50e3
    assert Fault.SETPOINT_CLAMPED in Fault(out.fault_flags)
    # a reading past the limit plus margin: the safe state, as always
    controller.update_sensor("s", 56e3, 0.002)
    out = controller.step(0.003)
    assert out.mode == PressureMode.FAULT and out.valves == (Valve.VENT,)
    assert not out.regulator_enabled and Fault.OVERPRESSURE in Fault(out.fault_flags)


def test_identification_mode_suspends_only_the_checks_against_the_plant_model():
    """A chamber twice as fast as the model (what identification is for) steps further between
    two readings than the model allows: outside identification a sensor jump, not in it; the
    sensors' disagreement still counts in it."""
    for identifying, expected in ((False, Fault.SENSOR_IMPLAUSIBLE), (True, Fault.NONE)):
        controller = active()
        controller.identification = identifying
        controller.command(0.0, Source.HOLD, math.nan, 0.0)
        for k in range(1, 40):
            now = 0.002 * k
            jump = 0.0 if k < 20 else 30e3  # 30 kPa in one 2 ms sample, both sensors
            controller.update_sensor("a", jump, now)
            controller.update_sensor("b", jump, now + 1e-4)
            out = controller.step(now + 2e-4)
        assert Fault(out.fault_flags) & Fault.SENSOR_IMPLAUSIBLE == expected, identifying
    controller = _identifying()
    controller.command(0.0, Source.HOLD, math.nan, 0.0)
    for k in range(1, 60):
        now = 0.002 * k
        controller.update_sensor("a", 0.0, now)
        controller.update_sensor("b", 20e3, now + 1e-4)
        out = controller.step(now + 2e-4)
    assert Fault.SENSOR_DISAGREE in Fault(out.fault_flags) and out.mode == PressureMode.FAULT

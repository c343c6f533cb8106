#!/usr/bin/env python3
"""Speed against accuracy across the suite: kinematics models, pressure estimators, plant
integrators.

Kinematics: L0, L1 and L2 against the PyElastica reference (softgrip_ros.model.reference, the
`--with-reference` extra), in free bending over 0-60 kPa and in contact scenes (clamping 40 and
30 mm cylinders, pinching a 0.1 mm sheet). Error: the left tip's distance from the reference's;
cost: the median time of one pose. Also D1/D2 against the paper's points. Held-out scenes
(pressures between the benchmark's, another cylinder and sheet pressure) check each bound where
it was not computed. Against the FE truth (the 3-D FE, config/fe3d_reference.yaml): every model
with the paper's and the FE's calibration in free bending from the FE's vacuum limit to +50 kPa,
and L0-L2 with the FE's calibration in the FE's clamp scenes (sheets and cylinders).
config/model_error_bounds.yaml, the table `fidelity: auto` chooses from, takes each model's
median cost; in free bending its largest error against the FE with its law fitted to the FE
(checked at the FE pressures that fit did not see); in contact the larger of its errors against
PyElastica and against the FE's clamp scenes.
Estimators: RMSE against the plant's truth and the cost of a step (KF, EKF, UKF, raw sensors).
Integrators: the stiff 1 mL fill to 30 kPa; explicit Euler, our backward Euler and its
extrapolation (the simulated device's truth) over a dt sweep, and RK45 over a tolerance sweep,
against an LSODA solution at rtol 1e-10; divergence points marked.
Auto: the demo grasp's pressure trace and scenes through SceneModel(auto), cost per sample
against the cheapest model, error at the benchmark's points.

Writes docs/speed_vs_accuracy.md, docs/speed_accuracy_{kinematics,estimators,integrators}.png and
config/model_error_bounds.yaml; --json prints the points and the `pareto` lists instead. --quick
takes a few points on a coarse reference (4 elements per segment) and fewer integrator steps,
prints the same keys and writes nothing: it checks that the script runs, not the figures.
Reproduce: bash scripts/setup.sh --with-reference; source scripts/env.sh;
python scripts/bench_speed_accuracy.py   (about 2-4 minutes on 2 cores)
"""
import math
import pathlib
import statistics
import sys
import time

import numpy as np
import yaml
from scipy.integrate import solve_ivp
from tqdm import tqdm

from softgrip_ros.devtools.benchmarking import (benchmark_parser, machine_line, median_seconds,
                                                update_section, strict_json)
from softgrip_ros.model.calibration import build_kinematics
from softgrip_ros.model.fidelity import (CONTACT_VALIDATED_RANGE_PA, FREE, MODELS, SCENE_CLASSES,
                                         ErrorBounds, Scene, SceneModel, cylinder_scene)
from softgrip_ros.model.pneumatics import (P_ATM_PA, PlantInputs, PlantState, PneumaticParameters,
                                           PneumaticPlant, Valve)
from softgrip_ros.model.reference import ReferenceFinger
from softgrip_ros.model.rod import RodFinger, Sheet
from softgrip_ros.devtools.model_validation import rows as paper_rows
from softgrip_ros.model.fe_data import (FE_CALIBRATION_NAMES, HELD_OUT_PRESSURES_PA,
                                          load_fe3d_reference, load_fe_truth)

ROOT = pathlib.Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "speed_vs_accuracy.md"
BOUNDS = ROOT / "config" / "model_error_bounds.yaml"
CHARTS = {
    name: ROOT / "docs" / f"speed_accuracy_{name}.png"
    for name in ("kinematics", "estimators", "integrators", "fe")
}
# against the FE: each law with the paper's constants and with its own fitted to the FE
FE_CALIBRATIONS = {"paper": {"l0": "type_II", "l1": "type_II"}, "FE": FE_CALIBRATION_NAMES}
FE_METHODS = ("l0", "l1", "l2", "pyelastica")
FREE_PRESSURES_PA = [
    0.0, 5e3, 10e3, 15e3, 20e3, 25e3, 30e3, 35e3, 40e3, 45e3, 48e3, 52e3, 56e3, 60e3
]
HELD_OUT_FREE_PRESSURES_PA = [2.5e3, 17.5e3, 32.5e3, 42.5e3, 50e3, 58e3]
INTEGRATOR_STEPS_S = [1e-5, 3e-5, 1e-4, 3e-4, 1e-3, 3e-3, 1e-2, 2e-2]
# backward Euler over a step and its two halves, combined to second order: the simulated
# device's truth (PneumaticPlant.advance, TRUTH_STEP_S)
EXTRAPOLATED = "extrapolated backward Euler (truth)"
QUICK = {
    "free": [0.0, 25e3, 52e3], "contacts": 2, "held_out": 2, "elements_per_segment": 4,
    "integrator_steps_s": [1e-4, 1e-3, 2e-2]
}
TOLERANCE_M = 1e-2  # the kinematics node's default tolerance_m
AUTO_PASSES = 3


def contact_cases(rod):
    """(label, scene, pressure): clamping cylinders opened around them, and pinching a sheet; their
    pressures span CONTACT_VALIDATED_RANGE_PA, the range the contact bound is said to hold on."""
    cylinder_40 = cylinder_scene(rod, 0.040, 30e3)
    cylinder_30 = cylinder_scene(rod, 0.030, 25e3)
    sheet = Scene(Sheet(1e-4), 2e3)
    cases = ([(f"40 mm cylinder at {p / 1e3:.0f} kPa", cylinder_40, p)
              for p in (0.0, -5e3, -10e3, -20e3)]
             # the release path: the vent and the opening, the object still between the fingers
             + [(f"40 mm cylinder at +{p / 1e3:.0f} kPa (releasing)", cylinder_40, p)
                for p in (5e3, 10e3, 20e3, 30e3)] +
             [("30 mm cylinder at -10 kPa", cylinder_30, -10e3)] +
             [(f"0.1 mm sheet at {p / 1e3:.0f} kPa", sheet, p) for p in (-5e3, -20e3)])
    pressures = [p for _, _, p in cases]
    assert (min(pressures), max(pressures)
            ) == CONTACT_VALIDATED_RANGE_PA, "the contact range says where it was measured"
    return cases


def tip_error_m(a, b):
    return math.hypot(a[0] - b[0], a[1] - b[1])


def held_out_cases(rod):
    """Scenes the bounds are not computed from, to check that they hold between the benchmark's
    points."""
    return ([(f"free at {p / 1e3:g} kPa", FREE, p) for p in HELD_OUT_FREE_PRESSURES_PA] +
            [("35 mm cylinder at -15 kPa", cylinder_scene(rod, 0.035, 28e3), -15e3),
             ("0.1 mm sheet at -10 kPa", Scene(Sheet(1e-4), 2e3), -10e3)])


def kinematics_points(repeat: int, reference: ReferenceFinger, rod: RodFinger, cases=None,
                      desc: str = "kinematics vs PyElastica", timed: bool = True,
                      quick: bool = False) -> dict:
    """Each case's tip error against the reference per model and, if ``timed``, the cost of a
    pose."""
    free_models = {m: build_kinematics(m, max_pressure_pa=60e3) for m in ("l0", "l1")}
    validated_max = free_models["l1"].calibration.validated_max_pressure_pa
    if cases is None:
        free = QUICK["free"] if quick else FREE_PRESSURES_PA
        contact = contact_cases(rod)
        cases = [(f"free at {p / 1e3:.0f} kPa", FREE, p)
                 for p in free] + ([contact[2], contact[-1]] if quick else contact)
    points = []
    for label, scene, pressure in tqdm(cases, desc=desc, file=sys.stderr):
        ref = reference.solve(pressure, obstacle=scene.obstacle,
                              from_pressure_pa=scene.opening_gauge_pa)
        if not ref.at_rest:
            raise RuntimeError(
                f"the reference did not settle for {label}: speed {ref.max_speed_m_s:.3g} m/s")
        scene_class = "contact" if scene.contact else (
            "free" if pressure <= validated_max else "free_beyond")
        row = {
            "case": label, "pressure_pa": pressure, "scene_class": scene_class,
            "reference_s": ref.wall_s, "reference_force_n": ref.contact_force_n, "error_m": {},
            "cost_s": {}, "l1_tip": _tip(free_models["l1"], pressure)
        }
        for name, model in free_models.items():
            row["error_m"][name] = tip_error_m(_tip(model, pressure), ref.tip)
            if timed:
                row["cost_s"][name] = median_seconds(lambda m=model: m.pose(pressure), 200, repeat)
        solution = rod.solve(pressure, obstacle=scene.obstacle,
                             from_pressure_pa=scene.opening_gauge_pa)
        if not solution.converged:
            raise RuntimeError(f"L2 did not converge for {label}: {solution.message}")
        row["error_m"]["l2"] = tip_error_m(solution.tip, ref.tip)
        row["l2_force_n"] = solution.contact_force_n
        if timed:
            number = 200 if not scene.contact else 1
            row["cost_s"]["l2"] = median_seconds(
                lambda: rod.solve(pressure, obstacle=scene.obstacle, from_pressure_pa=scene.
                                  opening_gauge_pa), number, repeat)
            row["cost_s"]["reference"] = ref.wall_s
        points.append(row)
    return {
        "points": points, "validated_max_pa": validated_max,
        "rest_tip": _tip(free_models["l1"], 0.0)
    }


def bound_checks(held_out: dict, table: dict) -> dict:
    """Per model and scene class: the largest held-out error, the bound, and whether the bound
    holds."""
    checks = {}
    for model in MODELS:
        for scene_class in SCENE_CLASSES:
            errors = [
                p["error_m"][model] for p in held_out["points"] if p["scene_class"] == scene_class
            ]
            if errors:
                bound = table[model]["tip_error_bound_m"][scene_class]
                checks.setdefault(model, {})[scene_class] = {
                    "largest_error_m": max(errors), "bound_m": bound, "holds": max(errors) <= bound
                }
    return checks


def _tip(model, pressure):
    pose = model.pose(pressure)
    return float(pose.left_tip_x_m), float(pose.left_tip_z_m)


def error_bounds(kinematics: dict) -> dict:
    """Per model: the largest error per scene class and the median cost over the free points
    (contact for L2's cost would overstate it where the scene is free)."""
    table = {}
    for model in MODELS:
        bounds = {
            c: max(p["error_m"][model] for p in kinematics["points"] if p["scene_class"] == c)
            for c in SCENE_CLASSES
        }
        cost = statistics.median(p["cost_s"][model] for p in kinematics["points"]
                                 if p["scene_class"] != "contact")
        contact_cost = statistics.median(p["cost_s"][model] for p in kinematics["points"]
                                         if p["scene_class"] == "contact")
        table[model] = {
            "tip_error_bound_m": bounds, "median_cost_s": cost,
            "median_contact_cost_s": contact_cost
        }
    return table


def estimator_points(repeat: int) -> list:
    sys.path.insert(0, str(ROOT / "scripts"))
    from bench_estimator import step_costs_us
    from softgrip_ros.devtools import estimator_simulation as sim
    from softgrip_ros.estimation.filters import FILTER_TYPES
    trajectory = sim.simulate(seed=7)
    points = [{"method": f"raw {name}", "cost_us": 0.0, "rmse_pa": trajectory.raw_rmse(name)}
              for name in trajectory.sensor_std]
    # the three filters' passes interleaved, in one run
    costs = step_costs_us(trajectory, repeat)
    for filter_type in tqdm(FILTER_TYPES, desc="estimators", file=sys.stderr):
        points.append({
            "method": filter_type, "cost_us": statistics.median(costs[filter_type]),
            "rmse_pa": sim.run(trajectory, sim.config_for(trajectory, filter_type)).rmse()
        })
    return points


def integrator_points(repeat: int, steps_s=INTEGRATOR_STEPS_S) -> dict:
    """Error against cost: the device's chamber filled to 25 kPa over 0.3 s, against LSODA at rtol
    1e-10 (as tests/test_model_pneumatics.py). Divergence: the stiff 1 mL rigid chamber filled to
    30 kPa, where the equilibrium (30 kPa) is known, so no reference solve is needed (an adaptive
    solver chatters there: LSODA at rtol 1e-8 took 3.4 million evaluations)."""
    plant = PneumaticPlant()
    inputs = PlantInputs(regulator_setpoint_gauge_pa=25e3, valves=(Valve.SUPPLY,))
    duration, grid = 0.3, np.linspace(0.005, 0.3, 60)
    start = [0.0, P_ATM_PA]
    reference = solve_ivp(lambda t, y: plant.derivative(y, inputs), (0.0, duration), start,
                          method="LSODA", rtol=1e-10, atol=1e-6, t_eval=grid)
    truth = reference.y[1] - P_ATM_PA

    def fixed_step(model, stepper, model_inputs, dt, length, regulator_start):
        state, times, values = PlantState(regulator_start, np.array([P_ATM_PA])), [], []
        with np.errstate(all="ignore"):
            for k in range(int(round(length / dt))):
                state = stepper(state, model_inputs, dt)
                times.append((k + 1) * dt)
                values.append(state.chamber_pa[0] - P_ATM_PA)
        return np.array(times), np.array(values)

    def error(values):
        worst = float(np.max(np.abs(values - truth)))
        return worst if math.isfinite(worst) else math.inf

    stiff = PneumaticPlant(
        PneumaticParameters(chamber_volume_m3=1e-6, min_chamber_volume_m3=0.2e-6,
                            chamber_compliance_m3_per_pa=0.0))
    fill_30 = PlantInputs(regulator_setpoint_gauge_pa=30e3, valves=(Valve.SUPPLY,))
    points = []
    for dt in tqdm(steps_s, desc="integrators", file=sys.stderr):
        for method, name in (("explicit Euler", "explicit_euler_step"),
                             ("backward Euler (ours)", "step"),
                             (EXTRAPOLATED, "extrapolated_step")):
            times, values = fixed_step(plant, getattr(plant, name), inputs, dt, duration, 0.0)
            cost = median_seconds(
                lambda n=name, d=dt: fixed_step(plant, getattr(plant, n), inputs, d, duration, 0.0
                                                ), 1, 3 if dt < 1e-4 else repeat)
            _, stiff_values = fixed_step(stiff, getattr(stiff, name), fill_30, dt, 0.5, 30e3)
            tail = stiff_values[int(0.8 * stiff_values.size):]
            points.append({
                "method": method, "setting": f"dt {dt:g} s", "dt_s": dt, "cost_s": cost,
                "error_pa": error(np.interp(grid, times, values)) if times.size else math.inf,
                "stiff_ripple_pa": float(np.max(np.abs(tail - 30e3)))
                if np.all(np.isfinite(tail)) else math.inf, "stiff_physical": bool(
                    np.all(np.isfinite(stiff_values)) and np.min(stiff_values) > -P_ATM_PA)
            })
    for rtol in (1e-3, 1e-5, 1e-7):
        for method in ("RK45", "LSODA"):

            def run(m=method, r=rtol):
                return solve_ivp(lambda t, y: plant.derivative(y, inputs), (0.0, duration), start,
                                 method=m, rtol=r, atol=1e-3, t_eval=grid)

            solution = run()
            points.append({
                "method": method, "setting": f"rtol {rtol:g}", "dt_s": math.nan,
                "cost_s": median_seconds(run, 1, repeat),
                "error_pa": error(solution.y[1] - P_ATM_PA), "stiff_ripple_pa": math.nan,
                "stiff_physical": True, "evaluations": int(solution.nfev)
            })
    euler = [p for p in points if p["method"] == "explicit Euler"]
    ripple_limit = min((p["dt_s"] for p in euler if p["stiff_ripple_pa"] > 200.0),
                       default=math.nan)
    unphysical = min((p["dt_s"] for p in euler if not p["stiff_physical"]), default=math.nan)
    return {
        "points": points, "euler_ripple_over_200pa_from_dt_s": ripple_limit,
        "euler_unphysical_from_dt_s": unphysical
    }


def demo_grasp_trace():
    """The demo grasp's pressure over time, sampled at 200 Hz with the estimate's noise (80 Pa):
    open to 17 kPa (free), hold, clamp a 40 mm cylinder to -10 kPa (contact), hold 2 s, vent."""
    rng = np.random.default_rng(3)

    def lag(start, end, n, tau=25):
        return end + (start - end) * np.exp(-np.arange(n) / tau)

    phases = [(lag(0.0, 17e3, 100), False), (np.full(60, 17e3), False),
              (lag(17e3, -10e3, 100), True), (np.full(400, -10e3), True),
              (lag(-10e3, 0.0, 100), False)]
    return [(float(p + rng.normal(0.0, 80.0)), contact) for values, contact in phases
            for p in values]


def auto_points(rod: RodFinger, bounds: ErrorBounds, kinematics: dict, held_out: dict,
                fe: dict) -> dict:
    """auto's cost in the demo grasp against L0 everywhere; its largest error in the validated
    range (free bending to 46 kPa against the FE, the chosen law fitted to it, every FE pressure
    including the held-out ones; contact against PyElastica, the benchmark's and the held-out
    scenes), and beyond 46 kPa, where it warns."""
    scene = cylinder_scene(rod, 0.040, 17e3)
    trace = demo_grasp_trace()
    # microseconds a sample: the two interleaved, AUTO_PASSES times each, the median of the
    # passes' medians (one pass each read 3.4 against 1.9 us where repeated runs agree on 1.2x)
    passes = {"auto": [], "l0": []}
    for run in range(AUTO_PASSES):
        for fidelity in passes:
            model = SceneModel(fidelity, TOLERANCE_M, bounds=bounds)
            samples = []
            for index, (pressure, contact) in enumerate(
                    tqdm(trace, desc=f"demo trace, {fidelity}, pass {run + 1}", file=sys.stderr)):
                started = time.perf_counter()
                model.evaluate(pressure, scene if contact else FREE, now_s=index / 200.0)
                samples.append(time.perf_counter() - started)
            passes[fidelity].append((statistics.median(samples), statistics.fmean(samples),
                                     model.solves))
    costs = {fidelity: {"median_s": statistics.median(p[0] for p in runs),
                        "mean_s": statistics.median(p[1] for p in runs),
                        "l2_solves": runs[0][2]} for fidelity, runs in passes.items()}
    chooser = SceneModel("auto", TOLERANCE_M, bounds=bounds).selector
    chosen = {c: chooser.choose_for_class(c).model for c in SCENE_CLASSES}
    fitted = [r for r in fe["points"] if r["calibration"] == "FE"]
    contact = [p["error_m"][chosen["contact"]] for p in kinematics["points"] + held_out["points"]
               if p["scene_class"] == "contact"]
    free = [r["tip_error_m"][chosen["free"]] for r in fitted if _fe_class(r["pressure_pa"]) ==
            "free"]
    beyond = [r["tip_error_m"][chosen["free_beyond"]] for r in fitted
              if _fe_class(r["pressure_pa"]) == "free_beyond"]
    return {
        "costs": costs, "median_cost_ratio": costs["auto"]["median_s"] / costs["l0"]["median_s"],
        "chosen": chosen, "worst_error_m": _largest(free + contact),
        "worst_beyond_error_m": _largest(beyond), "tolerance_m": TOLERANCE_M
    }


def pareto(points, cost_key, error_key, name_key) -> list:
    """The names of the points no other point beats on both cost and error."""
    names = []
    for p in points:
        dominated = any(q[cost_key] <= p[cost_key] and q[error_key] <= p[error_key] and
                        (q[cost_key] < p[cost_key] or q[error_key] < p[error_key]) for q in points)
        if not dominated and p[name_key] not in names:
            names.append(p[name_key])
    return names


def kinematics_pareto(kinematics: dict) -> dict:
    result = {}
    for scene_class in SCENE_CLASSES:
        rows = [p for p in kinematics["points"] if p["scene_class"] == scene_class]
        summary = [{
            "method": m, "cost_s": statistics.median(r["cost_s"][m]
                                                     for r in rows), "error_m": max(r["error_m"][m]
                                                                                    for r in rows)
        } for m in MODELS]
        summary.append({
            "method": "reference", "cost_s": statistics.median(r["reference_s"] for r in rows),
            "error_m": 0.0
        })
        result[scene_class] = pareto(summary, "cost_s", "error_m", "method")
    return result


def write_bounds(table: dict, finger_length_m: float, reference: ReferenceFinger,
                 fe: dict) -> None:
    """``table``: auto_table's (free bending against the FE, contact against PyElastica)."""
    rod = (f"PyElastica Cosserat rod driven by L1's law, {reference.rod.elements_per_segment} "
           "elements per segment, run to rest")
    fe_text = (f"the 3-D FE finger with contact (w = {fe['fe_width_mm']:g} mm, "
               f"{fe['fe_element_size_m'] * 1e3:.1f} mm mesh, config/fe3d_reference.yaml), each "
               "law fitted to it (type_II_fe, type_II_fe_l1): the law's own error, at the FE "
               "pressures its calibration was fitted to, from its vacuum limit up")
    contact_text = (f"the larger of: {rod}; and the 3-D FE's clamp scenes (sheets and "
                    "cylinders, while touching), each law fitted to the FE")
    doc = {
        "references": {"free": fe_text, "free_beyond": fe_text, "contact": contact_text},
        "finger_length_m": finger_length_m,
        "tolerance_unit": "m (tip position)", "scene_classes": {
            "free": "free bending inside the validated range",
            "free_beyond": "free bending above 46 kPa",
            "contact": "an object between the fingers (cylinders clamped, a sheet pinched)"
        }, "contact_pressure_range_pa": [float(p) for p in CONTACT_VALIDATED_RANGE_PA], "models": {
            m: {
                "median_cost_s": float(f"{v['median_cost_s']:.4g}"), "tip_error_bound_m": {
                    c: float(f"{b:.4g}")
                    for c, b in v["tip_error_bound_m"].items()
                }
            }
            for m, v in table.items()
        }
    }
    with BOUNDS.open("w") as handle:
        handle.write(
            "# Model error bounds against the references and the cost of one pose. Written by\n"
            "# scripts/bench_speed_accuracy.py; do not edit by hand. fidelity: auto reads it.\n")
        yaml.safe_dump(doc, handle, sort_keys=False)


def rod_segment_angles(nodes_m, elements_per_segment: int, inclination_rad: float) -> list:
    """The five segment bends of a rod's backbone nodes (bending part, clamp first): the turn of
    the tangent across each segment, the tangent at an inner boundary being the mean of its two
    elements' headings."""
    d = np.diff(np.asarray(nodes_m), axis=0)
    headings = np.arctan2(d[:, 0], d[:, 1])
    boundary = [inclination_rad]
    for k in range(1, 5):
        i = k * elements_per_segment
        boundary.append(0.5 * (headings[i - 1] + headings[i]))
    boundary.append(float(headings[5 * elements_per_segment - 1]))
    return [boundary[k] - boundary[k + 1] for k in range(5)]


def fe_points(repeat: int, quick: bool) -> dict:
    """Every model against the FE truth (the 3-D FE's default sweep, config/fe3d_reference.yaml)
    in free bending: L0, L1, L2 and PyElastica, each with the paper's calibration and with its
    law's calibration fitted to the FE (PyElastica and L2 run the L1 law). Under vacuum the FE's
    finger bends on past the centre line, so L0 and L1 are taken as fingers that do not meet
    (``free_shape``). Tip error and D2 error; the median cost of a pose. Then the FE's clamp
    scenes (:func:`fe_contact_points`)."""
    reference = load_fe_truth()
    pressures = [p.pressure_pa for p in reference.points if p.pressure_pa != 0.0]
    if quick:
        pressures = [pressures[0]] + pressures[-9::5]
    rows = []
    for calibration, names in FE_CALIBRATIONS.items():
        kins = {law: build_kinematics(law, names[law], max_pressure_pa=60e3) for law in names}
        rod = RodFinger(kins["l1"].geometry, kins["l1"].calibration)
        elastica = ReferenceFinger(rod, elements_per_segment=QUICK["elements_per_segment"]
                                   if quick else 16)
        for p in tqdm(pressures, desc=f"against the FE, {calibration} calibration",
                      file=sys.stderr):
            truth = reference.at(p)
            row = {"pressure_pa": p, "calibration": calibration, "tip_error_m": {},
                   "d2_error_m": {}, "cost_s": {}}
            for law, kin in kins.items():
                if p >= 0.0:
                    pose = kin.pose(p)
                    tip, d2 = (pose.left_tip_x_m, pose.left_tip_z_m), pose.tip_spacing_m
                else:
                    tip, d2 = kin.free_shape(p)
                row["tip_error_m"][law] = tip_error_m(tip, truth.tip)
                row["d2_error_m"][law] = abs(d2 - truth.d2_m)
                row["cost_s"][law] = median_seconds(lambda k=kin: k.pose(p), 50, repeat)
            solution = rod.solve(p)
            row["tip_error_m"]["l2"] = tip_error_m(solution.tip, truth.tip)
            row["d2_error_m"]["l2"] = abs(kins["l1"].spacings_for_angles(
                p, solution.segment_angles_rad)[1] - truth.d2_m)
            row["cost_s"]["l2"] = median_seconds(lambda: rod.solve(p), 20, repeat)
            ref = elastica.solve(p, from_pressure_pa=0.0)
            angles = rod_segment_angles(ref.nodes_m, elastica.rod.elements_per_segment,
                                        kins["l1"].geometry.inclination_rad)
            row["tip_error_m"]["pyelastica"] = tip_error_m(ref.tip, truth.tip)
            row["d2_error_m"]["pyelastica"] = abs(
                kins["l1"].spacings_for_angles(p, angles)[1] - truth.d2_m)
            row["cost_s"]["pyelastica"] = ref.wall_s
            rows.append(row)
    validated = {c: {law: build_kinematics(law, n[law]).calibration.validated_max_pressure_pa
                     for law in n} for c, n in FE_CALIBRATIONS.items()}
    summary = []
    for calibration in FE_CALIBRATIONS:
        for method in FE_METHODS:
            law = "l0" if method == "l0" else "l1"
            top = validated[calibration][law]
            inside = [r for r in rows if r["calibration"] == calibration and
                      r["pressure_pa"] <= top]
            summary.append({
                "method": f"{method.upper() if method != 'pyelastica' else 'PyElastica'}, "
                          f"{calibration} calibration",
                "calibration": calibration, "model": method, "validated_max_pa": top,
                "cost_s": statistics.median(r["cost_s"][method] for r in inside),
                "tip_error_m": max(r["tip_error_m"][method] for r in inside),
                "d2_error_m": max(r["d2_error_m"][method] for r in inside)})
    fe_cost = reference.sweep["seconds"] / len(reference.points)
    summary.append({"method": "FE (the truth)", "calibration": "", "model": "fe",
                    "validated_max_pa": max(p.pressure_pa for p in reference.points),
                    "cost_s": fe_cost, "tip_error_m": 0.0, "d2_error_m": 0.0})
    contact = fe_contact_points(quick)
    bounds = fe_error_bounds(rows, contact)
    return {
        "points": rows, "summary": summary, "fe_cost_s": fe_cost, "contact_points": contact,
        "fe_element_size_m": reference.sweep["element_size_m"],
        "fe_width_mm": reference.figures["fe3d_width_mm"],
        "fe_vacuum_limit_kpa": reference.figures["fe3d_vacuum_limit_kpa"],
        "pareto_tip": pareto(summary, "cost_s", "tip_error_m", "method"),
        "pareto_d2": pareto(summary, "cost_s", "d2_error_m", "method"),
        "fe_bounds": bounds,
        "fe_checks": fe_bound_checks(rows, bounds),
    }


def fe_contact_points(quick: bool) -> list:
    """The FE's clamp scenes (config/fe3d_reference.yaml's ``clamp``: a sheet or a cylinder
    clamped from where the finger opened clear of it) against L2 in the same scene and L0/L1
    (which place no object), each law fitted to the FE: the left tip's error per pressure."""
    document = load_fe3d_reference()
    clamps = [c for c in document["clamp"] if c.get("states")]
    if quick:
        clamps = clamps[:1]
    kins = {law: build_kinematics(law, FE_CALIBRATION_NAMES[law], max_pressure_pa=60e3)
            for law in ("l0", "l1")}
    rod = RodFinger(kins["l1"].geometry, kins["l1"].calibration)
    rows = []
    for clamp in clamps:
        size_m, opening_pa = clamp["size_mm"] * 1e-3, clamp["opening_kpa"] * 1e3
        obstacle = (Sheet(size_m) if clamp["kind"] == "flat" else
                    cylinder_scene(rod, size_m, opening_pa).obstacle)
        states = clamp["states"][1::3] if quick else clamp["states"]
        label = f"{clamp['size_mm']:g} mm {'sheet' if clamp['kind'] == 'flat' else 'cylinder'}"
        for state in tqdm(states, desc=f"the FE's clamp of a {label}", file=sys.stderr):
            p = state["pressure_kpa"] * 1e3
            truth = [v * 1e-3 for v in state["tip_mm"]]
            solution = rod.solve(p, obstacle, from_pressure_pa=opening_pa, steps=8)
            row = {"scene": label, "pressure_pa": p, "touching": state["normal_force_n"] > 0.0,
                   "tip_error_m": {"l2": tip_error_m(solution.tip, truth)}}
            for law, kin in kins.items():
                pose = kin.pose(p)
                row["tip_error_m"][law] = tip_error_m((pose.left_tip_x_m, pose.left_tip_z_m),
                                                      truth)
            rows.append(row)
    return rows


def _fe_class(pressure_pa: float) -> str:
    return "free" if pressure_pa <= 46e3 else "free_beyond"


def _largest(values) -> float:
    return max(values, default=math.nan)


def fe_error_bounds(rows, contact_rows) -> dict:
    """Per model, each law fitted to the FE (its own error, not the paper calibration's): the
    largest tip error in free bending inside and beyond 46 kPa (the classes of
    config/model_error_bounds.yaml), over the pressures the FE calibration was fitted to; and
    in the FE's clamp scenes while the finger touches the object."""
    fitted = [r for r in rows if r["calibration"] == "FE" and not _held_out(r["pressure_pa"])]
    bounds = {model: {c: _largest(r["tip_error_m"][model] for r in fitted
                                  if _fe_class(r["pressure_pa"]) == c)
                      for c in ("free", "free_beyond")} for model in MODELS}
    for model in MODELS:
        bounds[model]["contact"] = _largest(r["tip_error_m"][model] for r in contact_rows
                                            if r["touching"])
    return bounds


def _held_out(pressure_pa: float) -> bool:
    return any(abs(pressure_pa - h) < 1.0 for h in HELD_OUT_PRESSURES_PA)


def fe_bound_checks(rows, bounds: dict) -> dict:
    """Per model and class: the largest error at the FE pressures the calibration did not see
    (fe_data.HELD_OUT_PRESSURES_PA), against the bound from the others."""
    held = [r for r in rows if r["calibration"] == "FE" and _held_out(r["pressure_pa"])]
    checks = {}
    for model in MODELS:
        for scene_class in ("free", "free_beyond"):
            errors = [r["tip_error_m"][model] for r in held
                      if _fe_class(r["pressure_pa"]) == scene_class]
            if errors:
                bound = bounds[model][scene_class]
                checks.setdefault(model, {})[scene_class] = {
                    "largest_error_m": max(errors), "bound_m": bound,
                    "holds": max(errors) <= bound}
    return checks


def auto_table(table: dict, fe_bounds: dict) -> dict:
    """The bounds fidelity: auto reads: free bending against the FE (each law fitted to it), the
    contact scenes the larger of the errors against PyElastica and against the FE's clamp
    scenes; the costs from the PyElastica benchmark's timings."""
    return {m: {**table[m], "tip_error_bound_m": {
        "free": fe_bounds[m]["free"], "free_beyond": fe_bounds[m]["free_beyond"],
        "contact": max(table[m]["tip_error_bound_m"]["contact"],
                       fe_bounds[m]["contact"])}} for m in MODELS}


def fe_chart(fe: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    colours = {"l0": "tab:blue", "l1": "tab:orange", "l2": "tab:green",
               "pyelastica": "tab:purple", "fe": "tab:red"}
    fig, axes = plt.subplots(1, 2, figsize=(12, 6.6))
    for ax, key, label in ((axes[0], "tip_error_m", "tip error"),
                           (axes[1], "d2_error_m", "D2 error")):
        front = fe["pareto_tip" if key == "tip_error_m" else "pareto_d2"]
        for point in fe["summary"]:
            marker = {"paper": "s", "FE": "o", "": "*"}[point["calibration"]]
            ax.plot(point["cost_s"] * 1e6, max(point[key] * 1e3, 1e-2), marker,
                    ms=11 if marker == "*" else 8, color=colours[point["model"]],
                    mfc="none" if marker == "s" else None,
                    label=f"{point['method']} (validated to "
                          f"{point['validated_max_pa'] / 1e3:.0f} kPa)")
        pts = sorted((p for p in fe["summary"] if p["method"] in front),
                     key=lambda p: p["cost_s"])
        ax.plot([p["cost_s"] * 1e6 for p in pts], [max(p[key] * 1e3, 1e-2) for p in pts], "k:",
                lw=1, label="Pareto set")
        ax.set(xscale="log", yscale="log", xlabel="compute time per pose [us] (median)",
               ylabel=f"largest {label} against the FE [mm]",
               title=f"{label.capitalize()} in the validated range (FE at 0.01 mm)")
        ax.grid(True, which="both", alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=8, loc="lower center", ncol=3)
    fig.subplots_adjust(bottom=0.27, wspace=0.25, left=0.07, right=0.98, top=0.94)
    fig.savefig(CHARTS["fe"], dpi=100)
    plt.close(fig)


def fe_report(fe: dict) -> list:
    lines = [
        "## Against the finite-element truth", "",
        "![against the FE](speed_accuracy_fe.png)", "",
        "The FE truth (`config/fe3d_reference.yaml`, `scripts/bench_fe.py --3d-only`; "
        f"w = {fe['fe_width_mm']:g} mm, {fe['fe_element_size_m'] * 1e3:.1f} mm mesh, "
        f"{fe['fe_cost_s']:.1f} s per pressure in its sweep) is one finger in 3-D with side "
        "walls: the silicone's Yeoh law in full, pressure following the walls, contact between "
        "neighbouring blocks and within each cavity, no gravity. "
        "PyElastica is the rod driven by L1's law, so it shares L1's bending law and its "
        "calibration; its D2 is taken on its backbone with L1's chamber surfaces. Each model runs "
        "with the paper's calibration (`type_II`) and with its law's calibration fitted to the FE "
        "(`type_II_fe` for L0; `type_II_fe_l1` for L1, L2 and PyElastica); free bending from the "
        f"FE's vacuum limit ({fe['fe_vacuum_limit_kpa']:.0f} kPa; below 0 the fingers are taken "
        "as not meeting, bending on past the centre line as the FE's single finger does) to "
        "+50 kPa. Errors are the largest in each model's validated range.", "",
        "| model | validated to | median cost per pose | tip error [mm] | D2 error [mm] |",
        "|---|---|---|---|---|"]
    for p in fe["summary"]:
        cost = (f"{p['cost_s']:.1f} s" if p["cost_s"] > 0.1 else f"{p['cost_s'] * 1e6:.1f} us")
        lines.append(f"| {p['method']} | {p['validated_max_pa'] / 1e3:.0f} kPa | {cost} | "
                     f"{p['tip_error_m'] * 1e3:.2f} | {p['d2_error_m'] * 1e3:.2f} |")
    lines += [
        "", f"Pareto set, tip error: {', '.join(fe['pareto_tip'])}. D2 error: "
        f"{', '.join(fe['pareto_d2'])}.", "",
        "Tip error bounds against the FE with each law fitted to it (the law's own error, which "
        "is what the choice between models trades against cost): " + "; ".join(
            f"{m.upper()} {b['free'] * 1e3:.2f} mm to 46 kPa, {b['free_beyond'] * 1e3:.2f} mm "
            f"beyond, {b['contact'] * 1e3:.2f} mm in the FE's clamp scenes"
            for m, b in fe["fe_bounds"].items()) + ". "
        "`fidelity: auto` reads these in free bending (from the pressures each calibration was "
        "fitted to; at the held-out ones: " + "; ".join(
            f"{m.upper()} {c['free']['largest_error_m'] * 1e3:.2f} mm"
            + ("" if c["free"]["holds"] else " (exceeds its bound)")
            for m, c in fe["fe_checks"].items() if "free" in c) + "). No law is within 1 mm of "
        "the FE, so the default `tolerance_m` is 10 mm (it was 1 mm against PyElastica, which "
        "shares L1's law): with 1 mm every free pose would warn. The bounds are each law's own "
        "error after a calibration to the truth; with the paper's calibration (the default "
        "`gripper_model`, type_II) the FE lies far away (table below), a gap between the "
        "paper and the FE, not between the laws: calibrate to your gripper "
        "(`softgrip_calibrate`). In contact, `fidelity: auto` takes the larger of each model's "
        "error against PyElastica and against the FE's clamp scenes (table after the next).",
        "",
        "| pressure | calibration | " + " | ".join(
            f"{m} tip / D2 [mm]" for m in ("L0", "L1", "L2", "PyElastica")) + " |",
        "|---|---|---|---|---|---|"]
    for r in fe["points"]:
        lines.append(f"| {r['pressure_pa'] / 1e3:.0f} kPa | {r['calibration']} | " + " | ".join(
            f"{r['tip_error_m'][m] * 1e3:.2f} / {r['d2_error_m'][m] * 1e3:.2f}"
            for m in FE_METHODS) + " |")
    lines += ["", "The FE's clamp scenes, each law fitted to the FE: the tip's error (mm); L2 "
              "places the object, L0 and L1 do not.", "",
              "| scene | pressure | touching | L0 | L1 | L2 |", "|---|---|---|---|---|---|"]
    for r in fe["contact_points"]:
        lines.append(f"| {r['scene']} | {r['pressure_pa'] / 1e3:+.0f} kPa | "
                     f"{'yes' if r['touching'] else 'no'} | " + " | ".join(
                         f"{r['tip_error_m'][m] * 1e3:.2f}" for m in MODELS) + " |")
    return lines + [""]


def charts(result: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    kin = result["kinematics"]
    colours = {"l0": "tab:blue", "l1": "tab:orange", "l2": "tab:green", "reference": "tab:red"}
    markers = {"free": "o", "free_beyond": "^", "contact": "s"}
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 5.4))
    for point in kin["points"]:
        for model in MODELS:
            left.plot(point["cost_s"][model] * 1e6,
                      max(point["error_m"][model], 1e-7) * 1e3, markers[point["scene_class"]],
                      color=colours[model], alpha=0.75, ms=6)
        left.plot(point["reference_s"] * 1e6, 1e-4, markers[point["scene_class"]],
                  color=colours["reference"], ms=6, alpha=0.75)
    for model, colour in colours.items():
        left.plot(
            [], [], "o", color=colour, label={
                "l0": "L0 (validated: free, <= 46 kPa)", "l1": "L1 (free, 0-60 kPa)",
                "l2": "L2 (free and contact)",
                "reference": "PyElastica (the reference; plotted at 1e-4 mm)"
            }[model])
    for scene_class, marker in markers.items():
        left.plot([], [], marker, color="grey", label=scene_class.replace("_", " "))
    left.axhline(TOLERANCE_M * 1e3, ls="--", color="grey", lw=1)
    left.text(2e3, TOLERANCE_M * 1e3 * 1.15, "auto's default tolerance", color="grey", fontsize=8)
    left.set(xscale="log", yscale="log", xlabel="compute time per pose [us] (median)",
             ylabel="tip error against the reference [mm]",
             title="Kinematics: accuracy against cost")
    left.grid(True, which="both", alpha=0.3)
    # below: no point hidden
    left.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.15), ncol=3)
    free = [p for p in kin["points"] if p["scene_class"] != "contact"]
    pressures = [p["pressure_pa"] / 1e3 for p in free]
    for model in MODELS:
        right.plot(pressures, [max(p["error_m"][model], 1e-7) * 1e3 for p in free], "o-",
                   color=colours[model], label=model.upper())
    right.axvspan(kin["validated_max_pa"] / 1e3, 60, color="grey", alpha=0.15,
                  label="beyond the validated range")
    right.set(yscale="log", xlabel="gauge pressure [kPa]",
              ylabel="tip error against the reference [mm]",
              title="Free bending: error against pressure")
    _finish(plt, fig, right, CHARTS["kinematics"])

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for point in result["estimators"]:
        ax.plot(max(point["cost_us"], 0.1), point["rmse_pa"], "D" if point["cost_us"] else "x",
                ms=9, label=point["method"])
    ax.set(xscale="log", yscale="log", xlabel="cost of a step [us] (raw sensors plotted at 0.1)",
           ylabel="RMSE against truth [Pa]", title="Pressure estimators: accuracy against cost")
    _finish(plt, fig, ax, CHARTS["estimators"])

    fig, ax = plt.subplots(figsize=(7.2, 4.6))
    integ = result["integrators"]
    for method, style in (("explicit Euler", "o-"), ("backward Euler (ours)", "s-"),
                          (EXTRAPOLATED, "D-"), ("RK45", "^-"), ("LSODA", "v-")):
        pts = [p for p in integ["points"] if p["method"] == method]
        ax.plot([p["cost_s"] * 1e3 for p in pts], [min(p["error_pa"], 1e9) for p in pts], style,
                label=method)
        for p in pts:
            if method.endswith("Euler") or p["setting"].startswith("rtol 1e-03"):
                ax.annotate(p["setting"], (p["cost_s"] * 1e3, min(p["error_pa"], 1e9)), fontsize=6,
                            alpha=0.7)
    for key, text in (("euler_ripple_over_200pa_from_dt_s", "Euler ripple > 200 Pa"),
                      ("euler_unphysical_from_dt_s", "Euler unphysical")):
        dt = integ[key]
        match = [p for p in integ["points"] if p["method"] == "explicit Euler" and p["dt_s"] == dt]
        if match:
            ax.plot(match[0]["cost_s"] * 1e3, min(match[0]["error_pa"], 1e9), "rx", ms=14, mew=2)
            ax.annotate(f"{text} (dt {dt:g} s)",
                        (match[0]["cost_s"] * 1e3, min(match[0]["error_pa"], 1e9)), color="red",
                        fontsize=8, xytext=(10, -12), textcoords="offset points")
    ax.set(xscale="log", yscale="log", xlabel="cost of 0.3 s of simulation [ms] (median)",
           ylabel="largest error against LSODA rtol 1e-10 [Pa]",
           title="Plant integrators (25 kPa fill; red: stiff-case failures)")
    _finish(plt, fig, ax, CHARTS["integrators"])


def _finish(plt, fig, ax, path) -> None:
    """Grid and legend on ``ax``, then save and close ``fig``."""
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def target_rows(result: dict) -> list:
    """The issue's targets as markdown table rows (header included)."""
    kin, bounds, auto = result["kinematics"], result["bounds"], result["auto"]
    finger = result["finger_length_m"]
    free = [p for p in kin["points"] if p["scene_class"] == "free"]
    contact = [p for p in kin["points"] if p["scene_class"] == "contact"]
    ref_free = statistics.median(p["reference_s"] for p in free)
    ref_contact = statistics.median(p["reference_s"] for p in contact)
    l0_speedup = ref_free / bounds["l0"]["median_cost_s"]
    l2_speedup = ref_contact / bounds["l2"]["median_contact_cost_s"]
    l2_error = max(p["error_m"]["l2"] for p in kin["points"])
    rest = kin["rest_tip"]
    l0_rel = max(p["error_m"]["l0"] /
                 math.hypot(p["l1_tip"][0] - rest[0], p["l1_tip"][1] - rest[1]) for p in free
                 if p["pressure_pa"] > 0)
    l0_check = result["fe"]["fe_checks"]["l0"]["free"]
    targets = [
        ("L0 faster than the reference per pose", f"{l0_speedup:,.0f}x", ">= 1,000x", l0_speedup
         >= 1000),
        ("L0 within its validated error bound: largest error against the FE at the held-out "
         "free pressures (" + ", ".join(f"{h / 1e3:g}" for h in HELD_OUT_PRESSURES_PA
                                        if _fe_class(h) == "free")
         + " kPa; L0 fitted to the FE without them) against the bound from the others",
         f"{1e3 * l0_check['largest_error_m']:.2f} mm / {1e3 * l0_check['bound_m']:.2f} mm",
         "<= the bound", l0_check["holds"]),
        ("*Comparison, not the target:* L0 error against the reference in its validated range, "
         "per tip displacement", f"{100 * l0_rel:.2f} %",
         "<= 3.5 % would match the paper's linear-law accuracy against its FEA", l0_rel <= 0.035),
        ("L2 faster than PyElastica, contact scenes", f"{l2_speedup:,.0f}x", ">= 20x", l2_speedup
         >= 20),
        ("L2 tip error against PyElastica, all scenes",
         f"{1e3 * l2_error:.3f} mm = {100 * l2_error / finger:.2f} % of the finger",
         "<= 2 % of the finger length", l2_error <= 0.02 * finger),
        ("auto's median cost in the demo grasp against the cheapest (L0)",
         f"{auto['median_cost_ratio']:.2f}x", "<= 1.5x", auto["median_cost_ratio"] <= 1.5),
        ("auto's largest error in the validated range, held-out points included (free bending "
         f"against the FE: {auto['chosen']['free'].upper()}; contact against PyElastica: "
         f"{auto['chosen']['contact'].upper()})", f"{1e3 * auto['worst_error_m']:.3f} mm",
         f"<= tolerance {1e3 * auto['tolerance_m']:.1f} mm", auto["worst_error_m"]
         <= auto["tolerance_m"]),
        ("*Reported:* auto beyond 46 kPa, outside every law's validated range (it warns "
         f"there), {auto['chosen']['free_beyond'].upper()} against the FE",
         f"{1e3 * auto['worst_beyond_error_m']:.2f} mm", "reported", True),
    ]
    return (["| target | measured | wanted | |", "|---|---|---|---|"] + [
        f"| {name} | {value} | {want} | {'meets' if ok else '**misses**'} |"
        for name, value, want, ok in targets
    ])


def report(result: dict, command: str) -> str:
    kin, bounds, auto = result["kinematics"], result["bounds"], result["auto"]
    lines = [
        "# Speed against accuracy", "",
        f"Command: `{command}` ({machine_line()}). Figures vary by 10-30 % between runs on this "
        "shared machine; "
        "ratios are taken within one run. Two references: the finite-element finger "
        "(`softgrip_ros.model.fe`), the independent truth of the material and geometry, in "
        "free bending; and a dynamic Cosserat rod in PyElastica "
        f"({result['reference']}), driven by L1's segment moments and run to rest with "
        "damping (`softgrip_ros.model.reference`; what it captures that L0-L2 do not is in its "
        "docstring), which judges rod mechanics and the contact scenes the FE does not model. "
        "The error bounds `fidelity: auto` reads are against the FE in free bending (each law "
        "fitted to it: the law's own error) and against PyElastica in contact.",
        "", "## Targets", ""
    ] + target_rows(result)
    lines += [""] + fe_report(result["fe"])
    lines += [
        "## Kinematics against PyElastica", "", "![kinematics](speed_accuracy_kinematics.png)", "",
        "Tip error against the reference (mm) and the median cost of one pose (us). Free bending "
        "uses the same "
        "L1 law in the reference, so L1 and L2 there differ from it only by the rod's axial "
        "stretch, shear and "
        "discretisation; L0's error is its linear law. In contact scenes L0 and L1 ignore the "
        "object.", "",
        "**Read the free-bending errors with care.** The reference is driven by L1's segment "
        "moments (the issue's "
        "\"same segment moments\"), so it arbitrates rod mechanics, not the material law: L0's "
        "free-bending error "
        "here is the gap between the two laws, and against the paper's own numbers (table below) "
        "L0 is the closer "
        "one at 50 kPa (D2 fitted, 0 %) while L1 overshoots D2 by about 20 %. So `auto` no "
        "longer takes its free-bending bounds from here but from the FE section above, which "
        "settles which law is right. Measured per tip displacement, the gap between the laws "
        "is far above the paper's 3.5 % "
        "(the targets table shows it as a comparison): at low pressure the L1 law bends less than "
        "the linear "
        "one for the same gain, and a separate L1 calibration (tried: gain 5.08, c_b 2.88e-6 1/Pa "
        "fitted to "
        "the same alpha and D2) still left 18 % at 5 kPa.", "",
        "| case | class | L0 err | L1 err | L2 err | L0 us | L1 us | L2 us | reference s | force "
        "L2 / ref [N] |", "|---|---|---|---|---|---|---|---|---|---|"
    ]
    for p in kin["points"]:
        force = (f"{p['l2_force_n']:.3f} / {p['reference_force_n']:.3f}"
                 if p["scene_class"] == "contact" else "")
        lines.append(f"| {p['case']} | {p['scene_class']} | " +
                     " | ".join(f"{1e3 * p['error_m'][m]:.3f}" for m in MODELS) + " | " +
                     " | ".join(f"{1e6 * p['cost_s'][m]:.1f}"
                                for m in MODELS) + f" | {p['reference_s']:.2f} | {force} |")
    lines += [
        "",
        "Error bounds written to `config/model_error_bounds.yaml` (the largest error per scene "
        "class: free bending against the FE, each law fitted to it; contact against PyElastica; "
        "`fidelity: auto` picks the cheapest model whose bound meets `tolerance_m`, "
        f"{1e3 * TOLERANCE_M:.0f} mm by default):", "",
        "| model | free [mm] | free beyond 46 kPa [mm] | contact [mm] | median cost, free [us] | "
        "median cost, contact [us] |", "|---|---|---|---|---|---|"
    ]
    for m in MODELS:
        b = bounds[m]["tip_error_bound_m"]
        lines.append(f"| {m.upper()} | {1e3 * b['free']:.3f} | {1e3 * b['free_beyond']:.3f} | "
                     f"{1e3 * b['contact']:.2f} | "
                     f"{1e6 * bounds[m]['median_cost_s']:.1f} | "
                     f"{1e6 * bounds[m]['median_contact_cost_s']:.1f} |")
    lines += [
        "", "Held-out scenes (not used for the PyElastica bounds; their errors in mm against "
        "PyElastica, checked against those bounds, which the file keeps for contact):",
        "", "| case | class | L0 err | L1 err | L2 err |", "|---|---|---|---|---|"
    ]
    for p in result["held_out"]["points"]:
        lines.append(f"| {p['case']} | {p['scene_class']} | " +
                     " | ".join(f"{1e3 * p['error_m'][m]:.3f}" for m in MODELS) + " |")
    broken = [
        f"{m.upper()} {c.replace('_', ' ')} ({1e3 * v['largest_error_m']:.3f} > "
        f"{1e3 * v['bound_m']:.3f} mm)" for m, classes in result["bound_checks"].items()
        for c, v in classes.items() if not v["holds"]
    ]
    lines += [
        "", "Every bound holds at the held-out scenes."
        if not broken else "Bounds exceeded at held-out scenes: " + "; ".join(broken) + "."
    ]
    lines += [
        "",
        "Against the paper's points (D1, D2 in mm; L2 equals L1 in free bending, the reference "
        "has no "
        "chamber ballooning so it is not compared here):", "", "| quantity | paper | L0 | L1 |",
        "|---|---|---|---|"
    ]
    for row in result["paper_rows"]:
        lines.append(f"| {row['quantity']} | {row['paper']:.2f} | {row['l0']:.2f} "
                     f"({row['l0_err_pct']:+.1f} %) | "
                     f"{row['l1']:.2f} ({row['l1_err_pct']:+.1f} %) |")
    lines += [
        "", "Pareto (non-dominated in median cost and largest error), per scene class: " +
        "; ".join(f"{c}: {', '.join(v)}" for c, v in result["pareto"]["kinematics"].items()) + ".",
        "", "## Auto fidelity in the demo grasp", "",
        "The demo's pressure trace (open to 17 kPa, clamp a 40 mm cylinder to -10 kPa, hold, "
        "vent; 760 samples "
        "at 200 Hz with 80 Pa noise) through `SceneModel`: auto median "
        f"{1e6 * auto['costs']['auto']['median_s']:.1f} us "
        f"(mean {1e6 * auto['costs']['auto']['mean_s']:.1f} us, "
        f"{auto['costs']['auto']['l2_solves']} L2 solves), "
        f"L0 everywhere median {1e6 * auto['costs']['l0']['median_s']:.1f} us. L2 runs again only "
        "when the pressure "
        "moves by more than 200 Pa and at most every 0.1 s, so neither the clamp's sweep nor the "
        "hold solves at every sample.", "", "## Estimators", "",
        "![estimators](speed_accuracy_estimators.png)", "",
        "| method | cost of a step [us] | RMSE [Pa] |", "|---|---|---|"
    ]
    lines += [
        f"| {p['method']} | {p['cost_us']:.1f} | {p['rmse_pa']:.1f} |"
        for p in result["estimators"]
    ]
    lines += [
        "", f"Pareto: {', '.join(result['pareto']['estimators'])}.", "", "## Plant integrators",
        "", "![integrators](speed_accuracy_integrators.png)", "",
        "Error and cost: the device's chamber filled to 25 kPa (0.3 s) against LSODA at rtol "
        "1e-10. Stiff columns: "
        "the 1 mL rigid chamber filled to 30 kPa (0.5 s), its ripple about the known equilibrium "
        "in the last 20 %.", "",
        "| method | setting | cost [ms] | largest error [Pa] | stiff ripple [Pa] | stiff physical "
        "|", "|---|---|---|---|---|---|"
    ]
    for p in result["integrators"]["points"]:
        lines.append(
            f"| {p['method']} | {p['setting']} | {1e3 * p['cost_s']:.2f} | {p['error_pa']:.3g} | "
            f"{p['stiff_ripple_pa']:.3g} | {p['stiff_physical']} |")
    integ = result["integrators"]
    lines += [
        "", "On the stiff chamber, explicit Euler's ripple exceeds 200 Pa from dt = "
        f"{integ['euler_ripple_over_200pa_from_dt_s']:g} s and it "
        "leaves the physical range (below vacuum, or not finite) from dt = "
        f"{integ['euler_unphysical_from_dt_s']:g} s; "
        "backward Euler stays monotone and settles at every dt (pinned in "
        "tests/test_model_pneumatics.py). The extrapolated step (three backward-Euler solves, "
        "combined to second order; the simulated device's truth, at dt 1e-3 s) keeps that and "
        "is second order. "
        f"Pareto: {', '.join(result['pareto']['integrators'])}.", ""
    ]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = benchmark_parser(
        __doc__, "a few points on a coarse reference; writes nothing", 5,
        "timed repeats per point (median)",
        json_help="print the points and pareto lists as JSON, write nothing")
    args = parser.parse_args(argv)
    if args.quick:
        args.repeat = 3
    started = time.perf_counter()
    l1 = build_kinematics("l1")
    rod = RodFinger(l1.geometry, l1.calibration)
    reference = (ReferenceFinger(rod, elements_per_segment=QUICK["elements_per_segment"])
                 if args.quick else ReferenceFinger(rod))
    kinematics = kinematics_points(args.repeat, reference, rod, quick=args.quick)
    table = error_bounds(kinematics)
    held_out_scenes = held_out_cases(rod)
    if args.quick:
        held_out_scenes = [held_out_scenes[1], held_out_scenes[-1]]
    held_out = kinematics_points(args.repeat, reference, rod, held_out_scenes, "held-out scenes",
                                 timed=False)
    fe = fe_points(args.repeat, args.quick)
    chosen_from = auto_table(table, fe["fe_bounds"])
    bounds = ErrorBounds({m: v["tip_error_bound_m"]
                          for m, v in chosen_from.items()},
                         {m: v["median_cost_s"]
                          for m, v in chosen_from.items()}, "this run")
    result = {
        "kinematics": kinematics, "bounds": chosen_from, "pyelastica_bounds": table,
        "finger_length_m": l1.geometry.total_length_m, "fe": fe,
        "reference": f"{reference.rod.elements_per_segment} elements per segment",
        "estimators": estimator_points(args.repeat), "integrators": integrator_points(
            args.repeat, QUICK["integrator_steps_s"] if args.quick else INTEGRATOR_STEPS_S),
        "auto": auto_points(rod, bounds, kinematics, held_out, fe), "held_out": held_out,
        "bound_checks": bound_checks(held_out, table), "paper_rows": [{
            "quantity": r.quantity, "paper": r.paper, "l0": r.l0_calibrated, "l1": r.l1,
            "l0_err_pct": r.error_pct(r.l0_calibrated), "l1_err_pct": r.error_pct(r.l1)
        } for r in paper_rows() if r.unit == "mm"]
    }
    result["pareto"] = {
        "fe_tip": result["fe"]["pareto_tip"], "fe_d2": result["fe"]["pareto_d2"],
        "kinematics": kinematics_pareto(kinematics),
        "estimators": pareto(result["estimators"], "cost_us", "rmse_pa", "method"),
        "integrators": pareto(
            [p for p in result["integrators"]["points"] if math.isfinite(p["error_pa"])], "cost_s",
            "error_pa", "method")
    }
    if args.json:
        print(strict_json(result))
        return 0
    if args.quick:
        print("\n".join(target_rows(result)))
        return 0
    write_bounds(chosen_from, l1.geometry.total_length_m, reference, fe)
    charts(result)
    fe_chart(result["fe"])
    DOC.write_text(report(result, "python scripts/bench_speed_accuracy.py") + "\n")
    update_section(
        "bench_speed_accuracy", "## Speed against accuracy (`scripts/bench_speed_accuracy.py`)\n\n"
        f"Command: `python scripts/bench_speed_accuracy.py` ({machine_line()}; needs "
        "`scripts/setup.sh "
        "--with-reference`). The issue's targets; every point, chart and the error bounds are in "
        "[speed_vs_accuracy.md](speed_vs_accuracy.md).\n\n" + "\n".join(target_rows(result)))
    print(DOC.read_text().split("## Kinematics")[0])
    print(
        f"done in {time.perf_counter() - started:.0f} s; wrote {DOC.relative_to(ROOT)}, "
        f"{BOUNDS.relative_to(ROOT)} "
        f"and {', '.join(str(c.relative_to(ROOT)) for c in CHARTS.values())}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())

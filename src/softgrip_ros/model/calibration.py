"""Calibration of the bending model against the paper's numbers, with its provenance.

What is fitted, to what (type II), and what is held out:

=========================  ==============================================  ===========
constants                  fitted to                                       count
=========================  ==============================================  ===========
saturation p_sat, width w  FEA curvature growth 50->55 kPa (7.5 %) and     2 for 2
                           55->60 kPa (0.61 %)
gain g, ballooning c_b     alpha(25 kPa) = 68.4 deg, D2(50 kPa) = 151 mm   2 for 2
=========================  ==============================================  ===========

Held out and predicted: D1 at 0 and 50 kPa (16 and 94.3 mm), the linear model's
agreement with the FEA below 45 kPa. Types I and III get their own gain from their
alpha(25 kPa) alone and inherit the rest from type II.

All fits use L0; L1 uses the same constants ("one calibration"), so its error
against the paper is a prediction too.
"""
from __future__ import annotations

import dataclasses
import datetime
import math
import pathlib

import yaml

from softgrip_ros.fileio import write_text_atomically
from softgrip_ros.model.bending import BendingCalibration, Saturation
from softgrip_ros.model.geometry import FingerGeometry, load_geometry
from softgrip_ros.model.kinematics import GripperKinematics
from softgrip_ros.model.material import YeohMaterial

CALIBRATION_FILE = "model_calibration.yaml"
PAPER_FILE = "paper_results.yaml"


@dataclasses.dataclass(frozen=True)
class PaperNumbers:
    """The numbers of paper_results.yaml used here, in SI units."""

    material: YeohMaterial
    alpha_25kpa_rad: dict  # cavity type -> alpha at 25 kPa
    d1_0_m: float
    d1_50kpa_m: float
    d2_0_m: float
    d2_50kpa_m: float
    growth_50_55: float  # fractional curvature growth
    growth_55_60: float
    validated_max_pressure_pa: float
    linear_model_max_error: float  # model vs FEA below 45 kPa, fraction

    @classmethod
    def load(cls, path=None) -> "PaperNumbers":
        if path is None:
            from softgrip_ros.config_paths import config_file
            path = config_file(PAPER_FILE)
        with pathlib.Path(path).open() as handle:
            doc = yaml.safe_load(handle)
        alpha = doc["included_angle_alpha"]
        curvature = doc["curvature_vs_pressure_type_II"]
        return cls(
            material=YeohMaterial(doc["material"]["C10_MPa"] * 1e6,
                                  doc["material"]["C20_MPa"] * 1e6),
            alpha_25kpa_rad={
                f"type_{name.split('_')[1]}": math.radians(entry["alpha_deg"])
                for name, entry in alpha.items() if name.startswith("type_")
            },
            d1_0_m=doc["root_spacing_D1_type_II"]["p0_mm"] * 1e-3,
            d1_50kpa_m=doc["root_spacing_D1_type_II"]["p50_mm"] * 1e-3,
            d2_0_m=doc["tip_spacing_D2_type_II"]["p0_mm"] * 1e-3,
            d2_50kpa_m=doc["tip_spacing_D2_type_II"]["p50_mm"] * 1e-3,
            growth_50_55=curvature["fea_curvature_growth_50_to_55_kPa_pct"] / 100.0,
            growth_55_60=curvature["fea_curvature_growth_55_to_60_kPa_pct"] / 100.0,
            validated_max_pressure_pa=curvature["stable_and_in_line_with_model_up_to_kPa"] * 1e3,
            linear_model_max_error=curvature["model_vs_fea_max_error_pct_up_to_45kPa"] / 100.0,
        )


def mean_curvature_per_m(kinematics: GripperKinematics, pressure_pa: float) -> float:
    """Total backbone bend over the bending length (1/m), the paper's Fig. 18 quantity."""
    thetas = kinematics.bending.angles(float(pressure_pa))
    return sum(thetas) / (len(thetas) * kinematics.geometry.segment_length_m)


def _least_squares(*args, **kwargs):
    """scipy's least_squares, imported when a fit runs: the nodes load this module for the
    calibration alone, and scipy.optimize costs them a third of a second and MBs at start."""
    from scipy.optimize import least_squares
    return least_squares(*args, **kwargs)


def fit_saturation(growth_50_55: float, growth_55_60: float) -> tuple[float, float]:
    """(p_sat, w) in Pa such that p_eff grows by the two FEA fractions."""

    def residuals(params):
        p_sat, width = params * 1e3
        sat = Saturation(
            BendingCalibration(saturation_pressure_pa=p_sat, saturation_width_pa=width))
        e50, e55, e60 = (sat.effective_pressure(p * 1e3) for p in (50.0, 55.0, 60.0))
        return [(e55 / e50 - 1.0 - growth_50_55) * 100.0, (e60 / e55 - 1.0 - growth_55_60) * 100.0]

    fit = _least_squares(residuals, x0=[55.0, 2.0], bounds=([40.0, 0.1], [80.0, 20.0]),
                         xtol=1e-14, ftol=1e-14)
    if max(abs(r) for r in fit.fun) > 1e-6:
        raise RuntimeError(
            f"saturation fit did not converge: residuals {fit.fun} (percentage points)")
    return float(fit.x[0] * 1e3), float(fit.x[1] * 1e3)


def calibrate_type_ii(geometry: FingerGeometry, paper: PaperNumbers) -> BendingCalibration:
    p_sat, width = fit_saturation(paper.growth_50_55, paper.growth_55_60)

    def model(gain, compliance):
        return GripperKinematics(
            geometry,
            BendingCalibration(gain=float(gain), ballooning_compliance_per_pa=float(compliance),
                               saturation_pressure_pa=p_sat, saturation_width_pa=width,
                               validated_max_pressure_pa=paper.validated_max_pressure_pa),
            material=paper.material, model="l0", max_pressure_pa=60e3)

    def residuals(params):
        kin = model(params[0], params[1] * 1e-6)
        return [
            (kin.pose(25e3).included_angle_rad / paper.alpha_25kpa_rad["type_II"] - 1.0) * 100.0,
            (kin.pose(50e3).tip_spacing_m / paper.d2_50kpa_m - 1.0) * 100.0
        ]

    fit = _least_squares(residuals, x0=[5.0, 0.1], bounds=([0.01, 0.0], [100.0, 100.0]),
                         xtol=1e-14, ftol=1e-14)
    if max(abs(r) for r in fit.fun) > 1e-6:
        raise RuntimeError(f"type II calibration did not converge: residuals {fit.fun} %")
    return model(fit.x[0], fit.x[1] * 1e-6).calibration


def calibrate_gain_from_alpha(geometry: FingerGeometry, paper: PaperNumbers,
                              alpha_25kpa_rad: float,
                              base: BendingCalibration) -> BendingCalibration:
    """A type's own gain from its alpha at 25 kPa, everything else from ``base``."""

    def residual(params):
        calibration = dataclasses.replace(base, gain=float(params[0]))
        kin = GripperKinematics(geometry, calibration, material=paper.material, model="l0")
        return [(kin.pose(25e3).included_angle_rad / alpha_25kpa_rad - 1.0) * 100.0]

    fit = _least_squares(residual, x0=[base.gain], bounds=([1e-3], [1e3]), xtol=1e-14, ftol=1e-14)
    return dataclasses.replace(base, gain=float(fit.x[0]))


def calibrate_all(paper: PaperNumbers, geometry_path=None, fe_reference=None) -> dict:
    """Calibrations of types II, I and III from the paper, keyed by type name; with
    ``fe_reference`` (softgrip_ros.model.fe_data.FEReference, the FE truth) also type II's L0
    and L1 fitted to the FE (type_II_fe, type_II_fe_l1)."""
    type_ii = calibrate_type_ii(load_geometry("type_II", geometry_path), paper)
    result = {"type_II": type_ii}
    for name in ("type_I", "type_III"):
        result[name] = calibrate_gain_from_alpha(load_geometry(name, geometry_path), paper,
                                                 paper.alpha_25kpa_rad[name], type_ii)
    if fe_reference is not None:
        from softgrip_ros.model.fe_data import FE_CALIBRATION_NAMES, fit_to_fe
        for law, name in FE_CALIBRATION_NAMES.items():
            result[name] = fit_to_fe(load_geometry(name, geometry_path), fe_reference, law)
    return result


def write_calibration(calibrations: dict, path, paper_path: str) -> None:
    doc = {
        "provenance": {
            "date": datetime.date.today().isoformat(),
            "data": f"{paper_path}: alpha(25 kPa) per type, D2(50 kPa) type II, FEA curvature "
                    "growth 50-55-60 kPa",
            "method": (
                "softgrip_ros.model.calibration (scripts/validate_model.py --calibrate): "
                "L0 model; saturation (2 constants) solved from the 2 growth figures; "
                "type II gain and ballooning compliance (2 constants) solved from alpha(25 kPa) "
                "and D2(50 kPa) by least squares (exactly determined); types I and III: "
                "gain only, from their alpha(25 kPa). Held out: D1(0), D1(50 kPa)."),
            "fe_types": (
                "type_II_fe (L0) and type_II_fe_l1 (L1): gain and ballooning compliance fitted "
                "by least squares to the FE truth's alpha(p) and D2(p) at its positive "
                "pressures (config/fe3d_reference.yaml: the 3-D FE with contact at its default "
                "width; softgrip_ros.model.fe_data.fit_to_fe), 15 and 35 kPa held out; no "
                "saturation."),
        },
        "types": {
            name: {
                field.name: float(getattr(cal, field.name))
                for field in dataclasses.fields(cal)
            }
            for name, cal in calibrations.items()
        },
    }
    write_text_atomically(path, "# Bending-model calibration, written by "
                          "scripts/validate_model.py --calibrate. Do not edit by hand.\n"
                          + yaml.safe_dump(doc, sort_keys=False))


def load_calibration(cavity_type: str = "type_II", path=None) -> BendingCalibration:
    if path is None:
        from softgrip_ros.config_paths import config_file
        path = config_file(CALIBRATION_FILE)
    with pathlib.Path(path).open() as handle:
        doc = yaml.safe_load(handle)
    try:
        entry = doc["types"][cavity_type]
    except (KeyError, TypeError):
        raise ValueError(f"{path}: no calibration for cavity type {cavity_type!r}") from None
    return BendingCalibration(**{k: float(v) for k, v in entry.items()})


def build_kinematics(model: str = "l0", gripper_model: str = "type_II",
                     max_pressure_pa: float = 50e3) -> GripperKinematics:
    """The calibrated model of one gripper: a built-in cavity type or a user's calibration
    (see softgrip_ros.model.gripper_models)."""
    from softgrip_ros.model.gripper_models import resolve
    geometry, calibration = resolve(gripper_model)
    return GripperKinematics(geometry, calibration, model=model, max_pressure_pa=max_pressure_pa)

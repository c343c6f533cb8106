"""The model against the paper: the numbers behind scripts/validate_model.py.

Three variants of type II are compared: L0 uncalibrated (g = 1, no ballooning, no
saturation: eq. 16-17 exactly as mapped), L0 calibrated, and L1 with the same
calibration. Each quantity says whether its paper value was used by the fit
("fitted") or not ("held out"), so a match can be told from a prediction.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from softgrip_ros.model.bending import BendingCalibration
from softgrip_ros.model.calibration import PaperNumbers, load_calibration, mean_curvature_per_m
from softgrip_ros.model.geometry import load_geometry
from softgrip_ros.model.kinematics import GripperKinematics


@dataclasses.dataclass(frozen=True)
class Row:
    quantity: str
    unit: str
    paper: float
    role: str  # "fitted", "held out", "geometry"
    l0_uncalibrated: float
    l0_calibrated: float
    l1: float
    pressure_pa: float  # where the quantity is taken (for the "validated range" column)

    def error_pct(self, value: float) -> float:
        return 100.0 * (value - self.paper) / self.paper if self.paper else math.nan


def models(cavity_type: str = "type_II"):
    geometry = load_geometry(cavity_type)
    calibrated = load_calibration(cavity_type)
    uncalibrated = BendingCalibration(
        gain=1.0, validated_max_pressure_pa=calibrated.validated_max_pressure_pa)
    kwargs = dict(max_pressure_pa=GripperKinematics.MODEL_MAX_PRESSURE_PA)
    return (GripperKinematics(geometry, uncalibrated, model="l0", **kwargs),
            GripperKinematics(geometry, calibrated, model="l0", **kwargs),
            GripperKinematics(geometry, calibrated, model="l1", **kwargs))


def _growth_pct(kin, low, high):
    return 100.0 * (mean_curvature_per_m(kin, high) / mean_curvature_per_m(kin, low) - 1.0)


def rows(paper: PaperNumbers | None = None) -> list[Row]:
    paper = paper or PaperNumbers.load()
    variants = models()

    def each(function):
        return [function(kin) for kin in variants]

    table = [
        Row("alpha at 0 kPa", "deg", 15.0, "geometry",
            *each(lambda k: math.degrees(k.pose(0.0).included_angle_rad)), 0.0),
        Row("alpha at 25 kPa", "deg", math.degrees(paper.alpha_25kpa_rad["type_II"]), "fitted",
            *each(lambda k: math.degrees(k.pose(25e3).included_angle_rad)), 25e3),
        Row("D2 at 0 kPa", "mm", paper.d2_0_m * 1e3, "geometry",
            *each(lambda k: k.pose(0.0).tip_spacing_m * 1e3), 0.0),
        Row("D2 at 50 kPa", "mm", paper.d2_50kpa_m * 1e3, "fitted",
            *each(lambda k: k.pose(50e3).tip_spacing_m * 1e3), 50e3),
        Row("D1 at 0 kPa", "mm", paper.d1_0_m * 1e3, "held out",
            *each(lambda k: k.pose(0.0).root_spacing_m * 1e3), 0.0),
        Row("D1 at 50 kPa", "mm", paper.d1_50kpa_m * 1e3, "held out",
            *each(lambda k: k.pose(50e3).root_spacing_m * 1e3), 50e3),
        Row("curvature growth 50->55 kPa", "%", paper.growth_50_55 * 100, "fitted",
            *each(lambda k: _growth_pct(k, 50e3, 55e3)), 55e3),
        Row("curvature growth 55->60 kPa", "%", paper.growth_55_60 * 100, "fitted",
            *each(lambda k: _growth_pct(k, 55e3, 60e3)), 60e3),
    ]
    return table


def summary(paper: PaperNumbers | None = None) -> dict:
    """The --json figures (calibrated L0, the production model), plus L1 and the uncalibrated
    L0."""
    paper = paper or PaperNumbers.load()
    table = {row.quantity: row for row in rows(paper)}
    validated_max = models()[1].calibration.validated_max_pressure_pa
    in_range = [
        row for row in table.values() if row.pressure_pa <= min(45e3, validated_max) and row.paper
    ]
    result = {
        "alpha_25kPa_deg": table["alpha at 25 kPa"].l0_calibrated,
        "D1_50kPa_mm": table["D1 at 50 kPa"].l0_calibrated,
        "D2_50kPa_mm": table["D2 at 50 kPa"].l0_calibrated,
        "curvature_growth_50_55_pct": table["curvature growth 50->55 kPa"].l0_calibrated,
        "curvature_growth_55_60_pct": table["curvature growth 55->60 kPa"].l0_calibrated,
        "max_model_err_pct_to_45kPa": max(abs(r.error_pct(r.l0_calibrated)) for r in in_range),
        "max_model_err_quantity_to_45kPa": max(
            in_range, key=lambda r: abs(r.error_pct(r.l0_calibrated))).quantity,
        "fitted_constants": 4,
        "fitted_to_numbers": 4,
        "held_out": [r.quantity for r in table.values() if r.role == "held out"],
    }
    for prefix, attribute in (("l1_", "l1"), ("l0_uncalibrated_", "l0_uncalibrated")):
        result[prefix + "alpha_25kPa_deg"] = getattr(table["alpha at 25 kPa"], attribute)
        result[prefix + "D1_50kPa_mm"] = getattr(table["D1 at 50 kPa"], attribute)
        result[prefix + "D2_50kPa_mm"] = getattr(table["D2 at 50 kPa"], attribute)
    return result


# ---- against the FE truth (config/fe3d_reference.yaml, written by scripts/bench_fe.py) -------
FE_KEYS = ("fe_alpha_25kPa_deg", "fe_D2_50kPa_mm", "fe_D1_0kPa_mm", "fe_D1_50kPa_mm",
           "fe_curvature_growth_50_55_pct", "fe_curvature_growth_55_60_pct",
           "fe_verification_error_pct", "fe_mesh_change_pct", "fe_volume_change_pct")
LINEAR_RANGE_PA = 45e3  # the paper: its linear law within 3.5 % of its FEA up to 45 kPa


@dataclasses.dataclass(frozen=True)
class ModelAgainstFE:
    """One model's errors against the FE over the positive sweep (absolute, worst)."""

    name: str
    law: str  # "l0" or "l1"
    calibration: str  # "paper" or "fe"
    alpha_deg_to_45: float
    d2_mm_to_45: float
    tip_mm_to_45: float
    alpha_deg_beyond: float  # 50-60 kPa
    d2_mm_beyond: float
    tip_mm_beyond: float
    tip_mm_held_out: float  # at the FE calibration's held-out pressures


def fe_models():
    """{(law, calibration): (name, kinematics)}: L0 and L1 with the paper's calibration
    (type_II) and with the FE truth's (type_II_fe, type_II_fe_l1)."""
    from softgrip_ros.model.fe_data import FE_CALIBRATION_NAMES
    geometry = load_geometry("type_II")
    top = GripperKinematics.MODEL_MAX_PRESSURE_PA
    out = {}
    for calibration, names in (("paper", {"l0": "type_II", "l1": "type_II"}),
                               ("fe", FE_CALIBRATION_NAMES)):
        for law, name in names.items():
            label = (f"{law.upper()}, paper calibration" if calibration == "paper" else
                     f"{law.upper()}, FE calibration ({name})")
            out[law, calibration] = (label, GripperKinematics(
                geometry, load_calibration(name), model=law, max_pressure_pa=top))
    return out


def against_fe(reference) -> list[ModelAgainstFE]:
    from softgrip_ros.model.fe_data import HELD_OUT_PRESSURES_PA, errors_against_fe
    pressures = [p.pressure_pa for p in reference.positive()]
    result = []
    for (law, calibration), (name, kin) in fe_models().items():
        rows = errors_against_fe(kin, reference, pressures)
        low = [r for r in rows if r[0] <= LINEAR_RANGE_PA]
        high = [r for r in rows if r[0] > LINEAR_RANGE_PA]
        held = [r for r in rows if any(abs(r[0] - h) < 1.0 for h in HELD_OUT_PRESSURES_PA)]

        def worst(selection, column):
            return max(abs(r[column]) for r in selection)

        result.append(ModelAgainstFE(name, law, calibration, worst(low, 1), worst(low, 2),
                                     worst(low, 3), worst(high, 1), worst(high, 2),
                                     worst(high, 3), worst(held, 3)))
    return result


def fe_linearity(reference) -> tuple[float, float]:
    """The FE's mean curvature against the best line through the origin on (0, 45 kPa]: the
    largest relative deviation there (%), and the line's slope (1/m per Pa)."""
    points = [p for p in reference.positive() if p.pressure_pa <= LINEAR_RANGE_PA]
    p = np.array([q.pressure_pa for q in points])
    kappa = np.array([q.mean_curvature_per_m for q in points])
    slope = float(np.dot(p, kappa) / np.dot(p, p))
    return float(np.max(np.abs(slope * p / kappa - 1.0)) * 100.0), slope


FE3D_KEYS = ("fe3d_width_mm", "fe_block_contact_first_kpa_plane_strain",
             "fe3d_interpenetration_max_mm", "fe3d_verification_error_pct",
             "fe3d_mesh_change_pct", "fe3d_volume_change_pct", "fe3d_vacuum_limit_kpa")


def fe3d_summary(document) -> dict:
    """The --json keys of the 3-D FE (#49) from config/fe3d_reference.yaml's document."""
    from softgrip_ros.model.fe_data import FE3D_BAND_KEYS
    out = {key: document["figures"][key] for key in FE3D_KEYS}
    out["fe3d_band"] = [{key: entry[key] for key in FE3D_BAND_KEYS}
                        for entry in document["band"]]
    return out


def _fe_growth_pct(truth, low_pa: float, high_pa: float):
    """The mean curvature's growth from ``low_pa`` to ``high_pa`` (%); None past the sweep."""
    try:
        low, high = truth.at(low_pa), truth.at(high_pa)
    except KeyError:
        return None
    return 100.0 * (high.mean_curvature_per_m / low.mean_curvature_per_m - 1.0)


def fe_summary(truth) -> dict:
    """The --json FE keys of the FE truth (:func:`softgrip_ros.model.fe_data.load_fe_truth`, the
    3-D FE's default sweep), and the models' worst errors against it."""
    figures = truth.figures
    out = {
        "fe_alpha_25kPa_deg": math.degrees(truth.at(25e3).alpha_rad),
        "fe_D2_50kPa_mm": truth.at(50e3).d2_m * 1e3,
        "fe_D1_0kPa_mm": truth.at(0.0).d1_m * 1e3,
        "fe_D1_50kPa_mm": truth.at(50e3).d1_m * 1e3,
        "fe_curvature_growth_50_55_pct": _fe_growth_pct(truth, 50e3, 55e3),
        "fe_curvature_growth_55_60_pct": _fe_growth_pct(truth, 55e3, 60e3),
        "fe_verification_error_pct": float(figures["fe3d_verification_error_pct"]),
        "fe_mesh_change_pct": float(figures["fe3d_mesh_change_pct"]),
        "fe_volume_change_pct": float(figures["fe3d_volume_change_pct"]),
        "fe_linear_law_max_deviation_to_45kPa_pct": fe_linearity(truth)[0],
        "fe_vacuum_limit_kpa": float(figures["fe3d_vacuum_limit_kpa"]),
    }
    for row in against_fe(truth):
        key = f"{row.law}_{row.calibration}_cal"
        out[f"{key}_tip_err_vs_fe_to_45kPa_mm"] = row.tip_mm_to_45
        out[f"{key}_D2_err_vs_fe_to_45kPa_mm"] = row.d2_mm_to_45
        out[f"{key}_alpha_err_vs_fe_to_45kPa_deg"] = row.alpha_deg_to_45
    return out

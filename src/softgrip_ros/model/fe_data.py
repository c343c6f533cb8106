"""The FE references' committed results, and the bending calibration fitted to them.

Two files, both written by scripts/bench_fe.py (the FE extra); reading them needs no FE library:

* config/fe3d_reference.yaml, **the FE truth**: the 3-D finger with contact
  (softgrip_ros.model.fe3d) at its default width, free bending from its vacuum limit to +50 kPa,
  the band of widths and the clamp sweeps. :func:`load_fe_truth` reads its default sweep.
* config/fe_reference.yaml, the plane-strain FE (softgrip_ros.model.fe): it has no contact
  between neighbouring blocks, so it is read only up to PLANE_STRAIN_VALID_TO_PA
  (:func:`load_fe_reference`): the 3-D code's plane-strain check at 2 kPa and the world's bending
  volume share at -5 to +10 kPa.

The FE calibration (``type_II_fe`` for L0, ``type_II_fe_l1`` for L1): the gain g and the chamber
ballooning compliance c_b of each law, fitted by least squares to the FE truth's alpha(p) and
D2(p) at its positive pressures except the held-out ones. The saturation stays off
(p_sat = inf). The paper calibration (``type_II``) is untouched; a user picks one by the nodes'
``gripper_model``.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import yaml
from scipy.optimize import least_squares

from softgrip_ros.model.bending import BendingCalibration
from softgrip_ros.model.geometry import FingerGeometry
from softgrip_ros.model.kinematics import GripperKinematics

FE_REFERENCE_FILE = "fe_reference.yaml"
FE3D_REFERENCE_FILE = "fe3d_reference.yaml"
# FE points the calibration does not see, inside the span of those it does (the free bound
# is checked there, not extrapolated)
HELD_OUT_PRESSURES_PA = (15e3, 35e3)
FE_CALIBRATION_NAMES = {"l0": "type_II_fe", "l1": "type_II_fe_l1"}
# the geometry both FE references are computed on (scripts/bench_fe.py); the FE models share it
FE_GEOMETRY_NAME = "type_II"
# the plane-strain FE's blocks 1 and 2 come closer than its wall-contact gap (0.2 mm) just above
# this (FingerFE.block_gaps_m; tests/test_fe_reference.py checks it)
PLANE_STRAIN_VALID_TO_PA = 10e3
# residual scales: one degree of alpha weighs as one millimetre of D2
ALPHA_SCALE_RAD = math.radians(1.0)
D2_SCALE_M = 1e-3


def at_pressure(items, pressure_pa: float, where: str):
    """The item (a sweep's state or point) at ``pressure_pa``; KeyError saying where it lacks."""
    for item in items:
        if abs(item.pressure_pa - pressure_pa) < 1e-6:
            return item
    raise KeyError(f"{where} has no point at {pressure_pa / 1e3:+.1f} kPa")


@dataclasses.dataclass(frozen=True)
class FEPoint:
    pressure_pa: float
    alpha_rad: float
    d1_m: float
    d2_m: float
    mean_curvature_per_m: float
    tip: tuple  # (x m, z m, angle rad)
    backbone_m: np.ndarray
    cavity_areas_m2: tuple = ()  # per chamber, per unit width (plane strain only)


@dataclasses.dataclass(frozen=True)
class FEReference:
    """One FE sweep's states (free bending) and its file's figures. ``valid_to_pa``: the highest
    pressure at which the FE models what happens; :meth:`at` refuses pressures above it
    (KeyError)."""

    points: tuple  # FEPoint, ascending pressure
    figures: dict
    sweep: dict
    verification: dict
    source: str = FE3D_REFERENCE_FILE
    valid_to_pa: float = math.inf

    def at(self, pressure_pa: float) -> FEPoint:
        if pressure_pa > self.valid_to_pa:
            raise KeyError(f"config/{self.source} is not a truth above "
                           f"{self.valid_to_pa / 1e3:.1f} kPa (its neighbouring blocks meet there "
                           f"and it has no contact between them); asked for "
                           f"{pressure_pa / 1e3:+.1f} kPa")
        return at_pressure(self.points, pressure_pa, f"config/{self.source}")

    def positive(self) -> list:
        """The states above 0 Pa that the FE is valid at."""
        return [p for p in self.points if 0.0 < p.pressure_pa <= self.valid_to_pa]


def _point(state: dict) -> FEPoint:
    return FEPoint(
        pressure_pa=float(state["pressure_pa"]), alpha_rad=math.radians(state["alpha_deg"]),
        d1_m=state["D1_mm"] * 1e-3, d2_m=state["D2_mm"] * 1e-3,
        mean_curvature_per_m=float(state["mean_curvature_per_m"]),
        tip=(state["tip_x_mm"] * 1e-3, state["tip_z_mm"] * 1e-3,
             math.radians(state["tip_angle_deg"])),
        backbone_m=np.asarray(state["backbone_mm"], dtype=float) * 1e-3,
        cavity_areas_m2=tuple(a * 1e-6 for a in state.get("cavity_areas_mm2", ())))


def load_fe_reference(path=None) -> FEReference:
    """The plane-strain FE (config/fe_reference.yaml), read up to PLANE_STRAIN_VALID_TO_PA."""
    if path is None:
        from softgrip_ros.config_paths import config_file
        path = config_file(FE_REFERENCE_FILE)
    with open(path) as stream:
        document = yaml.safe_load(stream)
    return FEReference(tuple(_point(s) for s in document["states"]), dict(document["figures"]),
                       dict(document["sweep"]), dict(document["verification"]),
                       FE_REFERENCE_FILE, PLANE_STRAIN_VALID_TO_PA)


def load_fe_truth(path=None) -> FEReference:
    """The FE truth: the 3-D FE's default sweep (config/fe3d_reference.yaml, at its
    ``fe3d_width_mm``), from its vacuum limit to its highest pressure. FileNotFoundError or
    ValueError as :func:`load_fe3d_reference`."""
    document = load_fe3d_reference(path)
    return FEReference(tuple(_point(s) for s in document["states"]), dict(document["figures"]),
                       dict(document["sweep"]), dict(document["verification"]))


FE3D_BAND_KEYS = ("width_mm", "base_mm", "curvature_2kPa_per_m", "alpha_25kPa_deg",
                  "D2_50kPa_mm", "D1_50kPa_mm", "block_contact_first_kpa",
                  "clamp_force_sheet_n_at_-30kPa")


def load_fe3d_reference(path=None) -> dict:
    """config/fe3d_reference.yaml (scripts/bench_fe.py writes it) as a document: ``figures``,
    ``band`` (a list of dicts with at least FE3D_BAND_KEYS), ``sweep``, ``verification`` and
    ``states``. FileNotFoundError if it is absent; ValueError if a key is missing."""
    if path is None:
        from softgrip_ros.config_paths import config_file
        path = config_file(FE3D_REFERENCE_FILE)
    with open(path) as stream:
        document = yaml.safe_load(stream)
    for key in ("figures", "band", "sweep", "verification", "states"):
        if key not in (document or {}):
            raise ValueError(f"{path}: no {key!r}; rewrite it with python scripts/bench_fe.py")
    for entry in document["band"]:
        missing = [key for key in FE3D_BAND_KEYS if key not in entry]
        if missing:
            raise ValueError(f"{path}: a band entry lacks {missing}")
    return document


def fit_to_fe(geometry: FingerGeometry, reference: FEReference, law: str,
              held_out=HELD_OUT_PRESSURES_PA) -> BendingCalibration:
    """``law``'s gain and ballooning compliance from the FE's alpha and D2 (see the module),
    validated to the FE's highest pressure."""
    points = [p for p in reference.positive()
              if not any(abs(p.pressure_pa - h) < 1.0 for h in held_out)]
    top = max(p.pressure_pa for p in reference.points)

    def calibration(params):
        return BendingCalibration(gain=float(params[0]),
                                  ballooning_compliance_per_pa=float(params[1]) * 1e-6,
                                  validated_max_pressure_pa=top)

    def residuals(params):
        kin = GripperKinematics(geometry, calibration(params), model=law, max_pressure_pa=top)
        out = []
        for point in points:
            pose = kin.pose(point.pressure_pa)
            out.append((pose.included_angle_rad - point.alpha_rad) / ALPHA_SCALE_RAD)
            out.append((pose.tip_spacing_m - point.d2_m) / D2_SCALE_M)
        return out

    fit = least_squares(residuals, x0=[1.0, 0.1], bounds=([1e-3, 0.0], [1e3, 1e3]),
                        xtol=1e-12, ftol=1e-12)
    return calibration(fit.x)


def errors_against_fe(kinematics: GripperKinematics, reference: FEReference, pressures_pa):
    """Per pressure: (p, alpha error deg, D2 error mm, tip position error mm) of a model."""
    rows = []
    for p in pressures_pa:
        point = reference.at(p)
        pose = kinematics.pose(p)
        rows.append((p, math.degrees(pose.included_angle_rad - point.alpha_rad),
                     (pose.tip_spacing_m - point.d2_m) * 1e3,
                     math.hypot(pose.left_tip_x_m - point.tip[0],
                                pose.left_tip_z_m - point.tip[1]) * 1e3))
    return rows

"""Fit the bending model to a user's measurements of their own fingers (softgrip_calibrate).

The measurements are a CSV: a column ``pressure_pa`` and any of

=================  ===============================================  =====================
column             model quantity (softgrip_ros.model.kinematics)   default std (no std_)
=================  ===============================================  =====================
alpha_deg          included angle alpha between the chamber faces   1 deg
tip_spacing_m      D2, between the tip chambers                     1 mm
root_spacing_m     D1, between the root chambers                    1 mm
left_tip_x_m       left tip, across (x of tip_pose, from the centre) 1 mm
left_tip_y_m       left tip, along the fingers (z of tip_pose)      1 mm
=================  ===============================================  =====================

each with an optional ``std_<column>`` (one standard deviation, same unit). An empty cell is a
quantity not measured at that pressure.

What is fitted (the L0 law, as the packaged calibration; L1 uses the same constants):

- the gain g of eq. 16, always;
- the ballooning compliance, when a position (D1, D2 or the tip) was measured: alpha alone
  cannot tell it from the gain, both turn the chamber faces in proportion to p;
- the saturation pressure, and its width too, when there are measurements above 45 kPa (one
  pressure there: the pressure only; two or more: both).

Everything else comes from the base model and is said to. When every measured column has its
std column the noise is known: the intervals come from (J^T J)^-1 and the normal quantile, and
the residuals' chi^2 per degree of freedom checks the stated std. Otherwise the default std
weigh the columns and one common scale is estimated from the residuals (Student t).
"""
from __future__ import annotations

import csv
import dataclasses
import math
import pathlib

import numpy as np
from scipy import stats
from scipy.optimize import least_squares

from softgrip_ros.model.bending import BendingCalibration
from softgrip_ros.model.geometry import FingerGeometry
from softgrip_ros.model.kinematics import GripperKinematics


@dataclasses.dataclass(frozen=True)
class Quantity:
    pose_field: str
    to_column: float  # model SI value * this = the column's unit
    default_std: float
    label: str
    # what a measurement may be at all, in the column's unit: beyond it, a typo or a unit slip
    valid: tuple = (-1.0, 1.0)


QUANTITIES = {
    "alpha_deg": Quantity("included_angle_rad", 180.0 / math.pi, 1.0, "alpha (deg)",
                          (-180.0, 360.0)),
    "tip_spacing_m": Quantity("tip_spacing_m", 1.0, 1e-3, "D2 (m)"),
    "root_spacing_m": Quantity("root_spacing_m", 1.0, 1e-3, "D1 (m)"),
    "left_tip_x_m": Quantity("left_tip_x_m", 1.0, 1e-3, "left tip x (m)"),
    "left_tip_y_m": Quantity("left_tip_z_m", 1.0, 1e-3, "left tip y (m)"),
}
POSITIONS = ("tip_spacing_m", "root_spacing_m", "left_tip_x_m", "left_tip_y_m")


@dataclasses.dataclass(frozen=True)
class Constant:
    """One fitted constant: its BendingCalibration field, the scale the solver works in, bounds
    in that scale."""

    scale: float
    low: float
    high: float
    unit: str


CONSTANTS = {
    "gain": Constant(1.0, 1e-3, 1e3, ""),
    "ballooning_compliance_per_pa": Constant(1e-6, 0.0, 1e3, "1/Pa"),
    "saturation_pressure_pa": Constant(1e3, 5.0, 200.0, "Pa"),
    "saturation_width_pa": Constant(1e3, 0.1, 50.0, "Pa"),
}
SATURATION_ABOVE_PA = 45e3  # below this the FEA follows the linear law (paper Fig. 18)
MIN_PRESSURE_PA = GripperKinematics.MODEL_MIN_PRESSURE_PA
MAX_PRESSURE_PA = GripperKinematics.MODEL_MAX_PRESSURE_PA
WIDE_INTERVAL = 0.25  # a 95 % half-width beyond this fraction of the value is flagged
RANK_TOLERANCE = 1e-7  # smallest / largest relative sensitivity below this: not determined


@dataclasses.dataclass
class Measurements:
    """pressure_pa (N,); values and std: column -> (N,), NaN where not measured; std None when
    the file gave no std column for it."""

    pressure_pa: np.ndarray
    values: dict
    std: dict
    source: str = ""

    def __len__(self) -> int:
        return int(self.pressure_pa.size)

    def subset(self, rows) -> "Measurements":
        return Measurements(self.pressure_pa[rows], {c: v[rows] for c, v in self.values.items()},
                            {c: (None if s is None else s[rows]) for c, s in self.std.items()},
                            self.source)

    @property
    def noise_known(self) -> bool:
        return all(s is not None for s in self.std.values())

    def weights(self, column: str) -> np.ndarray:
        std = self.std[column]
        return (np.full(len(self), QUANTITIES[column].default_std) if std is None else std)

    def observations(self) -> int:
        return int(sum(np.isfinite(v).sum() for v in self.values.values()))

    def distinct(self) -> int:
        """Distinct (pressure, quantity) pairs measured: repeats add no spread."""
        return sum(len(set(self.pressure_pa[np.isfinite(v)].round(3))) for v in
                   self.values.values())


def load_csv(path) -> Measurements:
    """Read and check the measurements; ValueError naming the row or column at fault."""
    path = pathlib.Path(path)
    try:
        with path.open(newline="") as handle:
            rows = list(csv.reader(handle))
    except OSError as error:
        raise ValueError(f"{path}: cannot read: {error.strerror}") from None
    rows = [r for r in rows if r and any(cell.strip() for cell in r)
            and not r[0].lstrip().startswith("#")]
    if not rows:
        raise ValueError(f"{path}: empty file")
    header = [h.strip() for h in rows[0]]
    known = {"pressure_pa", *QUANTITIES, *(f"std_{q}" for q in QUANTITIES)}
    unknown = [h for h in header if h not in known]
    if unknown:
        raise ValueError(f"{path}: unknown columns {unknown}; known: pressure_pa, "
                         f"{', '.join(QUANTITIES)} and std_<column>")
    if len(set(header)) != len(header):
        raise ValueError(f"{path}: a column appears twice in the header {header}")
    if "pressure_pa" not in header:
        raise ValueError(f"{path}: no pressure_pa column")
    measured = [q for q in QUANTITIES if q in header]
    if not measured:
        raise ValueError(f"{path}: no measured quantity; give one or more of "
                         f"{', '.join(QUANTITIES)}")
    for h in header:
        if h.startswith("std_") and h[4:] not in header:
            raise ValueError(f"{path}: {h} without a {h[4:]} column")
    table = np.full((len(rows) - 1, len(header)), np.nan)
    for line, row in enumerate(rows[1:], start=2):
        if len(row) > len(header):
            raise ValueError(f"{path}: line {line}: {len(row)} cells for {len(header)} columns")
        for column, cell in enumerate(row):
            if cell.strip():
                try:
                    table[line - 2, column] = float(cell)
                except ValueError:
                    raise ValueError(f"{path}: line {line}, {header[column]}: not a number: "
                                     f"{cell!r}") from None
    data = dict(zip(header, table.T))
    pressure = data["pressure_pa"]
    for line, p in enumerate(pressure, start=2):
        if not math.isfinite(p):
            raise ValueError(f"{path}: line {line}: pressure_pa is missing or not finite")
        if not MIN_PRESSURE_PA <= p <= MAX_PRESSURE_PA:
            raise ValueError(f"{path}: line {line}: pressure_pa {p:g} is outside the model's "
                             f"range [{MIN_PRESSURE_PA:g}, {MAX_PRESSURE_PA:g}] Pa")
    std = {}
    for q in measured:
        if np.any(np.isinf(data[q])):
            raise ValueError(f"{path}: {q}: an infinite value")
        low, high = QUANTITIES[q].valid
        outside = np.isfinite(data[q]) & ((data[q] < low) | (data[q] > high))
        if np.any(outside):
            line = int(np.argmax(outside)) + 2
            raise ValueError(f"{path}: line {line}: {q} {data[q][line - 2]:g} is outside "
                             f"[{low:g}, {high:g}], what a {QUANTITIES[q].label} can be")
        s = data.get(f"std_{q}")
        if s is not None:
            bad = np.isfinite(data[q]) & ~(np.isfinite(s) & (s > 0) & (s < high - low))
            if np.any(bad):
                line = int(np.argmax(bad)) + 2
                raise ValueError(f"{path}: line {line}: std_{q} must be a positive number "
                                 f"below {high - low:g} where {q} is given")
        std[q] = s
    result = Measurements(pressure, {q: data[q] for q in measured}, std, str(path))
    if result.observations() == 0:
        raise ValueError(f"{path}: no measured value in any row")
    return result


@dataclasses.dataclass
class BendingFit:
    """What softgrip_calibrate found. fitted: name -> (value, standard error, (low, high));
    inherited: name -> value; loo_residuals: column -> (N,) measured less the prediction of a
    fit without that row (NaN where not measured or not refittable)."""

    calibration: BendingCalibration
    fitted: dict
    inherited: dict
    residuals: dict  # column -> (N,) measured less fitted
    loo_residuals: dict
    chi2_per_dof: float  # known noise: should be near 1; otherwise the estimated scale squared
    dof: int
    noise_known: bool
    confidence: float
    loss: str
    flags: list
    measurements: Measurements


def choose_constants(data: Measurements, requested=None) -> list:
    """The constants to fit: ``requested`` (checked), or what the data determine."""
    high = sorted(set(data.pressure_pa[data.pressure_pa > SATURATION_ABOVE_PA].round(3)))
    if requested:
        unknown = [n for n in requested if n not in CONSTANTS]
        if unknown:
            raise ValueError(f"unknown constants {unknown}; known: {', '.join(CONSTANTS)}")
        names = list(dict.fromkeys(requested))
        if "saturation_pressure_pa" in names and not high:
            raise ValueError("the saturation pressure needs measurements above "
                             f"{SATURATION_ABOVE_PA / 1e3:.0f} kPa; there are none")
        if "saturation_width_pa" in names and len(high) < 2:
            raise ValueError("the saturation width needs measurements at two or more pressures "
                             f"above {SATURATION_ABOVE_PA / 1e3:.0f} kPa; there are {len(high)}")
    else:
        names = ["gain"]
        if any(np.isfinite(data.values[c]).any() for c in POSITIONS if c in data.values):
            names.append("ballooning_compliance_per_pa")
        names += ["saturation_pressure_pa", "saturation_width_pa"][:len(high)]
        while len(names) > 1 and data.distinct() < len(names) and \
                "ballooning_compliance_per_pa" in names:
            names.remove("ballooning_compliance_per_pa")
    moving = data.pressure_pa[np.abs(data.pressure_pa) > 1e3]
    if "gain" in names and moving.size == 0:
        raise ValueError("every measurement is at 0 Pa: no pressure spread, so the gain is not "
                         "determined; measure at pressures away from 0")
    if data.observations() < len(names):
        raise ValueError(f"{data.observations()} measured value(s) for {len(names)} constants "
                         f"({', '.join(names)}): measure more points")
    if data.distinct() < len(names):
        raise ValueError(
            f"the measurements hold {data.distinct()} distinct (pressure, quantity) pair(s) for "
            f"{len(names)} constants ({', '.join(names)}): no pressure spread; measure at more "
            "pressures or more quantities")
    return names


def _kinematics(geometry, calibration) -> GripperKinematics:
    return GripperKinematics(geometry, calibration, model="l0",
                             max_pressure_pa=GripperKinematics.MODEL_MAX_PRESSURE_PA)


def predict(geometry: FingerGeometry, calibration: BendingCalibration, pressure_pa) -> dict:
    """Every quantity the CSV can hold, in its column's unit, at ``pressure_pa``."""
    poses = _kinematics(geometry, calibration).poses(np.asarray(pressure_pa, dtype=float))
    return {c: np.asarray(getattr(poses, q.pose_field)) * q.to_column
            for c, q in QUANTITIES.items()}


def fit(data: Measurements, geometry: FingerGeometry, base: BendingCalibration,
        constants=None, loss: str = "linear", confidence: float = 0.95,
        leave_one_out: bool = True) -> BendingFit:
    """Fit ``constants`` (default: :func:`choose_constants`) by scipy's least squares; the rest
    from ``base``. ValueError when the data cannot determine what was asked."""
    names = choose_constants(data, constants)
    if loss not in ("linear", "soft_l1", "huber", "cauchy", "arctan"):
        raise ValueError(f"unknown loss {loss!r}: linear, soft_l1, huber, cauchy or arctan")
    dropped = []
    while True:
        solution = _solve(data, geometry, base, names, loss)
        undetermined = _undetermined(solution.jac, solution.x, names)
        if undetermined is None:
            break
        if constants or len(names) == 1:  # asked for by name: refuse rather than drop it
            raise ValueError(f"the data do not determine {undetermined}: the measured "
                             "quantities do not change with it; measure other quantities or "
                             "other pressures, or fit fewer constants (--fit)")
        names.remove(undetermined)
        dropped.append(undetermined)
    calibration = _calibration(base, names, solution.x)
    jacobian = solution.jac
    fitted_values = predict(geometry, calibration, data.pressure_pa)
    residuals = {c: data.values[c] - fitted_values[c] for c in data.values}
    whitened = np.concatenate([(residuals[c] / data.weights(c))[np.isfinite(data.values[c])]
                               for c in data.values])
    dof = whitened.size - len(names)
    chi2 = float(whitened @ whitened) / dof if dof > 0 else math.nan
    cov = np.linalg.inv(jacobian.T @ jacobian)
    if data.noise_known:
        quantile = stats.norm.ppf(0.5 + confidence / 2.0)
    elif dof > 0:
        cov = cov * chi2
        quantile = stats.t.ppf(0.5 + confidence / 2.0, dof)
    else:
        cov, quantile = cov * math.nan, math.nan
    fitted = {}
    flags = [f"{name}: these data do not determine it, so it is inherited" for name in dropped]
    for i, name in enumerate(names):
        scale = CONSTANTS[name].scale
        value = float(solution.x[i] * scale)
        se = float(math.sqrt(cov[i, i]) * scale) if math.isfinite(cov[i, i]) else math.nan
        fitted[name] = (value, se, (value - quantile * se, value + quantile * se))
        if not math.isfinite(se):
            flags.append(f"{name}: no interval, as many measured values as constants (add "
                         "points, or std columns)")
        elif quantile * se > WIDE_INTERVAL * abs(value):
            flags.append(f"{name}: its {confidence:.0%} interval is +-"
                         f"{100 * quantile * se / abs(value):.0f} % (> {WIDE_INTERVAL:.0%}): the "
                         "data hardly determine it")
    if data.noise_known and dof > 0 and stats.chi2.sf(chi2 * dof, dof) < 0.01:
        flags.append(f"residuals are {math.sqrt(chi2):.1f}x the stated std (chi^2/dof "
                     f"{chi2:.2f}): the std columns or the model are off")
    inherited = {f.name: float(getattr(base, f.name))
                 for f in dataclasses.fields(BendingCalibration) if f.name not in names}
    loo = _leave_one_out(data, geometry, base, names, loss, solution.x) if leave_one_out else {}
    return BendingFit(calibration, fitted, inherited, residuals, loo, chi2, dof,
                      data.noise_known, confidence, loss, flags, data)


def _calibration(base: BendingCalibration, names, x) -> BendingCalibration:
    return dataclasses.replace(base, **{n: float(v * CONSTANTS[n].scale)
                                        for n, v in zip(names, x)})


def _solve(data: Measurements, geometry, base, names, loss, x0=None):
    columns = list(data.values)
    masks = {c: np.isfinite(data.values[c]) for c in columns}
    weights = {c: data.weights(c)[masks[c]] for c in columns}

    def residual(x):
        predicted = predict(geometry, _calibration(base, names, x), data.pressure_pa)
        return np.concatenate([(predicted[c][masks[c]] - data.values[c][masks[c]]) / weights[c]
                               for c in columns])

    if x0 is None:
        x0 = []
        for n in names:
            value = getattr(base, n) / CONSTANTS[n].scale
            if not math.isfinite(value):  # a base without saturation
                value = 55.0
            x0.append(min(max(value, CONSTANTS[n].low + 1e-3), CONSTANTS[n].high))
    bounds = ([CONSTANTS[n].low for n in names], [CONSTANTS[n].high for n in names])
    return least_squares(residual, np.asarray(x0, dtype=float), bounds=bounds, loss=loss,
                         x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12)


def _undetermined(jacobian: np.ndarray, x: np.ndarray, names) -> str | None:
    """The constant the measured quantities (nearly) do not change with, or None."""
    relative = jacobian * np.where(np.abs(x) > 0, np.abs(x), 1.0)
    if not np.all(np.isfinite(relative)):
        raise ValueError("the model could not be evaluated around the fit")
    _, singular, vt = np.linalg.svd(relative, full_matrices=False)
    if singular[0] == 0.0 or singular[-1] / singular[0] < RANK_TOLERANCE:
        return names[int(np.argmax(np.abs(vt[-1])))]
    return None


def _leave_one_out(data, geometry, base, names, loss, x_full) -> dict:
    out = {c: np.full(len(data), np.nan) for c in data.values}
    for row in range(len(data)):
        keep = np.arange(len(data)) != row
        rest = data.subset(keep)
        try:
            choose_constants(rest, names)
            solution = _solve(rest, geometry, base, names, loss, x0=x_full)
        except ValueError:
            continue
        predicted = predict(geometry, _calibration(base, names, solution.x),
                            data.pressure_pa[row:row + 1])
        for c in data.values:
            out[c][row] = data.values[c][row] - predicted[c][0]
    return out

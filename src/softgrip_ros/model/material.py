"""Yeoh hyperelastic silicone: stresses, and the constants fitted from a tensile test.

Strain energy (paper eq. 5), incompressible::

    W = C10 (I1 - 3) + C20 (I1 - 3)^2 + C30 (I1 - 3)^3

Uniaxial tension (lambda2 = lambda3 = lambda^-1/2, I1 = lambda^2 + 2/lambda)::

    P = 2 (lambda - lambda^-2) dW/dI1          nominal (first Piola) stress
    sigma = lambda P                           true stress (paper eq. 6)

Planar tension, plane strain (lambda3 = 1, lambda2 = 1/lambda, I1 - 3 = lambda^2 + lambda^-2 - 2),
the state of a chamber wall (paper eq. 8)::

    P = 2 (lambda - lambda^-3) dW/dI1          small-strain slope dP/dlambda = 8 C10

with dW/dI1 = C10 + 2 C20 (I1 - 3) + 3 C30 (I1 - 3)^2. All stresses in Pa.
"""
from __future__ import annotations

import csv
import dataclasses
import math
import pathlib

import numpy as np


@dataclasses.dataclass(frozen=True)
class YeohMaterial:
    """Yeoh constants in Pa; the paper's silicone (E620#A) by default."""

    c10_pa: float = 0.08e6
    c20_pa: float = 0.015e6
    c30_pa: float = 0.0

    def __post_init__(self):
        for name in ("c10_pa", "c20_pa", "c30_pa"):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise ValueError(f"YeohMaterial.{name} must be finite, got {value!r}")
        if self.c10_pa <= 0.0:
            raise ValueError(
                f"YeohMaterial.c10_pa must be > 0 (initial shear modulus / 2), got {self.c10_pa}")

    def dw_di1(self, i1_minus_3):
        """dW/dI1 at I1 - 3 (Pa)."""
        x = np.asarray(i1_minus_3, dtype=float)
        return self.c10_pa + 2.0 * self.c20_pa * x + 3.0 * self.c30_pa * x * x

    def strain_energy(self, i1_minus_3):
        """W at I1 - 3 (J/m^3)."""
        x = np.asarray(i1_minus_3, dtype=float)
        return self.c10_pa * x + self.c20_pa * x**2 + self.c30_pa * x**3

    def uniaxial_nominal_stress(self, stretch):
        lam = _positive_stretch(stretch)
        return 2.0 * (lam - lam**-2) * self.dw_di1(lam**2 + 2.0 / lam - 3.0)

    def uniaxial_true_stress(self, stretch):
        lam = _positive_stretch(stretch)
        return lam * self.uniaxial_nominal_stress(lam)

    def planar_nominal_stress(self, stretch):
        lam = _positive_stretch(stretch)
        return 2.0 * (lam - lam**-3) * self.dw_di1(lam**2 + lam**-2 - 2.0)

    def planar_nominal_stress_of_strain(self, strain):
        """Planar nominal stress at lambda = 1 + strain, free of cancellation for tiny strains.

        lambda - lambda^-3 = e (4 + 6e + 4e^2 + e^3) / (1 + e)^3 and
        I1 - 3 = (e (2 + e) / (1 + e))^2, so P keeps full relative precision as e -> 0.
        """
        e = np.asarray(strain, dtype=float)
        if np.any(e <= -1.0):
            raise ValueError("strain must be > -1 (stretch > 0)")
        one_plus = 1.0 + e
        x = (e * (2.0 + e) / one_plus)**2
        return 2.0 * e * (4.0 + e * (6.0 + e * (4.0 + e))) / one_plus**3 * self.dw_di1(x)

    def planar_nominal_stress_slope(self, stretch):
        """dP/dlambda of the planar nominal stress (Pa), for Newton steps and implicit
        derivatives."""
        lam = _positive_stretch(stretch)
        x = lam**2 + lam**-2 - 2.0
        dx = 2.0 * lam - 2.0 * lam**-3
        d2w = 2.0 * self.c20_pa + 6.0 * self.c30_pa * x
        return 2.0 * (1.0 + 3.0 * lam**-4) * self.dw_di1(x) + 2.0 * (lam - lam**-3) * d2w * dx

    def planar_true_stress(self, stretch):
        lam = _positive_stretch(stretch)
        return lam * self.planar_nominal_stress(lam)

    @property
    def planar_modulus_pa(self) -> float:
        """Small-strain slope of the planar nominal stress, 8 C10 (Pa)."""
        return 8.0 * self.c10_pa


def _positive_stretch(stretch):
    lam = np.asarray(stretch, dtype=float)
    if not np.all(np.isfinite(lam)):
        raise ValueError("stretch must be finite (got NaN or inf)")
    if np.any(lam <= 0.0):
        raise ValueError(f"stretch must be > 0, got minimum {lam.min()}")
    return lam


@dataclasses.dataclass(frozen=True)
class YeohFit:
    """Result of :func:`fit_yeoh`: constants (Pa), standard errors (Pa) and confidence
    intervals."""

    material: YeohMaterial
    standard_errors_pa: dict
    confidence_intervals_pa: dict
    confidence_level: float
    residual_rms_pa: float
    points: int

    def summary(self) -> str:
        lines = [f"Yeoh fit over {self.points} points ({self.confidence_level:.0%} confidence):"]
        for name in self.standard_errors_pa:
            value = getattr(self.material, name)
            low, high = self.confidence_intervals_pa[name]
            lines.append(
                f"  {name[:3].upper():4s} = {value / 1e6:.5f} MPa  "
                f"(se {self.standard_errors_pa[name] / 1e6:.5f}, CI [{low / 1e6:.5f}, "
                f"{high / 1e6:.5f}] MPa)"
            )
        lines.append(
            f"  residual RMS of the linearised stress y = {self.residual_rms_pa / 1e3:.3f} kPa")
        return "\n".join(lines)


MIN_FIT_POINTS = 5


def fit_yeoh(stretch, nominal_stress_pa, include_c30: bool = False,
             confidence_level: float = 0.95) -> YeohFit:
    """Fit C10, C20 (and C30) to uniaxial tensile data by the paper's linearised least squares.

    With y = P / (2 (lambda - lambda^-2)) and x = I1 - 3 the model is linear,
    y = C10 + 2 C20 x + 3 C30 x^2, so ordinary least squares gives the constants
    and their covariance. Points at lambda = 1 carry no information (0/0) and are
    skipped. Raises ValueError naming the first bad row (1-based, data rows).
    """
    lam = np.asarray(stretch, dtype=float).ravel()
    stress = np.asarray(nominal_stress_pa, dtype=float).ravel()
    validate_tensile_data(lam, stress)
    informative = np.abs(lam - 1.0) > 1e-9
    lam, stress = lam[informative], stress[informative]
    n_params = 3 if include_c30 else 2
    if lam.size < max(MIN_FIT_POINTS, n_params + 2):
        raise ValueError(f"too few points to fit: {lam.size} away from lambda = 1, "
                         f"need at least {max(MIN_FIT_POINTS, n_params + 2)}")
    x = lam**2 + 2.0 / lam - 3.0
    y = stress / (2.0 * (lam - lam**-2))
    columns = [np.ones_like(x), 2.0 * x] + ([3.0 * x**2] if include_c30 else [])
    design = np.column_stack(columns)
    coefficients, _, rank, _ = np.linalg.lstsq(design, y, rcond=None)
    if rank < n_params:
        raise ValueError(
            "tensile data span too small a stretch range to separate the Yeoh constants")
    residuals = y - design @ coefficients
    dof = lam.size - n_params
    sigma2 = float(residuals @ residuals) / dof
    covariance = sigma2 * np.linalg.inv(design.T @ design)
    errors = np.sqrt(np.diag(covariance))
    from scipy import stats  # only for a fit's interval: not on a node's path
    t_value = stats.t.ppf(0.5 + confidence_level / 2.0, dof)
    names = ["c10_pa", "c20_pa", "c30_pa"][:n_params]
    material = YeohMaterial(**dict(zip(names, (float(c) for c in coefficients))))
    return YeohFit(
        material=material,
        standard_errors_pa={n: float(e)
                            for n, e in zip(names, errors)},
        confidence_intervals_pa={
            n: (float(c - t_value * e), float(c + t_value * e))
            for n, c, e in zip(names, coefficients, errors)
        },
        confidence_level=confidence_level,
        residual_rms_pa=float(np.sqrt(np.mean(residuals**2))),
        points=int(lam.size),
    )


def validate_tensile_data(stretch, stress) -> None:
    """Raise ValueError naming the first row (1-based) that makes no sense."""
    if stretch.shape != stress.shape:
        raise ValueError(f"stretch and stress lengths differ: {stretch.size} vs {stress.size}")
    for row, (lam, p) in enumerate(zip(stretch, stress), start=1):
        if not (math.isfinite(lam) and math.isfinite(p)):
            raise ValueError(f"row {row}: NaN or inf (stretch={lam}, stress={p})")
        if lam <= 0.0:
            raise ValueError(f"row {row}: stretch must be > 0, got {lam}")
        if row > 1 and lam <= stretch[row - 2]:
            raise ValueError(
                f"row {row}: stretch is not increasing ({stretch[row - 2]} then {lam})")
    if stretch.size < MIN_FIT_POINTS:
        raise ValueError(f"too few points: {stretch.size}, need at least {MIN_FIT_POINTS}")


def load_tensile_csv(path) -> tuple[np.ndarray, np.ndarray]:
    """Read (stretch, nominal stress in Pa) from a CSV with a header naming its columns.

    The first column is ``stretch`` (lambda) or ``strain`` (engineering, lambda - 1);
    the second is the nominal stress, ``stress_pa``, ``stress_kpa`` or ``stress_mpa``.
    """
    path = pathlib.Path(path)
    with path.open(newline="") as handle:
        rows = list(csv.reader(handle))
    if not rows:
        raise ValueError(f"{path}: empty file")
    header = [h.strip().lower() for h in rows[0]]
    if len(header) < 2:
        raise ValueError(
            f"{path}: the header needs two columns (stretch|strain, "
            "stress_pa|stress_kpa|stress_mpa)"
        )
    kinds = {"stretch": 0.0, "strain": 1.0}
    scales = {"stress_pa": 1.0, "stress_kpa": 1e3, "stress_mpa": 1e6}
    if header[0] not in kinds or header[1] not in scales:
        raise ValueError(f"{path}: header {rows[0][:2]} not understood; use stretch|strain and "
                         "stress_pa|stress_kpa|stress_mpa")
    stretch, stress = [], []
    for line_number, row in enumerate(rows[1:], start=1):
        if not row or all(not cell.strip() for cell in row):
            continue
        try:
            first, second = float(row[0]), float(row[1])
        except (ValueError, IndexError):
            raise ValueError(f"{path}: row {line_number}: not two numbers: {row!r}") from None
        stretch.append(first + kinds[header[0]])
        stress.append(second * scales[header[1]])
    return np.array(stretch), np.array(stress)

"""Yeoh material: stress laws, the linearised least-squares fit, and tensile-data validation."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from softgrip_ros.model.material import YeohMaterial, fit_yeoh, load_tensile_csv

pytestmark = pytest.mark.cpu  # computation only: scripts/test.sh runs it beside another

PAPER = YeohMaterial()


def test_small_strain_slopes():
    """Uniaxial slope 6 C10 (E = 3 mu, mu = 2 C10); planar (plane strain) slope 8 C10."""
    h = 1e-6
    for material in (PAPER, YeohMaterial(0.1e6, 0.0, 0.002e6)):
        uni = (material.uniaxial_nominal_stress(1 + h) -
               material.uniaxial_nominal_stress(1 - h)) / (2 * h)
        planar = (material.planar_nominal_stress(1 + h) -
                  material.planar_nominal_stress(1 - h)) / (2 * h)
        assert uni == pytest.approx(6 * material.c10_pa, rel=1e-8)
        assert planar == pytest.approx(8 * material.c10_pa, rel=1e-8)
        assert (material.planar_nominal_stress_slope(1.0) == pytest.approx(
            8 * material.c10_pa, rel=1e-12))


def test_stress_laws_against_the_strain_energy():
    """P = dW/dlambda along each path, by differentiating W numerically."""
    lam = np.linspace(0.6, 2.5, 9)
    h = 1e-6

    def uniaxial_energy(stretch):
        return PAPER.strain_energy(stretch**2 + 2 / stretch - 3)

    def planar_energy(stretch):
        return PAPER.strain_energy(stretch**2 + stretch**-2 - 2)

    assert PAPER.uniaxial_nominal_stress(lam) == pytest.approx(
        (uniaxial_energy(lam + h) - uniaxial_energy(lam - h)) / (2 * h), rel=1e-6)
    assert PAPER.planar_nominal_stress(lam) == pytest.approx(
        (planar_energy(lam + h) - planar_energy(lam - h)) / (2 * h), rel=1e-6)
    assert PAPER.uniaxial_true_stress(lam) == pytest.approx(lam *
                                                            PAPER.uniaxial_nominal_stress(lam))
    assert PAPER.planar_true_stress(lam) == pytest.approx(lam * PAPER.planar_nominal_stress(lam))


@settings(max_examples=50, deadline=None)
@given(st.floats(-0.9, 3.0))
def test_cancellation_free_planar_stress_agrees(strain):
    assert PAPER.planar_nominal_stress_of_strain(strain) == pytest.approx(
        PAPER.planar_nominal_stress(1 + strain), rel=1e-9, abs=1e-6)


def test_cancellation_free_planar_stress_keeps_precision_at_tiny_strain():
    assert (PAPER.planar_nominal_stress_of_strain(1e-12) == pytest.approx(
        8 * PAPER.c10_pa * 1e-12, rel=1e-11))


@pytest.mark.parametrize("truth, include_c30", [(YeohMaterial(0.08e6, 0.015e6), False),
                                                (YeohMaterial(0.12e6, -0.004e6, 0.0015e6), True)])
def test_fit_recovers_known_constants_within_its_intervals(truth, include_c30):
    """Synthetic tests with noise: the 95 % intervals hold the truth in ~95 % of repeats."""
    rng = np.random.default_rng(7)
    stretch = np.linspace(1.02, 3.0, 60)
    clean = truth.uniaxial_nominal_stress(stretch)
    covered, repeats = 0, 200
    names = ["c10_pa", "c20_pa"] + (["c30_pa"] if include_c30 else [])
    for _ in range(repeats):
        noisy = clean * (1 + 0.01 * rng.standard_normal(stretch.size))
        fit = fit_yeoh(stretch, noisy, include_c30=include_c30)
        covered += all(fit.confidence_intervals_pa[n][0] <= getattr(truth, n) <=
                       fit.confidence_intervals_pa[n][1] for n in names)
        for n in names:
            assert abs(getattr(fit.material, n) -
                       getattr(truth, n)) < 6 * fit.standard_errors_pa[n]
    # joint coverage of 2-3 marginal 95 % intervals: well above 80 %, and not a trivially wide
    # interval
    assert 0.80 <= covered / repeats <= 1.0
    exact = fit_yeoh(stretch, clean, include_c30=include_c30)
    for n in names:
        assert getattr(exact.material, n) == pytest.approx(getattr(truth, n), rel=1e-9, abs=1e-3)


def write_csv(path, header, rows):
    path.write_text(header + "\n" + "\n".join(",".join(str(v) for v in row)
                                              for row in rows) + "\n")
    return path


def test_csv_with_engineering_strain_and_kpa(tmp_path):
    strain = np.linspace(0.05, 1.5, 12)
    stress_kpa = PAPER.uniaxial_nominal_stress(1 + strain) / 1e3
    path = write_csv(tmp_path / "t.csv", "strain,stress_kpa", zip(strain, stress_kpa))
    stretch, stress = load_tensile_csv(path)
    assert stretch == pytest.approx(1 + strain)
    fit = fit_yeoh(stretch, stress)
    assert fit.material.c10_pa == pytest.approx(0.08e6, rel=1e-9)
    assert "C10" in fit.summary()


@pytest.mark.parametrize("rows, message", [
    ([(1.1, 1e3), (1.2, float("nan")), (1.3, 3e3), (1.4, 4e3), (1.5, 5e3)], "row 2: NaN"),
    ([(1.1, 1e3), (1.2, 2e3), (1.15, 3e3), (1.4, 4e3),
      (1.5, 5e3)], "row 3: stretch is not increasing"),
    ([(-0.1, 1e3), (1.2, 2e3), (1.3, 3e3), (1.4, 4e3), (1.5, 5e3)], "row 1: stretch must be > 0"),
    ([(1.1, 1e3), (1.2, 2e3), (1.3, 3e3)], "too few points"),
])
def test_nonsense_data_is_rejected_naming_the_row(tmp_path, rows, message):
    path = write_csv(tmp_path / "bad.csv", "stretch,stress_pa", rows)
    stretch, stress = load_tensile_csv(path)
    with pytest.raises(ValueError, match=message):
        fit_yeoh(stretch, stress)


def test_unreadable_csv_rows_and_headers(tmp_path):
    with pytest.raises(ValueError, match="row 2: not two numbers"):
        load_tensile_csv(write_csv(tmp_path / "a.csv", "stretch,stress_pa", [(1.1, 2.0),
                                                                             ("x", 3)]))
    with pytest.raises(ValueError, match="header"):
        load_tensile_csv(write_csv(tmp_path / "b.csv", "lambda,force", [(1.1, 2.0)]))
    with pytest.raises(ValueError, match="stretch must be > 0"):
        PAPER.planar_nominal_stress(0.0)
    with pytest.raises(ValueError, match="c10_pa must be > 0"):
        YeohMaterial(c10_pa=0.0)

"""The offline PyElastica reference: it reproduces the closed-form free bending, L2 agrees with it
in contact within the issue's 2 % of the finger length, and a run that does not settle says so.

Needs the reference extra (scripts/test.sh installs it). Each solve is 1-5 s of numba-compiled
time stepping, so the cases are few."""
import math

import numpy as np
import pytest

from softgrip_ros.model.calibration import build_kinematics
from softgrip_ros.model.reference import ReferenceFinger
from softgrip_ros.model.rod import Circle, RodFinger

pytestmark = pytest.mark.cpu  # computation only: scripts/test.sh runs it beside another

KIN = build_kinematics("l1")
ROD = RodFinger(KIN.geometry, KIN.calibration)
REFERENCE = ReferenceFinger(ROD)
FINGER_LENGTH_M = KIN.geometry.total_length_m


def tip_distance_m(a, b):
    return math.hypot(a[0] - b[0], a[1] - b[1])


def test_free_bending_settles_on_the_pcc_shape():
    """No contact, no gravity: the Cosserat rod at rest is the PCC chain, up to its axial stretch
    and shear (measured 7-20 um at 20-45 kPa; tolerance 0.1 mm)."""
    solution = REFERENCE.solve(30e3, from_pressure_pa=0.0)
    assert solution.at_rest and solution.max_speed_m_s < 1e-5
    pcc = KIN.tip_for_angles(KIN.bending.angles(30e3))
    assert tip_distance_m(solution.tip, pcc) < 1e-4
    assert solution.tip[2] == pytest.approx(pcc[2], abs=2e-3)
    assert solution.contact_force_n == 0.0


def test_l2_agrees_with_the_reference_when_clamping_a_cylinder():
    """Clamp a 40 mm cylinder from 30 kPa open to -20 kPa: tip within 2 % of the finger length (the
    issue's target; measured 0.46 mm = 0.4 %), clamp force within 10 % (measured 1.4 %)."""
    obstacle = Circle(0.0, 0.10, 0.02)
    reference = REFERENCE.solve(-20e3, obstacle=obstacle, from_pressure_pa=30e3)
    l2 = ROD.solve(-20e3, obstacle=obstacle, from_pressure_pa=30e3, steps=6)
    assert reference.at_rest and l2.converged
    assert tip_distance_m(reference.tip, l2.tip) < 0.02 * FINGER_LENGTH_M
    assert reference.contact_force_n == pytest.approx(l2.contact_force_n, rel=0.10)
    # the penalty spring's sink, force / stiffness
    assert 0.0 < reference.max_penetration_m < 1e-4


def test_a_run_that_does_not_settle_says_so():
    """Explicit (symplectic) time stepping diverges at a time step far above the rod's stability
    limit: the solution reports it is not at rest, never a silent wrong pose."""
    unstable = ReferenceFinger(ROD, elements_per_segment=4, time_step_s=2e-3, damping_per_s=1.0)
    solution = unstable.solve(30e3, from_pressure_pa=0.0, max_time_s=0.5)
    assert not solution.at_rest
    assert not (solution.max_speed_m_s < 1e-5)


@pytest.mark.parametrize("kwargs, message",
                         [(dict(elements_per_segment=1), "elements_per_segment"),
                          (dict(time_step_s=0.0), "time_step_s"),
                          (dict(contact_stiffness_n_per_m=math.nan), "contact_stiffness")])
def test_bad_parameters_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        ReferenceFinger(ROD, **kwargs)


def test_bad_scenes_are_refused():
    with pytest.raises(ValueError, match="pressure_pa"):
        REFERENCE.solve(math.nan)
    with pytest.raises(ValueError, match="overlaps"):
        REFERENCE.solve(-10e3, obstacle=Circle(0.0, 0.10, 0.02), from_pressure_pa=0.0)


def test_tip_and_nodes_are_finite_and_start_at_the_clamp():
    solution = REFERENCE.solve(10e3, from_pressure_pa=10e3, max_time_s=0.2)
    assert np.all(np.isfinite(solution.nodes_m))
    assert np.allclose(solution.nodes_m[0], ROD._start[:2], atol=1e-12)

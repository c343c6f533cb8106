"""L2, the rod model: it is the PCC chain when nothing touches it, and it resolves contact and
load."""
import math

import numpy as np
import pytest

from softgrip_ros.model.calibration import build_kinematics
from softgrip_ros.model.rod import Circle, RodFinger, Sheet

pytestmark = pytest.mark.cpu  # computation only: scripts/test.sh runs it beside another

KIN = build_kinematics("l1")
ROD = RodFinger(KIN.geometry, KIN.calibration)
# a 40 mm cylinder on the centre line, between the chamber faces
OBJECT_40MM = Circle(0.0, 0.10, 0.02)


@pytest.mark.parametrize("pressure_pa", [0.0, 1e-9, -1e-9, 1e3, 20e3, 45e3, -20e3])
def test_without_contact_or_gravity_it_is_the_pcc_chain(pressure_pa):
    """Tolerance 1e-6 m in tip position (the issue's); it is exact to rounding by construction."""
    solution = ROD.solve(pressure_pa)
    reference = KIN.tip_for_angles(KIN.bending.angles(pressure_pa))
    assert solution.converged
    assert np.allclose(solution.tip[:2], reference[:2], rtol=0.0, atol=1e-6)
    assert solution.tip[2] == pytest.approx(reference[2], abs=1e-9)
    assert np.allclose(solution.segment_angles_rad, KIN.bending.angles(pressure_pa), atol=1e-12)


def test_gradients_are_exact():
    """The energy gradient (with gravity) and the contact Jacobian against central differences."""
    kappa0 = ROD.free_curvatures(20e3)
    kappa = kappa0 + 0.3
    gravity = np.array([0.0, 9.81])
    _, gradient = ROD._energy_and_gradient(kappa, kappa0, gravity)
    h = 1e-6
    numeric = np.array([(ROD._energy_and_gradient(kappa + e, kappa0, gravity)[0] -
                         ROD._energy_and_gradient(kappa - e, kappa0, gravity)[0]) / (2 * h)
                        for e in np.eye(kappa.size) * h])
    assert np.allclose(gradient, numeric, rtol=1e-5, atol=1e-9 * np.abs(gradient).max())
    jacobian = ROD._gap_jacobian(OBJECT_40MM, kappa)
    numeric = np.array([
        (ROD._gaps(OBJECT_40MM,
                   ROD._shape(kappa + e)[3]) - ROD._gaps(OBJECT_40MM,
                                                         ROD._shape(kappa - e)[3])) / (2 * h)
        for e in np.eye(kappa.size) * h
    ]).T
    assert np.allclose(jacobian, numeric, atol=1e-9)


def test_clamping_a_40mm_cylinder_gives_contact_and_a_force_that_grows_with_vacuum():
    forces = []
    for pressure in (0.0, -5e3, -10e3, -20e3):
        solution = ROD.solve(pressure, obstacle=OBJECT_40MM, from_pressure_pa=30e3, steps=6)
        assert solution.converged, solution.message
        # the finger stays outside the object
        assert solution.max_penetration_m < 1e-9
        assert solution.contact_forces_n.size >= 1 and np.all(solution.contact_forces_n > 0)
        distances = np.hypot(solution.contact_points_m[:, 0],
                             solution.contact_points_m[:, 1] - 0.10)
        # contact points lie on the object
        assert np.allclose(distances, 0.02, atol=1e-7)
        forces.append(solution.contact_force_n)
    assert all(b > a for a, b in zip(forces, forces[1:]))
    # the object stops the finger: it closes less than it would in free bending
    free = ROD.solve(-20e3)
    blocked = ROD.solve(-20e3, obstacle=OBJECT_40MM, from_pressure_pa=30e3, steps=6)
    assert blocked.tip[0] < free.tip[0]


def test_an_object_out_of_reach_changes_nothing():
    far = Circle(0.0, 0.40, 0.02)
    solution, free = ROD.solve(20e3, obstacle=far), ROD.solve(20e3)
    assert solution.converged and solution.contact_forces_n.size == 0
    assert np.allclose(solution.tip[:2], free.tip[:2], atol=1e-8)


def test_pinching_a_thin_sheet_with_vacuum():
    solution = ROD.solve(-20e3, obstacle=Sheet(1e-4), from_pressure_pa=2e3)
    assert solution.converged, solution.message
    assert solution.contact_force_n > 0 and solution.max_penetration_m < 1e-9
    assert np.all(solution.contact_points_m[:, 0] == pytest.approx(-0.5e-4, abs=1e-9))


def test_gravity_bends_the_finger_the_way_it_pulls():
    """Pointing up (gravity along -z), an opened finger sags outwards (-x for the left finger) and
    down."""
    free, loaded = ROD.solve(20e3), ROD.solve(20e3, gravity_m_s2=(0.0, -9.81))
    assert loaded.converged, loaded.message
    assert loaded.tip[0] < free.tip[0] and loaded.tip[1] < free.tip[1]
    heavier = RodFinger(KIN.geometry, KIN.calibration,
                        linear_density_kg_per_m=2 * ROD.node_masses_kg[1] / ROD.element_length_m)
    assert heavier.solve(20e3, gravity_m_s2=(0.0, -9.81)).tip[0] < loaded.tip[0]


def test_failure_is_reported_never_silent():
    """A start shape inside the object cannot converge to a valid contact: the solution says so."""
    solution = ROD.solve(-10e3, obstacle=Circle(0.0, 0.10, 0.02), from_pressure_pa=0.0)
    assert not solution.converged and "overlaps" in solution.message
    # the largest pressure
    top = ROD.solve(60e3, obstacle=Circle(0.0, 0.40, 0.02), gravity_m_s2=(0.0, -9.81))
    assert top.converged and top.message == "converged"


@pytest.mark.parametrize("kwargs, message",
                         [(dict(pressure_pa=math.nan), "pressure_pa"),
                          (dict(pressure_pa=0.0, steps=0), "steps"),
                          (dict(pressure_pa=0.0, obstacle="ball"), "obstacle"),
                          (dict(pressure_pa=0.0, gravity_m_s2=(0, math.inf)), "gravity")])
def test_bad_input_is_refused_with_a_reason(kwargs, message):
    with pytest.raises(ValueError, match=message):
        ROD.solve(**kwargs)
    with pytest.raises(ValueError, match="radius"):
        Circle(0.0, 0.1, -1.0)
    with pytest.raises(ValueError, match="finger_width_m"):
        RodFinger(KIN.geometry, KIN.calibration, finger_width_m=5.0)


def test_the_onset_of_contact_is_continuous_and_converges():
    """Stability where methods fail: at the pressure where the closing finger first touches the
    cylinder the active set changes. Just before it there is no force; just after, a small one;
    both solves converge (or would say so), and the force starts from zero, without a jump."""
    from scipy.optimize import brentq

    def clearance(pressure):
        return ROD._gaps(OBJECT_40MM, ROD._shape(ROD.free_curvatures(pressure))[3]).min()

    # free shape touches the object here
    onset = brentq(clearance, 0.0, 30e3, xtol=1.0)
    before = ROD.solve(onset + 50.0, obstacle=OBJECT_40MM, from_pressure_pa=30e3, steps=6)
    after = ROD.solve(onset - 50.0, obstacle=OBJECT_40MM, from_pressure_pa=30e3, steps=6)
    deeper = ROD.solve(onset - 2e3, obstacle=OBJECT_40MM, from_pressure_pa=30e3, steps=6)
    assert before.converged and after.converged and deeper.converged, (before.message,
                                                                       after.message)
    assert before.contact_force_n == 0.0
    assert 0.0 < after.contact_force_n < 0.05 * deeper.contact_force_n
    assert after.max_penetration_m < 1e-9


def test_the_chamber_faces_are_rounded_so_the_closed_fingers_clear_the_centre_line():
    """Table 1 puts the tip chambers' faces 0.5 mm from the centre line at their middles, but the
    faces are tilted by the inclination: flat, their far edges crossed it by 1.3 mm at rest, and a
    sheet could not be pinched from the fingers' rest. Rounded (FingerGeometry's outline), the
    rest shape clears a 0.1 mm sheet and pinches it from 0 Pa."""
    rod = RodFinger(KIN.geometry, KIN.calibration)
    geometry = KIN.geometry
    assert geometry.chamber_surface_offset_m(4, 0.0) == pytest.approx(
        geometry.chamber_face_offset_m(4))
    assert geometry.chamber_surface_offset_m(4, 0.5 * geometry.chamber_length_m) < \
        geometry.chamber_face_offset_m(4) - geometry.dome_radius_m(4) + 1e-12
    solution = rod.solve(-5e3, Sheet(1e-4), from_pressure_pa=0.0)
    assert solution.converged, solution.message
    assert solution.contact_force_n > 0.0

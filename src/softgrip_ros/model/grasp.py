"""The paper's one-number clamp law: the grasp manager's law until the tabulated one
(:mod:`softgrip_ros.model.force_law`) replaced it, kept as the baseline the grasp benchmark
compares planners against (``scripts/bench_grasp.py``).

**Contact.** An object of diameter d between the tips is touched when the free tip spacing
D2(p) falls to d: the contact pressure p_c = D2^-1(d) (the kinematics' inverse). A sheet
thinner than the 1 mm rest gap is touched just below 0 Pa.

**Clamp force law (an assumption, calibrated to the paper's one number).** Past contact the
normal force of each finger grows linearly with how far the pressure is taken below contact:
``F_n = k (p_c - p)`` for p < p_c, else 0. Two fingers hold a weight by friction when
``2 mu F_n >= m g``. The paper reports holding up to 1 kg (paper_results.yaml, grasp); taking
that as the hold at the controller's lowest pressure (-60 kPa) on a thin object (p_c ~ 0) with
mu = 0.5 gives ``k = 1 kg * g / (2 * 0.5 * 60 kPa) = 1.635e-4 N/Pa``. The paper gives no
force-pressure curve, so the linearity and mu are assumptions, not measurements.

The clamp pressure for a mass m is then ``p = p_c - SF m g / (2 mu k)``, with safety factor SF.
"""
from __future__ import annotations

import dataclasses
import math

from softgrip_ros.checks import require_positive

G_M_PER_S2 = 9.80665


@dataclasses.dataclass(frozen=True)
class OneNumberClampLaw:
    """stiffness_n_per_pa: k; friction_coefficient: mu used when a command gives none;
    safety_factor: SF; min_squeeze_pa: the least squeeze below contact, even for a weightless
    object."""

    stiffness_n_per_pa: float = G_M_PER_S2 * 1.0 / (2.0 * 0.5 * 60e3)
    friction_coefficient: float = 0.5
    safety_factor: float = 2.0
    min_squeeze_pa: float = 3e3

    def __post_init__(self):
        require_positive(self, "stiffness_n_per_pa", "friction_coefficient", "safety_factor")
        if self.safety_factor < 1.0:
            raise ValueError(f"safety_factor must be at least 1, got {self.safety_factor}")
        if not (math.isfinite(self.min_squeeze_pa) and self.min_squeeze_pa >= 0.0):
            raise ValueError("min_squeeze_pa must be >= 0 and finite")

    def normal_force_n(self, pressure_pa: float, contact_pressure_pa: float) -> float:
        """F_n of one finger at ``pressure_pa`` (0 before contact)."""
        return self.stiffness_n_per_pa * max(contact_pressure_pa - pressure_pa, 0.0)

    def required_normal_force_n(self, mass_kg: float,
                                friction_coefficient: float | None = None) -> float:
        mu = self.friction_coefficient if friction_coefficient is None else friction_coefficient
        return self.safety_factor * mass_kg * G_M_PER_S2 / (2.0 * mu)

    def clamp_pressure_pa(self, mass_kg: float, contact_pressure_pa: float,
                          friction_coefficient: float | None = None) -> float:
        """The gauge pressure that holds ``mass_kg`` with the safety factor."""
        squeeze = self.required_normal_force_n(mass_kg,
                                               friction_coefficient) / self.stiffness_n_per_pa
        return contact_pressure_pa - max(squeeze, self.min_squeeze_pa)

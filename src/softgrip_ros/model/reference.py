"""The offline high-fidelity reference: a dynamic Cosserat rod in PyElastica, run to rest.

Optional (``bash scripts/setup.sh --with-reference``, or ``pip install softgrip_ros[reference]``):
the core install never imports it. It is the yardstick that L0, L1 and L2 are charted against
in ``scripts/bench_speed_accuracy.py``, not a model the nodes run.

The bending part of the left finger is one Cosserat rod of ``elements_per_segment`` elements per
segment, clamped at the first segment's start. Pressure enters as the rest curvature: the L1 free
curvature kappa0_i(p) of each segment (the same segment moments EI kappa0 as L2). The rigid tip
piece extends the last element. Gravity acts on the rod and on the tip piece's mass. An object
(a :class:`~softgrip_ros.model.rod.Circle` or :class:`~softgrip_ros.model.rod.Sheet`) pushes on
the chamber-face points, ``d2 + m_i`` from the backbone, with a stiff penalty spring; the force
acts at the face, so it also loads the rod with its moment. The pressure ramps from
``from_pressure_pa`` to ``pressure_pa``, then the rod runs with linear damping until it is at rest.

What it captures that L0, L1 and L2 do not:
  * axial stretch and transverse shear of the backbone (Cosserat, not Kirchhoff), with E from the
    same EI over a circular section and G = E/3 (incompressible silicone);
  * the dynamics of getting there: the pressure ramp, inertia, and a compliant (penalty) contact
    that the finger reaches by moving, not by a constrained minimisation;
  * curvature that varies element by element inside a segment under contact, at 4-8x L2's
    resolution.
What it does not capture either: the chamber walls' ballooning, the 3-D section, friction.
Its own errors: the penalty spring lets the face sink by force / stiffness (reported), and the
discretisation (elements per segment) converges at first order.
"""
from __future__ import annotations

import dataclasses
import functools
import math
import time

import numpy as np

from softgrip_ros.model.rod import Circle, RodFinger, Sheet

INSTALL_HINT = ("the reference model needs PyElastica: bash scripts/setup.sh --with-reference "
                "(or pip install 'softgrip_ros[reference]')")


def elastica_available() -> bool:
    try:
        import elastica  # noqa: F401
    except ImportError:
        return False
    return True


@dataclasses.dataclass
class ReferenceSolution:
    """A rest state of the left finger in the PyElastica rod."""

    pressure_pa: float
    # (x, z, tangent angle from +z) of the tip piece's end, as RodSolution.tip
    tip: tuple
    nodes_m: np.ndarray  # (K, 2) rod nodes x, z
    contact_force_n: float  # magnitude of the summed penalty forces on the finger
    max_penetration_m: float  # deepest face point inside the object at rest
    # the largest node speed at the end (rest means below rest_speed_m_s)
    max_speed_m_s: float
    at_rest: bool
    simulated_s: float
    steps: int
    wall_s: float


class ReferenceFinger:
    """The PyElastica reference of one finger, built on the same geometry, bending law and mass
    as ``rod`` (an L2 :class:`RodFinger`, which also supplies the start shape and face offsets).

    elements_per_segment: rod resolution (L2's default is 8).
    contact_stiffness_n_per_m: penalty spring per face node.
    damping_per_s: the uniform damping rate that brings the rod to rest.
    """

    def __init__(self, rod: RodFinger, elements_per_segment: int = 16,
                 contact_stiffness_n_per_m: float = 2e4, damping_per_s: float = 150.0,
                 time_step_s: float = 1e-5):
        if not elastica_available():
            raise ImportError(INSTALL_HINT)
        if not (isinstance(elements_per_segment, int) and 2 <= elements_per_segment <= 100):
            raise ValueError(
                "elements_per_segment must be an integer in [2, 100], got "
                f"{elements_per_segment!r}"
            )
        for name, value in (("contact_stiffness_n_per_m", contact_stiffness_n_per_m),
                            ("damping_per_s", damping_per_s), ("time_step_s", time_step_s)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive, got {value}")
        self.rod = RodFinger(rod.geometry, rod.calibration, rod.material,
                             elements_per_segment=elements_per_segment,
                             finger_width_m=rod.finger_width_m,
                             linear_density_kg_per_m=rod.linear_density_kg_per_m)
        self.contact_stiffness_n_per_m = contact_stiffness_n_per_m
        self.damping_per_s = damping_per_s
        self.time_step_s = time_step_s
        g = rod.geometry
        # a circular section carrying L2's EI and mass per length; its radius is half the wall
        # depth d2
        self.radius_m = 0.5 * g.chamber_bottom_to_sidewall_m
        area = math.pi * self.radius_m**2
        self.youngs_modulus_pa = self.rod.bending_stiffness_nm2 / (0.25 * math.pi *
                                                                   self.radius_m**4)
        self.density_kg_m3 = self.rod.linear_density_kg_per_m / area

    def solve(self, pressure_pa: float, obstacle: Circle | Sheet | None = None, gravity_m_s2=None,
              from_pressure_pa: float | None = None, ramp_s: float = 0.2, max_time_s: float = 3.0,
              rest_speed_m_s: float = 1e-5) -> ReferenceSolution:
        """Ramp the pressure from ``from_pressure_pa`` (default: ``pressure_pa``, no ramp) and run
        until every node moves slower than ``rest_speed_m_s`` or ``max_time_s`` of simulated
        time."""
        import elastica as ea

        from_pressure_pa = pressure_pa if from_pressure_pa is None else from_pressure_pa
        for name, value in (("pressure_pa", pressure_pa), ("from_pressure_pa", from_pressure_pa)):
            if not math.isfinite(value):
                raise ValueError(f"{name} must be finite, got {value}")
        rod_model = self.rod
        start_kappa, end_kappa = rod_model.free_curvatures(
            from_pressure_pa), rod_model.free_curvatures(pressure_pa)
        nodes, headings, _, surface, _, theta, direction, _ = rod_model._shape(start_kappa)
        gaps = rod_model._gaps(obstacle, surface)
        if gaps.size and gaps.min() < 0.0:
            raise ValueError(
                f"the object overlaps the finger's start shape at {from_pressure_pa:.0f} Pa")
        n = theta.size
        ds = rod_model.element_length_m
        position = np.zeros((3, n + 1))
        position[0], position[2] = nodes[:, 0], nodes[:, 1]
        directors = np.stack([_directors(angle) for angle in direction], axis=-1)  # (3, 3, n)

        class Simulator(ea.BaseSystemCollection, ea.Constraints, ea.Forcing, ea.Damping):
            pass

        turning_clamp, finger_loads = _build_classes()
        simulator = Simulator()
        cosserat = ea.CosseratRod.straight_rod(n, position[:, 0], position[:, 1] - position[:, 0],
                                               directors[0, :, 0], n * ds, self.radius_m,
                                               self.density_kg_m3,
                                               youngs_modulus=self.youngs_modulus_pa,
                                               shear_modulus=self.youngs_modulus_pa / 3.0,
                                               position=position, directors=directors)
        simulator.append(cosserat)
        phi0 = rod_model._start[2]

        def load_fraction(t):
            return 1.0 if ramp_s <= 0.0 else min(1.0, t / ramp_s)

        def first_heading(t):
            kappa = start_kappa + load_fraction(t) * (end_kappa - start_kappa)
            return phi0 - 0.5 * kappa[0] * ds

        simulator.constrain(cosserat).using(turning_clamp, constrained_position_idx=(0,),
                                            constrained_director_idx=(0,),
                                            first_heading=first_heading)
        gravity = None if gravity_m_s2 is None else np.asarray(gravity_m_s2,
                                                               dtype=float).reshape(2)
        loads = dict(model=rod_model, obstacle=obstacle, stiffness=self.contact_stiffness_n_per_m,
                     gravity=gravity)
        simulator.add_forcing_to(cosserat).using(finger_loads, **loads)
        simulator.dampen(cosserat).using(ea.AnalyticalLinearDamper,
                                         uniform_damping_constant=self.damping_per_s,
                                         time_step=self.time_step_s)
        simulator.finalize()
        stepper = ea.PositionVerlet()
        dt, t, steps = np.float64(self.time_step_s), np.float64(0.0), 0
        chunk = max(1, int(round(0.01 / self.time_step_s)))
        started = time.perf_counter()
        speed = math.inf
        while t < max_time_s:
            kappa = start_kappa + load_fraction(float(t)) * (end_kappa - start_kappa)
            # voronoi: mean of the two elements; elastica bends the other way about +y
            cosserat.rest_kappa[1, :] = -0.5 * (kappa[:-1] + kappa[1:])
            for _ in range(chunk):
                t = stepper.step(simulator, t, dt)
            steps += chunk
            speed = float(np.max(np.linalg.norm(cosserat.velocity_collection, axis=0)))
            if not np.isfinite(speed):
                break
            if t >= ramp_s and speed < rest_speed_m_s:
                break
        wall = time.perf_counter() - started
        return self._solution(pressure_pa, cosserat, obstacle, speed, rest_speed_m_s, float(t),
                              steps, wall)

    def _solution(self, pressure_pa, cosserat, obstacle, speed, rest_speed, simulated, steps,
                  wall) -> ReferenceSolution:
        position = cosserat.position_collection
        nodes = np.column_stack([position[0], position[2]])
        surface, _ = _face_points(self.rod, cosserat)
        gaps = self.rod._gaps(obstacle, surface)
        penetration = float(max(0.0, -gaps.min())) if gaps.size else 0.0
        force = _contact_forces(self.rod, obstacle, surface, self.contact_stiffness_n_per_m)
        tangent = cosserat.director_collection[2, :, -1]
        heading = math.atan2(tangent[0], tangent[2])
        tip_length = self.rod.geometry.tip_length_m
        tip = (nodes[-1, 0] + tip_length * math.sin(heading),
               nodes[-1, 1] + tip_length * math.cos(heading), heading)
        finite = bool(np.all(np.isfinite(nodes)))
        return ReferenceSolution(
            pressure_pa=float(pressure_pa), tip=tip, nodes_m=nodes,
            contact_force_n=float(np.linalg.norm(force.sum(axis=0))) if force.size else 0.0,
            max_penetration_m=penetration, max_speed_m_s=speed, at_rest=finite and
            speed < rest_speed, simulated_s=simulated, steps=steps, wall_s=wall)


def _directors(heading_rad: float) -> np.ndarray:
    """Rows d1 (inward normal), d2 (+y), d3 (tangent) for a heading measured from +z towards +x."""
    s, c = math.sin(heading_rad), math.cos(heading_rad)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def _face_points(model: RodFinger, cosserat):
    """Chamber-face points of the rod's nodes (K, 2) and the inward normals there (K, 2)."""
    tangents = cosserat.director_collection[2]  # (3, n) element tangents
    node_tangents = np.empty((3, tangents.shape[1] + 1))
    node_tangents[:, 0], node_tangents[:, -1] = tangents[:, 0], tangents[:, -1]
    node_tangents[:, 1:-1] = tangents[:, :-1] + tangents[:, 1:]
    heading = np.arctan2(node_tangents[0], node_tangents[2])
    normals = np.column_stack([np.cos(heading), -np.sin(heading)])
    nodes = np.column_stack([cosserat.position_collection[0], cosserat.position_collection[2]])
    return nodes + model.surface_offsets_m[:, None] * normals, normals


def _contact_forces(model: RodFinger, obstacle, surface, stiffness) -> np.ndarray:
    """Penalty forces (M, 2) on the chamber-face nodes, zero where they clear the object."""
    if obstacle is None:
        return np.zeros((0, 2))
    gaps = model._gaps(obstacle, surface)
    faces = surface[model.contact_nodes]
    if isinstance(obstacle, Circle):
        outward = faces - np.array([obstacle.center_x_m, obstacle.center_z_m])
        outward /= np.linalg.norm(outward, axis=1)[:, None]
    else:
        outward = np.tile([-1.0, 0.0], (faces.shape[0], 1))
    return (stiffness * np.maximum(0.0, -gaps))[:, None] * outward


@functools.lru_cache(maxsize=None)
def _build_classes():
    """Subclasses of PyElastica's, built on first use (the core install has no elastica)."""
    import elastica as ea

    class TurningClamp(ea.OneEndFixedBC):
        """The clamp at the first node; the first element's direction follows the pressure ramp
        (it is the chord of the first element, which turns by half that element's bend)."""

        def __init__(self, *args, first_heading, **kwargs):
            super().__init__(*args, **kwargs)
            self.first_heading = first_heading

        def constrain_values(self, system, time):
            self.fixed_directors_collection[...] = _directors(self.first_heading(float(time)))
            super().constrain_values(system, time)

    class FingerLoads(ea.NoForces):
        """Penalty contact at the chamber faces (force and its moment) and the tip piece's
        weight."""

        def __init__(self, model, obstacle, stiffness, gravity):
            super().__init__()
            self.model, self.obstacle, self.stiffness = model, obstacle, stiffness
            self.gravity = gravity

        def apply_forces(self, system, time=0.0):
            model = self.model
            if self.gravity is not None:
                weights = np.outer(self.gravity, model.node_masses_kg)  # (2, K)
                system.external_forces[0] += weights[0]
                system.external_forces[2] += weights[1]
                tip_force = model.tip_mass_kg * self.gravity
                tangent = system.director_collection[2, :, -1]
                arm = 0.5 * model.geometry.tip_length_m * np.array([tangent[0], tangent[2]])
                self._add(system, -1, tip_force, arm)
            if self.obstacle is None:
                return
            surface, _ = _face_points(model, system)
            forces = _contact_forces(model, self.obstacle, surface, self.stiffness)
            nodes = np.column_stack([system.position_collection[0], system.position_collection[2]])
            for index, force in zip(model.contact_nodes, forces):
                if force[0] != 0.0 or force[1] != 0.0:
                    self._add(system, index, force, surface[index] - nodes[index])

        @staticmethod
        def _add(system, node, force, arm):
            """A force at ``node + arm`` in the x-z plane: the force on the node, and its moment
            (about y) on the adjacent element(s), in their material frames."""
            system.external_forces[0, node] += force[0]
            system.external_forces[2, node] += force[1]
            # (r x F)_y with r, F in x-z
            moment_y = arm[1] * force[0] - arm[0] * force[1]
            last = system.director_collection.shape[2] - 1
            node = node if node >= 0 else last + 1
            elements = [k for k in (node - 1, node) if 0 <= k <= last]
            for k in elements:
                torque = np.array([0.0, moment_y / len(elements), 0.0])
                system.external_torques[:, k] += system.director_collection[:, :, k] @ torque

    return TurningClamp, FingerLoads

"""The fingers of the physics world: each a pseudo-rigid chain of hinged links, driven by the
chamber pressure through a bending law, with the outline of paper Table 1 for contact.

**The chain.** Each bending segment i (arc length s = L3 + h3) is split into sub-arcs; sub-arc j
of length l_j is replaced by a straight half-link, a hinge and a straight half-link (a
pseudo-rigid-body model). A link between two hinges then points along the true arc's tangent at
the boundary between its two sub-arcs, so every segment is split at the middle of its chamber:
the chamber face, where D1 and D2 are measured, sits on a link whose tangent is exact. With three
sub-arcs per segment the chain's tip lies within 0.2 mm of the PCC arc at every pressure of the
built-in models (tests/test_world.py).

**Stiffness and drive.** Sub-arc j of segment i bends by phi_j = theta_i(p) l_j / s in free
bending, theta_i from the selected bending law (L0 or L1 of the gripper model). Its hinge has the
stiffness of that piece of the L2 rod, k_j = EI / l_j with EI = 16 C10 t w d^2 / g
(:class:`~softgrip_ros.model.rod.RodFinger`), and is driven by the torque k_j phi_j(p): a free
finger settles exactly where the law says, and a blocked one presses with the rod's stiffness,
so the world's contact force follows the L2 force law. The world damps each hinge in proportion
to its stiffness, so that the chain's first mode has the damping ratio it is given.

**Outline** (in the finger's own frame: a along the backbone from the start of the bending
part, n from the backbone towards the other finger; the layout of
:class:`~softgrip_ros.model.fe.mesh.FingerLayout`):

* the base layer, d2 thick, along the whole inclined part and the vertical root;
* each chamber block as a box from the base to ``d2 + m_i - r_i`` over L3, topped by a dome, a
  cylinder across the finger's width of radius r_i whose crest is the chamber face at
  ``d2 + m_i`` (plus the bending law's ballooning, which the world applies as the pressure
  changes): the outline of :meth:`FingerGeometry.chamber_surface_offset_m`, which L2 shares, so
  that both touch an object at the same place. The tip chambers' domes clear the centre line by
  0.26 mm at rest;
* the rigid tip piece, from the backbone to an inner face parallel to the centre line at rest,
  ``tip_clearance_m`` from it. Table 1's d3 = 14.7 mm thick square tip would cross the centre line
  by 3 mm at rest, so the finger's end is taken as bevelled.

The right finger is the mirror image. Lengths in m, angles in rad, torques in N m.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from softgrip_ros.model.bending import BendingCalibration, make_bending_law
from softgrip_ros.model.geometry import CHAMBER_COUNT, FingerGeometry
from softgrip_ros.model.kinematics import GripperKinematics
from softgrip_ros.model.material import YeohMaterial
from softgrip_ros.model.rod import DEFAULT_FINGER_WIDTH_M, RodFinger

SUB_ARCS_PER_SEGMENT = 3
# The share of the chambers' volume change that their bending explains in the FE's free sweep
# (config/fe_reference.yaml at -5, 5 and 10 kPa, where it is valid): the rest is the walls
# ballooning. bending_volume_share() recomputes it; tests/test_world.py checks that they agree.
FE_BENDING_VOLUME_SHARE = 0.15
# the tip piece's inner face at rest, this far from the centre line (each finger)
TIP_CLEARANCE_M = 1.0e-3


@dataclasses.dataclass(frozen=True)
class SubArc:
    """One hinge of the chain: the segment (chamber index) it belongs to, its arc length, its share
    of the segment's bend, and its arc coordinate (from the start of the bending part)."""

    segment: int
    start_m: float
    length_m: float

    @property
    def middle_m(self) -> float:
        return self.start_m + 0.5 * self.length_m


class PseudoRigidFinger:
    """One finger as a chain of hinges (the right finger is its mirror image).

    bending: "l0" or "l1", the law of the gripper model that drives the hinges.
    finger_width_m: the out-of-plane width (an assumption the paper leaves open, as in L2).
    sub_arcs_per_segment: hinges per chamber segment (at least 2: the split at the chamber's
        middle, and more pieces after it).
    """

    def __init__(self, geometry: FingerGeometry, calibration: BendingCalibration,
                 bending: str = "l0", finger_width_m: float = DEFAULT_FINGER_WIDTH_M,
                 sub_arcs_per_segment: int = SUB_ARCS_PER_SEGMENT,
                 material: YeohMaterial | None = None):
        if not (isinstance(sub_arcs_per_segment, int) and 2 <= sub_arcs_per_segment <= 12):
            raise ValueError(f"sub_arcs_per_segment must be an integer in [2, 12], got "
                             f"{sub_arcs_per_segment!r}")
        self.geometry, self.calibration = geometry, calibration
        self.material = material or YeohMaterial()
        # the rod holds the one stiffness and mass model of a finger (and checks the width)
        self.rod = RodFinger(geometry, calibration, self.material, bending=bending,
                             finger_width_m=finger_width_m)
        self.law = make_bending_law(bending, geometry, self.material, calibration)
        self.bending = bending
        self.finger_width_m = float(finger_width_m)
        g = geometry
        segment = g.segment_length_m
        middle = 0.5 * g.chamber_length_m
        arcs = []
        for i in range(CHAMBER_COUNT):
            start = i * segment
            arcs.append(SubArc(i, start, middle))
            rest = (segment - middle) / (sub_arcs_per_segment - 1)
            for k in range(sub_arcs_per_segment - 1):
                arcs.append(SubArc(i, start + middle + k * rest, rest))
        self.sub_arcs = tuple(arcs)
        self._segment_of = np.array([a.segment for a in arcs])
        self._share = np.array([a.length_m / segment for a in arcs])
        lengths = np.array([a.length_m for a in arcs])
        self.hinge_stiffness_nm_per_rad = self.rod.bending_stiffness_nm2 / lengths
        self.linear_density_kg_per_m = self.rod.linear_density_kg_per_m
        self._bulge_per_pa = np.array([calibration.ballooning_compliance_per_pa * m * m /
                                       g.chamber_length_m for m in g.chamber_depths_m])
        # below the tips' contact the kinematics holds the faces' ballooning; so does the world
        self.contact_pressure_pa = GripperKinematics(geometry, calibration, self.material,
                                                     model=bending).contact_pressure_pa

    @property
    def hinge_count(self) -> int:
        return len(self.sub_arcs)

    def segment_angles(self, pressure_pa: float) -> np.ndarray:
        """theta_i of the five segments in free bending (rad), from the law."""
        return np.asarray(self.law.angles(float(pressure_pa)), dtype=float)

    def hinge_angles(self, pressure_pa: float) -> np.ndarray:
        """Each hinge's free-bending angle phi_j (rad), shape (hinge_count,)."""
        return self.segment_angles(pressure_pa)[self._segment_of] * self._share

    def hinge_torques(self, pressure_pa: float) -> np.ndarray:
        """The drive torque of each hinge at ``pressure_pa`` (N m): k_j phi_j(p)."""
        return self.hinge_stiffness_nm_per_rad * self.hinge_angles(pressure_pa)

    def segment_angles_of_hinges(self, hinge_angles) -> np.ndarray:
        """The five segments' bends of a chain state: each segment's hinges summed (rad)."""
        return np.bincount(self._segment_of, weights=np.asarray(hinge_angles, dtype=float),
                           minlength=CHAMBER_COUNT)

    def bulges_m(self, pressure_pa: float) -> np.ndarray:
        """Each chamber face's ballooning towards the other finger (m), as the kinematics has it
        (see :mod:`softgrip_ros.model.kinematics`; held below the tips' contact pressure)."""
        p = max(float(pressure_pa), self.contact_pressure_pa)
        return self._bulge_per_pa * self.law.saturation.effective_pressure(p)

    def bending_volume_per_rad_m3(self) -> np.ndarray:
        """a_i w (m^3/rad, shape (5,)): the air a chamber gains per radian its segment bends open.

        Sections stay plane (PCC) and turn about the backbone, so the cavity's end walls, which
        stand (L3 - 2 m1) / s of the segment's arc apart, open by that share of theta_i, and
        the cavity between heights n1 = d2 and n2 = d2 + m_i - m1 above the backbone gains
        (n2^2 - n1^2) / 2 of area per radian (the layout of
        :class:`~softgrip_ros.model.fe.mesh.FingerLayout`). docs/world.md compares it with the
        FE's cavity areas."""
        g = self.geometry
        wall, bottom = g.wall_thickness_m, g.chamber_bottom_to_sidewall_m
        share = (g.chamber_length_m - 2.0 * wall) / g.segment_length_m
        top = np.array([bottom + m - wall for m in g.chamber_depths_m])
        return self.finger_width_m * share * 0.5 * (top * top - bottom * bottom)

    def bending_compliance_m3_per_pa(self) -> float:
        """d/dp of the air both fingers' free bending adds, sum a_i w dtheta_i/dp at 0 Pa
        (m^3/Pa), from :meth:`bending_volume_per_rad_m3` and the law's slope."""
        slopes = np.asarray(self.law.angle_slopes(0.0), dtype=float)
        return 2.0 * float(np.dot(self.bending_volume_per_rad_m3(), slopes))

    def dome_radius_m(self, chamber: int) -> float:
        return self.geometry.dome_radius_m(chamber)

    # ---- the chain in the plane (the drawing, and the tests' reference) -----------------------
    def planar_chain(self, hinge_angles, bulges_m=None):
        """The left finger of a chain state in the gripper's (x, z) plane: a dict with
        ``backbone`` (K, 2), ``tip`` (x, z, tangent angle from +z), ``faces`` (5, 2: each chamber
        face's middle, ballooned by ``bulges_m``), ``headings`` at the faces (5,)."""
        g = self.geometry
        phi = g.inclination_rad
        x = -g.root_x_m
        points = [(x, 0.0), (x, g.vertical_height_m)]
        z = g.vertical_height_m
        x, z = x + g.first_chamber_offset_m * math.sin(phi), z + g.first_chamber_offset_m * \
            math.cos(phi)
        points.append((x, z))
        bulges = np.zeros(CHAMBER_COUNT) if bulges_m is None else np.asarray(bulges_m)
        faces, headings = np.zeros((CHAMBER_COUNT, 2)), np.zeros(CHAMBER_COUNT)
        middle = 0.5 * g.chamber_length_m
        for arc, angle in zip(self.sub_arcs, hinge_angles):
            half = 0.5 * arc.length_m
            x, z = x + half * math.sin(phi), z + half * math.cos(phi)
            points.append((x, z))
            phi -= angle
            x, z = x + half * math.sin(phi), z + half * math.cos(phi)
            points.append((x, z))
            face_arc = arc.segment * g.segment_length_m + middle
            if abs(arc.start_m + arc.length_m - face_arc) < 1e-12:
                offset = g.chamber_face_offset_m(arc.segment) + bulges[arc.segment]
                faces[arc.segment] = (x + offset * math.cos(phi), z - offset * math.sin(phi))
                headings[arc.segment] = phi
        tip = (x + g.tip_length_m * math.sin(phi), z + g.tip_length_m * math.cos(phi), phi)
        points.append(tip[:2])
        return {"backbone": np.array(points), "tip": tip, "faces": faces, "headings": headings}

    def outline(self, hinge_angles, bulges_m=None) -> list:
        """Closed polygons (each (K, 2) in x, z) of the left finger's side view: the base layer
        and root, each chamber block, the tip piece. For drawings."""
        chain = self.planar_chain(hinge_angles, bulges_m)
        g = self.geometry
        backbone = chain["backbone"]
        polygons = []
        # the base layer: the backbone offset inwards by d2 (normals from the polyline)
        tangents = np.gradient(backbone, axis=0)
        tangents /= np.linalg.norm(tangents, axis=1)[:, None]
        normals = np.column_stack([tangents[:, 1], -tangents[:, 0]])
        inner = backbone + g.chamber_bottom_to_sidewall_m * normals
        polygons.append(np.vstack([backbone, inner[::-1]]))
        for i, (face, heading) in enumerate(zip(chain["faces"], chain["headings"])):
            t = np.array([math.sin(heading), math.cos(heading)])
            n = np.array([math.cos(heading), -math.sin(heading)])
            depth = g.chamber_face_offset_m(i) - g.chamber_bottom_to_sidewall_m
            bulge = 0.0 if bulges_m is None else float(bulges_m[i])
            base = face - (depth + bulge) * n
            half = 0.5 * g.chamber_length_m
            radius = self.dome_radius_m(i)
            crest = face - radius * n
            angles = np.linspace(-0.5 * math.pi, 0.5 * math.pi, 13)
            dome = [crest + radius * (math.cos(a) * n + math.sin(a) * t) for a in angles]
            side = min(half, radius)
            polygons.append(np.array([base - half * t, base + half * t,
                                      crest + side * t] + dome[::-1] + [crest - side * t]))
        polygons.append(self.tip_outline(chain))
        return polygons

    def tip_outline(self, chain) -> np.ndarray:
        """The tip piece's side view (4, 2) for a chain state: its backbone, its bevelled face."""
        g = self.geometry
        x, z, phi = chain["tip"]
        t = np.array([math.sin(phi), math.cos(phi)])
        n = np.array([math.cos(phi), -math.sin(phi)])
        end = np.array([x, z])
        start = end - g.tip_length_m * t
        near, far = self.tip_thicknesses_m()
        return np.array([start, end, end + far * n, start + near * n])

    def tip_thicknesses_m(self) -> tuple[float, float]:
        """The tip piece's thickness at its start and at its end (m): its inner face at rest lies
        ``TIP_CLEARANCE_M`` from the centre line (see the module docstring), never thicker than
        the chamber face before it."""
        g = self.geometry
        cos_i, sin_i = math.cos(g.inclination_rad), math.sin(g.inclination_rad)
        start_arc = g.first_chamber_offset_m + CHAMBER_COUNT * g.segment_length_m
        thickness = []
        for arc in (start_arc, g.inclined_length_m):
            backbone_x = -g.root_x_m + arc * sin_i
            thickness.append(min((-TIP_CLEARANCE_M - backbone_x) / cos_i,
                                 g.chamber_face_offset_m(CHAMBER_COUNT - 1)))
        if min(thickness) <= 0.0:
            raise ValueError(f"geometry {g.name}: the tip piece would cross the centre line at "
                             "rest; the finger's layout leaves it no thickness")
        return thickness[0], thickness[1]


def bending_volume_share(finger: PseudoRigidFinger, reference,
                         pressures_pa=(-5e3, 5e3, 10e3)) -> float:
    """The share of the FE's cavity area change that the bending explains: sum over chambers and
    ``pressures_pa`` of a_i (theta_i(p) - theta_i(0)), a_i the cavity's first moment
    (:meth:`PseudoRigidFinger.bending_volume_per_rad_m3` per unit width) and theta_i the FE
    backbone's turn over segment i, over the sum of the cavity areas' changes.
    ``reference``: a :class:`~softgrip_ros.model.fe_data.FEReference`."""
    g = finger.geometry
    moments = finger.bending_volume_per_rad_m3() / finger.finger_width_m

    def segment_turns(point) -> np.ndarray:
        backbone = point.backbone_m
        pieces = np.diff(backbone, axis=0)
        headings = np.unwrap(np.arctan2(pieces[:, 0], pieces[:, 1]))
        arc = np.concatenate([[0.0], np.cumsum(np.hypot(pieces[:, 0], pieces[:, 1]))])
        middles = 0.5 * (arc[1:] + arc[:-1])
        starts = g.first_chamber_offset_m + g.segment_length_m * np.arange(CHAMBER_COUNT + 1)
        tangents = np.interp(starts, middles, headings)
        return -np.diff(tangents)  # opening turns the heading towards -x: positive theta

    rest = reference.at(0.0)
    bent = explained = 0.0
    for pressure in pressures_pa:
        point = reference.at(pressure)
        bent += float(np.dot(moments, segment_turns(point) - segment_turns(rest)))
        explained += float(np.sum(np.subtract(point.cavity_areas_m2, rest.cavity_areas_m2)))
    return bent / explained

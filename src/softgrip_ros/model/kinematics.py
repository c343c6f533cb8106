"""Piecewise-constant-curvature kinematics of both fingers (paper eq. 18-24), forward and inverse.

A segment of arc length s bent by theta moves its end along the chord of a circular arc,
``s * sinc(theta/2)`` long, in the direction of the tangent turned by theta/2, and turns the
tangent by theta. This chord form is exact and smooth at theta = 0 (the straight finger);
the textbook ``s sin(theta)/theta`` is 0/0 there. Segments chain as planar rigid motions
from the root (frame and layout in :mod:`softgrip_ros.model.geometry`). The paper's eq. 33
adds chord *lengths*, which is right only for aligned segments, so it is not used.

Chamber surfaces, which the paper's alpha, D1 and D2 are measured on, are modelled
explicitly: each face sits ``d2 + m_i`` from the backbone and balloons under pressure by
``delta_i = c_b * p_eff * m_i^2 / L3`` towards the other finger, which also tilts its
surface tangent (at the face edge nearer the root) by ``psi_i = 4 delta_i / L3``
(a parabolic dome over the chamber length). Deeper root chambers balloon more.

Derived quantities (paper Sec. 4):
    alpha: included angle between the root- and tip-chamber surface tangents (rad),
        starting at the cavity type's initial value;
    D1, D2: spacing between the two root- (tip-) chamber surfaces (m), signed
        (negative would mean the faces overlap);
    tip pose: end of each finger's backbone, and its tangent angle from +z.

Negative pressure closes the fingers until the tip chambers touch (D2 = 0); below that
pressure the pose stays at contact and ``in_contact`` is set.
"""
from __future__ import annotations

import dataclasses
import math
import types

import numpy as np
from scipy.optimize import brentq

from softgrip_ros.model.bending import BendingCalibration, make_bending_law
from softgrip_ros.model.geometry import CHAMBER_COUNT, FingerGeometry
from softgrip_ros.model.material import YeohMaterial


def _sinc_slope_array(x):
    """d sinc(x) / dx = (x cos x - sin x) / x^2, by its series near 0 (the direct form cancels)."""
    x = np.asarray(x, dtype=float)
    small = np.abs(x) < 1e-3
    safe = np.where(small, 1.0, x)
    x2 = x * x
    series = x * (-1.0 / 3.0 + x2 / 30.0 - x2 * x2 / 840.0)
    return np.where(small, series, (safe * np.cos(safe) - np.sin(safe)) / (safe * safe))


def _sinc_slope_scalar(x: float) -> float:
    if abs(x) < 1e-3:
        x2 = x * x
        return x * (-1.0 / 3.0 + x2 / 30.0 - x2 * x2 / 840.0)
    return (x * math.cos(x) - math.sin(x)) / (x * x)


def _ratio_scalar(sin_x: float, x: float) -> float:
    """sin(x)/x given sin(x): exact to rounding for any x != 0, however small."""
    return sin_x / x if x != 0.0 else 1.0


def _trig_scalar(x: float) -> tuple[float, float, float]:
    """sin x, cos x and sinc x = sin(x)/x for a half-angle x."""
    sin_x = math.sin(x)
    return sin_x, math.cos(x), _ratio_scalar(sin_x, x)


def _trig_array(x):
    sin_x = np.sin(x)
    return sin_x, np.cos(x), np.divide(sin_x, x, out=np.ones_like(x), where=x != 0.0)


# Taylor coefficients of sinc(x) = sin(x)/x in x^2, up to x^16: for |x| < 1 the truncation error is
# below 1/19! ~ 8e-18, under float64 rounding.
_SINC_TAYLOR = tuple((-1.0)**k / math.factorial(2 * k + 1) for k in range(9))


def _trig_small_array(x):
    """:func:`_trig_array` for half-angles known to lie within (-1, 1) rad (segments bent by less
    than 2 rad), exact to rounding there and ~3x faster: sinc by its Taylor polynomial (Horner,
    in place), which needs no division and no special case at 0; sin = x sinc x;
    cos = sqrt(1 - sin^2)."""
    square = x * x
    sinc_x = np.full_like(x, _SINC_TAYLOR[-1])
    for coefficient in reversed(_SINC_TAYLOR[:-1]):
        sinc_x *= square
        sinc_x += coefficient
    sin_x = x * sinc_x
    return sin_x, np.sqrt(1.0 - sin_x * sin_x), sinc_x


_SCALAR_OPS = types.SimpleNamespace(trig=_trig_scalar, sinc_slope=_sinc_slope_scalar)
_ARRAY_OPS = types.SimpleNamespace(trig=_trig_array, sinc_slope=_sinc_slope_array)
_SMALL_ANGLE_ARRAY_OPS = types.SimpleNamespace(trig=_trig_small_array,
                                               sinc_slope=_sinc_slope_array)
BATCH_CHUNK = 8192  # keeps a chunk's temporaries in cache; 100k at once runs ~2x slower
# A batch's float results, one row each, in one block: a block of 4 MB or more is backed by huge
# pages (numpy asks for them), where separate arrays took ~45 page faults per 1,000 pressures.
_BATCH_ROWS = ("left_tip_x_m", "left_tip_z_m", "left_tip_angle_rad", "included_angle_rad",
               "root_spacing_m", "tip_spacing_m")


@dataclasses.dataclass(frozen=True)
class GripperPose:
    """The modelled state at one pressure (floats) or a batch of N pressures (arrays of shape
    (N,)).

    Tip poses are given for the left finger; the right finger is its mirror image
    (x -> -x, angle -> -angle): see :meth:`right_tip`.
    """

    pressure_pa: object
    segment_angles_rad: object  # (5,) or (N, 5)
    left_tip_x_m: object
    left_tip_z_m: object
    left_tip_angle_rad: object  # tangent angle from +z, positive towards the centre line
    included_angle_rad: object  # alpha
    root_spacing_m: object  # D1
    tip_spacing_m: object  # D2
    in_validated_range: object
    in_contact: object
    model: str

    def right_tip(self):
        return -self.left_tip_x_m, self.left_tip_z_m, -self.left_tip_angle_rad


class GripperKinematics:
    """Forward and inverse model of the two-finger gripper for one bending law.

    model: "l0" (linear, eq. 16-17) or "l1" (nonlinear Yeoh moment balance).
    max_pressure_pa: the highest gauge pressure the inverse may command.
    """

    MODEL_MAX_PRESSURE_PA = 60.0e3  # the paper's FEA range; the forward model refuses beyond
    MODEL_MIN_PRESSURE_PA = -100.0e3  # no gauge vacuum goes below -1 atm

    def __init__(self, geometry: FingerGeometry, calibration: BendingCalibration,
                 material: YeohMaterial | None = None, model: str = "l0",
                 max_pressure_pa: float = 50.0e3):
        self.geometry = geometry
        self.material = material or YeohMaterial()
        self.calibration = calibration
        self.bending = make_bending_law(model, geometry, self.material, calibration)
        self.model = self.bending.name
        if not (0.0 < max_pressure_pa <= self.MODEL_MAX_PRESSURE_PA):
            raise ValueError(
                f"max_pressure_pa must lie in (0, {self.MODEL_MAX_PRESSURE_PA}] Pa, got "
                f"{max_pressure_pa}"
            )
        self.max_pressure_pa = float(max_pressure_pa)
        g = geometry
        self._face_offsets = tuple(g.chamber_face_offset_m(i) for i in range(CHAMBER_COUNT))
        self._bulge_per_pa = tuple(calibration.ballooning_compliance_per_pa * m * m /
                                   g.chamber_length_m for m in g.chamber_depths_m)
        self._bulge_per_pa_array = np.array(self._bulge_per_pa)
        self._tilt_per_bulge = 4.0 / g.chamber_length_m
        self._half_chamber_fraction = 0.5 * g.chamber_length_m / g.segment_length_m
        self.contact_pressure_pa = self._find_contact_pressure()

    # ---- forward -------------------------------------------------------------------------
    def pose(self, pressure_pa: float) -> GripperPose:
        """The full state for one pressure, in pure Python floats (the fast path)."""
        p = _checked_scalar(pressure_pa)
        self._check_range(p, p)
        p_kin = p if p > self.contact_pressure_pa else self.contact_pressure_pa
        return self._assemble(p, self.bending.angles(p_kin), self._bulges(p_kin), _SCALAR_OPS,
                              in_contact=p <= self.contact_pressure_pa)

    def poses(self, pressures_pa) -> GripperPose:
        """The full state for a 1-D array of pressures, vectorised (in cache-sized chunks)."""
        p = _checked_array(pressures_pa)
        if p.size:
            self._check_range(float(p.min()), float(p.max()))
        if p.size <= BATCH_CHUNK:
            return self._poses_chunk(p)
        rows = len(_BATCH_ROWS)
        floats = np.empty((rows + CHAMBER_COUNT, p.size))
        flags = np.empty((2, p.size), dtype=bool)
        for start in range(0, p.size, BATCH_CHUNK):
            part = slice(start, start + BATCH_CHUNK)
            chunk = self._poses_chunk(p[part])
            for row, name in enumerate(_BATCH_ROWS):
                floats[row, part] = getattr(chunk, name)
            floats[rows:, part] = chunk.segment_angles_rad.T
            flags[0, part], flags[1, part] = chunk.in_validated_range, chunk.in_contact
        return GripperPose(pressure_pa=p, segment_angles_rad=floats[rows:].T,
                           in_validated_range=flags[0], in_contact=flags[1], model=self.model,
                           **dict(zip(_BATCH_ROWS, floats[:rows])))

    def _poses_chunk(self, p: np.ndarray) -> GripperPose:
        p_kin = np.maximum(p, self.contact_pressure_pa)
        p_eff = self.bending.saturation.effective_pressure(p_kin)
        theta = self.bending.angle_columns(p_kin, p_eff)
        bulge = [
            k * p_eff if i in self.MEASURED_CHAMBERS else 0.0
            for i, k in enumerate(self._bulge_per_pa)
        ]
        small = all(float(np.max(np.abs(column), initial=0.0)) < 2.0 for column in theta)
        return self._assemble(p, theta, bulge, _SMALL_ANGLE_ARRAY_OPS if small else _ARRAY_OPS,
                              in_contact=p <= self.contact_pressure_pa)

    def _bulges(self, p_kin: float):
        p_eff = self.bending.saturation.effective_pressure(p_kin)
        return tuple(k * p_eff for k in self._bulge_per_pa)

    def _assemble(self, p, theta, bulge, ops, in_contact) -> GripperPose:
        """theta, bulge: 5 per-segment values (floats, or 1-D arrays over the batch)."""
        faces, tip, _ = self._chain(theta, bulge, ops)
        (root_x, root_angle), (tip_face_x, tip_face_angle) = faces
        thetas = tuple(theta) if ops is _SCALAR_OPS else np.column_stack(theta)
        validated = (p >= self.contact_pressure_pa) & (
            p <= self.calibration.validated_max_pressure_pa)
        return GripperPose(
            pressure_pa=p, segment_angles_rad=thetas, left_tip_x_m=tip[0], left_tip_z_m=tip[1],
            left_tip_angle_rad=tip[2],
            included_angle_rad=self.geometry.initial_included_angle_rad +
            (root_angle - tip_face_angle), root_spacing_m=-2.0 * root_x,
            tip_spacing_m=-2.0 * tip_face_x,
            in_validated_range=bool(validated) if ops is _SCALAR_OPS else validated,
            in_contact=in_contact, model=self.model)

    # alpha, D1 and D2 need the root and tip chambers only
    MEASURED_CHAMBERS = (0, CHAMBER_COUNT - 1)

    def _chain(self, theta, bulge, ops):
        """Walk the left finger's backbone. Returns the root and tip chamber faces (x,
        surface angle), the tip (x, z, angle) and the segment ends (x, z, theta, heading
        sin, heading cos) for the derivative.

        The tangent is carried as (sin phi, cos phi) and turned by half-angle rotations,
        so each segment needs sin, cos and sinc of theta/2 (``ops.trig``) and nothing else
        transcendental.
        """
        g = self.geometry
        phi = g.inclination_rad
        sin_phi, cos_phi = math.sin(phi), math.cos(phi)
        x = -g.root_x_m + g.first_chamber_offset_m * sin_phi
        z = g.vertical_height_m + g.first_chamber_offset_m * cos_phi
        seg = g.segment_length_m
        faces, ends = [], []
        for i in range(CHAMBER_COUNT):
            th = theta[i]
            if i in self.MEASURED_CHAMBERS:
                faces.append(self._face(x, phi, sin_phi, cos_phi, th, bulge[i], i, ops))
            half = 0.5 * th
            sin_half, cos_half, sinc_half = ops.trig(half)
            chord = seg * sinc_half
            sin_heading = sin_phi * cos_half - cos_phi * sin_half  # phi - theta/2
            cos_heading = cos_phi * cos_half + sin_phi * sin_half
            x = x + chord * sin_heading
            z = z + chord * cos_heading
            sin_phi = sin_heading * cos_half - cos_heading * sin_half  # phi - theta
            cos_phi = cos_heading * cos_half + sin_heading * sin_half
            phi = phi - th
            ends.append((x, z, th, sin_heading, cos_heading))
        tip = (x + g.tip_length_m * sin_phi, z + g.tip_length_m * cos_phi, phi)
        return faces, tip, ends

    def _face(self, x, phi, sin_phi, cos_phi, th, bulge, i, ops):
        """Chamber i's face centre x and surface angle, for a segment starting at (x, phi).
        Only x is needed: alpha, D1 and D2 are measured across the gap between the fingers."""
        half = 0.5 * th * self._half_chamber_fraction  # a partial arc of L3/2 into the segment
        sin_half, cos_half, sinc_half = ops.trig(half)
        chord = self.geometry.segment_length_m * self._half_chamber_fraction * sinc_half
        sin_heading = sin_phi * cos_half - cos_phi * sin_half
        cos_heading = cos_phi * cos_half + sin_phi * sin_half
        cos_c = cos_heading * cos_half + sin_heading * sin_half
        # the inward normal at the chamber centre is (cos phi_c, -sin phi_c)
        return (x + chord * sin_heading + (self._face_offsets[i] + bulge) * cos_c,
                phi - 2.0 * half + self._tilt_per_bulge * bulge)

    def tip_for_angles(self, segment_angles_rad) -> tuple[float, float, float]:
        """The left tip (x, z, angle) for explicit segment bends (5 floats), without ballooning."""
        thetas = _checked_angles(segment_angles_rad)
        return self._chain(thetas, [0.0] * CHAMBER_COUNT, _SCALAR_OPS)[1]

    def spacings_for_angles(self, pressure_pa: float, segment_angles_rad) -> tuple[float, float]:
        """(D1, D2) in m for explicit segment bends (a rod's, say), with this model's chamber
        ballooning at ``pressure_pa``: the surfaces measured on another backbone."""
        thetas = _checked_angles(segment_angles_rad)
        p = _checked_scalar(pressure_pa)
        faces = self._chain(thetas, self._bulges(max(p, self.contact_pressure_pa)),
                            _SCALAR_OPS)[0]
        return -2.0 * faces[0][0], -2.0 * faces[1][0]

    def free_shape(self, pressure_pa: float) -> tuple[tuple, float]:
        """(the left tip (x, z, angle), D2) of fingers that do not meet: below the tips' contact
        pressure they bend on, past each other (the ballooning held as in :meth:`pose`). The
        reference of a finger bending on its own, e.g. the physics world's with no contact."""
        p = _checked_scalar(pressure_pa)
        self._check_range(p, p)
        faces, tip, _ = self._chain(self.bending.angles(p),
                                    self._bulges(max(p, self.contact_pressure_pa)), _SCALAR_OPS)
        return tip, -2.0 * faces[-1][0]

    # ---- derivative -----------------------------------------------------------------------
    def tip_slope(self, pressures_pa):
        """d(left tip x, z, angle)/dp for an array of pressures: shape (N, 3), in m/Pa and rad/Pa.

        Analytic: each segment's chord derivative plus the rigid rotation of everything
        after it about the segment's end. Zero in contact, where the pose is blocked.
        """
        p = _checked_array(pressures_pa)
        p_kin = np.maximum(p, self.contact_pressure_pa)
        slopes = np.asarray(self.bending.angle_slopes(p_kin))
        theta = self.bending.angle_columns(p_kin)
        dx, dz = self._tip_position_slope(theta, [slopes[:, i] for i in range(CHAMBER_COUNT)],
                                          _ARRAY_OPS)
        blocked = p < self.contact_pressure_pa
        return np.where(blocked[:, None], 0.0, np.column_stack([dx, dz, -slopes.sum(axis=1)]))

    def tip_slope_at(self, pressure_pa: float) -> tuple[float, float, float]:
        """:meth:`tip_slope` for one pressure, in pure Python floats (the nodes' fast path)."""
        p = _checked_scalar(pressure_pa)
        self._check_range(p, p)
        if p < self.contact_pressure_pa:
            return 0.0, 0.0, 0.0
        slopes = self.bending.angle_slopes(p)
        dx, dz = self._tip_position_slope(self.bending.angles(p), slopes, _SCALAR_OPS)
        return dx, dz, -sum(slopes)

    def _tip_position_slope(self, theta, slopes, ops):
        _, tip, ends = self._chain(theta, [0.0] * CHAMBER_COUNT, ops)
        seg = self.geometry.segment_length_m
        dx = dz = 0.0
        for (end_x, end_z, th, sin_heading, cos_heading), slope in zip(ends, slopes):
            # own chord: seg * sinc(th/2) along the heading phi - th/2
            chord = seg * ops.trig(0.5 * th)[2]
            dchord = 0.5 * seg * ops.sinc_slope(0.5 * th)
            own_x = dchord * sin_heading - 0.5 * chord * cos_heading
            own_z = dchord * cos_heading + 0.5 * chord * sin_heading
            # everything after turns by -dtheta about the end: d(v) = (-v_z, v_x)
            rot_x, rot_z = -(tip[1] - end_z), tip[0] - end_x
            dx = dx + (own_x + rot_x) * slope
            dz = dz + (own_z + rot_z) * slope
        return dx, dz

    def backbone(self, pressure_pa: float, points_per_segment: int = 8) -> np.ndarray:
        """The left finger's backbone as a polyline, shape (K, 2) in (x, z); mirror x for the
        right."""
        p = _checked_scalar(pressure_pa)
        if points_per_segment < 1:
            raise ValueError("points_per_segment must be >= 1")
        self._check_range(p, p)
        thetas = self.bending.angles(max(p, self.contact_pressure_pa))
        g = self.geometry
        x, z, phi = -g.root_x_m, 0.0, 0.0
        points = [(x, z)]
        pieces = [(g.vertical_height_m, 0.0, 1)]
        pieces_phi_jump = {1: g.inclination_rad}
        pieces.append((g.first_chamber_offset_m, 0.0, 1))
        pieces += [(g.segment_length_m, th, points_per_segment) for th in thetas]
        pieces.append((g.tip_length_m, 0.0, 1))
        for index, (length, th, steps) in enumerate(pieces):
            phi += pieces_phi_jump.get(index, 0.0)
            for _ in range(steps):
                part, dth = length / steps, th / steps
                chord = part * _ratio_scalar(math.sin(0.5 * dth), 0.5 * dth)
                x += chord * math.sin(phi - 0.5 * dth)
                z += chord * math.cos(phi - 0.5 * dth)
                phi -= dth
                points.append((x, z))
        return np.array(points)

    # ---- inverse --------------------------------------------------------------------------
    def tip_spacing_range_m(self) -> tuple[float, float]:
        """The D2 the gripper can reach between tip contact and max_pressure_pa."""
        return 0.0, self.pose(self.max_pressure_pa).tip_spacing_m

    def pressure_for_tip_spacing(self, tip_spacing_m: float) -> float:
        """The gauge pressure (Pa) at which D2 equals tip_spacing_m, by Brent's method.

        D2(p) is monotone between tip contact and max_pressure_pa. A D2 outside that
        range raises ValueError saying what the gripper can reach.
        """
        target = _checked_scalar(tip_spacing_m, "tip spacing")
        low_d2, high_d2 = self.tip_spacing_range_m()
        rounding = 1e-12 * high_d2  # a forward value at an end may round just past it
        if high_d2 < target <= high_d2 + rounding:
            return self.max_pressure_pa
        if not low_d2 <= target <= high_d2:
            raise ValueError(
                f"tip spacing {target * 1e3:.2f} mm is out of reach: the gripper spans "
                f"{low_d2 * 1e3:.2f} mm (tips touching) to {high_d2 * 1e3:.2f} mm "
                f"(at the {self.max_pressure_pa / 1e3:.1f} kPa limit)")
        if target == low_d2:
            return self.contact_pressure_pa
        return brentq(lambda p: self._free_tip_spacing(p) - target, self.contact_pressure_pa,
                      self.max_pressure_pa, xtol=1e-9, rtol=4 * np.finfo(float).eps)

    def _free_tip_spacing(self, p: float) -> float:
        """D2 at p ignoring tip contact (the inverse's and the contact search's cheap forward
        map)."""
        faces, _, _ = self._chain(self.bending.angles(p), self._bulges(p), _SCALAR_OPS)
        return -2.0 * faces[-1][0]

    def _find_contact_pressure(self) -> float:
        """The (negative) pressure at which the tip chambers touch, D2 = 0."""
        gap = self._free_tip_spacing
        low = -1.0
        while gap(low) > 0.0:
            low *= 2.0
            if low < self.MODEL_MIN_PRESSURE_PA:
                return self.MODEL_MIN_PRESSURE_PA
        return brentq(gap, low, 0.0, xtol=1e-9, rtol=4 * np.finfo(float).eps)

    def _check_range(self, low: float, high: float):
        if low < self.MODEL_MIN_PRESSURE_PA or high > self.MODEL_MAX_PRESSURE_PA:
            raise ValueError(
                f"pressure out of the model's range [{self.MODEL_MIN_PRESSURE_PA / 1e3:.0f}, "
                f"{self.MODEL_MAX_PRESSURE_PA / 1e3:.0f}] kPa: got {low / 1e3:.3f} to "
                f"{high / 1e3:.3f} kPa"
            )


def _checked_scalar(value, what: str = "pressure") -> float:
    if isinstance(value, (np.ndarray, list, tuple)):
        raise ValueError(
            f"{what} must be a single number here, got an array of shape {np.shape(value)}")
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a number, got {value!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"{what} must be finite, got {value}")
    return value


def _checked_angles(segment_angles_rad) -> list:
    thetas = [float(t) for t in segment_angles_rad]
    if len(thetas) != CHAMBER_COUNT or not all(math.isfinite(t) for t in thetas):
        raise ValueError(f"need {CHAMBER_COUNT} finite segment angles, got {segment_angles_rad!r}")
    return thetas


def _checked_array(values) -> np.ndarray:
    array = np.asarray(values, dtype=float)
    if array.ndim != 1:
        raise ValueError(f"pressures must be a 1-D array, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        bad = int(np.flatnonzero(~np.isfinite(array))[0])
        raise ValueError(f"pressures must be finite: element {bad} is {array[bad]}")
    return array


class TipTable:
    """The left tip (x, z, angle) of a model and its slope d/dp, tabulated once on a pressure grid
    and looked up by cubic Hermite interpolation (each node's value and exact slope): a few
    microseconds in pure Python, where an L1 pose and slope take about 150 us (five root solves).
    The nodes publish tip poses at up to 200 Hz; this is how L1 fits in that budget.

    The grid starts at the contact pressure (below it the pose is blocked: constant, zero slope),
    so the kink there is a node, not inside a cell. ``max_error_m`` and ``max_angle_error_rad``
    are measured at build time at the cell midpoints, where a Hermite cell's error peaks, against
    the model itself; build refuses a grid whose error exceeds ``max_allowed_error_m``.
    """

    def __init__(self, kinematics: GripperKinematics, step_pa: float = 100.0,
                 max_allowed_error_m: float = 1e-7):
        if not (math.isfinite(step_pa) and 1.0 <= step_pa <= 5e3):
            raise ValueError(f"step_pa must lie in [1, 5000] Pa, got {step_pa}")
        self.kinematics = kinematics
        self.model = kinematics.model
        low, high = kinematics.contact_pressure_pa, kinematics.max_pressure_pa
        cells = max(1, math.ceil((high - low) / step_pa))
        self.low_pa, self.high_pa, self.step_pa = low, high, (high - low) / cells
        grid = np.linspace(low, high, cells + 1)
        pose = kinematics.poses(grid)
        self._values = np.column_stack(
            [pose.left_tip_x_m, pose.left_tip_z_m, pose.left_tip_angle_rad])
        self._slopes = kinematics.tip_slope(grid)
        # the contact node's slope from above
        self._slopes[0] = kinematics.tip_slope(np.array([low + 1e-6]))[0]
        self._rows = [(tuple(v), tuple(s))
                      for v, s in zip(self._values.tolist(), self._slopes.tolist())]
        # the shape: the five segment angles (analytic slopes) and D2 (its slope by a central
        # difference of 1 Pa, one-sided at the grid's ends), for joint_states and the grasp
        angle_slopes = np.asarray(kinematics.bending.angle_slopes(grid))
        angle_slopes[0] = np.asarray(kinematics.bending.angle_slopes(np.array([low + 1e-6])))[0]
        above, below = np.minimum(grid + 1.0, high), np.maximum(grid - 1.0, low)
        d2_slope = ((kinematics.poses(above).tip_spacing_m - kinematics.poses(below).tip_spacing_m)
                    / (above - below))
        shape_values = np.column_stack([pose.segment_angles_rad, pose.tip_spacing_m])
        shape_slopes = np.column_stack([angle_slopes, d2_slope])
        self._shape_rows = [(tuple(v), tuple(s))
                            for v, s in zip(shape_values.tolist(), shape_slopes.tolist())]
        midpoints = 0.5 * (grid[1:] + grid[:-1])
        exact = kinematics.poses(midpoints)
        looked_up = self._midpoint_values(self._values, self._slopes)
        self.max_error_m = float(
            np.max(
                np.hypot(looked_up[:, 0] - exact.left_tip_x_m,
                         looked_up[:, 1] - exact.left_tip_z_m)))
        self.max_angle_error_rad = float(np.max(np.abs(looked_up[:, 2] -
                                                       exact.left_tip_angle_rad)))
        shapes = self._midpoint_values(shape_values, shape_slopes)
        self.max_shape_angle_error_rad = float(np.max(np.abs(shapes[:, :CHAMBER_COUNT] -
                                                             exact.segment_angles_rad)))
        self.max_tip_spacing_error_m = float(np.max(np.abs(shapes[:, CHAMBER_COUNT] -
                                                           exact.tip_spacing_m)))
        if max(self.max_error_m, self.max_tip_spacing_error_m) > max_allowed_error_m:
            raise ValueError(
                f"a {step_pa:g} Pa grid interpolates {self.model} within {self.max_error_m:.2e} m "
                "only, "
                f"more than the allowed {max_allowed_error_m:.2e} m: use a finer step")

    def _midpoint_values(self, values: np.ndarray, slopes: np.ndarray) -> np.ndarray:
        """What :meth:`_lookup` gives at every cell's midpoint (t = 1/2 in its Hermite basis),
        for all cells at once: (cells, columns)."""
        return 0.5 * (values[:-1] + values[1:]) + 0.125 * self.step_pa * (slopes[:-1] - slopes[1:])

    def tip(self, pressure_pa: float) -> tuple[tuple, tuple]:
        """((x, z, angle), (dx/dp, dz/dp, dangle/dp)) of the left tip at ``pressure_pa``
        (floats)."""
        return self._lookup(self._rows, pressure_pa)

    def shape(self, pressure_pa: float) -> tuple[tuple, float]:
        """(the five segment angles theta_i, rad; D2, m) at ``pressure_pa``, tabulated as the
        tip is (blocked below contact)."""
        values, _ = self._lookup(self._shape_rows, pressure_pa)
        return values[:CHAMBER_COUNT], values[CHAMBER_COUNT]

    def _lookup(self, rows, pressure_pa: float) -> tuple[tuple, tuple]:
        p = _checked_scalar(pressure_pa)
        self.kinematics._check_range(p, p)
        if p <= self.low_pa:
            return rows[0][0], (0.0,) * len(rows[0][0])
        if p >= self.high_pa:
            if p > self.high_pa:
                raise ValueError(f"pressure {p:.0f} Pa above the table's {self.high_pa:.0f} Pa")
            return rows[-1]
        position = (p - self.low_pa) / self.step_pa
        i = min(int(position), len(rows) - 2)
        t = position - i
        (v0, s0), (v1, s1) = rows[i], rows[i + 1]
        t2, t3, h = t * t, t * t * t, self.step_pa
        h00, h01 = 2 * t3 - 3 * t2 + 1, -2 * t3 + 3 * t2
        h10, h11 = (t3 - 2 * t2 + t) * h, (t3 - t2) * h
        value = tuple(h00 * a + h10 * da + h01 * b + h11 * db
                      for a, da, b, db in zip(v0, s0, v1, s1))
        # the interpolant's derivative
        g00, g10, g11 = (6 * t2 - 6 * t) / h, 3 * t2 - 4 * t + 1, 3 * t2 - 2 * t
        slope = tuple(g00 * (a - b) + g10 * da + g11 * db for a, da, b, db in zip(v0, s0, v1, s1))
        return value, slope


def pcc_joints(segment_angles_rad, segment_length_m: float) -> tuple:
    """Each bending segment of arc length s bent by theta as three joints, (turn, chord, turn):
    a turn of theta/2, a straight chord of s sinc(theta/2) and a turn of theta/2, which put the
    segment's end where the circular arc ends, with its tangent (the URDF's form: turns
    positive away from the centre line, as the opening pressure bends the finger)."""
    joints = []
    for theta in segment_angles_rad:
        half = 0.5 * float(theta)
        joints.append((half, segment_length_m * _ratio_scalar(math.sin(half), half), half))
    return tuple(joints)


def chord_joints(boundaries) -> tuple:
    """(turn, chord, turn) for each piece of a planar curve given at its ends: ``boundaries``
    [(x, z, tangent angle from +z)], one more than the pieces. Exact for any shape at those
    ends (the L2 rod's too); for a circular arc both turns are theta/2 (:func:`pcc_joints`)."""
    joints = []
    for (x0, z0, phi0), (x1, z1, phi1) in zip(boundaries[:-1], boundaries[1:]):
        heading = math.atan2(x1 - x0, z1 - z0)
        joints.append((phi0 - heading, math.hypot(x1 - x0, z1 - z0), heading - phi1))
    return tuple(joints)

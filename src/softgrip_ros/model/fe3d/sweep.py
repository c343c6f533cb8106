"""The 3-D finger's sweep: 0 to +50 kPa and 0 to -60 kPa, measured at each pressure, cached by
the hash of its inputs; and the pressures at which neighbouring chamber blocks first touch.

The positive side is loaded in one model from rest, the vacuum side in a fresh one. A side ends
early where Newton fails (``vacuum_stop`` / ``positive_stop`` say where and why); what was
measured before stays.
"""
from __future__ import annotations

import dataclasses
import math
import time

from softgrip_ros.model.fe.finger import (SweepProgress, hash_inputs, read_cache,
                                         write_cache)
from softgrip_ros.model.fe.solver import NotConverged, YeohMaterial
from softgrip_ros.model.fe_data import at_pressure
from softgrip_ros.model.fe3d.finger import DEFAULT_WIDTH_M, FE3DState, Finger3D
from softgrip_ros.model.geometry import FingerGeometry

# bump when a change to the 3-D FE changes its results, so that caches are recognised as stale
FE3D_MODEL_VERSION = 1
# the pressures, and 2 kPa for the small-pressure curvature of the band
POSITIVE_PRESSURES_PA = (0.0, 2e3) + tuple(5e3 * k for k in range(1, 11))
NEGATIVE_PRESSURES_PA = tuple(-5e3 * k for k in range(1, 13))
SWEEP_ELEMENT_SIZE_M = 3.0e-3
# load steps within a side: at most this large (a step that fails is halved)
LOAD_STEP_PA = 5e3
# two end walls "touch" once their least gap is below this: the penalty lets them overlap by
# micrometres, and the gap closes slowly as they come together
TOUCH_GAP_M = 0.02e-3


@dataclasses.dataclass
class FE3DSweep:
    """One finger of ``width_m`` swept over both sides; ``states`` ascending in pressure."""

    inputs_hash: str
    width_m: float
    plane_strain: bool
    element_size_m: float
    tetrahedra: int
    states: list
    positive_stop: str  # why the positive side ended before its last pressure ('' if not)
    vacuum_stop: str
    seconds: float  # the solve time, when it was computed (the cache keeps it)

    def at(self, pressure_pa: float) -> FE3DState:
        return at_pressure(self.states, pressure_pa, "the 3-D FE sweep")

    @property
    def vacuum_limit_pa(self) -> float:
        return min(s.pressure_pa for s in self.states)

    @property
    def interpenetration_max_m(self) -> float:
        return max(s.interpenetration_m for s in self.states)

    def block_contact_first_pa(self) -> list:
        """Per neighbouring pair of blocks (1-2, 2-3, ...), the pressure (Pa) at which their gap
        first falls to TOUCH_GAP_M, interpolated linearly between the sweep's pressures; NaN if
        it does not within the positive side."""
        positive = [s for s in self.states if s.pressure_pa >= 0.0]
        out = []
        for pair in range(len(positive[0].block_gaps_m)):
            found = math.nan
            for before, after in zip(positive, positive[1:]):
                g0, g1 = before.block_gaps_m[pair], after.block_gaps_m[pair]
                if g1 <= TOUCH_GAP_M < g0:
                    share = (g0 - TOUCH_GAP_M) / (g0 - g1)
                    found = before.pressure_pa + share * (after.pressure_pa - before.pressure_pa)
                    break
            out.append(found)
        return out

    def to_dict(self) -> dict:
        out = dataclasses.asdict(self)
        out["states"] = [s.to_dict() for s in self.states]
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "FE3DSweep":
        data = dict(data)
        data["states"] = [FE3DState.from_dict(s) for s in data["states"]]
        return cls(**data)


def inputs_hash(geometry: FingerGeometry, material: YeohMaterial, width_m: float,
                element_size_m: float, plane_strain: bool, positive_pa, negative_pa) -> str:
    """What a 3-D sweep depends on: the geometry, the material, the width, the mesh, the
    pressures and the code's version."""
    return "fe3d-" + hash_inputs(geometry, material, {
        "width_m": round(float(width_m), 9), "plane_strain": bool(plane_strain),
        "element_size_m": round(float(element_size_m), 9),
        "positive_pa": [round(float(p), 3) for p in positive_pa],
        "negative_pa": [round(float(p), 3) for p in negative_pa],
        "load_step_pa": LOAD_STEP_PA, "version": FE3D_MODEL_VERSION,
    })


def _check_side(pressures, sign: int, what: str) -> list:
    values = [float(p) for p in pressures]
    if any(not math.isfinite(p) or p * sign <= 0.0 for p in values) or any(
            abs(b) <= abs(a) for a, b in zip(values, values[1:])):
        raise ValueError(f"{what} must be {'positive' if sign > 0 else 'negative'} and grow "
                         f"in size, got {pressures!r}")
    return values


def sweep3d(geometry: FingerGeometry, width_m: float = DEFAULT_WIDTH_M,
            element_size_m: float = SWEEP_ELEMENT_SIZE_M, *, plane_strain: bool = False,
            positive_pa=POSITIVE_PRESSURES_PA, negative_pa=NEGATIVE_PRESSURES_PA,
            material: YeohMaterial | None = None, progress=print,
            use_cache: bool = True) -> FE3DSweep:
    """The finger measured at rest, at each of ``positive_pa`` (from rest, ascending; 0 may lead)
    and, on a fresh model, at each of ``negative_pa`` (descending), with contact. Cached by
    :func:`inputs_hash`; ``progress(message)`` hears of each pressure. ValueError for pressures
    out of order; Finger3D's errors for a width or mesh out of range."""
    material = material or YeohMaterial()
    positive = _check_side([p for p in positive_pa if p != 0.0], +1, "positive pressures")
    negative = _check_side(negative_pa, -1, "negative pressures")
    key = inputs_hash(geometry, material, width_m, element_size_m, plane_strain, positive,
                      negative)
    if use_cache:
        found = read_cache(key, FE3DSweep.from_dict)
        if found is not None:
            return found
    import ngsolve as ng

    started = time.perf_counter()
    report = SweepProgress(1 + len(positive) + len(negative), progress)
    stops = {}
    states = []
    with ng.TaskManager():
        for sign, side in ((+1, positive), (-1, negative)):
            finger = Finger3D(geometry, width_m, material, element_size_m,
                              plane_strain=plane_strain)
            if sign > 0:
                states.append(finger.measure())
                report(0.0, states[-1])
            stops[sign] = ""
            for pressure in side:
                try:
                    finger.solve(pressure, first_step_pa=LOAD_STEP_PA)
                except NotConverged as error:
                    stops[sign] = f"Newton failed beyond {finger.pressure_pa / 1e3:+.2f} kPa " \
                                  f"({error})"
                    report(pressure, stops[sign])
                    break
                states.append(finger.measure())
                report(pressure, states[-1])
    result = FE3DSweep(
        inputs_hash=key, width_m=float(width_m), plane_strain=bool(plane_strain),
        element_size_m=float(element_size_m), tetrahedra=finger.tetrahedra,
        states=sorted(states, key=lambda s: s.pressure_pa), positive_stop=stops[+1],
        vacuum_stop=stops[-1], seconds=time.perf_counter() - started)
    if use_cache:
        write_cache(key, result.to_dict())
    return result


def curvature_at(result: FE3DSweep, pressure_pa: float) -> float:
    """The mean curvature (1/m) at ``pressure_pa``, less the rest's."""
    return (result.at(pressure_pa).mean_curvature_per_m
            - result.at(0.0).mean_curvature_per_m)


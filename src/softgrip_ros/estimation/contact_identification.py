"""The fingers' contact learnt on a rigid object of known size (no ROS): softgrip_identify's
known-object step.

The grasp sensing (:mod:`softgrip_ros.estimation.grasp_sensing`) judges a closing by how much air
volume fingers stopped by an object keep: the bending's share of the chambers' dV/dp
(``bending_volume_share``). The built-in share is the FE's prediction for the paper's fingers; a
user's fingers, their walls and their tubing make it their own.

Clamps on an object of known size ``d`` and clamps on nothing, from the same opening: the fingers
stop where their free shape is that of ``p_d`` (the pressure whose modelled D2 is ``d``), or where
they meet each other. The share is the one under which the readings are best explained with the
fingers stopped there (the least summed chi-square, as the sensing weighs the readings). Both
kinds are needed: one object's closings alone are explained alike by a smaller share and a larger
contact, so an empty hand would pass for the object. With the share found, each closing must be
judged as what it was, by the sensing's own test. Its 95 % interval is where the chi-square rises
by 3.84 (scaled by the reduced chi-square when above 1), widened to the scatter of the closings'
own best shares when they scatter more.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from softgrip_ros.estimation.grasp_sensing import (ContactModel, ObjectStatus, closing_range_pa,
                                                   fit_contact, judge_closing, share_chi_square)

# the shares tried (dimensionless), all at once: the FE's prediction lies inside, and so do the
# values for thick-walled fingers (little bending volume) and thin ones (most of it)
SHARE_GRID = tuple(float(x) for x in np.round(np.linspace(0.02, 0.60, 291), 4))
CHI2_95 = 3.84  # the chi-square rise of a 95 % interval on one parameter


@dataclasses.dataclass(frozen=True)
class ShareFit:
    """The identified ``bending_volume_share`` (dimensionless) and its 95 % interval; the known
    object's size (m) and contact pressure (Pa gauge); each closing's felt size (m) under the
    identified share and under the model's own; the fit's reduced chi-square; the shares tried
    and their summed chi-square."""

    bending_volume_share: float
    ci95: tuple
    known_size_m: float
    known_contact_pa: float
    felt_sizes_m: tuple
    felt_sizes_before_m: tuple
    reduced_chi2: float
    shares: tuple
    costs: tuple


def fit_bending_share(object_jobs: list, empty_jobs: list, model: ContactModel,
                      known_size_m: float, shares=SHARE_GRID, progress=None) -> ShareFit:
    """The share that best explains the closings (MotionJobs, clamps from a steady opening wider
    than the object): ``object_jobs`` on the same rigid object of ``known_size_m`` m,
    ``empty_jobs`` on nothing; see the module. Both are needed: on one object's closings alone
    a smaller share and a larger contact explain the readings alike, so that an empty hand
    passes for the object. The interval is the wider of the chi-square's and the scatter of
    the closings' own best shares (Student's t). ``progress(text)`` is told each step.
    ValueError when a kind of closing is missing, the object does not fit between the meeting
    fingers and the closings' start, the readings cannot be fitted, the best share lies at the
    grid's edge (the data do not pin it), or with the best share the sensing does not judge
    each closing as what it was."""
    if not object_jobs or not empty_jobs:
        raise ValueError("needs closings on the object and closings on nothing, got "
                         f"{len(object_jobs)} and {len(empty_jobs)}")
    if any(job.opening for job in (*object_jobs, *empty_jobs)):
        raise ValueError("an opening is not a closing")
    if not (math.isfinite(known_size_m) and known_size_m > 0.0):
        raise ValueError(f"the known object's size must be a positive length, got "
                         f"{known_size_m} m")
    known_pa = float(model.pressure_for_tip_spacing(known_size_m))
    for job in object_jobs:
        low, high = closing_range_pa(model, job)
        if not (model.meet_pressure_pa < known_pa < high):
            raise ValueError(
                f"a {known_size_m * 1e3:.1f} mm object is met at {known_pa / 1e3:.1f} kPa, "
                f"outside the closing from {high / 1e3:.1f} kPa to the fingers' meeting at "
                f"{model.meet_pressure_pa / 1e3:.1f} kPa: open wider first, or use a larger "
                "object")
    closings = [(job, known_pa) for job in object_jobs] + [
        (job, model.meet_pressure_pa) for job in empty_jobs]
    grid = np.asarray(shares, dtype=float)
    table = []
    for index, (job, stop) in enumerate(closings):
        if progress is not None:
            progress(f"contact: closing {index + 1}/{len(closings)} under {grid.size} shares")
        table.append(share_chi_square(job.record, model, job.stamp_s, stop, grid))
    per_closing = np.array(table).T  # (shares, closings)
    cost = per_closing.sum(axis=1)
    if not np.all(np.isfinite(cost)):
        raise ValueError("the closings' readings cannot be fitted at their contacts")
    best = int(np.argmin(cost))
    if best in (0, grid.size - 1):
        raise ValueError(
            f"the readings are best explained at the edge of the shares tried "
            f"({grid[best]:.2f} of [{grid[0]:.2f}, {grid[-1]:.2f}]): the closings do not "
            "say how much volume the fingers' bending makes (did the object stop them?)")
    share = _parabola_minimum(grid, cost)
    fitted = dataclasses.replace(model, bending_volume_share=share)
    fits = [fit_contact(job.record, fitted, job.stamp_s, *closing_range_pa(fitted, job))
            for job, _ in closings]
    for index, ((job, stop), fit) in enumerate(zip(closings, fits)):
        verdict = judge_closing(fit, fitted, job.stamp_s, known_size_m)
        expected = (ObjectStatus.CONTACT_CLOSING if stop == known_pa
                    else ObjectStatus.NO_OBJECT)
        if verdict.status != expected:
            what = "the object" if stop == known_pa else "nothing"
            raise ValueError(f"closing {index + 1}, on {what}, is not judged so with the best "
                             f"share {share:.3f}: {verdict.evidence}")
    readings = sum(fit.samples for fit in fits)
    reduced = float(cost[best]) / max(readings - 1, 1)
    level = float(cost[best]) + CHI2_95 * max(reduced, 1.0)
    bounds = [_crossing(grid[best::-1], cost[best::-1], level),
              _crossing(grid[best:], cost[best:], level)]
    own = np.array([_parabola_minimum(grid, per_closing[:, k])
                    for k in range(per_closing.shape[1])])
    if own.size >= 3:
        from scipy.stats import t as student
        half = float(student.ppf(0.975, own.size - 1) * own.std(ddof=1) / math.sqrt(own.size))
        bounds = [min(bounds[0], share - half), max(bounds[1], share + half)]
    felt_before = tuple(
        fit_contact(job.record, model, job.stamp_s, *closing_range_pa(model, job)).object_size_m
        for job in object_jobs)
    return ShareFit(share, tuple(float(b) for b in bounds), float(known_size_m), known_pa,
                    tuple(fit.object_size_m for fit in fits[:len(object_jobs)]), felt_before,
                    reduced, tuple(float(g) for g in grid), tuple(float(c) for c in cost))


def _crossing(x: np.ndarray, y: np.ndarray, level: float) -> float:
    """Where ``y``, from its minimum at ``x[0]`` outwards, first reaches ``level`` (linear
    between the points); the last ``x`` when it never does (the data do not bound it there)."""
    for k in range(1, len(x)):
        if y[k] >= level:
            return float(x[k - 1] + (x[k] - x[k - 1]) * (level - y[k - 1]) / (y[k] - y[k - 1]))
    return float(x[-1])


def _parabola_minimum(x: np.ndarray, y: np.ndarray) -> float:
    """Where the parabola through the lowest of ``y`` and its neighbours has its minimum (the
    lowest point itself at an edge or when flat)."""
    k = int(np.argmin(y))
    if k in (0, len(y) - 1):
        return float(x[k])
    denominator = y[k - 1] - 2.0 * y[k] + y[k + 1]
    if denominator <= 0.0:
        return float(x[k])
    return float(x[k] - 0.5 * (x[k] - x[k - 1]) * (y[k + 1] - y[k - 1]) / denominator)

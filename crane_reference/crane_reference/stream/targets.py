"""Changing the task while the reference runs: the reachability check of a new :class:`Task` and the C2
blend from the constraints in force to the new ones."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable

import numpy as np

from ..dynamics.projection import PROJECTION_ITERATIONS, held_points
from ..model.parameters import Task
from ..model.profiles import Blend, Constant, Profile
from ..motion.constraints import ConstraintSet, paper_constraints
from ..motion.programmed_motion import POSITION_TOLERANCE, ProgrammedMotion
from ..motion.simulation import Scenario, Slew

ELLIPSE_POINTS = 145  # points per ellipse walked by the check
CHECK_HEIGHTS = 3  # heights between the present and the new final target height


class UnreachableTargetError(ValueError):
    """A requested ellipse / z target leaves the crane's workspace (or comes too near a singularity)."""


def check_task(scenario: Scenario, task: Task, z_now: float, margin: float) -> None:
    """Raise :class:`UnreachableTargetError` unless E can follow the whole ellipse of ``task`` at every
    height between ``z_now`` [m] and its final height z_E,s + z_increment, with the smallest singular
    value of K_dc (the task Jacobian of the dependent coordinates) at least ``margin``.  Checked with the
    model's own position constraints: walking around the ellipse with the slew joint
    (:attr:`~crane_reference.motion.simulation.Scenario.slew`, the paper's column), solving for the dependent
    coordinates (the paper's luff and knuckle angles) by continuation from the model's initial configuration."""
    for field in dataclasses.fields(Task):
        value = getattr(task, field.name)
        if not math.isfinite(value):
            raise UnreachableTargetError(f"{field.name} = {value}: must be a finite number")
    if task.ellipse_a <= 0 or task.ellipse_b <= 0 or task.rise_time <= 0:
        raise UnreachableTargetError("ellipse_a, ellipse_b and rise_time must be > 0")
    q = scenario.model.initial_q.copy()
    phi = np.linspace(-0.5 * np.pi, 1.5 * np.pi, ELLIPSE_POINTS)
    for z in np.linspace(z_now, scenario.z_static + task.z_increment, CHECK_HEIGHTS):
        points = np.column_stack((task.ellipse_a * np.cos(phi), task.ellipse_b * np.sin(phi), np.full(phi.size, z)))
        q = _hold(_motion(scenario, task.ellipse_a, task.ellipse_b, z), scenario.slew, q, points, margin)


def _motion(scenario: Scenario, a: float, b: float, z: float) -> ProgrammedMotion:
    """The paper's constraints for the ellipse (a, b) at the constant height z."""
    return ProgrammedMotion(scenario.dynamics, paper_constraints(Constant(a), Constant(b), Constant(z)),
                            min_singular_value=0.0)


def _hold(check: ProgrammedMotion, slew: Slew, q: np.ndarray, points: np.ndarray, margin: float) -> np.ndarray:
    """q with E held at each of ``points`` (N, 3) [m] in turn on ``check``'s constraints, by continuation from
    ``q`` with the ``slew`` joint at the azimuth atan2(y, x)
    (:func:`~crane_reference.dynamics.projection.held_points`): the
    solution at the last point; :class:`UnreachableTargetError` at the first point where E cannot be held, or
    only with the smallest singular value of K_dc below ``margin``."""
    q, held, positions, singular_values = held_points(
        np.ascontiguousarray(q, dtype=float), points, check.constraints.coefficients(0.0), check.holonomic_dependent,
        check.dynamics.chain, np.array(slew, dtype=float), POSITION_TOLERANCE, PROJECTION_ITERATIONS)
    off = np.hypot(positions[:, 0] - points[:, 0], positions[:, 1] - points[:, 1])
    failed = np.flatnonzero(~held | ~(off <= POINT_TOLERANCE) | ~(singular_values >= margin))
    if failed.size:
        i = failed[0]
        (x, y, z), p = points[i], positions[i]
        where = f"ellipse point ({x:.3f}, {y:.3f}) m at z = {z:.3f} m"
        if not held[i]:
            raise UnreachableTargetError(f"{where} is out of the crane's reach")
        if not off[i] <= POINT_TOLERANCE:  # the constraints also hold with E across the axis
            raise UnreachableTargetError(f"{where} is out of the crane's reach on the boom's side (the constraints "
                                         f"hold only with E at ({p[0]:.3f}, {p[1]:.3f}) m)")
        raise UnreachableTargetError(f"{where} is too near a stretch/fold singularity (smallest singular "
                                     f"value of K_dc {singular_values[i]:.3g} < {margin:g})")
    return q


POINT_TOLERANCE = 1e-6  # [m]
REACH_RESOLUTION = 1e-3  # [m]
REACH_FIRST_STEP = 0.5  # [m]


def reach(scenario: Scenario, radius: float, heights: Iterable[float], margin: float) -> tuple[float, float]:
    """[r_min, r_max] [m]: the distances from the column's axis at which E can be held at every one of
    ``heights`` (with the margin of :func:`check_task`), found from ``radius`` (reachable) outwards and
    inwards by continuation with halving steps, to :data:`REACH_RESOLUTION` (rounded inwards).  A circle of
    radius r in that range is then reachable point by point; an ellipse with both semi-axes in it needs
    :func:`check_task` still (this bounds the parameter ranges a user is offered)."""
    low, high = 0.0, math.inf
    for z in heights:
        bounds = []
        for direction in (-1.0, 1.0):
            q = _hold(_motion(scenario, radius, radius, z), scenario.slew, scenario.model.initial_q,
                      np.array([[radius, 0.0, z]]),
                      margin)
            r, step = radius, REACH_FIRST_STEP
            while step >= REACH_RESOLUTION:
                trial = r + direction * step
                try:
                    if trial <= 0.0:
                        raise UnreachableTargetError("E on the column's axis")
                    q = _hold(_motion(scenario, trial, trial, z), scenario.slew, q, np.array([[trial, 0.0, z]]),
                              margin)
                    r = trial
                except UnreachableTargetError:
                    step *= 0.5
            bounds.append(r)
        low, high = max(low, bounds[0]), min(high, bounds[1])
    return math.ceil(low / REACH_RESOLUTION) * REACH_RESOLUTION, math.floor(high / REACH_RESOLUTION) * REACH_RESOLUTION


def settled(profile: Profile, t: float) -> Profile:
    """``profile`` from t on with the blends in it that have finished by t dropped (also those inside a
    blend still running), so re-targeting faster than the blend time does not nest profiles further than
    the blends in progress."""
    if not isinstance(profile, Blend):
        return profile
    if t >= profile.t0 + profile.duration:
        return settled(profile.new, t)
    return dataclasses.replace(profile, old=settled(profile.old, t))


def blend_constraints(old: ConstraintSet, new: ConstraintSet, t0: float, duration: float) -> ConstraintSet:
    """Each constraint of ``old`` moving to its counterpart in ``new`` (same types, in order) along C2
    :class:`~crane_reference.model.profiles.Blend` of every profile field over [t0, t0 + duration]: at t0
    the constraints are those in force, so the motion stays C2; at the end they are the new ones."""
    if [type(c) for c in old.constraints] != [type(c) for c in new.constraints]:
        raise ValueError(f"cannot blend {[type(c).__name__ for c in old.constraints]} into "
                         f"{[type(c).__name__ for c in new.constraints]}: the constraint types must match")
    return ConstraintSet(tuple(
        dataclasses.replace(before, **{f.name: Blend(settled(getattr(before, f.name), t0), getattr(after, f.name), t0,
                                                     duration) for f in dataclasses.fields(before)})
        for before, after in zip(old.constraints, new.constraints, strict=True)))

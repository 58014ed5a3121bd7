"""Changing the task while the reference runs: the reachability check of a new :class:`Task` and the C2
blend from the constraints in force to the new ones."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..dynamics.linalg import smallest_singular_value
from ..model.parameters import Task
from ..model.profiles import Blend, Constant, Profile
from ..motion.constraints import ConstraintSet, paper_constraints
from ..motion.programmed_motion import ProgrammedMotion, ProjectionError
from ..motion.simulation import Scenario

ELLIPSE_POINTS = 145  # points per ellipse walked by the check
CHECK_HEIGHTS = 3  # heights between the present and the new final target height


class UnreachableTargetError(ValueError):
    """A requested ellipse / z target leaves the crane's workspace (or comes too near a singularity)."""


def check_task(scenario: Scenario, task: Task, z_now: float, margin: float) -> None:
    """Raise :class:`UnreachableTargetError` unless E can follow the whole ellipse of ``task`` at every
    height between ``z_now`` [m] and its final height z_E,s + z_increment, with the smallest singular
    value of K_dc (the task Jacobian of the dependent coordinates) at least ``margin``.  Checked with the
    model's own position constraints: walking around the ellipse with the column azimuth, solving for the
    luff and knuckle angles by continuation from the model's initial configuration."""
    for field in dataclasses.fields(Task):
        value = getattr(task, field.name)
        if not math.isfinite(value):
            raise UnreachableTargetError(f"{field.name} = {value}: must be a finite number")
    if task.ellipse_a <= 0 or task.ellipse_b <= 0 or task.rise_time <= 0:
        raise UnreachableTargetError("ellipse_a, ellipse_b and rise_time must be > 0")
    model = scenario.model
    q = model.initial_q.copy()
    for z in np.linspace(z_now, scenario.z_static + task.z_increment, CHECK_HEIGHTS):
        check = ProgrammedMotion(scenario.dynamics, paper_constraints(
            Constant(task.ellipse_a), Constant(task.ellipse_b), Constant(z)), min_singular_value=0.0)
        for phi in np.linspace(-0.5 * np.pi, 1.5 * np.pi, ELLIPSE_POINTS):
            x, y = task.ellipse_a * np.cos(phi), task.ellipse_b * np.sin(phi)
            q[model.drive_joint] = np.arctan2(y, x)
            where = f"ellipse point ({x:.3f}, {y:.3f}) m at z = {z:.3f} m"
            try:
                q, (p, C) = check.project_positions(0.0, q)
            except (ProjectionError, np.linalg.LinAlgError) as failure:
                raise UnreachableTargetError(f"{where} is out of the crane's reach") from failure
            grads = check.constraints.position_jacobian(0.0, p)
            sigma = smallest_singular_value(np.ascontiguousarray(grads @ C[:, check.dependent]))
            if not sigma >= margin:
                raise UnreachableTargetError(f"{where} is too near a stretch/fold singularity (smallest singular "
                                             f"value of K_dc {sigma:.3g} < {margin:g})")


def settled(profile: Profile, t: float) -> Profile:
    """Drop blends that have finished by t, so repeated re-targeting does not nest profiles forever."""
    while isinstance(profile, Blend) and t >= profile.t0 + profile.duration:
        profile = profile.new
    return profile


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

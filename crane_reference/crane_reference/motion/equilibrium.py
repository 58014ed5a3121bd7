"""Consistent start: static equilibrium of the constrained crane.

At rest (qd = 0, so h = 0) the programmed motion equations (8) reduce to P^T Q(q) = 0 on the
independent directions, together with Phi(q, 0) = 0.  The drive's joint (the paper's column) and the other
independent actuated joints are held by their actuators at their initial positions, so their rows are not
balanced by the free system but by the holding forces -(P^T Q) there; the drive's t_hold is reported (zero
for the paper's symmetric layout).  All other independent coordinates (base, RFE angles, joints on springs)
are free and settle under gravity and the springs; the dependent coordinates follow from the constraints.
The drive's own torque is taken just before t0 (off for the paper's torque step, zero for a spring drive whose
motor angle starts at the drive joint's initial angle).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import root

from ..model.chain import PRISMATIC
from .programmed_motion import ProgrammedMotion


class EquilibriumError(RuntimeError):
    """No static equilibrium was found."""


@dataclass(frozen=True)
class Equilibrium:
    """The equilibrium ``q``; the drive's ``holding_torque`` t_hold [N m or N]; ``holding_forces`` by the name
    of each held joint (the drive's among them) [N m or N]; the largest unbalanced generalized force left."""

    q: np.ndarray
    holding_torque: float
    max_force_residual: float
    holding_forces: dict[str, float]


def reduced_static_forces(motion: ProgrammedMotion, t: float, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P^T Q at qd = 0 [N or N m per independent coordinate], q with q_dc projected); P = B for ideal
    constraints, E_ic for servo-constraints (see :class:`ProgrammedMotion`)."""
    q, _ = motion.project_positions(t, q)
    solution = motion.solve(t, q, np.zeros_like(q), left_limit=True)
    return motion.projection(solution).T @ solution.dynamics.Q, q


def static_equilibrium(motion: ProgrammedMotion, q_start: np.ndarray, t0: float = 0.0,
                       force_tolerance: float = 1e-7) -> Equilibrium:
    """Equilibrium near ``q_start`` with the drive's coordinate and the independent actuated joints held at their
    values in ``q_start``."""
    motion.require_holonomic("a static equilibrium")
    model = motion.dynamics.model
    drive = model.drive_joint
    held = {drive, *(model.index(name) for name in model.actuated_joints)}
    rows = np.flatnonzero([k not in held for k in motion.independent])
    free = motion.independent[rows]
    q_base = q_start.copy()

    def residual(x: np.ndarray) -> np.ndarray:
        q = q_base.copy()
        q[free] = x
        forces, _ = reduced_static_forces(motion, t0, q)
        return forces[rows]

    q = q_base.copy()
    message = "no free coordinate: the held joints and the task fix the crane"
    if free.size:
        result = root(residual, q_start[free], method="hybr", options={"xtol": 1e-15})
        q[free], message = result.x, result.message
    forces, q = reduced_static_forces(motion, t0, q)
    worst = float(np.max(np.abs(forces[rows]), initial=0.0))
    if not worst <= force_tolerance:
        joint = model.joints[free[int(np.argmax(np.abs(forces[rows])))]]
        raise EquilibriumError(f"static equilibrium not found: largest unbalanced generalized force {worst:.3g} "
                               f"{'N' if joint.kind == PRISMATIC else 'N m'} on {joint.name} (solver: {message})")
    drive_row = int(np.flatnonzero(motion.independent == drive)[0])
    holding = {model.joint_names[k]: -float(force) for k, force in zip(motion.independent, forces, strict=True)
               if k in held}
    return Equilibrium(q, -float(forces[drive_row]), worst, holding)

"""Feedforward along the reference (:data:`FEEDFORWARDS`): none; the reference's own constraint forces at the
actuated joints (``reference``: what the reference node's preview carries as its efforts, without the drive's
torque, which the plant applies itself); or the inverse dynamics of the rigid crane (``rigid``):

    tau_ff = (M qdd + h - Q)[actuated joints]

of the rigid crane along its programmed motion (the same task and realisation as the reference; for a
flexible crane the rigid crane's own reference, whose accelerations carry no boom vibration), with Q
holding gravity, the support springs, damping and the drive as the plant has it.  These are the
torques that move the rigid crane as the reference does, as far as actuators on these joints can: for
a reference realised by the luff and knuckle torques (servo-constraints) the other rows balance and
tau_ff is exact on the rigid crane; under the ideal constraints the force at E also acts on the base,
which no actuator here reproduces.
"""

from __future__ import annotations

import numpy as np

from ..dynamics.chain_dynamics import CraneDynamics
from ..dynamics.evaluation import imbalance_rows
from ..model.chain import build_model
from ..model.description import CraneDescription
from ..model.drive import make_drive

FEEDFORWARDS = ("none", "rigid", "reference")


class RigidInverseDynamics:
    """tau_ff of the module docstring for references over the coordinates ``joint_names``."""

    def __init__(self, params: CraneDescription, joint_names: tuple[str, ...]):
        model = build_model(params, "rigid")
        self.dynamics = CraneDynamics(model, make_drive(params.drive, params.drive_start))
        self._columns = np.array([joint_names.index(name) for name in model.joint_names], dtype=np.int64)
        self._actuated = np.array([model.index(name) for name in model.actuated_joints], dtype=np.int64)

    def __call__(self, t: float | np.ndarray, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                 left_limit: bool = False) -> np.ndarray:
        """tau_ff [N m or N] (order of the actuated joints; (N, a) for N rows) at the reference's
        (q, qd, qdd) at t [s] (or rows (N, n) at times (N,); with ``left_limit`` the drive just before t: at a
        jump of its torque, with the qdd from before it), by O(n) inverse dynamics
        (:func:`~crane_reference.dynamics.evaluation.imbalance_rows`)."""
        rows = [np.ascontiguousarray(np.atleast_2d(x)[:, self._columns], dtype=float) for x in (q, qd, qdd)]
        drives = np.atleast_2d(self.dynamics.drive.kernel_parameters(np.atleast_1d(t), left_limit))
        out = imbalance_rows(*rows, drives, self.dynamics.chain)[:, self._actuated]
        return out if np.ndim(q) == 2 else out[0]

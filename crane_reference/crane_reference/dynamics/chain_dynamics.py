"""The Python face of the chain's compiled dynamics: :class:`CraneDynamics` (a model with its drive and
damping) evaluates M, h, Q and E's kinematics through the kernels of :mod:`.terms`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model.chain import ChainModel
from ..model.drive import Drive
from .structures import ChainData
from .terms import chain_terms, end_effector_jacobian, end_effector_poses, energy_accounts, generalized_forces


@dataclass(frozen=True)
class DynamicsTerms:
    """Everything eqs. (6)-(8) need at one (t, q, qd): M, h, the generalized forces Q (gravity, springs,
    dampers, drive), E's position, frame rotation, Jacobian C and bias d, the gravity potential."""

    M: np.ndarray
    h: np.ndarray
    Q: np.ndarray
    ee_position: np.ndarray
    ee_rotation: np.ndarray
    ee_jacobian: np.ndarray
    ee_bias: np.ndarray
    gravity_potential: float


def chain_data(model: ChainModel, damping_matrix: np.ndarray) -> ChainData:
    """The compiled description of ``model`` with the damping matrix D."""
    return ChainData(
        kinds=np.array([j.kind for j in model.joints], dtype=np.int64),
        axes=np.array([j.axis for j in model.joints], dtype=np.int64),
        origins=np.ascontiguousarray([j.origin for j in model.joints], dtype=float),
        body_joint=np.array([b.joint for b in model.bodies], dtype=np.int64),
        body_H=np.ascontiguousarray([b.inertia.pseudo_inertia() for b in model.bodies], dtype=float),
        gravity=float(model.gravity), ee_joint=int(model.end_effector_joint),
        ee_point=np.asarray(model.end_effector_point, dtype=float),
        stiffness=np.ascontiguousarray(model.stiffness, dtype=float),
        damping=np.ascontiguousarray(damping_matrix, dtype=float), damped=bool(np.any(damping_matrix != 0.0)),
        drive_joint=int(model.drive_joint), root_size=root_size(model.stiffness, damping_matrix))


def root_size(stiffness: np.ndarray, damping_matrix: np.ndarray) -> int:
    """The joints up to the last that K or D couples to another (the root block of the articulated solve)."""
    coupling = (stiffness != 0.0) | (damping_matrix != 0.0)
    np.fill_diagonal(coupling, False)
    coupled = np.flatnonzero(coupling.any(axis=0) | coupling.any(axis=1))
    return int(coupled.max()) + 1 if coupled.size else 0


class CraneDynamics:
    """Evaluates M, h, Q and the end-effector kinematics of a :class:`ChainModel` driven by ``drive``,
    with the model's dampers D (:attr:`ChainModel.damping_matrix`) plus ``joint_damping`` (n,)
    [N m s/rad or N s/m] on the diagonal (e.g. the velocity loops of joint drives; none by default)."""

    def __init__(self, model: ChainModel, drive: Drive, joint_damping: np.ndarray | None = None):
        self.model = model
        self.drive = drive
        self.damping_matrix = model.damping_matrix
        if joint_damping is not None:
            self.damping_matrix = self.damping_matrix + np.diag(joint_damping)
        self.chain = chain_data(model, self.damping_matrix)
        """Model data in the layout of the compiled kernels."""

    def terms(self, t: float, q: np.ndarray, qd: np.ndarray, left_limit: bool = False) -> DynamicsTerms:
        """Terms at (t, q, qd); ``left_limit`` evaluates the drive just before t (a step ending on a jump)."""
        c = chain_terms(q, qd, self.chain)
        Q = generalized_forces(q, qd, c.gravity_forces, self.chain, self.drive.kernel_parameters(t, left_limit))
        return DynamicsTerms(c.M, c.h, Q, c.ee_position, c.ee_rotation, c.ee_jacobian, c.ee_bias, c.gravity_potential)

    def end_effector(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position of E and its Jacobian C (3, n) at q."""
        return end_effector_jacobian(np.ascontiguousarray(q, dtype=float), self.chain)

    def end_effector_poses(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions of E (N, 3) and the rotation matrices of link 4's frame (world, (N, 3, 3)) at the rows
        of q (N, n); a single q (n,) gives one position (3,) and rotation (3, 3)."""
        Q = np.ascontiguousarray(np.atleast_2d(q), dtype=float)
        positions, rotations = end_effector_poses(Q, self.chain)
        return (positions, rotations) if np.ndim(q) == 2 else (positions[0], rotations[0])

    def accounts(self, t: float, q: np.ndarray, qd: np.ndarray, terms: DynamicsTerms,
                 left_limit: bool = False) -> np.ndarray:
        """(E_k, E_p, t_dr, P_dr, P_D) at (t, q, qd), see :func:`~.terms.energy_accounts`."""
        return energy_accounts(q, qd, terms.M, terms.gravity_potential, self.chain,
                               self.drive.kernel_parameters(t, left_limit))

"""Unconstrained equations of motion of the chain, M(q) qdd + h(q, qd) = Q(t, q, qd).

Sign convention: Q holds generalized *forces* (positive along +q), i.e. minus the paper's gradient
terms e = g + f_sup + f_l + d of eq. (8):

    Q = -dE_p,g/dq - K q - D qd + t_dr e_psi2,

with E_p,g = sum_l m^(l) g J_3 T^(l) r_C^(l), K = sum_s U^T S U (support springs, base block) +
S^(3) (RFE springs, boom block), D = beta_sup K_sup + beta_boom K_boom (optional Rayleigh damping,
zero in the paper) and t_dr the column drive (:mod:`crane_reference.drive`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ..model.chain import ChainModel
from ..model.drive import Drive
from ..model.parameters import Damping
from .inertia import (
    composite_inertias,
    composite_velocity_products,
    gravity_forces,
    mass_matrix,
    velocity_forces,
    world_pseudo_inertias,
)
from .kinematics import forward_kinematics, point_bias, point_jacobian, point_position_jacobian, velocity_terms


@njit(cache=True)
def position_terms(q, kinds, axes, origins, body_joint, body_H, gravity, ee_joint, ee_point):
    """What depends on q alone: frames T, twists S, world pseudo-inertias Hw, M, gravity forces, the
    total gravity potential, E's position p, the rotation R of its frame and its Jacobian C."""
    T, S = forward_kinematics(q, kinds, axes, origins)
    Hw = world_pseudo_inertias(T, body_joint, body_H)
    Hc = composite_inertias(Hw, body_joint, q.size)
    M = mass_matrix(S, Hc)
    Qg = gravity_forces(S, Hc, gravity)
    p, C = point_jacobian(T, S, ee_joint, ee_point)
    return T, S, Hw, M, Qg, gravity * Hc[0, 2, 3], p, T[ee_joint, :3, :3].copy(), C


@njit(cache=True)
def velocity_products(qd, T, S, Hw, body_joint, ee_joint, p):
    """What is quadratic in qd: the velocity terms h of (8) and E's d (C qdd + d is E's acceleration)."""
    _, B = velocity_terms(qd, S)
    h = velocity_forces(S, composite_velocity_products(Hw, B, body_joint, qd.size))
    return h, point_bias(B, ee_joint, p)


@njit(cache=True)
def chain_terms(q, qd, kinds, axes, origins, body_joint, body_H, gravity, ee_joint, ee_point):
    """M, h, gravity forces, total gravity potential, E's position, rotation, Jacobian C and d."""
    T, S, Hw, M, Qg, Vg, p, R, C = position_terms(q, kinds, axes, origins, body_joint, body_H, gravity, ee_joint,
                                                  ee_point)
    h, d = velocity_products(qd, T, S, Hw, body_joint, ee_joint, p)
    return M, h, Qg, Vg, p, R, C, d


@njit(cache=True)
def energy_accounts(q, qd, M, gravity_potential, K, D, drive, drive_joint):
    """Energies and powers at (q, qd) for the energy balance, with ``drive`` = (tau0, s_dr, psi_a, dpsi_a/dt):

    E_k = 1/2 qd^T M qd,  E_p = E_p,g + 1/2 q^T K q + 1/2 s_dr (psi_a - psi2)^2,
    t_dr = tau0 + s_dr (psi_a - psi2),
    P_dr = tau0 dpsi2/dt + s_dr (psi_a - psi2) dpsi_a/dt   (what the torque source or the motor feeds in),
    P_D = -qd^T D qd   (the dampers' power, <= 0).

    Returns the array (E_k, E_p, t_dr, P_dr, P_D)."""
    j = drive_joint
    stretch = drive[2] - q[j]
    return np.array([0.5 * (qd @ (M @ qd)), gravity_potential + 0.5 * (q @ (K @ q)) + 0.5 * drive[1] * stretch**2,
                     drive[0] + drive[1] * stretch, drive[0] * qd[j] + drive[1] * stretch * drive[3],
                     -(qd @ (D @ qd))])


@dataclass(frozen=True)
class DynamicsTerms:
    """Everything eqs. (6)-(8) need at one (t, q, qd)."""

    M: np.ndarray
    h: np.ndarray
    Q: np.ndarray
    ee_position: np.ndarray
    ee_rotation: np.ndarray
    ee_jacobian: np.ndarray
    ee_bias: np.ndarray
    gravity_potential: float


class CraneDynamics:
    """Evaluates M, h, Q and the end-effector kinematics of a :class:`ChainModel`."""

    def __init__(self, model: ChainModel, drive: Drive, damping: Damping | None = None):
        self.model = model
        self.drive = drive
        damping = damping or Damping()
        self.damping_matrix = damping.support * model.support_stiffness + damping.boom * model.boom_stiffness
        self._kinds = np.array([j.kind for j in model.joints], dtype=np.int64)
        self._axes = np.array([j.axis for j in model.joints], dtype=np.int64)
        self._origins = np.ascontiguousarray([j.origin for j in model.joints], dtype=float)
        self._body_joint = np.array([b.joint for b in model.bodies], dtype=np.int64)
        self._body_H = np.ascontiguousarray([b.inertia.pseudo_inertia() for b in model.bodies], dtype=float)
        self.chain = (self._kinds, self._axes, self._origins, self._body_joint, self._body_H, float(model.gravity),
                      int(model.end_effector_joint), np.asarray(model.end_effector_point, dtype=float),
                      np.ascontiguousarray(model.stiffness, dtype=float),
                      np.ascontiguousarray(self.damping_matrix, dtype=float), int(model.drive_joint))
        """Model data in the layout of the compiled solver (:mod:`crane_reference.kernels`)."""

    def terms(self, t: float, q: np.ndarray, qd: np.ndarray, left_limit: bool = False) -> DynamicsTerms:
        """Terms at (t, q, qd); ``left_limit`` evaluates the drive just before t (a step ending on a jump)."""
        m = self.model
        M, h, Qg, Vg, p, R, C, d = chain_terms(q, qd, self._kinds, self._axes, self._origins, self._body_joint,
                                               self._body_H, m.gravity, m.end_effector_joint,
                                               m.end_effector_point)
        Q = Qg - m.stiffness @ q - self.damping_matrix @ qd
        Q[m.drive_joint] += self.drive.torque(t, q[m.drive_joint], left_limit)
        return DynamicsTerms(M, h, Q, p, R, C, d, Vg)

    def end_effector(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position of E and its Jacobian C (3, n) at q."""
        m = self.model
        return point_position_jacobian(q, self._kinds, self._axes, self._origins, m.end_effector_joint,
                                       m.end_effector_point)

    def end_effector_pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position of E and the rotation matrix of link 4's frame (world) at q."""
        m = self.model
        T, _ = forward_kinematics(q, self._kinds, self._axes, self._origins)
        frame = T[m.end_effector_joint]
        return frame[:3, :3] @ m.end_effector_point + frame[:3, 3], frame[:3, :3].copy()

    def accounts(self, t: float, q: np.ndarray, qd: np.ndarray, terms: DynamicsTerms,
                 left_limit: bool = False) -> np.ndarray:
        """(E_k, E_p, t_dr, P_dr, P_D) at (t, q, qd), see :func:`energy_accounts`."""
        return energy_accounts(q, qd, terms.M, terms.gravity_potential, self.model.stiffness, self.damping_matrix,
                               self.drive.kernel_parameters(t, left_limit), self.model.drive_joint)

"""Unconstrained equations of motion of the chain, M(q) qdd + h(q, qd) = Q(t, q, qd).

Sign convention: Q holds generalized *forces* (positive along +q), i.e. minus the paper's gradient
terms e = g + f_sup + f_l + d of eq. (8):

    Q = -dE_p,g/dq - K q - D qd + t_dr e_psi2,

with E_p,g = sum_l m^(l) g J_3 T^(l) r_C^(l), K = sum_s U^T S U (support springs, base block) +
S^(3) (RFE springs, boom block), D = beta_sup K_sup + beta_boom K_boom (optional Rayleigh damping,
zero in the paper) and t_dr the column drive (:mod:`crane_reference.model.drive`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .inertia import (
    add_joint_accelerations,
    composite_inertias,
    composite_velocity_products,
    gravity_forces,
    mass_matrix,
    velocity_forces,
    world_pseudo_inertias,
)
from .kinematics import forward_kinematics, point_bias, point_jacobian, point_position, velocity_terms
from .linalg import matvec
from .structures import ChainData, ChainTerms


@njit(cache=True, nogil=True)
def add_joint_matrix_product(out, X, x, weight, chain: ChainData):
    """out += weight X x for the chain's stiffness K or damping D (n, n), in place and O(n): dense on the root block
    of the first ``chain.root_size`` joints, diagonal beyond it (no other joint is coupled, :class:`ChainData`)."""
    root_size = chain.root_size
    for i in range(root_size):
        total = 0.0
        for j in range(root_size):
            total += X[i, j] * x[j]
        out[i] += weight * total
    for i in range(root_size, x.size):
        out[i] += weight * X[i, i] * x[i]


@njit(cache=True)
def position_terms(q, chain: ChainData):
    """What depends on q alone: frames T, twists S and the terms of :func:`frame_terms`."""
    T, S = forward_kinematics(q, chain.kinds, chain.axes, chain.origins)
    return (T, S, *frame_terms(T, S, chain))


@njit(cache=True, inline='always')
def frame_terms(T, S, chain: ChainData):
    """From the frames T and twists S at q: world pseudo-inertias Hw, M, gravity forces, the total
    gravity potential, E's position p, the rotation R of its frame and its Jacobian C."""
    Hw = world_pseudo_inertias(T, chain.body_joint, chain.body_H)
    Hc = composite_inertias(Hw, chain.body_joint, S.shape[0])
    M = mass_matrix(S, Hc)
    Qg = gravity_forces(S, Hc, chain.gravity)
    p, C = point_jacobian(T, S, chain.ee_joint, chain.ee_point)
    return Hw, M, Qg, chain.gravity * Hc[0, 2, 3], p, T[chain.ee_joint, :3, :3].copy(), C


@njit(cache=True, inline='always')
def velocity_products(qd, S, Hw, chain: ChainData, p):
    """What is quadratic in qd: the velocity terms h of (8) and E's d (C qdd + d is E's acceleration)."""
    B = velocity_terms(qd, S)
    h = velocity_forces(S, composite_velocity_products(Hw, B, chain.body_joint, qd.size))
    return h, point_bias(B, chain.ee_joint, p)


@njit(cache=True, inline='always')
def inverse_dynamics(S, Hw, velocity_term, qdd, chain: ChainData):
    """M qdd + h - Q_g (inertia minus gravity forces) in O(n), without forming M (see :mod:`.inertia`);
    ``velocity_term`` is B of :func:`.kinematics.velocity_terms` at qd."""
    total = add_joint_accelerations(velocity_term, S, qdd, chain.gravity)
    return velocity_forces(S, composite_velocity_products(Hw, total, chain.body_joint, qdd.size))


@njit(cache=True)
def chain_terms(q, qd, chain: ChainData):
    """The chain's terms at (q, qd) (:class:`ChainTerms`)."""
    _, S, Hw, M, Qg, Vg, p, R, C = position_terms(q, chain)
    h, d = velocity_products(qd, S, Hw, chain, p)
    return ChainTerms(M, h, Qg, Vg, p, R, C, d)


@njit(cache=True)
def end_effector_jacobian(q, chain: ChainData):
    """E's position p and Jacobian C (3, n) at q, without velocity terms (for the projections)."""
    T, S = forward_kinematics(q, chain.kinds, chain.axes, chain.origins)
    return point_jacobian(T, S, chain.ee_joint, chain.ee_point)


@njit(cache=True)
def end_effector_poses(Q, chain: ChainData):
    """E's positions (N, 3) and the rotation matrices of its frame (link 4) (N, 3, 3) at the rows of Q (N, n)."""
    positions, rotations = np.empty((Q.shape[0], 3)), np.empty((Q.shape[0], 3, 3))
    for i in range(Q.shape[0]):
        T, _ = forward_kinematics(np.ascontiguousarray(Q[i]), chain.kinds, chain.axes, chain.origins)
        frame = T[chain.ee_joint]
        positions[i] = point_position(frame, chain.ee_point)
        rotations[i] = frame[:3, :3]
    return positions, rotations


DRIVE_PARAMETERS = 4
"""Length of the drive array (tau0, s_dr, psi_a, dpsi_a/dt) the kernels take; an array with n more entries
also carries the actuators' generalized forces tau_a [N m or N] on the n coordinates (a closed loop's
command, :class:`crane_reference.model.drive.Actuated`)."""


@njit(cache=True)
def drive_torque(drive, psi2):
    """t_dr = tau0 + s_dr (psi_a - psi2) for ``drive`` = (tau0, s_dr, psi_a, dpsi_a/dt) (a torque source has
    s_dr = 0; see :mod:`crane_reference.model.drive`)."""
    return drive[0] + drive[1] * (drive[2] - psi2)


@njit(cache=True, inline='always')
def generalized_forces(q, qd, gravity, chain: ChainData, drive):
    """Q = Q_g - K q - D qd + t_dr e_psi2 + tau_a with the gravity forces Q_g (the sign convention above) and
    the actuators' generalized forces tau_a = ``drive[4:]`` if ``drive`` carries them (see
    :data:`DRIVE_PARAMETERS`)."""
    forces = gravity.copy()
    add_applied_forces(forces, q, qd, chain, drive, 1.0)
    return forces


@njit(cache=True, inline='always')
def add_applied_forces(out, q, qd, chain: ChainData, drive, sign):
    """out += sign (-K q - D qd + t_dr e_psi2 + tau_a), in place: Q without its gravity forces
    (:func:`generalized_forces`)."""
    add_joint_matrix_product(out, chain.stiffness, q, -sign, chain)
    if chain.damped:
        add_joint_matrix_product(out, chain.damping, qd, -sign, chain)
    out[chain.drive_joint] += sign * drive_torque(drive, q[chain.drive_joint])
    for i in range(drive.size - DRIVE_PARAMETERS):
        out[i] += sign * drive[DRIVE_PARAMETERS + i]


@njit(cache=True, inline='always')
def energy_accounts(q, qd, M, gravity_potential, chain: ChainData, drive):
    """Energies and powers at (q, qd) for the energy balance, with ``drive`` = (tau0, s_dr, psi_a, dpsi_a/dt):

    E_k = 1/2 qd^T M qd,  E_p = E_p,g + 1/2 q^T K q + 1/2 s_dr (psi_a - psi2)^2,
    t_dr = tau0 + s_dr (psi_a - psi2),
    P_dr = tau0 dpsi2/dt + s_dr (psi_a - psi2) dpsi_a/dt + tau_a^T qd
    (what the torque source or the motor feeds in, and the actuators if ``drive`` carries tau_a),
    P_D = -qd^T D qd   (the dampers' power, <= 0).

    Returns the array (E_k, E_p, t_dr, P_dr, P_D)."""
    j = chain.drive_joint
    springs, dampers = np.zeros(q.size), np.zeros(q.size)  # K q and D qd
    add_joint_matrix_product(springs, chain.stiffness, q, 1.0, chain)
    add_joint_matrix_product(dampers, chain.damping, qd, 1.0, chain)
    stretch = drive[2] - q[j]
    power = drive[0] * qd[j] + drive[1] * stretch * drive[3]
    if drive.size > DRIVE_PARAMETERS:
        power += drive[DRIVE_PARAMETERS:] @ qd
    return np.array([0.5 * (qd @ matvec(M, qd)),
                     gravity_potential + 0.5 * (q @ springs) + 0.5 * drive[1] * stretch**2,
                     drive_torque(drive, q[j]), power,
                     -(qd @ dampers)])

"""Compiled (numba) evaluation of the programmed motion and of one generalized-alpha step.

The mathematics is documented where it is defined: chain terms in :mod:`crane_reference.dynamics`,
quadric constraints in :mod:`crane_reference.constraints`, equations (7)-(8) and the coordinate
partitioning in :mod:`crane_reference.programmed_motion`, the generalized-alpha method in
:mod:`crane_reference.integration`.  Here they are fused so that one integration step is one call:
the time-dependent data (constraint coefficients, drive) enter as numbers evaluated at the step's end.
The kernels release the GIL (``nogil``), so a ROS node's publishing thread runs while the solver steps.

``chain`` is the tuple (kinds, axes, origins, body_joint, body_H, gravity, ee_joint, ee_point, K, D,
drive_joint) and ``drive`` the tuple (tau0, s_dr, psi_a): the drive's generalized force on psi2 is
tau0 + s_dr (psi_a - psi2) (a torque source has s_dr = 0).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .dynamics import chain_terms
from .kinematics import point_position_jacobian


@njit(cache=True, nogil=True)
def quadric_values(p, Q, g, c):
    """Phi (m,) and Phi_p (m, 3) of stacked quadrics at p (value level, index 0)."""
    m = Q.shape[0]
    residual = np.empty(m)
    grads = np.empty((m, 3))
    for i in range(m):
        Qp = Q[i, 0] @ p
        residual[i] = p @ Qp + g[i, 0] @ p + c[i, 0]
        grads[i] = 2.0 * Qp + g[i, 0]
    return residual, grads


@njit(cache=True, nogil=True)
def constraint_terms(p, v, C, d, Q, g, c):
    """Phi, Phi_p, A = Phi_p C, b = -Phi_t and c_acc = -(Phi_p d + convective) of stacked quadrics."""
    residual, grads = quadric_values(p, Q, g, c)
    m = Q.shape[0]
    b = np.empty(m)
    c_acc = np.empty(m)
    for i in range(m):
        b[i] = -(p @ Q[i, 1] @ p + g[i, 1] @ p + c[i, 1])
        convective = (2.0 * v @ Q[i, 0] @ v + 2.0 * (2.0 * Q[i, 1] @ p + g[i, 1]) @ v
                      + p @ Q[i, 2] @ p + g[i, 2] @ p + c[i, 2])
        c_acc[i] = -(grads[i] @ d + convective)
    return residual, grads, grads @ C, b, c_acc


@njit(cache=True, nogil=True)
def velocity_map(A, independent, dependent):
    """B = d qd / d qd_ic (n, n_ic): identity rows on ic, Gamma = -K_dc^-1 K_ic rows on dc (eq. (7))."""
    n_ic = independent.size
    B = np.zeros((A.shape[1], n_ic))
    for col in range(n_ic):
        B[independent[col], col] = 1.0
    gamma = -np.linalg.solve(np.ascontiguousarray(A[:, dependent]), np.ascontiguousarray(A[:, independent]))
    for row in range(dependent.size):
        B[dependent[row]] = gamma[row]
    return B


@njit(cache=True, nogil=True)
def project_positions(q, Q, g, c, independent, dependent, chain, tolerance, max_iterations):
    """q with q_dc solved from Phi(q) = 0 by Newton (Jacobian K_dc); also (p, C) of the last iterate
    and whether it converged."""
    kinds, axes, origins, _, _, _, ee_joint, ee_point, _, _, _ = chain
    q = q.copy()
    for _ in range(max_iterations):
        p, C = point_position_jacobian(q, kinds, axes, origins, ee_joint, ee_point)
        residual, grads = quadric_values(p, Q, g, c)
        step = np.linalg.solve(grads @ np.ascontiguousarray(C[:, dependent]), residual)
        for i in range(dependent.size):
            q[dependent[i]] -= step[i]
        if np.max(np.abs(step)) <= tolerance:
            return q, p, C, True
    return q, p, C, False


@njit(cache=True, nogil=True)
def dependent_velocities(qd, p, C, Q, g, c, independent, dependent):
    """qd with qd_dc = K_dc^-1 (b - K_ic qd_ic), eq. (7)."""
    _, grads = quadric_values(p, Q, g, c)
    A = grads @ C
    m = Q.shape[0]
    b = np.empty(m)
    for i in range(m):
        b[i] = -(p @ Q[i, 1] @ p + g[i, 1] @ p + c[i, 1])
    qd = qd.copy()
    rhs = b - np.ascontiguousarray(A[:, independent]) @ qd[independent]
    qd_dc = np.linalg.solve(np.ascontiguousarray(A[:, dependent]), rhs)
    for i in range(dependent.size):
        qd[dependent[i]] = qd_dc[i]
    return qd


@njit(cache=True, nogil=True)
def projection_matrix(B, independent, servo):
    """Rows of the dynamics kept in (8): P = B for ideal constraints (projection on the directions the
    constraints allow), P = E_ic (the unactuated coordinates' own rows) for servo-constraints."""
    if not servo:
        return B
    P = np.zeros_like(B)
    for col in range(independent.size):
        P[independent[col], col] = 1.0
    return P


@njit(cache=True, nogil=True)
def evaluate(q, qd, Q, g, c, drive, independent, dependent, chain, servo):
    """Everything (8) needs and gives at (q, qd): dynamics terms, constraint terms, B, qdd, the
    reactions (lambda for ideal constraints, the dependent joints' torques tau for servo-constraints)
    and the generalized force they exert, M qdd + h - Q (= A^T lambda, or E_dc tau)."""
    kinds, axes, origins, body_joint, body_H, gravity, ee_joint, ee_point, K, D, drive_joint = chain
    M, h, Qg, Vg, p, R, C, d = chain_terms(q, qd, kinds, axes, origins, body_joint, body_H, gravity, ee_joint,
                                           ee_point)
    forces = Qg - K @ q - D @ qd
    forces[drive_joint] += drive[0] + drive[1] * (drive[2] - q[drive_joint])
    residual, grads, A, b, c_acc = constraint_terms(p, C @ qd, C, d, Q, g, c)
    B = velocity_map(A, independent, dependent)
    P = projection_matrix(B, independent, servo)
    lhs = np.vstack((P.T @ M, A))
    rhs = np.concatenate((P.T @ (forces - h), c_acc))
    qdd = np.linalg.solve(lhs, rhs)
    reaction_force = M @ qdd + h - forces
    reactions = reaction_force[dependent] if servo else np.linalg.solve(A @ A.T, A @ reaction_force)
    return M, h, forces, Vg, p, R, C, d, residual, grads, A, b, c_acc, B, qdd, reactions, reaction_force


@njit(cache=True, nogil=True)
def generalized_alpha_step(q0, qd0, qdd0, at0, M0, B0, h, alpha_m, alpha_f, gamma, beta, Q, g, c, drive,
                           independent, dependent, chain, servo, tolerance, max_iterations, projection_tolerance):
    """One generalized-alpha step on the independent coordinates (see :mod:`crane_reference.integration`).

    Returns q1, qd1, a~1, the evaluation at (q1, qd1), a status (0 converged, 1 Newton did not converge,
    2 the position constraints could not be solved) and the number of Newton iterations."""
    K, D = chain[8], chain[9]
    x0, v0, a0 = q0[independent], qd0[independent], qdd0[independent]
    ratio = (1.0 - alpha_f) / (1.0 - alpha_m)
    beta_p, gamma_p = h * h * beta * ratio, h * gamma * ratio
    P0 = projection_matrix(B0, independent, servo)
    M_r = P0.T @ M0 @ B0
    iteration_inverse = np.linalg.inv(M_r + beta_p * (P0.T @ K @ B0) + gamma_p * (P0.T @ D @ B0))
    q_guess = q0 + h * qd0 + 0.5 * h * h * qdd0
    a1 = a0.copy()
    status = 1
    for iteration in range(max_iterations):
        at1 = ((1.0 - alpha_f) * a1 + alpha_f * a0 - alpha_m * at0) / (1.0 - alpha_m)
        x1 = x0 + h * v0 + h * h * ((0.5 - beta) * at0 + beta * at1)
        v1 = v0 + h * ((1.0 - gamma) * at0 + gamma * at1)
        q1 = q_guess.copy()
        q1[independent] = x1
        q1, p, C, projected = project_positions(q1, Q, g, c, independent, dependent, chain,
                                                projection_tolerance, 25)
        if not projected:
            held = evaluate(q0, qd0, Q, g, c, drive, independent, dependent, chain, servo)
            return q0, qd0, at0, held, 2, iteration + 1
        qd1 = np.zeros_like(q1)
        qd1[independent] = v1
        qd1 = dependent_velocities(qd1, p, C, Q, g, c, independent, dependent)
        result = evaluate(q1, qd1, Q, g, c, drive, independent, dependent, chain, servo)
        q_guess = q1
        correction = -(iteration_inverse @ (M_r @ (a1 - result[14][independent])))
        a1 = a1 + correction
        # Accept only an iterate that already includes a Newton correction: stopping at the predictor
        # (possible near rest, where every correction is tiny) would make the step explicit.
        if iteration > 0 and beta_p * np.max(np.abs(correction)) <= tolerance:
            status = 0
            break
    return q1, qd1, at1, result, status, iteration + 1

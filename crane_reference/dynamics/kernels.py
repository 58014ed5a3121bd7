"""Compiled (numba) evaluation of the programmed motion and of generalized-alpha steps.

The mathematics is documented where it is defined: chain terms in :mod:`crane_reference.dynamics`,
quadric constraints (holonomic and first-order) in :mod:`crane_reference.constraints`, equations
(7)-(8) and the coordinate partitioning in :mod:`crane_reference.programmed_motion`, the
generalized-alpha method in :mod:`crane_reference.integration`.  Here they are fused so that one
integration step, or a run of steps, is one call: the time-dependent data (constraint coefficients,
drive) enter as numbers evaluated at each step's end.
The kernels release the GIL (``nogil``), so a ROS node's publishing thread runs while the solver steps.

``chain`` is the tuple (kinds, axes, origins, body_joint, body_H, gravity, ee_joint, ee_point, K, D,
drive_joint) and ``drive`` the array (tau0, s_dr, psi_a, dpsi_a/dt): the drive's generalized force on
psi2 is tau0 + s_dr (psi_a - psi2) (a torque source has s_dr = 0).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .kinematics import point_position_jacobian
from .terms import energy_accounts, position_terms, velocity_products


@njit(cache=True, nogil=True)
def _quadratic_form(Q, x, y):
    """x^T Q y over the leading len(x) x len(y) block of Q."""
    total = 0.0
    for a in range(x.size):
        for b in range(y.size):
            total += x[a] * Q[a, b] * y[b]
    return total


@njit(cache=True, nogil=True)
def _form_gradient(Q, g, x):
    """2 Q x + g over the leading len(x) block."""
    n = x.size
    out = np.empty(n)
    for a in range(n):
        total = g[a]
        for b in range(n):
            total += 2.0 * Q[a, b] * x[b]
        out[a] = total
    return out


@njit(cache=True, nogil=True)
def holonomic_values(p, Q, g, c, order):
    """Phi (n_h,) and Phi_p (n_h, 3) of the holonomic rows at p (value level, index 0)."""
    rows = np.flatnonzero(order == 0)
    residual = np.empty(rows.size)
    grads = np.empty((rows.size, 3))
    for k in range(rows.size):
        i = rows[k]
        residual[k] = _quadratic_form(Q[i, 0], p, p) + g[i, 0, :3] @ p + c[i, 0]
        grads[k] = _form_gradient(Q[i, 0], g[i, 0], p)
    return residual, grads


@njit(cache=True, nogil=True)
def velocity_residual(p, v, Q, g, c, order):
    """Velocity-level residuals, dPhi/dt = Phi_p v + Phi_t (holonomic rows) or Psi (first-order rows),
    and their gradients with respect to v, Phi_p or Psi_v (m, 3)."""
    m = Q.shape[0]
    residual = np.empty(m)
    grads = np.empty((m, 3))
    z = np.concatenate((p, v))
    for i in range(m):
        if order[i] == 0:
            grads[i] = _form_gradient(Q[i, 0], g[i, 0], p)
            residual[i] = grads[i] @ v + _quadratic_form(Q[i, 1], p, p) + g[i, 1, :3] @ p + c[i, 1]
        else:
            grads[i] = _form_gradient(Q[i, 0], g[i, 0], z)[3:]
            residual[i] = _quadratic_form(Q[i, 0], z, z) + g[i, 0] @ z + c[i, 0]
    return residual, grads


@njit(cache=True, nogil=True)
def acceleration_terms(p, v, C, d, Q, g, c, order):
    """A = gradients C (gradients Phi_p or Psi_v) and c of the acceleration-level constraints A qdd = c
    (see :mod:`crane_reference.constraints`)."""
    m = Q.shape[0]
    grads = np.empty((m, 3))
    c_acc = np.empty(m)
    z = np.concatenate((p, v))
    for i in range(m):
        if order[i] == 0:
            grads[i] = _form_gradient(Q[i, 0], g[i, 0], p)
            convective = (2.0 * _quadratic_form(Q[i, 0], v, v) + 2.0 * (_form_gradient(Q[i, 1], g[i, 1], p) @ v)
                          + _quadratic_form(Q[i, 2], p, p) + g[i, 2, :3] @ p + c[i, 2])
            c_acc[i] = -(grads[i] @ d + convective)
        else:
            full = _form_gradient(Q[i, 0], g[i, 0], z)
            grads[i] = full[3:]
            psi_t = _quadratic_form(Q[i, 1], z, z) + g[i, 1] @ z + c[i, 1]
            c_acc[i] = -(grads[i] @ d + full[:3] @ v + psi_t)
    return grads @ C, c_acc


@njit(cache=True, nogil=True)
def constraint_values(p, v, Q, g, c, order):
    """Residuals (Phi or Psi), gradients (Phi_p or Psi_v), distances |residual| / |gradient| and the
    velocity-level residuals (dPhi/dt or Psi)."""
    m = Q.shape[0]
    residual = np.empty(m)
    rate, grads = velocity_residual(p, v, Q, g, c, order)
    z = np.concatenate((p, v))
    for i in range(m):
        residual[i] = (_quadratic_form(Q[i, 0], p, p) + g[i, 0, :3] @ p + c[i, 0] if order[i] == 0
                       else _quadratic_form(Q[i, 0], z, z) + g[i, 0] @ z + c[i, 0])
    distance = np.empty(m)
    for i in range(m):
        distance[i] = abs(residual[i]) / np.sqrt(grads[i] @ grads[i])
    return residual, grads, distance, rate


@njit(cache=True, nogil=True)
def solve_small(A, B):
    """X = A^-1 B for a small square A (Gaussian elimination with partial pivoting; K_dc is 2 x 2 or
    3 x 3 here, where a LAPACK call costs more than the arithmetic), B of shape (m, k)."""
    m = A.shape[0]
    a = A.copy()
    x = B.copy()
    for col in range(m):
        pivot = col
        for row in range(col + 1, m):
            if abs(a[row, col]) > abs(a[pivot, col]):
                pivot = row
        if a[pivot, col] == 0.0:
            raise np.linalg.LinAlgError("singular matrix")
        if pivot != col:
            for k in range(m):
                a[col, k], a[pivot, k] = a[pivot, k], a[col, k]
            for k in range(x.shape[1]):
                x[col, k], x[pivot, k] = x[pivot, k], x[col, k]
        for row in range(col + 1, m):
            factor = a[row, col] / a[col, col]
            for k in range(col, m):
                a[row, k] -= factor * a[col, k]
            for k in range(x.shape[1]):
                x[row, k] -= factor * x[col, k]
    for col in range(m - 1, -1, -1):
        for k in range(x.shape[1]):
            total = x[col, k]
            for j in range(col + 1, m):
                total -= a[col, j] * x[j, k]
            x[col, k] = total / a[col, col]
    return x


@njit(cache=True, nogil=True)
def solve_small_vector(A, b):
    """x = A^-1 b for a small square A (see :func:`solve_small`)."""
    return solve_small(A, b.reshape((b.size, 1)))[:, 0]


@njit(cache=True, nogil=True)
def project_rows(X, B, independent, dependent, servo):
    """P^T X for X (n, k) without forming P: X[ic] + Gamma^T X[dc] for ideal constraints (P = B, whose
    rows are the identity on ic and Gamma on dc), X[ic] for servo-constraints (P = E_ic)."""
    out = np.empty((independent.size, X.shape[1]))
    for j in range(independent.size):
        out[j] = X[independent[j]]
    if not servo:
        for r in range(dependent.size):
            row = X[dependent[r]]
            for j in range(independent.size):
                weight = B[dependent[r], j]
                for k in range(X.shape[1]):
                    out[j, k] += weight * row[k]
    return out


@njit(cache=True, nogil=True)
def map_columns(Y, B, independent, dependent):
    """Y B for Y (k, n) without forming B: Y[:, ic] + Y[:, dc] Gamma."""
    out = np.empty((Y.shape[0], independent.size))
    for i in range(Y.shape[0]):
        for j in range(independent.size):
            total = Y[i, independent[j]]
            for r in range(dependent.size):
                total += Y[i, dependent[r]] * B[dependent[r], j]
            out[i, j] = total
    return out


@njit(cache=True, nogil=True)
def velocity_map(A, independent, dependent):
    """B = d qd / d qd_ic (n, n_ic): identity rows on ic, Gamma = -K_dc^-1 K_ic rows on dc (eq. (7))."""
    n_ic = independent.size
    B = np.zeros((A.shape[1], n_ic))
    for col in range(n_ic):
        B[independent[col], col] = 1.0
    gamma = -solve_small(np.ascontiguousarray(A[:, dependent]), np.ascontiguousarray(A[:, independent]))
    for row in range(dependent.size):
        B[dependent[row]] = gamma[row]
    return B


@njit(cache=True, nogil=True)
def project_positions(q, Q, g, c, order, holonomic_dependent, chain, tolerance, max_iterations):
    """q with the holonomically dependent coordinates solved from Phi(q) = 0 by Newton (Jacobian
    Phi_p C[:, hd]); also (p, C) of the last iterate and whether it converged."""
    kinds, axes, origins, _, _, _, ee_joint, ee_point, _, _, _ = chain
    q = q.copy()
    for _ in range(max_iterations):
        p, C = point_position_jacobian(q, kinds, axes, origins, ee_joint, ee_point)
        if holonomic_dependent.size == 0:
            return q, p, C, True
        residual, grads = holonomic_values(p, Q, g, c, order)
        step = solve_small_vector(grads @ np.ascontiguousarray(C[:, holonomic_dependent]), residual)
        for i in range(holonomic_dependent.size):
            q[holonomic_dependent[i]] -= step[i]
        if np.max(np.abs(step)) <= tolerance:
            return q, p, C, True
    return q, p, C, False


@njit(cache=True, nogil=True)
def dependent_velocities(qd, p, C, Q, g, c, order, dependent):
    """qd with qd_dc solved from the velocity-level constraints (eq. (7): K_dc qd_dc = b - K_ic qd_ic for
    rows linear in qd); Newton on qd_dc (Jacobian K_dc = A[:, dc]), one step when every row is linear in
    qd, until the step is below 1e-14 otherwise.  Also whether it converged."""
    linear = True
    for i in range(order.size):
        if order[i] == 1 and np.any(Q[i, 0, 3:, 3:] != 0.0):
            linear = False
    qd = qd.copy()
    for _ in range(1 if linear else 30):
        residual, grads = velocity_residual(p, C @ qd, Q, g, c, order)
        step = solve_small_vector(grads @ np.ascontiguousarray(C[:, dependent]), residual)
        for i in range(dependent.size):
            qd[dependent[i]] -= step[i]
        if linear or np.max(np.abs(step)) <= 1e-14:
            return qd, True
    return qd, False


@njit(cache=True, nogil=True)
def smallest_singular_value(K):
    """Smallest singular value of a square matrix (closed form for 2 x 2, the paper's K_dc)."""
    if K.shape[0] == 2:
        a, b, c, d = K[0, 0], K[0, 1], K[1, 0], K[1, 1]
        half_trace = 0.5 * (a * a + b * b + c * c + d * d)
        det = a * d - b * c
        return np.sqrt(max(half_trace - np.sqrt(max(half_trace * half_trace - det * det, 0.0)), 0.0))
    return np.linalg.svd(K)[1][-1]


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
def _cholesky_solve(L, b):
    """x with L L^T x = b (L lower triangular)."""
    n = b.size
    y = np.empty(n)
    for i in range(n):
        total = b[i]
        for k in range(i):
            total -= L[i, k] * y[k]
        y[i] = total / L[i, i]
    x = np.empty(n)
    for i in range(n - 1, -1, -1):
        total = y[i]
        for k in range(i + 1, n):
            total -= L[k, i] * x[k]
        x[i] = total / L[i, i]
    return x


@njit(cache=True, nogil=True)
def _accelerations(M, f, A, c_acc, B, independent, dependent, servo):
    """qdd from (8), [P^T M; A] qdd = [P^T f; c] with f = Q - h.  Ideal constraints (P = B): qdd = B a + e
    with e the particular solution (e_ic = 0, K_dc e_dc = c) and the reduced, symmetric positive definite
    system B^T M B a = B^T (f - M e) (Cholesky).  Servo-constraints: the square system by LU."""
    n = f.size
    if servo:
        lhs = np.empty((n, n))
        lhs[:independent.size] = project_rows(M, B, independent, dependent, True)
        lhs[independent.size:] = A
        rhs = np.empty(n)
        rhs[:independent.size] = f[independent]
        rhs[independent.size:] = c_acc
        return np.linalg.solve(lhs, rhs)
    e_dc = solve_small_vector(np.ascontiguousarray(A[:, dependent]), c_acc)
    load = f.copy()
    for r in range(dependent.size):
        load -= M[:, dependent[r]] * e_dc[r]
    reduced = map_columns(project_rows(M, B, independent, dependent, False), B, independent, dependent)
    a = _cholesky_solve(np.linalg.cholesky(reduced), project_rows(load.reshape((n, 1)), B, independent, dependent,
                                                                  False)[:, 0])
    qdd = B @ a
    for r in range(dependent.size):
        qdd[dependent[r]] += e_dc[r]
    return qdd


@njit(cache=True, nogil=True)
def _accelerations_at(q, qd, Q, g, c, order, drive, independent, dependent, chain, servo, project_velocities):
    """What a Newton iteration needs at (q, qd): qdd from (8), optionally after solving qd_dc from the
    velocity-level constraints (with E's Jacobian at q itself, between the position and the velocity
    parts of the dynamics).  Returns qd, the terms (M, h, forces, Vg, p, R, C, d, A, c, B, qdd) and
    whether the velocity constraints were solved."""
    kinds, axes, origins, body_joint, body_H, gravity, ee_joint, ee_point, K, D, drive_joint = chain
    T, S, Hw, M, Qg, Vg, p, R, C = position_terms(q, kinds, axes, origins, body_joint, body_H, gravity, ee_joint,
                                                  ee_point)
    solved = True
    if project_velocities:
        qd, solved = dependent_velocities(qd, p, C, Q, g, c, order, dependent)
    h, d = velocity_products(qd, T, S, Hw, body_joint, ee_joint, p)
    forces = Qg - K @ q
    if np.any(D != 0.0):
        forces -= D @ qd
    forces[drive_joint] += drive[0] + drive[1] * (drive[2] - q[drive_joint])
    A, c_acc = acceleration_terms(p, C @ qd, C, d, Q, g, c, order)
    B = velocity_map(A, independent, dependent)
    qdd = _accelerations(M, forces - h, A, c_acc, B, independent, dependent, servo)
    return qd, (M, h, forces, Vg, p, R, C, d, A, c_acc, B, qdd), solved


@njit(cache=True, nogil=True)
def _complete(q, qd, terms, Q, g, c, order, drive, dependent, chain, servo):
    """The full evaluation from the terms of :func:`_accelerations_at`: adds the constraint residuals,
    gradients, distances and velocity residuals, the reactions, their generalized force and the accounts."""
    K, D, drive_joint = chain[8], chain[9], chain[10]
    M, h, forces, Vg, p, R, C, d, A, c_acc, B, qdd = terms
    residual, grads, distance, rate = constraint_values(p, C @ qd, Q, g, c, order)
    reaction_force = M @ qdd + h - forces
    reactions = reaction_force[dependent] if servo else solve_small_vector(A @ A.T, A @ reaction_force)
    energy = energy_accounts(q, qd, M, Vg, K, D, drive, drive_joint)
    accounts = np.array([energy[0], energy[1], energy[2], energy[3], reaction_force @ qd, energy[4],
                         smallest_singular_value(np.ascontiguousarray(A[:, dependent]))])
    return (M, h, forces, Vg, p, R, C, d, residual, grads, A, c_acc, distance, rate, B, qdd, reactions,
            reaction_force, accounts)


@njit(cache=True, nogil=True)
def evaluate(q, qd, Q, g, c, order, drive, independent, dependent, chain, servo):
    """Everything (8) needs and gives at (q, qd): dynamics terms, constraint terms, B, qdd, the
    reactions (lambda for ideal constraints, the dependent joints' torques tau for servo-constraints),
    the generalized force they exert, M qdd + h - Q (= A^T lambda, or E_dc tau), and the accounts
    (E_k, E_p, t_dr, P_dr, P_constraints, P_D, sigma_min(K_dc)) (powers: what each source feeds in)."""
    qd, terms, _ = _accelerations_at(q, qd, Q, g, c, order, drive, independent, dependent, chain, servo, False)
    return _complete(q, qd, terms, Q, g, c, order, drive, dependent, chain, servo)


@njit(cache=True, nogil=True)
def generalized_alpha_step(q0, qd0, qdd0, at0, M0, B0, h, alpha_m, alpha_f, gamma, beta, Q, g, c, order, drive,
                           independent, dependent, integrated, holonomic_dependent, chain, servo, tolerance,
                           max_iterations, projection_tolerance):
    """One generalized-alpha step (see :mod:`crane_reference.integration`) of the integrated coordinates
    x = q[integrated] = (q_ic, q_vd): the independent ones and those made dependent by first-order
    constraints.  Newton (iteration matrix from M, K, D reduced with B) on the independent accelerations,
    fixed point on the q_vd ones; q_hd from the position constraints and qd_dc from the velocity-level
    constraints at every iterate.

    Returns q1, qd1, a~1 (of x), the evaluation at (q1, qd1), a status (0 converged, 1 Newton did not
    converge, 2 the position or velocity constraints could not be solved) and the number of iterations."""
    K, D = chain[8], chain[9]
    n_ic = independent.size
    x0, v0, a0 = q0[integrated], qd0[integrated], qdd0[integrated]
    ratio = (1.0 - alpha_f) / (1.0 - alpha_m)
    beta_p, gamma_p = h * h * beta * ratio, h * gamma * ratio
    M_r = map_columns(project_rows(M0, B0, independent, dependent, servo), B0, independent, dependent)
    iteration_matrix = M_r + beta_p * map_columns(project_rows(K, B0, independent, dependent, servo), B0,
                                                    independent, dependent)
    if np.any(D != 0.0):
        iteration_matrix += gamma_p * map_columns(project_rows(D, B0, independent, dependent, servo), B0,
                                                  independent, dependent)
    # symmetric positive definite for ideal constraints (P = B): Cholesky; servo rows: a general inverse
    factor = np.ascontiguousarray(np.linalg.cholesky(iteration_matrix) if not servo
                                  else np.linalg.inv(iteration_matrix))
    q_guess = q0 + h * qd0 + 0.5 * h * h * qdd0
    a1 = a0.copy()
    status = 1
    for iteration in range(max_iterations):
        at1 = ((1.0 - alpha_f) * a1 + alpha_f * a0 - alpha_m * at0) / (1.0 - alpha_m)
        x1 = x0 + h * v0 + h * h * ((0.5 - beta) * at0 + beta * at1)
        v1 = v0 + h * ((1.0 - gamma) * at0 + gamma * at1)
        q1 = q_guess.copy()
        q1[integrated] = x1
        q1, _, _, solved = project_positions(q1, Q, g, c, order, holonomic_dependent, chain, projection_tolerance, 25)
        qd1 = np.zeros_like(q1)
        qd1[integrated] = v1
        if solved:
            qd1, terms, solved = _accelerations_at(q1, qd1, Q, g, c, order, drive, independent, dependent, chain,
                                                   servo, True)
        if not solved:
            held = evaluate(q0, qd0, Q, g, c, order, drive, independent, dependent, chain, servo)
            return q0, qd0, at0, held, 2, iteration + 1
        q_guess = q1
        qdd1 = terms[11][integrated]
        correction = qdd1 - a1
        residual = M_r @ (a1[:n_ic] - qdd1[:n_ic])
        correction[:n_ic] = -(_cholesky_solve(factor, residual) if not servo else factor @ residual)
        a1 = a1 + correction
        # The accepted iterate is off by the correction not applied: bound it in velocities (see the module
        # docstring of crane_reference.integration).  Accept only an iterate that already includes a Newton
        # correction: stopping at the predictor (possible near rest, where every correction is tiny) would
        # make the step explicit.
        if iteration > 0 and gamma_p * np.max(np.abs(correction)) <= tolerance:
            status = 0
            break
    return q1, qd1, at1, _complete(q1, qd1, terms, Q, g, c, order, drive, dependent, chain, servo), status, \
        iteration + 1


@njit(cache=True, nogil=True)
def generalized_alpha_run(q, qd, qdd, at, M, B, t0, times, Qs, gs, cs, order, drives, alpha_m, alpha_f, gamma,
                          beta, independent, dependent, integrated, holonomic_dependent, chain, servo, tolerance,
                          max_iterations, projection_tolerance):
    """:func:`generalized_alpha_step` from t0 through ``times`` (N,) in one call, with the constraint
    coefficients (Qs, gs, cs) and drive parameters (drives) of each step's end.  Returns the number of
    steps completed, the status of the last one (0 when all converged), per-step rows (q, qd, qdd,
    reactions, constraint forces, E's position, rotation and velocity, residuals, distances, accounts,
    Newton iterations) and the last step's a~ and evaluation."""
    N, n, m = times.size, q.size, order.size
    rows_q, rows_qd, rows_qdd = np.empty((N, n)), np.empty((N, n)), np.empty((N, n))
    rows_reactions, rows_forces = np.empty((N, m)), np.empty((N, n))
    rows_p, rows_R, rows_v = np.empty((N, 3)), np.empty((N, 3, 3)), np.empty((N, 3))
    rows_residual, rows_distance = np.empty((N, m)), np.empty((N, m))
    rows_accounts, rows_iterations = np.empty((N, 7)), np.empty(N, dtype=np.int64)
    t = t0
    q1, qd1, at1, result, status, iterations = generalized_alpha_step(
        q, qd, qdd, at, M, B, times[0] - t, alpha_m, alpha_f, gamma, beta, Qs[0], gs[0], cs[0], order, drives[0],
        independent, dependent, integrated, holonomic_dependent, chain, servo, tolerance, max_iterations,
        projection_tolerance)
    completed = 0
    while status == 0:
        rows_q[completed], rows_qd[completed], rows_qdd[completed] = q1, qd1, result[15]
        rows_reactions[completed], rows_forces[completed] = result[16], result[17]
        rows_p[completed], rows_R[completed], rows_v[completed] = result[4], result[5], result[6] @ qd1
        rows_residual[completed], rows_distance[completed] = result[8], result[12]
        rows_accounts[completed], rows_iterations[completed] = result[18], iterations
        completed += 1
        if completed == N:
            break
        t = times[completed - 1]
        q1, qd1, at1, result, status, iterations = generalized_alpha_step(
            q1, qd1, result[15], at1, result[0], result[14], times[completed] - t, alpha_m, alpha_f, gamma, beta,
            Qs[completed], gs[completed], cs[completed], order, drives[completed], independent, dependent,
            integrated, holonomic_dependent, chain, servo, tolerance, max_iterations, projection_tolerance)
    rows = (rows_q, rows_qd, rows_qdd, rows_reactions, rows_forces, rows_p, rows_R, rows_v, rows_residual,
            rows_distance, rows_accounts, rows_iterations)
    return completed, status, rows, at1, result

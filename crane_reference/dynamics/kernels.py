"""Compiled (numba) evaluation of the programmed motion (7)-(8) and of generalized-alpha steps.

The mathematics is documented where it is defined: chain terms in :mod:`.terms`, quadric task
constraints in :mod:`.quadrics`, equations (7)-(8) and the coordinate partitioning in
:mod:`crane_reference.motion.programmed_motion`, the generalized-alpha method in
:mod:`crane_reference.motion.integration`.  Here they are fused so that one integration step, or a run
of steps, is one call; the data come and go as the named tuples of :mod:`.structures`.  Time-dependent
data (constraint coefficients, drive) enter as numbers evaluated at each step's end; ``drive`` is the
array (tau0, s_dr, psi_a, dpsi_a/dt) of :func:`.terms.drive_torque`.  The kernels release the GIL
(``nogil``), so a ROS node's publishing thread runs while the solver steps.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .linalg import cholesky_solve, map_columns, project_rows, smallest_singular_value, solve_small, solve_small_vector
from .quadrics import acceleration_terms, constraint_values, holonomic_values, velocity_residual
from .structures import (
    Accelerations,
    AlphaSettings,
    ChainData,
    Coefficients,
    Evaluation,
    Partition,
    Run,
    Step,
    StepRows,
)
from .terms import end_effector_jacobian, energy_accounts, generalized_forces, position_terms, velocity_products


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
def project_positions(q, k: Coefficients, holonomic_dependent, chain: ChainData, tolerance, max_iterations):
    """q with the holonomically dependent coordinates solved from Phi(q) = 0 by Newton (Jacobian
    Phi_p C[:, hd]); also (p, C) of the last iterate and whether it converged."""
    q = q.copy()
    for _ in range(max_iterations):
        p, C = end_effector_jacobian(q, chain)
        if holonomic_dependent.size == 0:
            return q, p, C, True
        residual, grads = holonomic_values(p, k)
        step = solve_small_vector(grads @ np.ascontiguousarray(C[:, holonomic_dependent]), residual)
        for i in range(holonomic_dependent.size):
            q[holonomic_dependent[i]] -= step[i]
        if np.max(np.abs(step)) <= tolerance:
            return q, p, C, True
    return q, p, C, False


@njit(cache=True, nogil=True)
def dependent_velocities(qd, p, C, k: Coefficients, dependent):
    """qd with qd_dc solved from the velocity-level constraints (eq. (7): K_dc qd_dc = b - K_ic qd_ic for
    rows linear in qd); Newton on qd_dc (Jacobian K_dc = A[:, dc]), one step when every row is linear in
    qd, until the step is below 1e-14 otherwise.  Also whether it converged."""
    linear = True
    for i in range(k.order.size):
        if k.order[i] == 1 and np.any(k.Q[i, 0, 3:, 3:] != 0.0):
            linear = False
    qd = qd.copy()
    for _ in range(1 if linear else 30):
        residual, grads = velocity_residual(p, C @ qd, k)
        step = solve_small_vector(grads @ np.ascontiguousarray(C[:, dependent]), residual)
        for i in range(dependent.size):
            qd[dependent[i]] -= step[i]
        if linear or np.max(np.abs(step)) <= 1e-14:
            return qd, True
    return qd, False


@njit(cache=True, nogil=True)
def _solve_accelerations(M, f, A, c_acc, B, partition: Partition):
    """qdd from (8), [P^T M; A] qdd = [P^T f; c] with f = Q - h.  Ideal constraints (P = B): qdd = B a + e
    with e the particular solution (e_ic = 0, K_dc e_dc = c) and the reduced, symmetric positive definite
    system B^T M B a = B^T (f - M e) (Cholesky).  Servo-constraints: the square system by LU."""
    independent, dependent = partition.independent, partition.dependent
    n = f.size
    if partition.servo:
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
    a = cholesky_solve(np.linalg.cholesky(reduced), project_rows(load.reshape((n, 1)), B, independent, dependent,
                                                                 False)[:, 0])
    qdd = B @ a
    for r in range(dependent.size):
        qdd[dependent[r]] += e_dc[r]
    return qdd


@njit(cache=True, nogil=True)
def accelerations_at(q, qd, k: Coefficients, drive, partition: Partition, chain: ChainData, project_velocities):
    """What a Newton iteration needs at (q, qd): qdd from (8), optionally after solving qd_dc from the
    velocity-level constraints (with E's Jacobian at q itself, between the position and the velocity
    parts of the dynamics).  Returns qd, the :class:`Accelerations` and whether the velocity
    constraints were solved."""
    T, S, Hw, M, Qg, Vg, p, R, C = position_terms(q, chain)
    solved = True
    if project_velocities:
        qd, solved = dependent_velocities(qd, p, C, k, partition.dependent)
    h, d = velocity_products(qd, T, S, Hw, chain, p)
    forces = generalized_forces(q, qd, Qg, chain, drive)
    A, c_acc = acceleration_terms(p, C @ qd, C, d, k)
    B = velocity_map(A, partition.independent, partition.dependent)
    qdd = _solve_accelerations(M, forces - h, A, c_acc, B, partition)
    return qd, Accelerations(M, h, forces, Vg, p, R, C, d, A, c_acc, B, qdd), solved


@njit(cache=True, nogil=True)
def complete(q, qd, acc: Accelerations, k: Coefficients, drive, partition: Partition, chain: ChainData):
    """The full :class:`Evaluation` from :func:`accelerations_at`: adds the constraint residuals,
    gradients, distances and velocity residuals, the reactions, their generalized force and the accounts."""
    dependent = partition.dependent
    residual, grads, distance, rate = constraint_values(acc.ee_position, acc.ee_jacobian @ qd, k)
    reaction_force = acc.M @ acc.qdd + acc.h - acc.forces
    reactions = (reaction_force[dependent] if partition.servo
                 else solve_small_vector(acc.A @ acc.A.T, acc.A @ reaction_force))
    energy = energy_accounts(q, qd, acc.M, acc.gravity_potential, chain, drive)
    accounts = np.array([energy[0], energy[1], energy[2], energy[3], reaction_force @ qd, energy[4],
                         smallest_singular_value(np.ascontiguousarray(acc.A[:, dependent]))])
    return Evaluation(acc, residual, grads, distance, rate, reactions, reaction_force, accounts)


@njit(cache=True, nogil=True)
def evaluate(q, qd, k: Coefficients, drive, partition: Partition, chain: ChainData):
    """Everything (8) needs and gives at (q, qd) (:class:`Evaluation`): dynamics terms, constraint terms,
    B, qdd, the reactions (lambda for ideal constraints, the dependent joints' torques tau for
    servo-constraints), the generalized force they exert, M qdd + h - Q (= A^T lambda, or E_dc tau), and
    the accounts (powers: what each source feeds in)."""
    qd, acc, _ = accelerations_at(q, qd, k, drive, partition, chain, False)
    return complete(q, qd, acc, k, drive, partition, chain)


@njit(cache=True, nogil=True)
def generalized_alpha_step(q0, qd0, qdd0, at0, M0, B0, h, k: Coefficients, drive, partition: Partition,
                           chain: ChainData, settings: AlphaSettings):
    """One generalized-alpha step (see :mod:`crane_reference.motion.integration`) of the integrated
    coordinates x = q[integrated] = (q_ic, q_vd): the independent ones and those made dependent by
    first-order constraints.  Newton (iteration matrix from M, K, D reduced with B) on the independent
    accelerations, fixed point on the q_vd ones; q_hd from the position constraints and qd_dc from the
    velocity-level constraints at every iterate.  Starts from q0, qd0, qdd0, the pseudo-acceleration at0
    and M0, B0 at t0; h is the step."""
    independent, dependent, integrated = partition.independent, partition.dependent, partition.integrated
    servo = partition.servo
    alpha_m, alpha_f, gamma, beta = settings.alpha_m, settings.alpha_f, settings.gamma, settings.beta
    K, D = chain.stiffness, chain.damping
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
    for iteration in range(settings.max_iterations):
        at1 = ((1.0 - alpha_f) * a1 + alpha_f * a0 - alpha_m * at0) / (1.0 - alpha_m)
        x1 = x0 + h * v0 + h * h * ((0.5 - beta) * at0 + beta * at1)
        v1 = v0 + h * ((1.0 - gamma) * at0 + gamma * at1)
        q1 = q_guess.copy()
        q1[integrated] = x1
        q1, _, _, solved = project_positions(q1, k, partition.holonomic_dependent, chain,
                                             settings.projection_tolerance, 25)
        qd1 = np.zeros_like(q1)
        qd1[integrated] = v1
        if solved:
            qd1, acc, solved = accelerations_at(q1, qd1, k, drive, partition, chain, True)
        if not solved:
            return Step(q0, qd0, at0, evaluate(q0, qd0, k, drive, partition, chain), 2, iteration + 1)
        q_guess = q1
        qdd1 = acc.qdd[integrated]
        correction = qdd1 - a1
        residual = M_r @ (a1[:n_ic] - qdd1[:n_ic])
        correction[:n_ic] = -(cholesky_solve(factor, residual) if not servo else factor @ residual)
        a1 = a1 + correction
        # The accepted iterate is off by the correction not applied: bound it in velocities (see the module
        # docstring of crane_reference.motion.integration).  Accept only an iterate that already includes a
        # Newton correction: stopping at the predictor (possible near rest, where every correction is tiny)
        # would make the step explicit.
        if iteration > 0 and gamma_p * np.max(np.abs(correction)) <= settings.tolerance:
            status = 0
            break
    return Step(q1, qd1, at1, complete(q1, qd1, acc, k, drive, partition, chain), status, iteration + 1)


@njit(cache=True, nogil=True)
def _at_step(k: Coefficients, i):
    """The coefficients of step i of a run (``k`` stacked on a leading step axis)."""
    return Coefficients(k.Q[i], k.g[i], k.c[i], k.order)


@njit(cache=True, nogil=True)
def generalized_alpha_run(q, qd, qdd, at, M, B, t0, times, k: Coefficients, drives, partition: Partition,
                          chain: ChainData, settings: AlphaSettings):
    """:func:`generalized_alpha_step` from t0 through ``times`` (N,) in one call, with the constraint
    coefficients ``k`` (stacked per step) and drive parameters ``drives`` (N, 4) of each step's end.
    Stops at the first step that fails; returns a :class:`Run`."""
    N, n, m = times.size, q.size, k.order.size
    rows = StepRows(np.empty((N, n)), np.empty((N, n)), np.empty((N, n)), np.empty((N, m)), np.empty((N, n)),
                    np.empty((N, 3)), np.empty((N, 3, 3)), np.empty((N, 3)), np.empty((N, m)), np.empty((N, m)),
                    np.empty((N, 7)), np.empty(N, dtype=np.int64))
    step = generalized_alpha_step(q, qd, qdd, at, M, B, times[0] - t0, _at_step(k, 0), drives[0], partition, chain,
                                  settings)
    completed = 0
    while step.status == 0:
        e = step.evaluation
        acc = e.terms
        rows.q[completed], rows.qd[completed], rows.qdd[completed] = step.q, step.qd, acc.qdd
        rows.reactions[completed], rows.constraint_forces[completed] = e.reactions, e.constraint_forces
        rows.ee_position[completed], rows.ee_rotation[completed] = acc.ee_position, acc.ee_rotation
        rows.ee_velocity[completed] = acc.ee_jacobian @ step.qd
        rows.residual[completed], rows.residual_distance[completed] = e.residual, e.distance
        rows.accounts[completed], rows.iterations[completed] = e.accounts, step.iterations
        completed += 1
        if completed == N:
            break
        step = generalized_alpha_step(step.q, step.qd, acc.qdd, step.pseudo_acceleration, acc.M, acc.velocity_map,
                                      times[completed] - times[completed - 1], _at_step(k, completed),
                                      drives[completed], partition, chain, settings)
    return Run(completed, step.status, rows, step)

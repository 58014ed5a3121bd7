"""Compiled (numba) evaluation of the programmed motion (7)-(8) and of the integrator's steps.

The mathematics is documented where it is defined: chain terms in :mod:`.terms`, quadric task
constraints in :mod:`.quadrics`, equations (7)-(8) and the coordinate partitioning in
:mod:`crane_reference.motion.programmed_motion`, the integrator in
:mod:`crane_reference.motion.integration`.  Here they are fused so that one integration step, or a run
of steps, is one call; the data come and go as the named tuples of :mod:`.structures`.  Time-dependent
data (constraint coefficients, drive) enter as numbers evaluated at each step's end; ``drive`` is the
array (tau0, s_dr, psi_a, dpsi_a/dt) of :func:`.terms.drive_torque`.  The kernels release the GIL
(``nogil``), so a ROS node's publishing thread runs while the solver steps.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .inertia import composite_inertias, mass_matrix, world_pseudo_inertias
from .kinematics import forward_kinematics, point_bias, point_jacobian, velocity_terms
from .linalg import (
    cholesky,
    cholesky_solve,
    congruent,
    larger_magnitude,
    largest_magnitude,
    map_columns,
    matmul,
    matvec,
    project_rows,
    smallest_singular_value,
    solve_small_in_place,
    solve_small_vector,
)
from .quadrics import acceleration_terms, constraint_values, holonomic_values, velocity_residual
from .structures import (
    ACCOUNTS,
    CONSTRAINTS_UNSOLVABLE,
    CONVERGED,
    NON_FINITE,
    NOT_CONVERGED,
    SINGULAR_VALUE,
    Accelerations,
    Advance,
    ChainData,
    Coefficients,
    Evaluation,
    Iterate,
    ModalCorrection,
    Partition,
    Projection,
    Run,
    StateTerms,
    Step,
    StepRows,
    StepSettings,
)
from .terms import (
    drive_torque,
    energy_accounts,
    frame_terms,
    generalized_forces,
    inverse_dynamics,
    velocity_products,
)


@njit(cache=True, nogil=True, inline='always')
def constraint_map(A, c_acc, independent, dependent):
    """The solution set of the acceleration constraints A qdd = c (eq. (7)): qdd = B qdd_ic + e with the
    velocity map B = d qd / d qd_ic (n, n_ic) (identity rows on ic, Gamma = -K_dc^-1 K_ic rows on dc)
    and the particular solution e (e_ic = 0, K_dc e_dc = c); returns B and e_dc."""
    n_ic, m = independent.size, dependent.size
    K_dc = np.empty((m, m))
    solution = np.empty((m, n_ic + 1))  # [K_ic c], then K_dc^-1 [K_ic c]
    for row in range(m):
        for j in range(m):
            K_dc[row, j] = A[row, dependent[j]]
        for j in range(n_ic):
            solution[row, j] = A[row, independent[j]]
        solution[row, n_ic] = c_acc[row]
    solve_small_in_place(K_dc, solution)
    B = np.zeros((A.shape[1], n_ic))
    for col in range(n_ic):
        B[independent[col], col] = 1.0
    for row in range(m):
        for col in range(n_ic):
            B[dependent[row], col] = -solution[row, col]
    return B, solution[:, n_ic]


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


ROUND_OFF_STEP = 1e-15
"""[rad or m]: a Newton correction of the position constraints this small is at the round-off of q."""

PROJECTION_ITERATIONS = 25
"""Newton iterations on the position constraints at most, at an iterate of a step."""


@njit(cache=True, nogil=True, inline='always')
def project_positions(q, k: Coefficients, holonomic_dependent, chain: ChainData, tolerance, max_iterations,
                      exact_frames=True):
    """q with the holonomically dependent coordinates solved from Phi(q) = 0 by Newton (Jacobian
    Phi_p C[:, hd]) until a correction of at most ``tolerance`` (:class:`Projection`).  The frames are those
    at the returned q itself, or with ``exact_frames`` False those before the last correction (off by at most
    ``tolerance``, one forward kinematics less: enough for the Newton iterates of a step)."""
    q = q.copy()
    for _ in range(max_iterations):
        T, S = forward_kinematics(q, chain.kinds, chain.axes, chain.origins)
        p, C = point_jacobian(T, S, chain.ee_joint, chain.ee_point)
        if holonomic_dependent.size == 0:
            return Projection(q, T, S, p, C, True)
        step, grads = holonomic_values(p, k)  # the residual, solved in place for the Newton step
        solve_small_in_place(matmul(grads, C, holonomic_dependent), step.reshape((step.size, 1)))
        size = largest_magnitude(step)
        if size <= ROUND_OFF_STEP:
            return Projection(q, T, S, p, C, True)
        for i in range(holonomic_dependent.size):
            q[holonomic_dependent[i]] -= step[i]
        if size <= tolerance:
            if exact_frames:
                T, S = forward_kinematics(q, chain.kinds, chain.axes, chain.origins)
                p, C = point_jacobian(T, S, chain.ee_joint, chain.ee_point)
            return Projection(q, T, S, p, C, True)
    return Projection(q, T, S, p, C, False)


@njit(cache=True, nogil=True)
def held_points(q, points, k: Coefficients, holonomic_dependent, chain: ChainData, slew, tolerance, max_iterations):
    """E held at each of ``points`` (N, 3) [m] in turn on the position constraints ``k``, by continuation: each
    from the solution at the point before (the first from ``q``) with the slew joint's angle set to the point's
    azimuth (``slew`` = (joint, sign, offset) of :class:`~crane_reference.motion.simulation.Slew`: q[joint] =
    sign (atan2(y, x) - offset)) and q_hd from :func:`project_positions` (exact frames).  Returns the solution at the
    last point held and, per point, whether Newton converged (a singular K_dc counts as not converged), E's
    position there and the smallest singular value of K_dc = Phi_p C[:, hd]; it stops at the first point not
    held (the rows from there on False and NaN)."""
    count = points.shape[0]
    held = np.zeros(count, dtype=np.bool_)
    positions = np.full((count, 3), np.nan)
    singular_values = np.full(count, np.nan)
    q = q.copy()
    for i in range(count):
        trial = q.copy()
        trial[int(slew[0])] = slew[1] * (np.arctan2(points[i, 1], points[i, 0]) - slew[2])
        try:
            at = project_positions(trial, k, holonomic_dependent, chain, tolerance, max_iterations)
        except Exception:  # numba catches no narrower class: a singular K_dc
            break
        if not at.solved:
            break
        grads = holonomic_values(at.ee_position, k)[1]
        singular_values[i] = smallest_singular_value(matmul(grads, at.ee_jacobian, holonomic_dependent))
        positions[i] = at.ee_position
        held[i] = True
        q = at.q
    return q, held, positions, singular_values


@njit(cache=True, nogil=True, inline='always')
def dependent_velocities(qd, p, C, k: Coefficients, dependent):
    """qd with qd_dc solved from the velocity-level constraints (eq. (7): K_dc qd_dc = b - K_ic qd_ic for
    rows linear in qd); Newton on qd_dc (Jacobian K_dc = A[:, dc]), one step when every row is linear in
    qd, until the step is below 1e-14 otherwise.  Also whether it converged."""
    linear = True
    order, Q = k.order, k.Q
    for i in range(order.size):
        if order[i] == 1:
            for a in range(3, 6):
                for b in range(3, 6):
                    linear = linear and Q[i, 0, a, b] == 0.0
    qd = qd.copy()
    for _ in range(1 if linear else 30):
        step, grads = velocity_residual(p, matvec(C, qd), k)  # the residual, solved in place for the step
        solve_small_in_place(matmul(grads, C, dependent), step.reshape((step.size, 1)))
        for i in range(dependent.size):
            qd[dependent[i]] -= step[i]
        if linear or largest_magnitude(step) <= 1e-14:
            return qd, True
    return qd, False


@njit(cache=True, nogil=True, inline='always')
def _accelerations_from(qdd_independent, B, e_dc, independent, dependent):
    """qdd = B qdd_ic + e (the acceleration constraints of (7) for given independent accelerations): qdd_ic
    itself, qdd_dc = Gamma qdd_ic + e_dc."""
    qdd = np.empty(B.shape[0])
    for j in range(independent.size):
        qdd[independent[j]] = qdd_independent[j]
    for r in range(dependent.size):
        total = e_dc[r]
        for j in range(independent.size):
            total += B[dependent[r], j] * qdd_independent[j]
        qdd[dependent[r]] = total
    return qdd


@njit(cache=True, nogil=True)
def _solve_accelerations(M, f, A, B, e_dc, c_acc, partition: Partition):
    """qdd from (8), [P^T M; A] qdd = [P^T f; c] with f = Q - h.  Ideal constraints (P = B): qdd = B a + e
    (:func:`constraint_map`) with the reduced, symmetric positive definite system B^T M B a = B^T (f - M e)
    (Cholesky).  Servo-constraints: the square system by LU."""
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
    load = f.copy()
    for r in range(dependent.size):
        load -= M[:, dependent[r]] * e_dc[r]
    rhs = project_rows(load.reshape((n, 1)), B, independent, dependent, False)[:, 0]
    a = cholesky_solve(cholesky(congruent(M, B, independent, dependent)), rhs)
    return _accelerations_from(a, B, e_dc, independent, dependent)


@njit(cache=True, nogil=True, inline='always')
def _terms_at(q, qd, T, S, k: Coefficients, drive, partition: Partition, chain: ChainData):
    """The position and velocity terms of (7)-(8) at (q, qd) from the frames there (:class:`StateTerms`)."""
    Hw, M, Qg, Vg, p, R, C = frame_terms(T, S, chain)
    h, d = velocity_products(qd, S, Hw, chain, p)
    forces = generalized_forces(q, qd, Qg, chain, drive)
    A, c_acc = acceleration_terms(p, matvec(C, qd), C, d, k)
    B, e_dc = constraint_map(A, c_acc, partition.independent, partition.dependent)
    return StateTerms(M, h, forces, Qg, Vg, p, R, C, d, A, c_acc, B, e_dc)


@njit(cache=True, nogil=True)
def accelerations_at(q, qd, k: Coefficients, drive, partition: Partition, chain: ChainData):
    """qdd from (8) at (q, qd) with everything it needs (:class:`Accelerations`)."""
    T, S = forward_kinematics(q, chain.kinds, chain.axes, chain.origins)
    s = _terms_at(q, qd, T, S, k, drive, partition, chain)
    qdd = _solve_accelerations(s.M, s.forces - s.h, s.A, s.velocity_map, s.particular, s.c, partition)
    return _with_accelerations(s, qdd)


@njit(cache=True, nogil=True, inline='always')
def _with_accelerations(s: StateTerms, qdd):
    """:class:`Accelerations` from :class:`StateTerms` and qdd."""
    return Accelerations(s.M, s.h, s.forces, s.gravity_forces, s.gravity_potential, s.ee_position, s.ee_rotation,
                         s.ee_jacobian, s.ee_bias, s.A, s.c, s.velocity_map, qdd)


@njit(cache=True, nogil=True, inline='always')
def _reactions(A, imbalance, partition: Partition):
    """The reactions to the imbalance M qdd + h - Q and their generalized force: for ideal constraints
    lambda = (A A^T)^-1 A (M qdd + h - Q) and A^T lambda (the imbalance itself where qdd solves (8); for the
    integrator's accelerations its part along the constraints: the rest is the modal correction's force,
    see :mod:`crane_reference.motion.integration`); for servo-constraints the dependent joints' torques and
    the imbalance."""
    if partition.servo:
        return imbalance[partition.dependent], imbalance
    reactions = solve_small_vector(matmul(A, A.T), matvec(A, imbalance))
    return reactions, matvec(np.ascontiguousarray(A.T), reactions)


@njit(cache=True, nogil=True, inline='always')
def _evaluation(q, qd, acc: Accelerations, k: Coefficients, drive, partition: Partition, chain: ChainData):
    """The full :class:`Evaluation` from :class:`Accelerations`: adds the constraint residuals, gradients,
    distances and velocity residuals, the reactions to the imbalance M qdd + h - Q and their generalized
    force (:func:`_reactions`), and the accounts."""
    dependent = partition.dependent
    residual, grads, distance, rate = constraint_values(acc.ee_position, matvec(acc.ee_jacobian, qd), k)
    reactions, reaction_force = _reactions(acc.A, matvec(acc.M, acc.qdd) + acc.h - acc.forces, partition)
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
    return _evaluation(q, qd, accelerations_at(q, qd, k, drive, partition, chain), k, drive, partition, chain)


@njit(cache=True, nogil=True)
def forces_jumped(s: Accelerations, q, qd, k: Coefficients, drive, partition: Partition, chain: ChainData):
    """:func:`evaluate` at the (q, qd) of the terms ``s`` (those of an evaluation there) under another ``drive``
    (the forces jumped there: a new command, a jump of the column drive's torque): the position and velocity
    terms of ``s`` kept, Q formed again from its Q_g and (8) solved again (``s.forces`` and ``s.qdd`` are not
    read).  ``q``, ``qd`` and ``k`` are those ``s`` was evaluated at."""
    forces = generalized_forces(q, qd, s.gravity_forces, chain, drive)
    e_dc = constraint_map(s.A, s.c, partition.independent, partition.dependent)[1]
    qdd = _solve_accelerations(s.M, forces - s.h, s.A, s.velocity_map, e_dc, s.c, partition)
    terms = Accelerations(s.M, s.h, forces, s.gravity_forces, s.gravity_potential, s.ee_position, s.ee_rotation,
                          s.ee_jacobian, s.ee_bias, s.A, s.c, s.velocity_map, qdd)
    return _evaluation(q, qd, terms, k, drive, partition, chain)


@njit(cache=True, nogil=True)
def _reduced_mass(M, B, partition: Partition):
    """M_r = B^T M B in the independent coordinates."""
    return congruent(M, B, partition.independent, partition.dependent)


@njit(cache=True, nogil=True)
def _congruence(X, weights):
    """X diag(weights) X^T, symmetric to the last bit."""
    scaled = X.copy()
    for m in range(weights.size):
        scaled[:, m] *= weights[m]
    product = scaled @ X.T
    return 0.5 * (product + product.T)


@njit(cache=True, nogil=True)
def modal_correction(reduced_mass, h, t, drive, partition: Partition, chain: ChainData, settings: StepSettings):
    """The modal terms of the step h at a configuration of reduced mass M_r = B^T M B (see
    :mod:`crane_reference.motion.integration`).  The springs act on independent coordinates only, so the
    reduced stiffness K_r = K[ic, ic] (plus the drive's spring on psi2) is constant; with M_r = L L^T the
    modes K_r phi = omega^2 M_r phi, Phi^T M_r Phi = I, are Phi = L^-T V with the
    eigenvectors V of L^-1 K_r L^-T.  A mode with omega h below ``settings.cutoff`` gets the inertia and
    damping corrections c and e that map its roots lambda of lambda^2 + d lambda + omega^2 (d = phi^T D_r phi,
    the physical modal damping) exactly: the trapezoidal rule on (1 - c) a + (d + e) v + omega^2 x has the
    roots lambda_hat = (2 / h) tanh(lambda h / 2), so 1 - c = omega^2 / (lambda_hat_1 lambda_hat_2) and
    d + e = -(1 - c) (lambda_hat_1 + lambda_hat_2) (undamped: c = 1 - ((omega h / 2) / tan(omega h / 2))^2,
    e = 0); a mode at or above the cutoff gets the damping e = 2 zeta omega.  In the independent coordinates
    Delta M_r = M_r Phi diag(c) Phi^T M_r = (L V) diag(c) (L V)^T and likewise D_u with e (neither acts on a
    motion no spring resists: Phi^T M_r = diag(omega^-2) Phi^T K_r).  Servo-constraints (P = E_ic: no
    symmetric reduced mass) get none, and so does the plain trapezoidal rule (``settings.modal`` False)."""
    independent = partition.independent
    n_ic = independent.size
    if partition.servo or not settings.modal:
        return ModalCorrection(np.zeros((n_ic, n_ic)), np.zeros((n_ic, n_ic)), t, h)
    L = cholesky(reduced_mass)
    stiffness = np.empty((n_ic, n_ic))
    for i in range(n_ic):
        for j in range(n_ic):
            stiffness[i, j] = chain.stiffness[independent[i], independent[j]]
        if independent[i] == chain.drive_joint:
            stiffness[i, i] += drive[1]
    L_inverse = np.linalg.inv(L)
    omega_squared, V = np.linalg.eigh(L_inverse @ stiffness @ L_inverse.T)
    LV = L @ V  # M_r Phi = L V
    modal_damping = np.zeros(n_ic)
    if chain.damped:
        physical = np.empty((n_ic, n_ic))
        for i in range(n_ic):
            for j in range(n_ic):
                physical[i, j] = chain.damping[independent[i], independent[j]]
        modes = np.ascontiguousarray((L_inverse.T @ V).T)  # row i: phi_i
        for i in range(n_ic):
            modal_damping[i] = modes[i] @ (physical @ modes[i])
    c = np.zeros(n_ic)
    d = np.zeros(n_ic)
    for i in range(n_ic):
        k = max(omega_squared[i], 0.0)
        omega = np.sqrt(k)
        if omega * h >= settings.cutoff:
            d[i] = 2.0 * settings.unresolved_damping * omega
            continue
        root = np.sqrt(complex(modal_damping[i] ** 2 - 4.0 * k))
        second = 0.5 * (-modal_damping[i] - root)
        if abs(second * h) < 1e-6:
            continue
        first = k / second  # the product of the roots is k: no cancellation for an overdamped mode
        mapped_first, mapped_second = (2.0 / h) * np.tanh(0.5 * h * first), (2.0 / h) * np.tanh(0.5 * h * second)
        product = (mapped_first * mapped_second).real
        mass = k / product if product != 0.0 else 1.0
        c[i] = 1.0 - mass
        d[i] = -mass * (mapped_first + mapped_second).real - modal_damping[i]
    return ModalCorrection(_congruence(LV, c), _congruence(LV, d), t, h)


@njit(cache=True, nogil=True)
def converted_accelerations(reduced_mass, a, v, old: ModalCorrection, new: ModalCorrection):
    """The independent accelerations under the modal correction ``new`` that balance the same force as ``a``
    under ``old`` (at the velocities v): (M_r - Delta M_new) a_new + D_new v = (M_r - Delta M_old) a + D_old v."""
    force = matvec(reduced_mass - old.inertia, a) + matvec(old.damping - new.damping, v)
    return cholesky_solve(cholesky(reduced_mass - new.inertia), force)


@njit(cache=True, nogil=True)
def corrected_accelerations(M, B, qdd, qd, correction: ModalCorrection, partition: Partition):
    """qdd of the equation corrected by ``correction`` at a state where qdd solves (8) itself (a restart that
    keeps the modal correction, e.g. after the forces jumped): the independent part converted from no
    correction (as :func:`converted_accelerations` with zero old terms: (M_r - Delta M) a + D_u v = M_r a_exact),
    the dependent part following through B (qdd = B a + e).  Servo-constraints have no correction: qdd as it
    is."""
    independent = partition.independent
    if partition.servo:
        return qdd.copy()
    reduced_mass = _reduced_mass(M, B, partition)
    exact = qdd[independent]
    force = matvec(reduced_mass, exact) - matvec(correction.damping, qd[independent])
    return qdd + matvec(B, cholesky_solve(cholesky(reduced_mass - correction.inertia), force) - exact)


@njit(cache=True, nogil=True)
def iteration_factor(M, B, h, correction: ModalCorrection, drive, partition: Partition, chain: ChainData):
    """The factor of the Newton iteration matrix P^T (M + h^2/4 K + h/2 D) B - Delta M_r + h/2 D_u for the
    step h (K with the drive's spring s_dr on psi2): its Cholesky factor for ideal constraints (P = B,
    symmetric positive definite), its inverse for servo-constraints (P = E_ic).  The model's springs and
    dampers act on independent coordinates only (:class:`~crane_reference.motion.programmed_motion.ProgrammedMotion`
    checks it), so their part is h^2/4 K[ic, ic] + h/2 D[ic, ic]; the drive's spring adds
    h^2/4 s_dr P[psi2]^T B[psi2] (psi2 may be dependent)."""
    independent, dependent, servo = partition.independent, partition.dependent, partition.servo
    if servo:
        reduced = map_columns(project_rows(M, B, independent, dependent, True), B, independent, dependent)
    else:
        reduced = congruent(M, B, independent, dependent)
    stiffness, damping, inertia, modal_damping = chain.stiffness, chain.damping, correction.inertia, correction.damping
    spring, drive_row = 0.25 * h * h * drive[1], B[chain.drive_joint]
    for i in range(independent.size):
        row = independent[i]
        left = drive_row[i] if not servo else (1.0 if row == chain.drive_joint else 0.0)
        for j in range(independent.size):
            column = independent[j]
            value = (0.25 * h * h) * stiffness[row, column] + (0.5 * h) * modal_damping[i, j] - inertia[i, j] \
                + spring * left * drive_row[j]
            if chain.damped:
                value += (0.5 * h) * damping[row, column]
            reduced[i, j] += value
    return cholesky(reduced) if not servo else np.linalg.inv(reduced)


@njit(cache=True, nogil=True, inline='always')
def _state_at(a1, x0, v0, a0, q_guess, qd_size, h, k: Coefficients, partition: Partition, chain: ChainData,
              settings: StepSettings, project, exact_frames):
    """The trapezoidal state for the accelerations a1 of the integrated coordinates,
    x1 = x0 + h v0 + h^2/4 (a0 + a1), v1 = v0 + h/2 (a0 + a1): q = ``q_guess`` with x1 and q_hd from the
    position constraints (``project``; frames as in :func:`project_positions`) or as guessed (the caller
    predicts it to second order in the change of x), qd with qd_dc from the velocity constraints
    (:class:`Iterate`)."""
    integrated = partition.integrated
    q1 = q_guess.copy()
    qd1 = np.zeros(qd_size)
    for i in range(integrated.size):
        q1[integrated[i]] = x0[i] + h * v0[i] + (0.25 * h * h) * (a0[i] + a1[i])
        qd1[integrated[i]] = v0[i] + (0.5 * h) * (a0[i] + a1[i])
    if project:
        at = project_positions(q1, k, partition.holonomic_dependent, chain, settings.projection_tolerance,
                               PROJECTION_ITERATIONS,
                               exact_frames)
    else:
        T, S = forward_kinematics(q1, chain.kinds, chain.axes, chain.origins)
        p, C = point_jacobian(T, S, chain.ee_joint, chain.ee_point)
        at = Projection(q1, T, S, p, C, True)
    solved = at.solved
    if solved:
        qd1, solved = dependent_velocities(qd1, at.ee_position, at.ee_jacobian, k, partition.dependent)
    return Iterate(at.q, qd1, at.T, at.S, at.ee_position, at.ee_jacobian, solved)


@njit(cache=True, nogil=True, inline='always')
def _predict_dependent(q, B, dx, holonomic_dependent):
    """q with q_hd moved by B[hd] dx (dx the change of the independent coordinates; B = d q / d q_ic)."""
    out = q.copy()
    for i in range(holonomic_dependent.size):
        row = holonomic_dependent[i]
        total = 0.0
        for j in range(B.shape[1]):
            total += B[row, j] * dx[j]
        out[row] += total
    return out


@njit(cache=True, nogil=True, inline='always')
def newton_residual(q, qd, a1, T, S, Hw, p, C, k: Coefficients, drive, partition: Partition, chain: ChainData):
    """At an iterate (q, qd) that meets the constraints, with the integrator's accelerations a1 of the
    integrated coordinates: the full qdd = B a1_ic + e (the acceleration constraints of (7); for q_vd this
    is the fixed-point update), the residual of (8), P^T (M qdd + h - Q), with M qdd + h - Q_g from
    inverse dynamics (O(n), no M; Hw the world pseudo-inertias at q), and B."""
    independent, dependent = partition.independent, partition.dependent
    velocity_term = velocity_terms(qd, S)
    d = point_bias(velocity_term, chain.ee_joint, p)
    A, c_acc = acceleration_terms(p, matvec(C, qd), C, d, k)
    B, e_dc = constraint_map(A, c_acc, independent, dependent)
    qdd = _accelerations_from(a1[:independent.size], B, e_dc, independent, dependent)
    imbalance = _imbalance(q, qd, qdd, S, Hw, velocity_term, chain, drive)
    return qdd, project_rows(imbalance.reshape((q.size, 1)), B, independent, dependent, partition.servo)[:, 0], B


@njit(cache=True, nogil=True, inline='always')
def _imbalance(q, qd, qdd, S, Hw, velocity_term, chain: ChainData, drive):
    """M qdd + h - Q at (q, qd) by O(n) inverse dynamics (no M), from the twists S, world pseudo-inertias Hw
    and velocity terms there: inverse dynamics with gravity, less the other generalized forces."""
    return inverse_dynamics(S, Hw, velocity_term, qdd, chain) - generalized_forces(q, qd, np.zeros(q.size), chain,
                                                                                   drive)


@njit(cache=True, nogil=True, inline='always')
def _end_accelerations(end: Iterate, a1, k: Coefficients, partition: Partition, chain: ChainData):
    """qdd = B a1_ic + e at the step's end state (the acceleration constraints of (7) there: E's velocity
    terms, A, c and B; no mass matrix), B and sigma_min(K_dc)."""
    d = point_bias(velocity_terms(end.qd, end.S), chain.ee_joint, end.ee_position)
    A, c_acc = acceleration_terms(end.ee_position, matvec(end.ee_jacobian, end.qd), end.ee_jacobian, d, k)
    dependent = partition.dependent
    K_dc = np.empty((dependent.size, dependent.size))
    for row in range(dependent.size):
        for j in range(dependent.size):
            K_dc[row, j] = A[row, dependent[j]]
    B, e_dc = constraint_map(A, c_acc, partition.independent, dependent)
    return (_accelerations_from(a1[:partition.independent.size], B, e_dc, partition.independent, dependent), B,
            smallest_singular_value(K_dc))


@njit(cache=True, nogil=True)
def _failed(q0, qd0, qdd0, B0, earlier, correction: ModalCorrection, status, iterations):
    """The :class:`Advance` of a step that failed with ``status``: its start, unsolved."""
    nan = np.full(3, np.nan)
    return Advance(q0, qd0, qdd0, B0, earlier, nan, np.full((3, 3), np.nan), nan, np.nan, correction, status,
                   iterations)


@njit(cache=True, nogil=True)
def _unsolved(it: Iterate, a1):
    """Why the constraints could not be met at the iterate ``it`` with accelerations a1: NON_FINITE when it
    overflowed, else CONSTRAINTS_UNSOLVABLE."""
    return CONSTRAINTS_UNSOLVABLE if np.isfinite(it.q.sum() + it.qd.sum() + a1.sum()) else NON_FINITE


@njit(cache=True, nogil=True, inline='always')
def _step_residual_at(it: Iterate, a1, correction: ModalCorrection, k: Coefficients, drive, partition: Partition,
                      chain: ChainData):
    """The residual of the step's equation, P^T (M qdd + h - Q) - Delta M_r a1_ic + D_u v_ic, at an iterate for
    the accelerations a1 (:func:`newton_residual` plus the modal terms); also qdd, B and the world
    pseudo-inertias Hw there."""
    n_ic = partition.independent.size
    Hw = world_pseudo_inertias(it.T, chain.body_joint, chain.body_H)
    qdd, residual, B = newton_residual(it.q, it.qd, a1, it.T, it.S, Hw, it.ee_position, it.ee_jacobian, k, drive,
                                       partition, chain)
    independent, qd, damping, inertia = partition.independent, it.qd, correction.damping, correction.inertia
    for i in range(n_ic):
        total = 0.0
        for j in range(n_ic):
            total += damping[i, j] * qd[independent[j]] - inertia[i, j] * a1[j]
        residual[i] += total
    return qdd, residual, B, Hw


@njit(cache=True, nogil=True, inline='always')
def predicted_accelerations(a0, earlier):
    """The predictor of a step's accelerations a1 of the integrated coordinates from those at its start, a0,
    and at the starts of the two steps before, ``earlier`` (2, n_x; row 0 the later, NaN where unknown): the
    quadratic through the three extrapolated one step, a1 = 3 a0 - 3 a_-1 + a_-2 (exact for accelerations
    quadratic in time: the slow motion's error after the Newton corrections shrinks with it); the linear one,
    2 a0 - a_-1, with one known; a0 with none."""
    if np.isnan(earlier[0, 0]):
        return a0.copy()
    if np.isnan(earlier[1, 0]):
        return 2.0 * a0 - earlier[0]
    return 3.0 * a0 - 3.0 * earlier[0] + earlier[1]


@njit(cache=True, nogil=True, inline='always')
def first_iterate(q0, qd0, qdd0, a0, a1, h, k: Coefficients, partition: Partition, chain: ChainData,
                  settings: StepSettings):
    """The step's first iterate: the trapezoidal state for the predicted accelerations a1 of the integrated
    coordinates (x0 + h v0 + h^2/4 (a0 + a1)) with q_hd from the position constraints, their Newton iteration
    starting from the Taylor polynomial q0 + h qd0 + h^2/2 qdd0 (off by O(h^3): one correction reaches the
    tolerance)."""
    integrated = partition.integrated
    return _state_at(a1, q0[integrated], qd0[integrated], a0, q0 + h * qd0 + (0.5 * h * h) * qdd0, q0.size, h, k,
                     partition, chain, settings, True, False)


@njit(cache=True, nogil=True)
def mass_at(S, Hw, chain: ChainData):
    """M at the configuration of the twists S and world pseudo-inertias Hw."""
    return mass_matrix(S, composite_inertias(Hw, chain.body_joint, S.shape[0]))


@njit(cache=True, nogil=True)
def step_residual(a1, q0, qd0, a0, correction: ModalCorrection, h, k: Coefficients, drive, partition: Partition,
                  chain: ChainData, settings: StepSettings):
    """The residual of the step's equation (:func:`_step_residual_at`) as a function of the accelerations a1 of
    the integrated coordinates, at the trapezoidal state for a1 with q_hd on the position constraints (what
    the Newton iteration drives to zero; its Jacobian is what :func:`iteration_factor` with M and B at the
    first iterate approximates)."""
    integrated = partition.integrated
    guess = q0 + h * qd0
    guess[integrated] += (0.25 * h * h) * (a0 + a1)
    it = _state_at(a1, q0[integrated], qd0[integrated], a0, guess, q0.size, h, k, partition, chain, settings, True,
                   True)
    return _step_residual_at(it, a1, correction, k, drive, partition, chain)[1]


@njit(cache=True, nogil=True)
def integration_step(q0, qd0, qdd0, B0, earlier, correction: ModalCorrection, t0, h, k: Coefficients, drive,
                     partition: Partition, chain: ChainData, settings: StepSettings):
    """One step of the integrator (see :mod:`crane_reference.motion.integration`) from t0 to t0 + h of the
    integrated coordinates x = q[integrated] = (q_ic, q_vd): the trapezoidal rule on the residual of (8)
    with the modal terms P^T (M qdd + h - Q) - Delta M_r a_ic + D_u v_ic.  Newton on the independent
    accelerations with the residual from inverse dynamics, fixed point on the q_vd ones, from the
    :func:`first_iterate` at the :func:`predicted_accelerations` (from ``earlier``, the accelerations of the
    integrated coordinates at the two previous steps' starts, NaN where unknown; forgotten at a new step
    size), whose M and B (the step end's to first order in h) give the iteration matrix
    (:func:`iteration_factor`); q_hd predicted to second order in the change of x at the later iterates,
    qd_dc from the velocity-level constraints at every iterate.  At least ``settings.evaluations``
    evaluations, then until the last correction is below the tolerance; the step ends at the state of the
    corrected accelerations, on the position constraints, with qdd = B a_ic + e there (:class:`Advance`; no
    M).

    The modal correction is computed again from M at q0 and B0 (:func:`modal_correction`) at the step nearest
    ``settings.refresh_interval`` after the one in use was, and for another step size.  It is a coefficient
    of the equation that follows the configuration: the step's end is solved with the new one, its start
    keeps the accelerations of the old one (Delta M_r piecewise constant in time, as the trapezoidal rule
    treats any coefficient; converting them would act on the slow motion's accelerations as on free
    vibration, a kick at every refresh).  A new step size (or a start: no correction yet) is a new
    equation, and the start's accelerations are solved from it: converted so that the force they balance
    stays the same, (M_r - Delta M_new) a_new + D_new v = (M_r - Delta M_old) a_old + D_old v (at a start the
    old terms are zero: a_old is the acceleration of (8) itself)."""
    independent, integrated, servo = partition.independent, partition.integrated, partition.servo
    n_ic = independent.size
    x0, v0, a0 = q0[integrated], qd0[integrated], qdd0[integrated].copy()
    new_step = abs(h - correction.step) > 1e-9 * h
    if new_step or t0 - correction.time >= settings.refresh_interval - 0.5 * h:
        T0, S0 = forward_kinematics(q0, chain.kinds, chain.axes, chain.origins)
        reduced_mass = _reduced_mass(mass_at(S0, world_pseudo_inertias(T0, chain.body_joint, chain.body_H), chain),
                                     B0, partition)
        fresh = modal_correction(reduced_mass, h, t0, drive, partition, chain, settings)
        if new_step and not servo:
            a0[:n_ic] = converted_accelerations(reduced_mass, a0[:n_ic], v0[:n_ic], correction, fresh)
        correction = fresh
    if new_step:  # the earlier accelerations are of another equation
        earlier = np.full(earlier.shape, np.nan)
    a1 = predicted_accelerations(a0, earlier)
    it = first_iterate(q0, qd0, qdd0, a0, a1, h, k, partition, chain, settings)
    if not it.solved:
        return _failed(q0, qd0, qdd0, B0, earlier, correction, _unsolved(it, a1), 1)
    qdd, residual, B, Hw = _step_residual_at(it, a1, correction, k, drive, partition, chain)
    M = mass_at(it.S, Hw, chain)
    factor = iteration_factor(M, B, h, correction, drive, partition, chain)
    q1 = it.q
    status = NOT_CONVERGED
    for iteration in range(settings.max_iterations):
        if iteration > 0:
            it = _state_at(a1, x0, v0, a0, q1, q0.size, h, k, partition, chain, settings, False, False)
            qdd, residual, B, Hw = _step_residual_at(it, a1, correction, k, drive, partition, chain)
        solved = cholesky_solve(factor, residual) if not servo else matvec(factor, residual)
        largest = 0.0
        for i in range(integrated.size):  # Newton on a_ic, fixed point on a_vd
            if i < n_ic:
                change = -solved[i]
                solved[i] = (0.25 * h * h) * change
            else:
                change = qdd[integrated[i]] - a1[i]
            a1[i] += change
            largest = larger_magnitude(largest, change)
        if not largest < np.inf:  # NaN or inf: an overflow, which no iteration mends
            return _failed(q0, qd0, qdd0, B0, earlier, correction, NON_FINITE, iteration + 1)
        # q_hd of the next iterate to second order in the change of x: dx = h^2/4 da
        q1 = _predict_dependent(it.q, B, solved, partition.holonomic_dependent)
        if iteration + 1 >= settings.evaluations and 0.5 * h * largest <= settings.tolerance:
            status = CONVERGED
            break
    end = _state_at(a1, x0, v0, a0, q1, q0.size, h, k, partition, chain, settings, True, True)
    if not end.solved:
        return _failed(q0, qd0, qdd0, B0, earlier, correction, _unsolved(end, a1), iteration + 1)
    qdd, B, singular_value = _end_accelerations(end, a1, k, partition, chain)
    later = np.empty_like(earlier)
    later[0], later[1] = a0, earlier[0]
    return Advance(end.q, end.qd, qdd, B, later, end.ee_position, end.T[chain.ee_joint, :3, :3].copy(),
                   matvec(end.ee_jacobian, end.qd), singular_value, correction, status, iteration + 1)


@njit(cache=True, nogil=True)
def step_evaluation(q, qd, qdd, k: Coefficients, drive, partition: Partition, chain: ChainData):
    """The full :class:`Evaluation` at a step's end (q, qd) with the integrator's qdd (reactions, residuals,
    accounts: what a caller reads of a step, computed only where it reads them)."""
    T, S = forward_kinematics(q, chain.kinds, chain.axes, chain.origins)
    return _evaluation(q, qd, _with_accelerations(_terms_at(q, qd, T, S, k, drive, partition, chain), qdd), k, drive,
                       partition, chain)


@njit(cache=True, nogil=True)
def _at_step(k: Coefficients, i):
    """The coefficients of step i of a run (``k`` stacked on a leading step axis)."""
    return Coefficients(k.Q[i], k.g[i], k.c[i], k.order)


@njit(cache=True, nogil=True)
def integration_run(q, qd, qdd, B, earlier, correction: ModalCorrection, t0, times, k: Coefficients, drives,
                    partition: Partition, chain: ChainData, settings: StepSettings, evaluated, stop):
    """:func:`integration_step` from t0 through ``times`` (N,) in one call, with the constraint
    coefficients ``k`` (stacked per step) and drive parameters ``drives`` (N, 4) of each step's end, B the
    velocity map at t0 and ``earlier`` the accelerations of the two steps before (:func:`integration_step`).
    The rows of the steps where ``evaluated`` (N,) is True, and of the last one, carry the full evaluation
    (:func:`step_evaluation`: reactions, residuals, accounts); the others NaN there but for sigma_min(K_dc)
    in the accounts (every step's; :func:`evaluated_rows` completes them later).
    Stops at the first step that fails, or after a step once ``stop[0]`` (a flag another thread or process may
    set while the run is in progress) is nonzero: then fewer than N steps completed, all converged.  Returns a
    :class:`Run`."""
    N, n, m = times.size, q.size, k.order.size
    rows = StepRows(np.empty((N, n)), np.empty((N, n)), np.empty((N, n)), np.full((N, m), np.nan),
                    np.full((N, n), np.nan), np.empty((N, 3)), np.empty((N, 3, 3)), np.empty((N, 3)),
                    np.full((N, m), np.nan), np.full((N, m), np.nan), np.full((N, len(ACCOUNTS)), np.nan),
                    np.empty(N, dtype=np.int64))
    step = integration_step(q, qd, qdd, B, earlier, correction, t0, times[0] - t0, _at_step(k, 0), drives[0],
                            partition, chain, settings)
    completed = 0
    while step.status == CONVERGED:
        rows.q[completed], rows.qd[completed], rows.qdd[completed] = step.q, step.qd, step.qdd
        rows.ee_position[completed], rows.ee_rotation[completed] = step.ee_position, step.ee_rotation
        rows.ee_velocity[completed], rows.iterations[completed] = step.ee_velocity, step.iterations
        rows.accounts[completed, SINGULAR_VALUE] = step.kdc_min_singular_value
        if evaluated[completed] and completed < N - 1:
            _evaluated_row(rows, completed, step_evaluation(step.q, step.qd, step.qdd, _at_step(k, completed),
                                                            drives[completed], partition, chain))
        completed += 1
        if completed == N or stop[0]:
            break
        step = integration_step(step.q, step.qd, step.qdd, step.velocity_map, step.earlier, step.correction,
                                times[completed - 1], times[completed] - times[completed - 1], _at_step(k, completed),
                                drives[completed], partition, chain, settings)
    if step.status == CONVERGED:
        i = completed - 1
        last = step_evaluation(step.q, step.qd, step.qdd, _at_step(k, i), drives[i], partition, chain)
        _evaluated_row(rows, i, last)
    else:  # the evaluation at the failed step's start
        last = evaluate(step.q, step.qd, _at_step(k, completed), drives[completed], partition, chain)
    return Run(completed, step.status, rows, Step(step.q, step.qd, last, step.earlier, step.correction, step.status,
                                                  step.iterations))


@njit(cache=True, nogil=True)
def evaluated_rows(q, qd, qdd, k: Coefficients, drives, partition: Partition, chain: ChainData):
    """What a reader of computed steps that :func:`integration_run` left unevaluated needs of their full
    evaluation (:func:`step_evaluation`), without M: rows of q, qd and the integrator's qdd (N, n) with the
    constraint coefficients ``k`` (stacked per row) and the drive parameters ``drives`` of each; returns the
    generalized force of the constraints (N, n; :func:`_reactions` to M qdd + h - Q by O(n) inverse
    dynamics), the drive torque (N,) [N m] and the constraint distances (N, m) [m]."""
    N, n, m = q.shape[0], q.shape[1], k.order.size
    forces, torques, distances = np.empty((N, n)), np.empty(N), np.empty((N, m))
    for i in range(N):
        k_i = _at_step(k, i)
        imbalance, T, S, velocity_term = _imbalance_at(q[i], qd[i], qdd[i], drives[i], chain)
        p, C = point_jacobian(T, S, chain.ee_joint, chain.ee_point)
        v = matvec(C, qd[i])
        A = acceleration_terms(p, v, C, point_bias(velocity_term, chain.ee_joint, p), k_i)[0]
        forces[i] = _reactions(A, imbalance, partition)[1]
        torques[i] = drive_torque(drives[i], q[i, chain.drive_joint])
        distances[i] = constraint_values(p, v, k_i)[2]
    return forces, torques, distances


@njit(cache=True, nogil=True)
def imbalance_rows(q, qd, qdd, drives, chain: ChainData):
    """M qdd + h - Q at the rows of q, qd and qdd (N, n), with the drive parameters ``drives`` of each row,
    by O(n) inverse dynamics (no M)."""
    out = np.empty_like(q)
    for i in range(q.shape[0]):
        out[i] = _imbalance_at(q[i], qd[i], qdd[i], drives[i], chain)[0]
    return out


@njit(cache=True, nogil=True, inline='always')
def _imbalance_at(q, qd, qdd, drive, chain: ChainData):
    """M qdd + h - Q at (q, qd, qdd) by O(n) inverse dynamics (:func:`_imbalance`), with the frames T, twists S
    and velocity terms it computed on the way."""
    T, S = forward_kinematics(q, chain.kinds, chain.axes, chain.origins)
    velocity_term = velocity_terms(qd, S)
    imbalance = _imbalance(q, qd, qdd, S, world_pseudo_inertias(T, chain.body_joint, chain.body_H), velocity_term,
                           chain, drive)
    return imbalance, T, S, velocity_term


@njit(cache=True, nogil=True)
def _evaluated_row(rows: StepRows, i, e: Evaluation):
    """Row i of a run's rows from the full evaluation of its step."""
    rows.reactions[i], rows.constraint_forces[i] = e.reactions, e.constraint_forces
    rows.residual[i], rows.residual_distance[i] = e.residual, e.distance
    rows.accounts[i] = e.accounts

"""Compiled evaluation of (7)-(8) at a state: the chain and constraint terms, qdd, the reactions and their
generalized force, the accounts (:class:`~.structures.Evaluation`); (8) solved again where only the forces jumped;
the imbalance M qdd + h - Q by O(n) inverse dynamics.  ``drive`` is the array (tau0, s_dr, psi_a, dpsi_a/dt) of
:func:`.terms.drive_torque` followed by any actuator forces; the kernels release the GIL (``nogil``), so a ROS
node's publishing thread runs while the solver computes."""

from __future__ import annotations

import numpy as np
from numba import njit

from .inertia import world_pseudo_inertias
from .kinematics import forward_kinematics, velocity_terms
from .linalg import (
    cholesky,
    cholesky_solve,
    congruent,
    matmul,
    matvec,
    project_rows,
    smallest_singular_value,
    solve_small_vector,
)
from .projection import constraint_map
from .quadrics import acceleration_terms, constraint_values
from .structures import Accelerations, ChainData, Coefficients, Evaluation, Partition, StateTerms
from .terms import (
    add_applied_forces,
    energy_accounts,
    frame_terms,
    generalized_forces,
    inverse_dynamics,
    velocity_products,
)


@njit(cache=True, nogil=True, inline='always')
def accelerations_from(qdd_independent, B, e_dc, independent, dependent):
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
    return accelerations_from(a, B, e_dc, independent, dependent)


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
def reactions_to(A, imbalance, partition: Partition):
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
    force (:func:`reactions_to`), and the accounts."""
    dependent = partition.dependent
    residual, grads, distance, rate = constraint_values(acc.ee_position, matvec(acc.ee_jacobian, qd), k)
    reactions, reaction_force = reactions_to(acc.A, matvec(acc.M, acc.qdd) + acc.h - acc.forces, partition)
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


@njit(cache=True, nogil=True, inline='always')
def imbalance_from_terms(q, qd, qdd, S, Hw, velocity_term, chain: ChainData, drive):
    """M qdd + h - Q at (q, qd) by O(n) inverse dynamics (no M), from the twists S, world pseudo-inertias Hw
    and velocity terms there: inverse dynamics with gravity, less the other generalized forces."""
    imbalance = inverse_dynamics(S, Hw, velocity_term, qdd, chain)
    add_applied_forces(imbalance, q, qd, chain, drive, -1.0)
    return imbalance


@njit(cache=True, nogil=True)
def step_evaluation(q, qd, qdd, k: Coefficients, drive, partition: Partition, chain: ChainData):
    """The full :class:`Evaluation` at a step's end (q, qd) with the integrator's qdd (reactions, residuals,
    accounts: what a caller reads of a step, computed only where it reads them)."""
    T, S = forward_kinematics(q, chain.kinds, chain.axes, chain.origins)
    return _evaluation(q, qd, _with_accelerations(_terms_at(q, qd, T, S, k, drive, partition, chain), qdd), k, drive,
                       partition, chain)


@njit(cache=True, nogil=True)
def imbalance_rows(q, qd, qdd, drives, chain: ChainData):
    """M qdd + h - Q at the rows of q, qd and qdd (N, n), with the drive parameters ``drives`` of each row,
    by O(n) inverse dynamics (no M)."""
    out = np.empty_like(q)
    for i in range(q.shape[0]):
        out[i] = imbalance_at(q[i], qd[i], qdd[i], drives[i], chain)[0]
    return out


@njit(cache=True, nogil=True, inline='always')
def imbalance_at(q, qd, qdd, drive, chain: ChainData):
    """M qdd + h - Q at (q, qd, qdd) by O(n) inverse dynamics (:func:`imbalance_from_terms`), with the frames T,
    twists S and velocity terms it computed on the way."""
    T, S = forward_kinematics(q, chain.kinds, chain.axes, chain.origins)
    velocity_term = velocity_terms(qd, S)
    imbalance = imbalance_from_terms(q, qd, qdd, S, world_pseudo_inertias(T, chain.body_joint, chain.body_H),
                                     velocity_term, chain, drive)
    return imbalance, T, S, velocity_term

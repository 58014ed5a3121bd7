"""Compiled integration step (see :mod:`crane_reference.motion.integration`): the prediction, the Newton iterates on
the independent accelerations with the position constraints projected at each, and the step's end."""

from __future__ import annotations

import numpy as np
from numba import njit

from .evaluation import accelerations_from, imbalance_from_terms
from .inertia import composite_inertias, mass_matrix, world_pseudo_inertias
from .iteration_matrix import articulated_iteration_factor, dense_iteration_factor, iteration_solve
from .kinematics import forward_kinematics, point_bias, point_jacobian, velocity_terms
from .linalg import larger_magnitude, matvec, project_rows, smallest_singular_value
from .modal_correction import (
    converted_accelerations,
    modal_correction,
    reduced_mass_matrix,
    refreshed_correction,
    stiffness_product,
    tracked_correction,
)
from .projection import PROJECTION_ITERATIONS, constraint_map, dependent_velocities, project_positions
from .quadrics import acceleration_terms
from .structures import (
    CONSTRAINTS_UNSOLVABLE,
    CONVERGED,
    NON_FINITE,
    NOT_CONVERGED,
    ChainData,
    Coefficients,
    ModalCorrection,
    Partition,
    Projection,
    RefreshInputs,
    StepEnd,
    StepSettings,
    StepStart,
    TrialState,
)

GUESSED, PROJECTED, PROJECTED_EXACT = 0, 1, 2
"""How :func:`_state_at` gets the holonomically dependent positions q_hd: as the caller guessed them (to second
order in the change of x), from the position constraints with the frames before Newton's last correction, or
from them with the frames at the returned q (:func:`project_positions`' ``exact_frames``)."""


@njit(cache=True, nogil=True, inline='always')
def _state_at(a1, x0, v0, a0, q_guess, qd_size, h, k: Coefficients, partition: Partition, chain: ChainData,
              settings: StepSettings, dependent):
    """The trapezoidal state for the accelerations a1 of the integrated coordinates,
    x1 = x0 + h v0 + h^2/4 (a0 + a1), v1 = v0 + h/2 (a0 + a1): q = ``q_guess`` with x1 and q_hd as ``dependent``
    says (:data:`GUESSED`, :data:`PROJECTED`, :data:`PROJECTED_EXACT`), qd with qd_dc from the velocity
    constraints (:class:`TrialState`)."""
    integrated = partition.integrated
    q1 = q_guess.copy()
    qd1 = np.zeros(qd_size)
    for i in range(integrated.size):
        q1[integrated[i]] = x0[i] + h * v0[i] + (0.25 * h * h) * (a0[i] + a1[i])
        qd1[integrated[i]] = v0[i] + (0.5 * h) * (a0[i] + a1[i])
    if dependent != GUESSED:
        at = project_positions(q1, k, partition.holonomic_dependent, chain, settings.projection_tolerance,
                               PROJECTION_ITERATIONS, dependent == PROJECTED_EXACT)
    else:
        T, S = forward_kinematics(q1, chain.kinds, chain.axes, chain.origins)
        p, C = point_jacobian(T, S, chain.ee_joint, chain.ee_point)
        at = Projection(q1, T, S, p, C, True)
    solved = at.solved
    if solved:
        qd1, solved = dependent_velocities(qd1, at.ee_position, at.ee_jacobian, k, partition.dependent)
    return TrialState(at.q, qd1, at.T, at.S, at.ee_position, at.ee_jacobian, solved)


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
    qdd = accelerations_from(a1[:independent.size], B, e_dc, independent, dependent)
    imbalance = imbalance_from_terms(q, qd, qdd, S, Hw, velocity_term, chain, drive)
    return qdd, project_rows(imbalance.reshape((q.size, 1)), B, independent, dependent, partition.servo)[:, 0], B


@njit(cache=True, nogil=True, inline='always')
def _end_accelerations(end: TrialState, a1, k: Coefficients, partition: Partition, chain: ChainData):
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
    return (accelerations_from(a1[:partition.independent.size], B, e_dc, partition.independent, dependent), B,
            smallest_singular_value(K_dc))


@njit(cache=True, nogil=True)
def _failed(q0, qd0, qdd0, B0, earlier, correction: ModalCorrection, status, iterations):
    """The :class:`StepEnd` of a step that failed with ``status``: its start, unsolved."""
    nan = np.full(3, np.nan)
    return StepEnd(q0, qd0, qdd0, B0, earlier, nan, np.full((3, 3), np.nan), nan, np.nan, correction, status,
                   iterations)


@njit(cache=True, nogil=True)
def _unsolved(it: TrialState, a1):
    """Why the constraints could not be met at the iterate ``it`` with accelerations a1: NON_FINITE when it
    overflowed, else CONSTRAINTS_UNSOLVABLE."""
    return CONSTRAINTS_UNSOLVABLE if np.isfinite(it.q.sum() + it.qd.sum() + a1.sum()) else NON_FINITE


@njit(cache=True, nogil=True, inline='always')
def _plain_residual_at(it: TrialState, a1, k: Coefficients, drive, partition: Partition, chain: ChainData):
    """:func:`newton_residual` at an iterate for the accelerations a1, P^T (M qdd + h - Q) without the modal
    terms; also qdd, B and the world pseudo-inertias Hw there."""
    Hw = world_pseudo_inertias(it.T, chain.body_joint, chain.body_H)
    qdd, residual, B = newton_residual(it.q, it.qd, a1, it.T, it.S, Hw, it.ee_position, it.ee_jacobian, k, drive,
                                       partition, chain)
    return qdd, residual, B, Hw


@njit(cache=True, nogil=True, inline='always')
def add_modal_terms(residual, qd, a1, correction: ModalCorrection, drive, partition: Partition, chain: ChainData):
    """residual += D_u v_ic - Delta M_r a1_ic, the modal terms of the step's equation (in place), by the resolved
    modes in O(n r): U (diag(e - beta omega^2) U^T v - diag(c) U^T a) + beta K_r v (:class:`ModalCorrection`)."""
    independent, on_resolved = partition.independent, correction.on_resolved
    n_ic = independent.size
    v = np.empty((n_ic, 1))
    for i in range(n_ic):
        v[i, 0] = qd[independent[i]]
    if correction.unresolved_beta != 0.0:
        springs = stiffness_product(v, drive, partition, chain)
        for i in range(n_ic):
            residual[i] += correction.unresolved_beta * springs[i, 0]
    inertia_weights, damping_weights = correction.inertia_weights, correction.damping_weights
    for m in range(correction.resolved):
        on_velocity, on_acceleration = 0.0, 0.0
        for i in range(n_ic):
            on_velocity += on_resolved[i, m] * v[i, 0]
            on_acceleration += on_resolved[i, m] * a1[i]
        weight = damping_weights[m] * on_velocity - inertia_weights[m] * on_acceleration
        for i in range(n_ic):
            residual[i] += on_resolved[i, m] * weight


@njit(cache=True, nogil=True, inline='always')
def _step_residual_at(it: TrialState, a1, correction: ModalCorrection, k: Coefficients, drive, partition: Partition,
                      chain: ChainData):
    """The residual of the step's equation, P^T (M qdd + h - Q) - Delta M_r a1_ic + D_u v_ic, at an iterate for
    the accelerations a1; also qdd, B and the world pseudo-inertias Hw there."""
    qdd, residual, B, Hw = _plain_residual_at(it, a1, k, drive, partition, chain)
    add_modal_terms(residual, it.qd, a1, correction, drive, partition, chain)
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
    out = np.empty(a0.size)
    if np.isnan(earlier[1, 0]):
        for i in range(a0.size):
            out[i] = 2.0 * a0[i] - earlier[0, i]
        return out
    for i in range(a0.size):
        out[i] = 3.0 * a0[i] - 3.0 * earlier[0, i] + earlier[1, i]
    return out


@njit(cache=True, nogil=True, inline='always')
def first_iterate(q0, qd0, qdd0, a0, a1, h, k: Coefficients, partition: Partition, chain: ChainData,
                  settings: StepSettings):
    """The step's first iterate: the trapezoidal state for the predicted accelerations a1 of the integrated
    coordinates (x0 + h v0 + h^2/4 (a0 + a1)) with q_hd from the position constraints, their Newton iteration
    starting from the Taylor polynomial q0 + h qd0 + h^2/2 qdd0 (off by O(h^3): one correction reaches the
    tolerance)."""
    integrated = partition.integrated
    taylor = np.empty(q0.size)
    for i in range(q0.size):
        taylor[i] = q0[i] + h * qd0[i] + (0.5 * h * h) * qdd0[i]
    return _state_at(a1, q0[integrated], qd0[integrated], a0, taylor, q0.size, h, k, partition, chain, settings,
                     PROJECTED)


@njit(cache=True, nogil=True)
def mass_at(S, Hw, chain: ChainData):
    """M at the configuration of the twists S and world pseudo-inertias Hw."""
    return mass_matrix(S, composite_inertias(Hw, chain.body_joint, S.shape[0]))


@njit(cache=True, nogil=True)
def refresh_inputs(q, B, partition: Partition, chain: ChainData):
    """What a refresh of the modal correction reads at q with the velocity map B (:class:`RefreshInputs`: M_r =
    B^T M B, the twists and the world pseudo-inertias)."""
    T, S = forward_kinematics(q, chain.kinds, chain.axes, chain.origins)
    Hw = world_pseudo_inertias(T, chain.body_joint, chain.body_H)
    return RefreshInputs(reduced_mass_matrix(mass_at(S, Hw, chain), B, partition), S, Hw)


@njit(cache=True, nogil=True)
def step_residual(a1, q0, qd0, a0, correction: ModalCorrection, h, k: Coefficients, drive, partition: Partition,
                  chain: ChainData, settings: StepSettings):
    """The residual of the step's equation (:func:`_step_residual_at`) as a function of the accelerations a1 of
    the integrated coordinates, at the trapezoidal state for a1 with q_hd on the position constraints (what
    the Newton iteration drives to zero; its Jacobian is what the iteration matrix
    (:mod:`~crane_reference.dynamics.iteration_matrix`) with M and B at the first iterate approximates)."""
    integrated = partition.integrated
    guess = q0 + h * qd0
    guess[integrated] += (0.25 * h * h) * (a0 + a1)
    it = _state_at(a1, q0[integrated], qd0[integrated], a0, guess, q0.size, h, k, partition, chain, settings,
                   PROJECTED_EXACT)
    return _step_residual_at(it, a1, correction, k, drive, partition, chain)[1]


@njit(cache=True, nogil=True)
def integration_step(start: StepStart, h, k: Coefficients, drive, partition: Partition, chain: ChainData,
                     settings: StepSettings):
    """One step of the integrator (see :mod:`crane_reference.motion.integration`) from the ``start`` at t0 to
    t0 + h of the integrated coordinates x = q[integrated] = (q_ic, q_vd): the trapezoidal rule on the residual of (8)
    with the modal terms P^T (M qdd + h - Q) - Delta M_r a_ic + D_u v_ic.  Newton on the independent
    accelerations with the residual from inverse dynamics, fixed point on the q_vd ones, from the
    :func:`first_iterate` at the :func:`predicted_accelerations` (from ``earlier``, the accelerations of the
    integrated coordinates at the two previous steps' starts, NaN where unknown; forgotten at a new step
    size), whose M and B (the step end's to first order in h) give the iteration matrix
    (:mod:`~crane_reference.dynamics.iteration_matrix`: formed densely, or with ``settings.articulated`` solved by
    the articulated-body recursion without M); q_hd predicted to second order in the change of x at the later iterates,
    qd_dc from the velocity-level constraints at every iterate.  At least ``settings.evaluations``
    evaluations, then until the last correction is below the tolerance; the step ends at the state of the
    corrected accelerations, on the position constraints, with qdd = B a_ic + e there (:class:`StepEnd`; no
    M).

    The modal correction is computed again from M at q0 and B0 at the step nearest ``settings.refresh_interval``
    after the one in use was (:func:`modal_correction`, or with ``settings.subspace_refresh``
    :func:`refreshed_correction` from its modes), and for another step size (:func:`modal_correction`); between,
    its resolved modes are carried to the configuration of the first iterate (:func:`tracked_correction` with its M
    and B, before the modal terms enter its residual) at the step nearest ``settings.mode_tracking_interval`` after
    they last were (``tracked`` counts from the step's start t0; where the tracked modes' span degenerates, the full
    eigenproblem there, which counts as a refresh at t0).  It is a coefficient
    of the equation that follows the configuration: the step's end is solved with the new one, its start
    keeps the accelerations of the old one (Delta M_r piecewise constant in time, as the trapezoidal rule
    treats any coefficient; converting them would act on the slow motion's accelerations as on free
    vibration, a kick at every refresh).  A new step size (or a start: no correction yet) is a new
    equation, and the start's accelerations are solved from it: converted so that the force they balance
    stays the same, (M_r - Delta M_new) a_new + D_new v = (M_r - Delta M_old) a_old + D_old v (at a start the
    old terms are zero: a_old is the acceleration of (8) itself)."""
    t0, q0, qd0, qdd0, B0, earlier, correction = start
    independent, integrated, servo = partition.independent, partition.integrated, partition.servo
    n_ic = independent.size
    x0, v0, a0 = q0[integrated], qd0[integrated], qdd0[integrated]  # copies (integer indices)
    new_step = abs(h - correction.step) > 1e-9 * h
    if new_step or t0 - correction.time >= settings.refresh_interval - 0.5 * h:
        at_start = refresh_inputs(q0, B0, partition, chain)
        if settings.subspace_refresh and not new_step:
            fresh = refreshed_correction(at_start.reduced_mass, at_start.S, at_start.Hw, B0, correction, h, t0, drive,
                                         partition, chain, settings)
        else:
            fresh = modal_correction(at_start.reduced_mass, h, t0, drive, partition, chain, settings)
        if new_step and not servo:
            a0[:n_ic] = converted_accelerations(at_start.reduced_mass, a0[:n_ic], v0[:n_ic], correction, fresh)
        correction = fresh
    if new_step:  # the earlier accelerations are of another equation
        earlier = np.full(earlier.shape, np.nan)
    a1 = predicted_accelerations(a0, earlier)
    it = first_iterate(q0, qd0, qdd0, a0, a1, h, k, partition, chain, settings)
    if not it.solved:
        return _failed(q0, qd0, qdd0, B0, earlier, correction, _unsolved(it, a1), 1)
    qdd, residual, B, Hw = _plain_residual_at(it, a1, k, drive, partition, chain)
    tracking = correction.resolved > 0 and t0 - correction.tracked >= settings.mode_tracking_interval - 0.5 * h
    articulated = settings.articulated and not servo
    M = mass_at(it.S, Hw, chain) if tracking or not articulated else np.empty((0, 0))
    if tracking:
        correction = tracked_correction(reduced_mass_matrix(M, B, partition), correction, t0, drive, partition,
                                        chain, settings)
    add_modal_terms(residual, it.qd, a1, correction, drive, partition, chain)
    if articulated:
        factor = articulated_iteration_factor(it.S, Hw, B, h, correction, drive, partition, chain)
    else:
        factor = dense_iteration_factor(M, B, h, correction, drive, partition, chain)
    q1 = it.q
    status = NOT_CONVERGED
    for iteration in range(settings.max_iterations):
        if iteration > 0:
            it = _state_at(a1, x0, v0, a0, q1, q0.size, h, k, partition, chain, settings, GUESSED)
            qdd, residual, B, Hw = _step_residual_at(it, a1, correction, k, drive, partition, chain)
        solved = iteration_solve(factor, residual, partition)
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
    end = _state_at(a1, x0, v0, a0, q1, q0.size, h, k, partition, chain, settings, PROJECTED_EXACT)
    if not end.solved:
        return _failed(q0, qd0, qdd0, B0, earlier, correction, _unsolved(end, a1), iteration + 1)
    qdd, B, singular_value = _end_accelerations(end, a1, k, partition, chain)
    later = np.empty_like(earlier)
    later[0], later[1] = a0, earlier[0]
    return StepEnd(end.q, end.qd, qdd, B, later, end.ee_position, end.T[chain.ee_joint, :3, :3].copy(),
                   matvec(end.ee_jacobian, end.qd), singular_value, correction, status, iteration + 1)

"""Compiled modal correction of the integrator's step (see :mod:`crane_reference.motion.integration`): the reduced
mass, the corrections per mode, and the accelerations and Newton iteration factor under them."""

from __future__ import annotations

import numpy as np
from numba import njit

from .articulated import constrained_factor, constraint_rows, joint_term, reduced_solve
from .linalg import (
    cholesky,
    cholesky_or_stop,
    cholesky_solve,
    cholesky_solve_columns,
    congruent,
    jacobi_eigh,
    lower_inverse,
    map_columns,
    matvec,
    project_rows,
)
from .structures import ChainData, ModalCorrection, Partition, StepSettings


@njit(cache=True, nogil=True)
def reduced_mass_matrix(M, B, partition: Partition):
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
def no_correction(n_ic):
    """No modal correction yet (time -inf): the next step computes it."""
    zeros = np.zeros((n_ic, n_ic))
    return ModalCorrection(zeros, zeros.copy(), zeros.copy(), 0, -np.inf, 0.0, -np.inf, zeros.copy(), np.zeros(n_ic),
                           np.zeros(n_ic), 0.0)


SHIFT = 1.0
"""[rad^2/s^2]: :func:`tracked_correction` iterates with K_r + SHIFT M_r, positive definite although no spring
resists the slew (a mode of zero frequency)."""


@njit(cache=True, nogil=True)
def reduced_stiffness(drive, partition: Partition, chain: ChainData):
    """K_r = K[ic, ic] plus the drive's spring s_dr (``drive[1]``) on psi2: the springs act on independent
    coordinates only, so K_r is constant."""
    independent = partition.independent
    n_ic = independent.size
    stiffness = np.empty((n_ic, n_ic))
    for i in range(n_ic):
        for j in range(n_ic):
            stiffness[i, j] = chain.stiffness[independent[i], independent[j]]
        if independent[i] == chain.drive_joint:
            stiffness[i, i] += drive[1]
    return stiffness


@njit(cache=True, nogil=True)
def reduced_drive_spring(drive, partition: Partition, chain: ChainData):
    """The drive's spring s_dr (``drive[1]``) as K_r holds it: on psi2 when psi2 is independent, else none (the
    springs act on independent coordinates only)."""
    for i in range(partition.independent.size):
        if partition.independent[i] == chain.drive_joint:
            return drive[1]
    return 0.0


@njit(cache=True, nogil=True)
def _modal_damping(modes, count, partition: Partition, chain: ChainData):
    """d_i = phi_i^T D_r phi_i of the first ``count`` columns phi_i of ``modes`` (D_r = D[ic, ic]; zeros for an
    undamped chain)."""
    independent = partition.independent
    n_ic = independent.size
    out = np.zeros(count)
    if not chain.damped:
        return out
    for m in range(count):
        total = 0.0
        for i in range(n_ic):
            for j in range(n_ic):
                total += modes[i, m] * chain.damping[independent[i], independent[j]] * modes[j, m]
        out[m] = total
    return out


@njit(cache=True, nogil=True)
def _resolved_terms(omega_squared, modal_damping, h):
    """The inertia and damping corrections c and e of resolved modes of squared frequencies omega^2 and physical
    modal damping d (see :func:`modal_correction`): the trapezoidal rule on (1 - c) a + (d + e) v + omega^2 x has
    the roots exp(lambda h) of lambda^2 + d lambda + omega^2 (zero for a mode no spring resists)."""
    c = np.zeros(omega_squared.size)
    e = np.zeros(omega_squared.size)
    for i in range(omega_squared.size):
        k = max(omega_squared[i], 0.0)
        root = np.sqrt(complex(modal_damping[i] ** 2 - 4.0 * k))
        second = 0.5 * (-modal_damping[i] - root)
        if abs(second * h) < 1e-6:
            continue
        first = k / second  # the product of the roots is k: no cancellation for an overdamped mode
        mapped_first, mapped_second = (2.0 / h) * np.tanh(0.5 * h * first), (2.0 / h) * np.tanh(0.5 * h * second)
        product = (mapped_first * mapped_second).real
        mass = k / product if product != 0.0 else 1.0
        c[i] = 1.0 - mass
        e[i] = -mass * (mapped_first + mapped_second).real - modal_damping[i]
    return c, e


@njit(cache=True, nogil=True)
def _generalized_modes(stiffness, mass):
    """The modes of the pencil (K, M) (symmetric, M positive definite): omega^2 ascending and Phi with
    Phi^T M Phi = I, as Phi = L^-T V with M = L L^T and V the eigenvectors of L^-1 K L^-T; also L V = M Phi."""
    L = cholesky(mass)
    L_inverse = np.linalg.inv(L)
    reduced = L_inverse @ stiffness @ L_inverse.T
    omega_squared, V = np.linalg.eigh(_symmetric(reduced))
    return omega_squared, L_inverse.T @ V, L @ V


@njit(cache=True, nogil=True)
def _symmetric(A):
    """(A + A^T) / 2."""
    return 0.5 * (A + A.T)


@njit(cache=True, nogil=True)
def modal_correction(reduced_mass, h, t, drive, partition: Partition, chain: ChainData, settings: StepSettings):
    """The modal terms of the step h at a configuration of reduced mass M_r = B^T M B (see
    :mod:`crane_reference.motion.integration`), from the full eigenproblem K_r phi = omega^2 M_r phi, Phi^T M_r Phi
    = I (K_r :func:`reduced_stiffness`).  A mode with omega below omega_c (:func:`cutoff_angular_frequency`) gets
    the inertia and damping corrections c and e that map its roots lambda of lambda^2 + d lambda + omega^2 (d =
    phi^T D_r phi, the physical modal damping) exactly: the trapezoidal rule on (1 - c) a + (d + e) v + omega^2 x
    has the roots lambda_hat = (2 / h) tanh(lambda h / 2), so 1 - c = omega^2 / (lambda_hat_1 lambda_hat_2) and d +
    e = -(1 - c) (lambda_hat_1 + lambda_hat_2) (undamped: c = 1 - ((omega h / 2) / tan(omega h / 2))^2, e = 0); a
    mode at or above omega_c gets the damping e = beta omega^2, beta = 2 zeta / omega_c (damping ratio zeta omega /
    omega_c: ``settings.unresolved_damping`` zeta at omega_c, stiffness-proportional, so that the unresolved part of
    D_u is beta (K_r - M_r Phi_r diag(omega_r^2) Phi_r^T M_r), K_r less a part of the resolved modes' rank).  In the
    independent coordinates Delta M_r = M_r Phi diag(c) Phi^T M_r and likewise D_u with e (neither acts on a motion
    no spring resists: Phi^T M_r = diag(omega^-2) Phi^T K_r), both from the resolved modes alone
    (:func:`_terms_of_resolved_modes`).  Servo-constraints (P = E_ic: no symmetric reduced mass) get none, and so
    does the plain trapezoidal rule (``settings.modal`` False)."""
    n_ic = partition.independent.size
    zeros = np.zeros((n_ic, n_ic))
    if partition.servo or not settings.modal:
        return ModalCorrection(zeros, zeros.copy(), zeros.copy(), 0, t, h, t, zeros.copy(), np.zeros(n_ic),
                               np.zeros(n_ic), 0.0)
    stiffness = reduced_stiffness(drive, partition, chain)
    omega_squared, modes, on_modes = _generalized_modes(stiffness, reduced_mass)
    resolved = 0
    omega_c = cutoff_angular_frequency(h, settings.cutoff, settings.resolved_bandwidth)
    while resolved < n_ic and np.sqrt(max(omega_squared[resolved], 0.0)) < omega_c:
        resolved += 1
    c, e = _resolved_terms(omega_squared[:resolved], _modal_damping(modes, resolved, partition, chain), h)
    on_resolved = np.ascontiguousarray(on_modes[:, :resolved])
    return _terms_of_resolved_modes(on_resolved, omega_squared[:resolved], c, e, unresolved_beta(h, settings),
                                    stiffness, modes, t, h, t)


GUARD_MODES = 8
"""Modes iterated beyond the resolved ones by :func:`refreshed_correction`: a mode that comes below the cutoff from
among them is seen (the count changes, and the full eigenproblem counts again), one from beyond them would not be;
together they set how fast the resolved ones converge."""

REFRESH_SHIFT = 0.3
"""The shift s of :func:`refreshed_correction`'s iteration as a fraction of omega_c^2
(:func:`cutoff_angular_frequency`)."""

REFRESH_TOLERANCE = 1e-5
"""The largest residual (K_r - omega^2 M_r) phi, relative to (omega^2 + s) M_r phi, that :func:`refreshed_correction`
accepts of a resolved mode or the lowest guard mode."""

REFRESH_ITERATIONS = 4
"""Iterations after which :func:`refreshed_correction` solves the full eigenproblem instead."""


@njit(cache=True, nogil=True)
def refreshed_correction(reduced_mass, S, Hw, B, correction: ModalCorrection, h, t, drive, partition: Partition,
                         chain: ChainData, settings: StepSettings):
    """``correction`` (of the step h) computed again at the configuration of reduced mass M_r, twists S, world
    pseudo-inertias Hw and velocity map B, as :func:`modal_correction` computes it but by subspace iteration from its
    modes: X_0 = the resolved modes and :data:`GUARD_MODES` more, Y = (K_r + s M_r)^-1 M_r X (s =
    :data:`REFRESH_SHIFT` omega_c^2), and X = the Rayleigh-Ritz modes of the pencil (K_r, M_r) on the span of Y
    (those of (Y^T K_r Y, Y^T M_r Y)).  Each iteration shrinks a mode's error by (omega^2 + s) / (omega_g^2 + s),
    omega_g the lowest mode beyond the iterated ones: the shift near the cutoff amplifies the resolved modes alike,
    and keeps a guard mode's direction (with s = 0 a guard mode far above the cutoff is lost under the resolved
    ones' round-off).  (K_r + s M_r)^-1 = s^-1 (B^T (M + K / s) B)^-1 by the articulated-body solve (K with the drive's
    spring where K_r holds it; :func:`~crane_reference.dynamics.articulated.reduced_solve`), O(n) per mode.  The
    iteration stops when the residual ||K_r phi - omega^2 M_r phi|| / ((omega^2 + s) ||M_r phi||) of every resolved
    mode and of the lowest guard is at most :data:`REFRESH_TOLERANCE`.  The Rayleigh-Ritz step is done as in
    :func:`tracked_correction` (Y^T M_r Y = L L^T with Y's columns of M_r-norm 1, then Jacobi rotations: after the
    first iteration the projected pencil is nearly diagonal).  The full eigenproblem is solved instead when the
    iteration does not stop within :data:`REFRESH_ITERATIONS`, when the number of modes below the cutoff changes (a
    mode crossed it: the guard modes are counted again), when no guard mode fits (r + :data:`GUARD_MODES` >= n_ic),
    when the span degenerates (a squared pivot of L below 1e-10, or one not positive), when no mode is resolved, for
    servo-constraints and without ``settings.modal``; a fallback after iterating costs its iterations on top of the
    eigenproblem."""
    n_ic, r, independent = partition.independent.size, correction.resolved, partition.independent
    count = r + GUARD_MODES
    if r == 0 or count >= n_ic or partition.servo or not settings.modal:
        return modal_correction(reduced_mass, h, t, drive, partition, chain, settings)
    cutoff_squared = cutoff_angular_frequency(h, settings.cutoff, settings.resolved_bandwidth) ** 2
    shift = REFRESH_SHIFT * cutoff_squared
    factor = constrained_factor(S, Hw, constraint_rows(B, partition), 1.0 / shift, 0.0,
                                reduced_drive_spring(drive, partition, chain) / shift, chain)
    X = np.ascontiguousarray(correction.modes[:, :count])
    on_X = reduced_mass @ X
    for _ in range(REFRESH_ITERATIONS):
        Y = reduced_solve(factor, independent, on_X)
        on_Y = reduced_mass @ Y
        springs = stiffness_product(Y, drive, partition, chain)
        spanned, omega_squared, X, on_X, springs = _ritz_modes(Y, on_Y, springs, 1e-10)
        if not spanned:
            break
        if omega_squared[r - 1] >= cutoff_squared or omega_squared[r] < cutoff_squared:
            break
        largest = 0.0
        for m in range(r + 1):
            residual, norm_squared = 0.0, 0.0
            for i in range(n_ic):
                residual += (springs[i, m] - omega_squared[m] * on_X[i, m]) ** 2
                norm_squared += on_X[i, m] ** 2
            largest = max(largest, np.sqrt(residual / norm_squared) / (omega_squared[m] + shift))
        if largest <= REFRESH_TOLERANCE:
            modes = np.zeros((n_ic, n_ic))
            modes[:, :count] = X
            c, e = _resolved_terms(omega_squared[:r], _modal_damping(X, r, partition, chain), h)
            return _terms_of_resolved_modes(np.ascontiguousarray(on_X[:, :r]), omega_squared[:r], c, e,
                                            unresolved_beta(h, settings), reduced_stiffness(drive, partition, chain),
                                            modes, t, h, t)
    return modal_correction(reduced_mass, h, t, drive, partition, chain, settings)


@njit(cache=True, nogil=True)
def cutoff_angular_frequency(h, cutoff, resolved_bandwidth):
    """omega_c = min(``cutoff`` / h, ``resolved_bandwidth``) [rad/s]: the step h resolves the modes below it (see
    :mod:`crane_reference.motion.integration`)."""
    return min(cutoff / h, resolved_bandwidth)


@njit(cache=True, nogil=True)
def unresolved_beta(h, settings: StepSettings):
    """beta = 2 zeta / omega_c [s] (omega_c :func:`cutoff_angular_frequency`, zeta =
    ``settings.unresolved_damping``): an unresolved mode's damping e = beta omega^2 (:func:`modal_correction`)."""
    return 2.0 * settings.unresolved_damping / cutoff_angular_frequency(h, settings.cutoff, settings.resolved_bandwidth)


@njit(cache=True, nogil=True)
def _terms_of_resolved_modes(on_resolved, omega_squared, c, e, beta, stiffness, modes, time, h, tracked):
    """:class:`ModalCorrection` from the resolved modes alone (U = M_r Phi_r, their omega^2, c and e) and the
    unresolved modes' rate beta: Delta M_r = U diag(c) U^T, and D_u = U diag(e - beta omega^2) U^T + beta K_r, since
    the unresolved modes' part sum_u beta omega_u^2 M_r phi_u phi_u^T M_r is beta K_r less the resolved modes' part
    (K_r = M_r Phi diag(omega^2) Phi^T M_r over all modes; ``stiffness`` K_r).  U, c and e - beta omega^2 are kept,
    padded to n_ic, for the residual's products and the iteration matrix."""
    n, r = stiffness.shape[0], c.size
    damping_weights = e - beta * np.maximum(omega_squared, 0.0)
    padded, inertia_weights, padded_damping = np.zeros((n, n)), np.zeros(n), np.zeros(n)
    padded[:, :r], inertia_weights[:r], padded_damping[:r] = on_resolved, c, damping_weights
    return ModalCorrection(_congruence(on_resolved, c), _congruence(on_resolved, damping_weights) + beta * stiffness,
                           modes, r, time, h, tracked, padded, inertia_weights, padded_damping, beta)


@njit(cache=True, nogil=True)
def stiffness_product(V, drive, partition: Partition, chain: ChainData):
    """K_r V (:func:`reduced_stiffness`) for the columns of V (n_ic x m), in O(n) a column: K is diagonal beyond
    the chain's root block; each row of K is read once for all columns."""
    independent, stiffness, root_size = partition.independent, chain.stiffness, chain.root_size
    n_ic, columns = independent.size, V.shape[1]
    out = np.empty((n_ic, columns))
    for i in range(n_ic):
        row = independent[i]
        diagonal = stiffness[row, row]
        for m in range(columns):
            out[i, m] = diagonal * V[i, m]
        if row < root_size:
            for j in range(n_ic):
                if j != i and independent[j] < root_size:
                    coupling = stiffness[row, independent[j]]
                    for m in range(columns):
                        out[i, m] += coupling * V[j, m]
        if row == chain.drive_joint:
            for m in range(columns):
                out[i, m] += drive[1] * V[i, m]
    return out


@njit(cache=True, nogil=True)
def tracked_correction(reduced_mass, correction: ModalCorrection, t, drive, partition: Partition, chain: ChainData,
                       settings: StepSettings):
    """``correction`` carried to the configuration of ``reduced_mass`` by tracking its resolved modes Phi_r: one
    shift-inverted subspace iteration from them, X = (K_r + s M_r)^-1 M_r Phi_r (s = :data:`SHIFT`), and the
    Rayleigh-Ritz step on X (the modes of the pencil (X^T K_r X, X^T M_r X), by Jacobi rotations: it is nearly
    diagonal) give the new Phi_r; Delta M_r and D_u follow from them as in :func:`modal_correction`: the
    unresolved modes' damping is beta K_r less the tracked modes' part, so that it damps no resolved mode (a stale
    D_u otherwise damps a resolved mode psi by sum_u e_u (phi_u^T M_r psi)^2); on Ritz vectors that are not yet
    the pencil's modes it is indefinite by the order of their residual, beta (K_r Phi_r - M_r Phi_r diag(omega^2)).  The
    modes stay resolved, and their number stays, until the next full eigenproblem (``time`` is its; ``tracked`` becomes
    t).  When the tracked modes' span degenerates (a squared pivot of the Cholesky factor of their Gram matrix, the
    columns of M_r-norm 1, below 1e-10, or one not positive) the full eigenproblem is solved instead, as
    :func:`refreshed_correction` does (:func:`modal_correction` at t)."""
    r = correction.resolved
    if r == 0:
        return correction
    h = correction.step
    stiffness = reduced_stiffness(drive, partition, chain)
    driving = reduced_mass @ np.ascontiguousarray(correction.modes[:, :r])
    X = cholesky_solve_columns(cholesky(stiffness + SHIFT * reduced_mass), driving)
    MX = reduced_mass @ X
    springs = driving - SHIFT * MX  # K_r X = M_r Phi_r - s M_r X
    spanned, omega_squared, phi_r, on_resolved, _ = _ritz_modes(X, MX, springs, 1e-10)
    if not spanned:
        return modal_correction(reduced_mass, h, t, drive, partition, chain, settings)
    modes = correction.modes.copy()
    modes[:, :r] = phi_r
    c, e = _resolved_terms(omega_squared, _modal_damping(phi_r, r, partition, chain), h)
    return _terms_of_resolved_modes(on_resolved, omega_squared, c, e, correction.unresolved_beta, stiffness, modes,
                                    correction.time, h, t)


@njit(cache=True, nogil=True)
def _ritz_modes(Y, on_Y, springs, smallest_squared_pivot):
    """The Rayleigh-Ritz step on the span of Y's columns (on_Y = M_r Y and springs = K_r Y; the three scaled in place
    so that Y's columns have M_r-norm 1): Y^T M_r Y = L L^T and the modes of L^-1 Y^T K_r Y L^-T by Jacobi rotations
    (nearly diagonal when Y is near the modes).  (True, omega^2 ascending, Phi = Y L^-T W, M_r Phi, K_r Phi), or False
    first when L has a squared pivot not above ``smallest_squared_pivot`` (the span degenerates; 0: not
    positive)."""
    n = Y.shape[0]
    for m in range(Y.shape[1]):
        norm_squared = 0.0
        for i in range(n):
            norm_squared += Y[i, m] * on_Y[i, m]
        scale = 1.0 / np.sqrt(norm_squared)
        for i in range(n):
            Y[i, m] *= scale
            on_Y[i, m] *= scale
            springs[i, m] *= scale
    L, positive = cholesky_or_stop(_symmetric(Y.T @ on_Y))
    if not positive or not np.min(np.diag(L)) ** 2 > smallest_squared_pivot:
        return False, np.empty(0), Y, on_Y, springs
    inverse = lower_inverse(L)
    omega_squared, W = jacobi_eigh(_symmetric(inverse @ (Y.T @ springs) @ inverse.T))
    rotation = inverse.T @ W
    return True, omega_squared, Y @ rotation, on_Y @ rotation, springs @ rotation


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
    reduced_mass = reduced_mass_matrix(M, B, partition)
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
    inertia, modal_damping = correction.inertia, correction.damping
    stiffness, damping, damped = chain.stiffness, chain.damping, chain.damped
    spring, drive_row = 0.25 * h * h * drive[1], B[chain.drive_joint]
    for i in range(independent.size):
        row = independent[i]
        left = drive_row[i] if not servo else (1.0 if row == chain.drive_joint else 0.0)
        for j in range(independent.size):
            reduced[i, j] += joint_term(0.25 * h * h, 0.5 * h, stiffness, damping, damped, row, independent[j]) \
                + (0.5 * h) * modal_damping[i, j] - inertia[i, j] + spring * left * drive_row[j]
    return cholesky(reduced) if not servo else np.linalg.inv(reduced)

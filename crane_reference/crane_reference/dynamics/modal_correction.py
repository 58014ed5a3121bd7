"""Compiled modal correction of the integrator's step (see :mod:`crane_reference.motion.integration`): the reduced
mass, the corrections per mode, and the accelerations and Newton iteration factor under them."""

from __future__ import annotations

import numpy as np
from numba import njit

from .linalg import cholesky, cholesky_solve, congruent, map_columns, matvec, project_rows
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

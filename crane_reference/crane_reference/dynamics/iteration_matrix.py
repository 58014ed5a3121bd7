"""The Newton iteration matrix of a step (see :mod:`crane_reference.motion.integration`), factored and solved
(compiled with numba): densely, or, O(n) in the chain, by the articulated-body recursion and Woodbury's identity.

The iteration matrix is J = B^T (M + h^2/4 K + h/2 D) B - Delta M_r + h/2 D_u (K with the drive's spring s_dr on
psi2; :func:`~crane_reference.dynamics.modal_correction.iteration_factor` forms and factors it).  With the resolved
modes' U = M_r Phi_r and the unresolved modes' damping beta omega^2 (:class:`ModalCorrection`), -Delta M_r +
h/2 D_u = U diag(W) U^T + h/2 beta K_r with W = -c + h/2 (e - beta omega^2), so J = Y + U diag(W) U^T with
Y = B^T X' B, X' = M + (h^2/4 + beta h/2) K + h/2 D + (h^2/4 + beta h/2) s_dr on psi2 (h^2/4 s_dr where psi2 is
dependent: K_r, and so beta K_r, holds the drive's spring only on an independent psi2): Y is solved by
:mod:`~crane_reference.dynamics.articulated` (the task constraints as rows A with A B = 0), and
J^-1 = Y^-1 - Y^-1 U (I + diag(W) U^T Y^-1 U)^-1 diag(W) U^T Y^-1 (U's r columns solved once to factor; diag(W) is
not inverted, so a weight may be zero).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .articulated import constrained_factor, constraint_rows, reduced_solve
from .factors import ArticulatedFactor, ConstrainedFactor, IterationFactor
from .linalg import cholesky_solve, matvec
from .modal_correction import iteration_factor, reduced_drive_spring
from .structures import ChainData, ModalCorrection, Partition


@njit(cache=True, nogil=True)
def dense_iteration_factor(M, B, h, correction: ModalCorrection, drive, partition: Partition, chain: ChainData):
    """J formed and factored by :func:`~crane_reference.dynamics.modal_correction.iteration_factor`."""
    none, empty, no_joints = np.empty((0, 0)), np.empty(0), np.empty((0, 6))
    articulated = ArticulatedFactor(no_joints, no_joints, empty, none)
    return IterationFactor(np.ascontiguousarray(iteration_factor(M, B, h, correction, drive, partition, chain)),
                           ConstrainedFactor(articulated, none, none, none), none, none, none, empty)


@njit(cache=True, nogil=True)
def articulated_iteration_factor(S, Hw, B, h, correction: ModalCorrection, drive, partition: Partition,
                                 chain: ChainData):
    """J = Y + U diag(W) U^T at the twists S, world pseudo-inertias Hw and velocity map B, W = -c + h/2 (e - beta
    omega^2) of the correction's resolved modes: Y's articulated factor, Y^-1 U and the capacitance
    (I + diag(W) U^T Y^-1 U)^-1 (ideal constraints only: P = B)."""
    r, independent = correction.resolved, partition.independent
    beta = correction.unresolved_beta
    spring_weight = 0.25 * h * h + 0.5 * h * beta
    drive_spring = 0.25 * h * h * drive[1] + 0.5 * h * beta * reduced_drive_spring(drive, partition, chain)  # beta K_r
    constrained = constrained_factor(S, Hw, constraint_rows(B, partition), spring_weight, 0.5 * h, drive_spring,
                                     chain)
    on_resolved = np.ascontiguousarray(correction.on_resolved[:, :r])
    weights = -correction.inertia_weights[:r] + (0.5 * h) * correction.damping_weights[:r]
    solved = reduced_solve(constrained, independent, on_resolved) if r > 0 else np.empty((independent.size, 0))
    capacitance = on_resolved.T @ solved if r > 0 else np.empty((0, 0))
    for i in range(r):
        for j in range(r):
            capacitance[i, j] *= weights[i]
        capacitance[i, i] += 1.0
    inverse = np.ascontiguousarray(np.linalg.inv(capacitance)) if r > 0 else capacitance
    return IterationFactor(np.empty((0, 0)), constrained, on_resolved, solved, inverse, weights)


@njit(cache=True, nogil=True)
def iteration_solve(factor: IterationFactor, residual, partition: Partition):
    """J^-1 residual: by the dense factor (Cholesky; the inverse for servo-constraints), or by Woodbury's identity
    on the articulated one."""
    if factor.dense.shape[0] > 0:
        return cholesky_solve(factor.dense, residual) if not partition.servo else matvec(factor.dense, residual)
    column = np.empty((residual.size, 1))
    column[:, 0] = residual
    y = reduced_solve(factor.constrained, partition.independent, column)[:, 0]
    r = factor.weights.size
    if r > 0:
        projected = matvec(factor.on_resolved.T, y) * factor.weights
        y -= matvec(factor.solved, matvec(factor.capacitance, projected))
    return y

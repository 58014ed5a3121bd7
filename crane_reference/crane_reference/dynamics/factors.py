"""The factors of a step's Newton iteration matrix that the compiled kernels pass on (numba-compatible named tuples):
the articulated-body factor of X (:mod:`~crane_reference.dynamics.articulated`), with the task constraints' Schur
complement, and the iteration matrix's factor, dense or articulated with Woodbury's columns
(:mod:`~crane_reference.dynamics.iteration_matrix`)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class ArticulatedFactor(NamedTuple):
    """X = M + J factored by :func:`~crane_reference.dynamics.articulated.articulated_factor`: the joints' twists
    ``s`` (n, 6), ``U`` = I^A s and ``D`` = s^T I^A s + J_kk of the joints beyond the root block (n, 6 and n; the
    root's rows unused), and ``root`` the Cholesky factor of the root block with the articulated inertia of the
    joints beyond it."""

    s: np.ndarray
    U: np.ndarray
    D: np.ndarray
    root: np.ndarray


class ConstrainedFactor(NamedTuple):
    """B^T X B factored by :func:`~crane_reference.dynamics.articulated.constrained_factor`: the ``articulated``
    factor of X, the constraint Jacobian ``A`` (m, n), ``Z`` = X^-1 A^T and ``schur`` the Cholesky factor of A Z."""

    articulated: ArticulatedFactor
    A: np.ndarray
    Z: np.ndarray
    schur: np.ndarray


class IterationFactor(NamedTuple):
    """The Newton iteration matrix of a step, factored (:mod:`~crane_reference.dynamics.iteration_matrix`):
    densely, ``dense`` its Cholesky factor (ideal constraints) or its inverse (servo-constraints), the other fields
    empty; or by the articulated-body recursion, ``dense`` empty (0 x 0), ``constrained`` the factor of
    Y = B^T X' B, ``on_resolved`` U (n_ic, r), ``solved`` Y^-1 U, ``capacitance`` (I + diag(W) U^T Y^-1 U)^-1 and
    ``weights`` W (r,), so that (Y + U diag(W) U^T)^-1 = Y^-1 - Y^-1 U capacitance diag(W) U^T Y^-1 (Woodbury)."""

    dense: np.ndarray
    constrained: ConstrainedFactor
    on_resolved: np.ndarray
    solved: np.ndarray
    capacitance: np.ndarray
    weights: np.ndarray

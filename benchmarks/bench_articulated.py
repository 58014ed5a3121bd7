"""Prototype of the O(n) solve an O(n) step needs, against the dense factor the step uses today.

    python benchmarks/bench_articulated.py [--rfe 6 12 24 48] [--states 5]

The Newton iteration matrix of a step is B^T X B (plus the modal terms) with X = M + h^2/4 K + h/2 D and the column
drive's spring s_dr on psi2 (:func:`~crane_reference.dynamics.modal_correction.iteration_factor`); today it is
formed (M, then B^T X B) and factored by Cholesky, O(n^3).  Here X is solved by the articulated-body recursion
(Featherstone's ABA in the world frame, without velocity terms) with the diagonal of h^2/4 K + h/2 D as the joints'
armature; the joints whose springs are coupled (the base on its support springs: K's off-diagonal entries) form a
root block, solved densely once the joints beyond it are eliminated.  The task constraints A qdd = c enter by a
Schur complement: B spans the null space of A with B[ic] = I, so B^T X B a = r is the KKT system
[X A^T; A 0] [y; lambda] = [E_ic r; 0] with a = y[ic]: y = X^-1 (E_ic r - A^T lambda),
(A X^-1 A^T) lambda = A X^-1 E_ic r (m + 1 articulated solves, m the dependent coordinates).

Per crane of ``--rfe`` (the flexible model, n_rfe elements per flexible link) it prints the largest difference of
the reduced solution from numpy's dense solve of B^T X B at ``--states`` random states (relative to the solution's
largest entry: the check), and, in ABA of its own chain (Pinocchio, this run), the cost of: the articulated
factorization with the constraints' Schur complement; one solve of the reduced system; today's M and iteration
factor; a Cholesky solve with it; and the factorization with r more solves, what a modal correction of rank r
(the resolved modes, Woodbury) adds.
"""

from __future__ import annotations

import argparse
from typing import NamedTuple

import numpy as np
from common import aba_time, call_seconds
from numba import njit

from crane_reference.dynamics.evaluation import accelerations_at
from crane_reference.dynamics.inertia import world_pseudo_inertias
from crane_reference.dynamics.kinematics import forward_kinematics
from crane_reference.dynamics.linalg import cholesky, cholesky_solve, matvec
from crane_reference.dynamics.modal_correction import iteration_factor, modal_correction, reduced_mass_matrix
from crane_reference.dynamics.step import mass_at
from crane_reference.model.config import load_config
from crane_reference.motion.integration import ExactFrequencyTrapezoidal
from crane_reference.motion.simulation import Scenario
from crane_reference.motion.steps import ONLINE_STEP


class ArticulatedFactor(NamedTuple):
    """X = M + armature + root block, factored: the joints' twists s (n, 6), U = I^A s and D = s^T I^A s + armature
    of the joints beyond the root block, and the Cholesky factor of the root block with the articulated inertia of
    the joints beyond it."""

    s: np.ndarray
    U: np.ndarray
    D: np.ndarray
    root: np.ndarray


@njit(cache=True)
def spatial_inertias(Hw, body_joint, n):
    """Per joint, the spatial inertia (6 x 6, world frame about its origin, rows (omega, v)) of the bodies fixed
    after it: s_i^T I s_j = tr(S_i J S_j^T) for the bodies' world pseudo-inertia J = [Sigma, m c; m c^T, m],
    I = [tr(Sigma) 1 - Sigma, (m c)^; (m c)^T, m 1]."""
    inertia = np.zeros((n, 6, 6))
    for body in range(body_joint.size):
        k, J = body_joint[body], Hw[body]
        trace = J[0, 0] + J[1, 1] + J[2, 2]
        for a in range(3):
            for b in range(3):
                inertia[k, a, b] += (trace if a == b else 0.0) - J[a, b]
            inertia[k, 3 + a, 3 + a] += J[3, 3]
        for a, b, c in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):  # (m c)^[a, b] = -m c_c, (m c)^[b, a] = m c_c
            inertia[k, a, 3 + b] -= J[c, 3]
            inertia[k, 3 + b, a] -= J[c, 3]
            inertia[k, b, 3 + a] += J[c, 3]
            inertia[k, 3 + a, b] += J[c, 3]
    return inertia


@njit(cache=True)
def articulated_factor(S, Hw, body_joint, joint_matrix, root_size):
    """The factor of X = M + ``joint_matrix`` (h^2/4 K + h/2 D with the drive's spring: diagonal beyond the first
    ``root_size`` joints) at the twists S and world pseudo-inertias Hw: the backward pass of the articulated-body
    recursion, I^A_k = I_k + I^a_(k+1), U_k = I^A_k s_k, D_k = s_k^T U_k + X_kk - M_kk,
    I^a_k = I^A_k - U_k U_k^T / D_k, down to the root block, whose X' = s_i^T (I^a_b + sum_(l=k..b-1) I_l) s_j
    + joint_matrix[i, j] (k = max(i, j)) is factored by Cholesky.  Loops over the six components: no array is
    made per joint."""
    n = S.shape[0]
    inertia = spatial_inertias(Hw, body_joint, n)
    s = np.empty((n, 6))
    for k in range(n):
        s[k, 0], s[k, 1], s[k, 2] = S[k, 2, 1], S[k, 0, 2], S[k, 1, 0]
        s[k, 3], s[k, 4], s[k, 5] = S[k, 0, 3], S[k, 1, 3], S[k, 2, 3]
    U = np.zeros((n, 6))
    D = np.zeros(n)
    articulated = np.zeros((6, 6))
    for k in range(n - 1, root_size - 1, -1):
        d = joint_matrix[k, k]
        for a in range(6):
            total = 0.0
            for c in range(6):
                articulated[a, c] += inertia[k, a, c]
                total += articulated[a, c] * s[k, c]
            U[k, a] = total
            d += s[k, a] * total
        D[k] = d
        for a in range(6):
            scaled = U[k, a] / d
            for c in range(6):
                articulated[a, c] -= scaled * U[k, c]
    root = joint_matrix[:root_size, :root_size].copy()
    projected = np.empty(6)
    for k in range(root_size - 1, -1, -1):
        for a in range(6):
            total = 0.0
            for c in range(6):
                articulated[a, c] += inertia[k, a, c]
                total += articulated[a, c] * s[k, c]
            projected[a] = total
        for i in range(k + 1):
            value = 0.0
            for a in range(6):
                value += s[i, a] * projected[a]
            root[i, k] += value
            if i != k:
                root[k, i] += value
    return ArticulatedFactor(s, U, D, cholesky(root))


@njit(cache=True)
def articulated_solve(factor: ArticulatedFactor, tau):
    """x = X^-1 tau: the bias of the joints beyond the root block gathered inward (u_k = tau_k - s_k^T p,
    p += U_k u_k / D_k), the root block solved, then outward x_k = (u_k - U_k^T alpha) / D_k, alpha += s_k x_k
    (alpha the spatial acceleration of the body before joint k)."""
    s, U, D, root = factor
    n, b = tau.size, root.shape[0]
    u = np.empty(n)
    p = np.zeros(6)
    for k in range(n - 1, b - 1, -1):
        total = tau[k]
        for a in range(6):
            total -= s[k, a] * p[a]
        u[k] = total
        scaled = total / D[k]
        for a in range(6):
            p[a] += U[k, a] * scaled
    rhs = np.empty(b)
    for i in range(b):
        total = tau[i]
        for a in range(6):
            total -= s[i, a] * p[a]
        rhs[i] = total
    x = np.empty(n)
    x[:b] = cholesky_solve(root, rhs)
    alpha = np.zeros(6)
    for i in range(b):
        for a in range(6):
            alpha[a] += s[i, a] * x[i]
    for k in range(b, n):
        total = u[k]
        for a in range(6):
            total -= U[k, a] * alpha[a]
        x[k] = total / D[k]
        for a in range(6):
            alpha[a] += s[k, a] * x[k]
    return x


class ConstrainedFactor(NamedTuple):
    """The Schur complement of the task constraints: Z = X^-1 A^T and the Cholesky factor of A Z."""

    articulated: ArticulatedFactor
    A: np.ndarray
    Z: np.ndarray
    schur: np.ndarray


@njit(cache=True)
def constrained_factor(S, Hw, body_joint, joint_matrix, root_size, A):
    """:func:`articulated_factor` with the constraints' Schur complement (m more solves)."""
    factor = articulated_factor(S, Hw, body_joint, joint_matrix, root_size)
    Z = np.empty((A.shape[1], A.shape[0]))
    for row in range(A.shape[0]):
        Z[:, row] = articulated_solve(factor, A[row].copy())
    return ConstrainedFactor(factor, A, Z, cholesky(A @ Z))


@njit(cache=True)
def reduced_solve(factor: ConstrainedFactor, independent, r):
    """a with B^T X B a = r: y = X^-1 (E_ic r - A^T lambda), (A X^-1 A^T) lambda = A X^-1 E_ic r, a = y[ic]."""
    load = np.zeros(factor.A.shape[1])
    for i in range(independent.size):
        load[independent[i]] = r[i]
    y = articulated_solve(factor.articulated, load)
    y -= matvec(factor.Z, cholesky_solve(factor.schur, matvec(factor.A, y)))
    return y[independent]


def joint_matrix(chain, drive, h):
    """h^2/4 K + h/2 D with the drive's spring s_dr on psi2 (X - M of the iteration matrix, full coordinates), and
    the size of its root block (the joints up to the last with an off-diagonal entry)."""
    matrix = 0.25 * h * h * chain.stiffness + 0.5 * h * chain.damping
    matrix[chain.drive_joint, chain.drive_joint] += 0.25 * h * h * drive[1]
    coupled = np.flatnonzero(np.any(matrix - np.diag(np.diag(matrix)) != 0.0, axis=1))
    return matrix, int(coupled.max()) + 1 if coupled.size else 0


class Case(NamedTuple):
    """A state of a crane and what the solves need there."""

    S: np.ndarray
    Hw: np.ndarray
    A: np.ndarray
    B: np.ndarray
    M: np.ndarray


def random_case(scenario: Scenario, rng: np.random.Generator) -> Case:
    """A random state near the static equilibrium (every coordinate moved by up to 0.05 rad or m; velocities up to
    0.5 rad/s or m/s): the frames, A, B and M there."""
    motion = scenario.motion
    chain, partition = motion.dynamics.chain, motion.partition
    q = scenario.equilibrium.q + rng.uniform(-0.05, 0.05, scenario.equilibrium.q.size)
    qd = rng.uniform(-0.5, 0.5, q.size)
    acc = accelerations_at(q, qd, motion.constraints.coefficients(0.5), motion.dynamics.drive.kernel_parameters(0.5),
                           partition, chain)
    T, S = forward_kinematics(q, chain.kinds, chain.axes, chain.origins)
    return Case(S, world_pseudo_inertias(T, chain.body_joint, chain.body_H), acc.A, acc.velocity_map, acc.M)


@njit
def _repeat_articulated(S, Hw, body_joint, matrix, root_size, A, n):
    total = 0.0
    for _ in range(n):
        total += constrained_factor(S, Hw, body_joint, matrix, root_size, A).schur[0, 0]
    return total


@njit
def _repeat_reduced_solve(factor, independent, r, n):
    total = 0.0
    for _ in range(n):
        total += reduced_solve(factor, independent, r)[0]
    return total


@njit
def _repeat_dense(S, Hw, B, correction, drive, partition, chain, h, n):
    total = 0.0
    for _ in range(n):
        total += iteration_factor(mass_at(S, Hw, chain), B, h, correction, drive, partition, chain)[0, 0]
    return total


@njit
def _repeat_dense_solve(factor, r, n):
    total = 0.0
    for _ in range(n):
        total += cholesky_solve(factor, r)[0]
    return total


def crane(n_rfe: int, states: int, repeat: int) -> None:
    """The check and the costs for the flexible crane with ``n_rfe`` elements per flexible link."""
    scenario = Scenario(load_config().with_rfe_count(n_rfe), "flexible")
    motion = scenario.motion
    chain, partition = motion.dynamics.chain, motion.partition
    independent = partition.independent
    drive, h = motion.dynamics.drive.kernel_parameters(0.5), ONLINE_STEP
    matrix, root_size = joint_matrix(chain, drive, h)
    rng = np.random.default_rng(n_rfe)
    worst = 0.0
    for _ in range(states):
        case = random_case(scenario, rng)
        r = rng.normal(size=independent.size)
        dense = np.linalg.solve(case.B.T @ (case.M + matrix) @ case.B, r)
        factor = constrained_factor(case.S, case.Hw, chain.body_joint, matrix, root_size, case.A)
        worst = max(worst, np.abs(reduced_solve(factor, independent, r) - dense).max() / np.abs(dense).max())
    aba = aba_time(scenario)
    correction = modal_correction(reduced_mass_matrix(case.M, case.B, partition), h, 0.0, drive, partition, chain,
                                  ExactFrequencyTrapezoidal(motion).settings)
    dense_factor = iteration_factor(case.M, case.B, h, correction, drive, partition, chain)

    def cost(function, *arguments) -> float:
        function(*arguments, 10)
        return min(call_seconds(lambda: function(*arguments, repeat), 1, median=True) for _ in range(5)) / repeat

    factor_cost = cost(_repeat_articulated, case.S, case.Hw, chain.body_joint, matrix, root_size, case.A)
    solve_cost = cost(_repeat_reduced_solve, factor, independent, r)
    dense_cost = cost(_repeat_dense, case.S, case.Hw, case.B, correction, drive, partition, chain, h)
    dense_solve_cost = cost(_repeat_dense_solve, dense_factor, r)
    rank = correction.resolved
    print(f"n_rfe={n_rfe:2d} dof={chain.kinds.size:3d} n_ic={independent.size:3d} root block {root_size}: "
          f"articulated against dense {worst:.1e} (largest, relative, {states} random states); ABA {aba * 1e6:.2f} us; "
          f"in ABA: articulated factor with the constraints {factor_cost / aba:.2f}, a reduced solve "
          f"{solve_cost / aba:.3f}, with Woodbury's {rank} resolved columns "
          f"{(factor_cost + rank * solve_cost) / aba:.2f}; "
          f"today M and the iteration factor {dense_cost / aba:.2f}, a Cholesky solve {dense_solve_cost / aba:.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rfe", nargs="+", type=int, default=[6, 12, 24, 48])
    parser.add_argument("--states", type=int, default=5)
    args = parser.parse_args()
    if args.states < 1:
        parser.error("--states: at least 1 random state")
    for n_rfe in args.rfe:
        crane(n_rfe, args.states, 3000 if n_rfe <= 12 else 500)


if __name__ == "__main__":
    main()

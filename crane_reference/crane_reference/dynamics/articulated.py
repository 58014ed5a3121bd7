"""The articulated-body solve of X = M + w K + d D + s e_psi2 e_psi2^T (compiled with numba): O(n) for a serial chain
whose springs and dampers couple only the first joints (the base on its support springs), without forming M.

The Newton iteration matrix of a step is B^T X B plus the modal terms, with w = h^2/4 + beta h/2, d = h/2 and s the
drive's spring s_dr so weighted (:mod:`~crane_reference.dynamics.iteration_matrix`).  X is M with a joint-space term
diagonal beyond the root block of the first ``chain.root_size`` joints.  Featherstone's
articulated-body recursion (ABA without velocity terms), here in the world frame, solves M x = tau; the diagonal
of J enters it as the joints' armature, and the root block, once the joints beyond it are eliminated, is solved
densely.  With the composite world pseudo-inertia of a body, J = T H T^T = [Sigma, m c; m c^T, m], and the joint's
twist s = (omega, v) (the 4 x 4 S_k of :mod:`crane_reference.dynamics.kinematics`), tr(S_i J S_j^T) = s_i^T I s_j
with the spatial inertia I = [tr(Sigma) 1 - Sigma, (m c)^; (m c)^T, m 1] (rows (omega, v), about the world origin),
so the entries m_ij = tr(S_i Hc_max(i,j) S_j^T) of :mod:`crane_reference.dynamics.inertia` are s_i^T I^c s_j.

The task constraints A qdd = c (A the m x n constraint Jacobian of (7), B spanning its null space with B[ic] = I)
enter by a Schur complement: B^T X B a = r is the KKT system [X A^T; A 0] [y; lambda] = [E_ic r; 0] with a = y[ic],
so y = X^-1 (E_ic r - A^T lambda), (A X^-1 A^T) lambda = A X^-1 E_ic r: the factor solves the m columns of A^T
once, and each solve is one articulated solve.  A solve takes the columns of a matrix, each joint's arrays read once
for all of them.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .factors import ArticulatedFactor, ConstrainedFactor
from .linalg import cholesky, cholesky_solve_columns
from .structures import ChainData, Partition


@njit(cache=True, nogil=True, inline='always')
def joint_term(spring_weight, damper_weight, stiffness, damping, damped, row, column):
    """The entry (row, column) of spring_weight K + damper_weight D (without the drive's spring; ``damped``: D has a
    non-zero entry).  The caller passes the chain's arrays, not the chain: numba counts a reference at every
    extraction of an array from a tuple."""
    value = spring_weight * stiffness[row, column]
    if damped:
        value += damper_weight * damping[row, column]
    return value


@njit(cache=True, nogil=True)
def spatial_inertias(Hw, body_joint, n):
    """Per joint, the spatial inertia (6 x 6, world frame about its origin, rows (omega, v)) of the bodies that
    move with it (not those beyond later joints): I = [tr(Sigma) 1 - Sigma, (m c)^; (m c)^T, m 1] of their world
    pseudo-inertia J = [Sigma, m c; m c^T, m]."""
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


@njit(cache=True, nogil=True)
def articulated_factor(S, Hw, spring_weight, damper_weight, drive_spring, chain: ChainData):
    """The factor of X = M + spring_weight K + damper_weight D + ``drive_spring`` on psi2 at the twists S and world
    pseudo-inertias Hw: the backward pass of the
    articulated-body recursion from the last joint to the root block, I^A_k = I_k + I^a_(k+1), U_k = I^A_k s_k,
    D_k = s_k^T U_k + X_kk - M_kk, I^a_k = I^A_k - U_k U_k^T / D_k; then the root block
    X'_ij = s_i^T (I^a_b + sum_(l = k..b-1) I_l) s_j + X_ij - M_ij (k = max(i, j), b = the root's size),
    factored by Cholesky."""
    n, root_size = S.shape[0], chain.root_size
    inertia = spatial_inertias(Hw, chain.body_joint, n)
    s = np.empty((n, 6))
    for k in range(n):
        s[k, 0], s[k, 1], s[k, 2] = S[k, 2, 1], S[k, 0, 2], S[k, 1, 0]
        s[k, 3], s[k, 4], s[k, 5] = S[k, 0, 3], S[k, 1, 3], S[k, 2, 3]
    stiffness, damping, damped = chain.stiffness, chain.damping, chain.damped
    U = np.zeros((n, 6))
    D = np.zeros(n)
    articulated = np.zeros((6, 6))
    for k in range(n - 1, root_size - 1, -1):
        d = joint_term(spring_weight, damper_weight, stiffness, damping, damped, k, k) \
            + (drive_spring if k == chain.drive_joint else 0.0)
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
    root = np.empty((root_size, root_size))
    for i in range(root_size):
        for j in range(root_size):
            root[i, j] = joint_term(spring_weight, damper_weight, stiffness, damping, damped, i, j)
    if chain.drive_joint < root_size:
        root[chain.drive_joint, chain.drive_joint] += drive_spring
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


@njit(cache=True, nogil=True)
def articulated_solve(factor: ArticulatedFactor, tau):
    """X^-1 tau for the columns of tau (n, columns): the bias of the joints beyond the root block gathered inward
    (u_k = tau_k - s_k^T p, p += U_k u_k / D_k), the root block solved, then outward x_k = (u_k - U_k^T alpha) / D_k,
    alpha += s_k x_k (alpha the spatial acceleration of the body before joint k); each joint's arrays read once for
    all the columns."""
    s, U, D, root = factor
    n, b, columns = tau.shape[0], root.shape[0], tau.shape[1]
    u = np.empty((n, columns))
    p = np.zeros((columns, 6))
    for j in range(n - 1, b - 1, -1):
        for m in range(columns):
            total = tau[j, m]
            for a in range(6):
                total -= s[j, a] * p[m, a]
            u[j, m] = total
            scaled = total / D[j]
            for a in range(6):
                p[m, a] += U[j, a] * scaled
    rhs = np.empty((b, columns))
    for i in range(b):
        for m in range(columns):
            total = tau[i, m]
            for a in range(6):
                total -= s[i, a] * p[m, a]
            rhs[i, m] = total
    x = np.empty((n, columns))
    root_solution = cholesky_solve_columns(root, rhs)
    alpha = np.zeros((columns, 6))
    for i in range(b):
        for m in range(columns):
            x[i, m] = root_solution[i, m]
            for a in range(6):
                alpha[m, a] += s[i, a] * x[i, m]
    for j in range(b, n):
        for m in range(columns):
            total = u[j, m]
            for a in range(6):
                total -= U[j, a] * alpha[m, a]
            x[j, m] = total / D[j]
            for a in range(6):
                alpha[m, a] += s[j, a] * x[j, m]
    return x


@njit(cache=True, nogil=True)
def constraint_rows(B, partition: Partition):
    """Rows A (m, n) whose null space B spans (B[ic] = I): A[:, ic] = -B[dc], A[:, dc] = I (the acceleration
    constraints of (7) solved for q_dc)."""
    independent, dependent = partition.independent, partition.dependent
    rows = np.zeros((dependent.size, B.shape[0]))
    for i in range(dependent.size):
        for j in range(independent.size):
            rows[i, independent[j]] = -B[dependent[i], j]
        rows[i, dependent[i]] = 1.0
    return rows


@njit(cache=True, nogil=True)
def constrained_factor(S, Hw, A, spring_weight, damper_weight, drive_spring, chain: ChainData):
    """:func:`articulated_factor` with the task constraints' Schur complement: Z = X^-1 A^T (m solves) and the
    Cholesky factor of A Z."""
    factor = articulated_factor(S, Hw, spring_weight, damper_weight, drive_spring, chain)
    Z = articulated_solve(factor, np.ascontiguousarray(A.T))
    return ConstrainedFactor(factor, A, Z, cholesky(A @ Z))


@njit(cache=True, nogil=True)
def reduced_solve(factor: ConstrainedFactor, independent, R):
    """a with B^T X B a = r for the columns r of R (n_ic, k): y = X^-1 (E_ic r - A^T lambda), (A X^-1 A^T) lambda =
    A X^-1 E_ic r, a = y[ic]."""
    load = np.zeros((factor.A.shape[1], R.shape[1]))
    for i in range(independent.size):
        for m in range(R.shape[1]):
            load[independent[i], m] = R[i, m]
    Y = articulated_solve(factor.articulated, load)
    A, Z, k = factor.A, factor.Z, R.shape[1]
    on_rows = np.zeros((A.shape[0], k))  # A Y by loops: A has 2-3 rows, where a BLAS call costs more than the sum
    for i in range(A.shape[0]):
        for j in range(A.shape[1]):
            weight = A[i, j]
            for m in range(k):
                on_rows[i, m] += weight * Y[j, m]
    multipliers = cholesky_solve_columns(factor.schur, on_rows)
    for j in range(A.shape[1]):
        for i in range(A.shape[0]):
            weight = Z[j, i]
            for m in range(k):
                Y[j, m] -= weight * multipliers[i, m]
    out = np.empty((independent.size, k))
    for i in range(independent.size):
        for m in range(k):
            out[i, m] = Y[independent[i], m]
    return out

"""Small dense linear algebra for the kernels, without LAPACK/BLAS call overhead where the matrices are
small (K_dc is 2 x 2 or 3 x 3, C is 3 x n, the chain has tens of coordinates), and the products with the
velocity map B of eq. (7) without forming it."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def matvec(A, x):
    """A x for a 2-D A (loops: no BLAS call)."""
    out = np.empty(A.shape[0])
    for i in range(A.shape[0]):
        total = 0.0
        for j in range(A.shape[1]):
            total += A[i, j] * x[j]
        out[i] = total
    return out


@njit(cache=True, nogil=True)
def matmul(A, B, columns=None):
    """A B (or A B[:, columns]) for small 2-D arrays (loops: no BLAS call, no copy of the columns)."""
    count = B.shape[1] if columns is None else columns.size
    out = np.empty((A.shape[0], count))
    for j in range(count):
        column = j if columns is None else columns[j]
        for i in range(A.shape[0]):
            total = 0.0
            for k in range(A.shape[1]):
                total += A[i, k] * B[k, column]
            out[i, j] = total
    return out


@njit(cache=True, nogil=True)
def cholesky(A):
    """Lower-triangular L with L L^T = A for a symmetric positive definite A (raises otherwise)."""
    L, positive = cholesky_or_stop(A)
    if not positive:
        raise np.linalg.LinAlgError("matrix is not positive definite")
    return L


@njit(cache=True, nogil=True)
def cholesky_or_stop(A):
    """(L, True) with L L^T = A for a symmetric positive definite A; (L so far, False) at the first pivot that is
    not positive."""
    n = A.shape[0]
    L = np.zeros((n, n))
    for j in range(n):
        total = A[j, j]
        for k in range(j):
            total -= L[j, k] * L[j, k]
        if not total > 0.0:
            return L, False
        L[j, j] = np.sqrt(total)
        for i in range(j + 1, n):
            total = A[i, j]
            for k in range(j):
                total -= L[i, k] * L[j, k]
            L[i, j] = total / L[j, j]
    return L, True


@njit(cache=True, nogil=True)
def solve_small_in_place(a, x):
    """x <- a^-1 x for a small square a (Gaussian elimination with partial pivoting; K_dc is 2 x 2 or
    3 x 3 here, where a LAPACK call costs more than the arithmetic), x of shape (m, k); a is overwritten."""
    m = a.shape[0]
    for col in range(m):
        pivot = col
        for row in range(col + 1, m):
            if abs(a[row, col]) > abs(a[pivot, col]):
                pivot = row
        if a[pivot, col] == 0.0:
            raise np.linalg.LinAlgError("singular matrix")
        if pivot != col:
            for k in range(m):
                a[col, k], a[pivot, k] = a[pivot, k], a[col, k]
            for k in range(x.shape[1]):
                x[col, k], x[pivot, k] = x[pivot, k], x[col, k]
        for row in range(col + 1, m):
            factor = a[row, col] / a[col, col]
            for k in range(col, m):
                a[row, k] -= factor * a[col, k]
            for k in range(x.shape[1]):
                x[row, k] -= factor * x[col, k]
    for col in range(m - 1, -1, -1):
        for k in range(x.shape[1]):
            total = x[col, k]
            for j in range(col + 1, m):
                total -= a[col, j] * x[j, k]
            x[col, k] = total / a[col, col]


@njit(cache=True, nogil=True)
def solve_small_vector(A, b):
    """x = A^-1 b for a small square A (see :func:`solve_small_in_place`)."""
    x = b.copy()
    solve_small_in_place(A.copy(), x.reshape((x.size, 1)))
    return x


@njit(cache=True, nogil=True)
def larger_magnitude(largest, value):
    """max(largest, |value|), NaN when either is NaN, as numpy's max gives (Python's max drops a NaN that
    comes second, so a NaN iterate would meet every tolerance)."""
    size = abs(value)
    return size if size > largest or size != size else largest


@njit(cache=True, nogil=True)
def largest_magnitude(x):
    """max |x_i| (0 for an empty x; NaN when an x_i is NaN, see :func:`larger_magnitude`)."""
    largest = 0.0
    for i in range(x.size):
        largest = larger_magnitude(largest, x[i])
    return largest


@njit(cache=True, nogil=True)
def cholesky_solve(L, b):
    """x with L L^T x = b (L lower triangular)."""
    n = b.size
    y = np.empty(n)
    for i in range(n):
        total = b[i]
        for k in range(i):
            total -= L[i, k] * y[k]
        y[i] = total / L[i, i]
    x = np.empty(n)
    for i in range(n - 1, -1, -1):
        total = y[i]
        for k in range(i + 1, n):
            total -= L[k, i] * x[k]
        x[i] = total / L[i, i]
    return x


@njit(cache=True, nogil=True)
def lower_inverse(L):
    """L^-1 of a lower-triangular L (forward substitution on the identity's columns)."""
    n = L.shape[0]
    out = np.zeros((n, n))
    for j in range(n):
        out[j, j] = 1.0 / L[j, j]
        for i in range(j + 1, n):
            total = 0.0
            for k in range(j, i):
                total -= L[i, k] * out[k, j]
            out[i, j] = total / L[i, i]
    return out


@njit(cache=True, nogil=True)
def cholesky_solve_columns(L, B):
    """X with L L^T X = B for the columns of B (n, k) (L lower triangular; rows at a time, so the columns vectorize)."""
    n, k = B.shape
    Y = np.empty((n, k))
    for i in range(n):
        row = B[i].copy()
        for j in range(i):
            weight = L[i, j]
            for m in range(k):
                row[m] -= weight * Y[j, m]
        Y[i] = row / L[i, i]
    X = np.empty((n, k))
    for i in range(n - 1, -1, -1):
        row = Y[i].copy()
        for j in range(i + 1, n):
            weight = L[j, i]
            for m in range(k):
                row[m] -= weight * X[j, m]
        X[i] = row / L[i, i]
    return X


@njit(cache=True, nogil=True)
def smallest_singular_value(K):
    """Smallest singular value of a square matrix (closed form for 2 x 2, the paper's K_dc; inf for an empty
    one: no constraints, nothing that could become singular)."""
    if K.shape[0] == 0:
        return np.inf
    if K.shape[0] == 2:
        a, b, c, d = K[0, 0], K[0, 1], K[1, 0], K[1, 1]
        half_trace = 0.5 * (a * a + b * b + c * c + d * d)
        det = a * d - b * c
        return np.sqrt(max(half_trace - np.sqrt(max(half_trace * half_trace - det * det, 0.0)), 0.0))
    return np.linalg.svd(K)[1][-1]


@njit(cache=True, nogil=True)
def project_rows(X, B, independent, dependent, servo):
    """P^T X for X (n, k) without forming P: X[ic] + Gamma^T X[dc] for ideal constraints (P = B, whose
    rows are the identity on ic and Gamma on dc), X[ic] for servo-constraints (P = E_ic)."""
    out = np.empty((independent.size, X.shape[1]))
    for j in range(independent.size):
        out[j] = X[independent[j]]
    if not servo:
        for r in range(dependent.size):
            row = X[dependent[r]]
            for j in range(independent.size):
                weight = B[dependent[r], j]
                for k in range(X.shape[1]):
                    out[j, k] += weight * row[k]
    return out


@njit(cache=True, nogil=True)
def congruent(X, B, independent, dependent):
    """B^T X B for a symmetric X (n, n) without forming B: with Gamma the rows of B on dc,
    X[ic, ic] + X[ic, dc] Gamma + Gamma^T Z, Z = X[dc, ic] + X[dc, dc] Gamma (the lower triangle computed,
    the upper one its mirror: symmetric to the last bit)."""
    n_ic, m = independent.size, dependent.size
    gamma = np.empty((m, n_ic))
    Z = np.empty((m, n_ic))
    for r in range(m):
        for j in range(n_ic):
            gamma[r, j] = B[dependent[r], j]
    for r in range(m):
        for j in range(n_ic):
            total = X[dependent[r], independent[j]]
            for s in range(m):
                total += X[dependent[r], dependent[s]] * gamma[s, j]
            Z[r, j] = total
    out = np.empty((n_ic, n_ic))
    for i in range(n_ic):
        row = independent[i]
        for j in range(i + 1):
            total = X[row, independent[j]]
            for r in range(m):
                total += X[row, dependent[r]] * gamma[r, j] + gamma[r, i] * Z[r, j]
            out[i, j] = total
            out[j, i] = total
    return out


@njit(cache=True, nogil=True)
def map_columns(Y, B, independent, dependent):
    """Y B for Y (k, n) without forming B: Y[:, ic] + Y[:, dc] Gamma."""
    out = np.empty((Y.shape[0], independent.size))
    for i in range(Y.shape[0]):
        for j in range(independent.size):
            total = Y[i, independent[j]]
            for r in range(dependent.size):
                total += Y[i, dependent[r]] * B[dependent[r], j]
            out[i, j] = total
    return out


@njit(cache=True, nogil=True)
def jacobi_eigh(A, max_sweeps=30):
    """Eigenvalues (ascending) and orthonormal eigenvectors (columns) of a small symmetric A by cyclic Jacobi
    rotations (Golub and Van Loan, Algorithm 8.5.3), skipping a rotation whose angle, about
    a_pq / (a_qq - a_pp), is below round-off, until a sweep rotates nothing (at most ``max_sweeps``):
    quadratically convergent, so few sweeps from a nearly diagonal A; without LAPACK's call overhead, which
    dominates for the r x r problems of a tracked basis."""
    n = A.shape[0]
    a = A.copy()
    V = np.eye(n)
    for _ in range(max_sweeps):
        rotated = False
        for p in range(n - 1):
            for q in range(p + 1, n):
                apq = a[p, q]
                if abs(apq) <= 1e-17 * abs(a[q, q] - a[p, p]):
                    continue
                rotated = True
                tau = (a[q, q] - a[p, p]) / (2.0 * apq)
                t = (1.0 if tau >= 0.0 else -1.0) / (abs(tau) + np.sqrt(1.0 + tau * tau))
                c = 1.0 / np.sqrt(1.0 + t * t)
                s = t * c
                for k in range(n):  # A <- A J (columns p, q)
                    akp, akq = a[k, p], a[k, q]
                    a[k, p], a[k, q] = c * akp - s * akq, s * akp + c * akq
                for k in range(n):  # A <- J^T A (rows p, q)
                    apk, aqk = a[p, k], a[q, k]
                    a[p, k], a[q, k] = c * apk - s * aqk, s * apk + c * aqk
                for k in range(n):
                    vkp, vkq = V[k, p], V[k, q]
                    V[k, p], V[k, q] = c * vkp - s * vkq, s * vkp + c * vkq
        if not rotated:
            break
    values = np.empty(n)
    for i in range(n):
        values[i] = a[i, i]
    order = np.argsort(values)
    vectors = np.empty((n, n))
    for j in range(n):
        vectors[:, j] = V[:, order[j]]
    return values[order], vectors

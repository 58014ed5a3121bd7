"""Compiled terms of the quadric task constraints (the one implementation of the formulas of
:mod:`crane_reference.motion.constraints`; the Python classes there write the coefficients and call these).

A holonomic row is Phi(p, t) = p^T Q p + g^T p + c with coefficient arrays Q (3, k, k), g (3, k),
c (3,) holding the value and the first two time derivatives (index 0, 1, 2; only the leading 3 x 3
block is used):

    Phi_p = 2 Q p + g,   dPhi/dt = Phi_p p' + Phi_t,   Phi_t = p^T Q' p + g'^T p + c',
    d2Phi/dt2 = Phi_p p'' + convective,
    convective = p'^T 2Q p' + 2 (2 Q' p + g')^T p' + p^T Q'' p + g''^T p + c''.

A first-order row is Psi(z, t) = z^T Q z + g^T z + c in z = (p, p') (Q (2, 6, 6), value and first
derivative):

    (Psi_p, Psi_v) = 2 Q z + g,   dPsi/dt = Psi_v p'' + Psi_p p' + Psi_t,   Psi_t = z^T Q' z + g'^T z + c'.

With p'' = C qdd + d the acceleration-level row is A_i qdd = c_i with A_i = (Phi_p or Psi_v) C and
c_i = -(Phi_p d + convective) or -(Psi_v d + Psi_p p' + Psi_t).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .linalg import matmul
from .structures import Coefficients


@njit(cache=True, nogil=True)
def _entry(p, v, a):
    """Entry a of z = (p, v) (a < 3: of p)."""
    return p[a] if a < 3 else v[a - 3]


# The row functions below take the coefficients of all rows (Q (m, 3, k, k), g (m, 3, k), c (m, 3)) and the
# row i, derivative d, and address them by index: an array view would cost a reference count each.

@njit(cache=True, nogil=True)
def _quadratic_form(Q, i, d, p, v, n):
    """z^T Q z over the leading n x n block of Q[i, d], z = (p, v) (n = 3: p^T Q p)."""
    total = 0.0
    for a in range(n):
        row = 0.0
        for b in range(n):
            row += Q[i, d, a, b] * _entry(p, v, b)
        total += _entry(p, v, a) * row
    return total


@njit(cache=True, nogil=True)
def _linear_form(g, i, d, p, v, n):
    """g^T z over the leading n entries of g[i, d], z = (p, v)."""
    total = 0.0
    for a in range(n):
        total += g[i, d, a] * _entry(p, v, a)
    return total


@njit(cache=True, nogil=True)
def _gradient_entry(Q, g, i, d, p, v, n, a):
    """Entry a of 2 Q z + g over the leading n block of Q[i, d], g[i, d], z = (p, v)."""
    total = g[i, d, a]
    for b in range(n):
        total += 2.0 * Q[i, d, a, b] * _entry(p, v, b)
    return total


@njit(cache=True, nogil=True)
def _holonomic_value(Q, g, c, i, p, gradient, row):
    """Phi of holonomic row i at p; Phi_p written into gradient[row]."""
    for a in range(3):
        gradient[row, a] = _gradient_entry(Q, g, i, 0, p, p, 3, a)
    return _quadratic_form(Q, i, 0, p, p, 3) + _linear_form(g, i, 0, p, p, 3) + c[i, 0]


@njit(cache=True, nogil=True)
def _holonomic_rate(Q, g, c, i, p, v, gradient, row):
    """dPhi/dt = Phi_p v + Phi_t of holonomic row i at (p, v); Phi_p written into gradient[row]."""
    total = _quadratic_form(Q, i, 1, p, p, 3) + _linear_form(g, i, 1, p, p, 3) + c[i, 1]
    for a in range(3):
        gradient[row, a] = _gradient_entry(Q, g, i, 0, p, p, 3, a)
        total += gradient[row, a] * v[a]
    return total


@njit(cache=True, nogil=True)
def _holonomic_acceleration(Q, g, c, i, p, v, d, gradient, row):
    """The right-hand side -(Phi_p d + convective) of holonomic row i at (p, v) with bias d; Phi_p written
    into gradient[row]."""
    total = 2.0 * _quadratic_form(Q, i, 0, v, v, 3) + _quadratic_form(Q, i, 2, p, p, 3) \
        + _linear_form(g, i, 2, p, p, 3) + c[i, 2]  # the convective part
    for a in range(3):
        gradient[row, a] = _gradient_entry(Q, g, i, 0, p, p, 3, a)
        total += 2.0 * _gradient_entry(Q, g, i, 1, p, p, 3, a) * v[a] + gradient[row, a] * d[a]
    return -total


@njit(cache=True, nogil=True)
def _rate_value(Q, g, c, i, p, v, gradient, row):
    """Psi of first-order row i at (p, v); Psi_v written into gradient[row]."""
    for a in range(3):
        gradient[row, a] = _gradient_entry(Q, g, i, 0, p, v, 6, 3 + a)
    return _quadratic_form(Q, i, 0, p, v, 6) + _linear_form(g, i, 0, p, v, 6) + c[i, 0]


@njit(cache=True, nogil=True)
def _rate_acceleration(Q, g, c, i, p, v, d, gradient, row):
    """The right-hand side -(Psi_v d + Psi_p v + Psi_t) of first-order row i at (p, v); Psi_v written into
    gradient[row]."""
    total = _quadratic_form(Q, i, 1, p, v, 6) + _linear_form(g, i, 1, p, v, 6) + c[i, 1]  # Psi_t
    for a in range(3):
        gradient[row, a] = _gradient_entry(Q, g, i, 0, p, v, 6, 3 + a)
        total += _gradient_entry(Q, g, i, 0, p, v, 6, a) * v[a] + gradient[row, a] * d[a]
    return -total


@njit(cache=True, nogil=True)
def _one_row(Q, g, c):
    """The coefficients of one row (Q (derivatives, k, k), g (derivatives, k), c (derivatives,)) stacked as those
    of a single row."""
    return (Q.reshape((1, Q.shape[0], Q.shape[1], Q.shape[2])), g.reshape((1, g.shape[0], g.shape[1])),
            c.reshape((1, c.shape[0])))


@njit(cache=True, nogil=True)
def holonomic_value(Q, g, c, p):
    """Phi and Phi_p (3,) of one holonomic row (Q (3, 3, 3), g (3, 3), c (3,)) at p."""
    gradient = np.empty((1, 3))
    value = _holonomic_value(*_one_row(Q, g, c), 0, p, gradient, 0)
    return value, gradient[0]


@njit(cache=True, nogil=True)
def holonomic_rate(Q, g, c, p, v):
    """dPhi/dt = Phi_p v + Phi_t and Phi_p of one holonomic row at (p, v)."""
    gradient = np.empty((1, 3))
    value = _holonomic_rate(*_one_row(Q, g, c), 0, p, v, gradient, 0)
    return value, gradient[0]


@njit(cache=True, nogil=True)
def holonomic_acceleration(Q, g, c, p, v, d):
    """Phi_p and the right-hand side -(Phi_p d + convective) of one holonomic row at (p, v) with bias d."""
    gradient = np.empty((1, 3))
    value = _holonomic_acceleration(*_one_row(Q, g, c), 0, p, v, d, gradient, 0)
    return gradient[0], value


@njit(cache=True, nogil=True)
def rate_value(Q, g, c, p, v):
    """Psi and Psi_v (3,) of one first-order row (Q (2, 6, 6), g (2, 6), c (2,)) at (p, v)."""
    gradient = np.empty((1, 3))
    value = _rate_value(*_one_row(Q, g, c), 0, p, v, gradient, 0)
    return value, gradient[0]


@njit(cache=True, nogil=True, inline='always')
def holonomic_values(p, k: Coefficients):
    """Phi (n_h,) and Phi_p (n_h, 3) of the holonomic rows at p."""
    Q, g, c, order = k.Q, k.g, k.c, k.order
    count = 0
    for i in range(order.size):
        count += order[i] == 0
    residual = np.empty(count)
    grads = np.empty((count, 3))
    r = 0
    for i in range(order.size):
        if order[i] == 0:
            residual[r] = _holonomic_value(Q, g, c, i, p, grads, r)
            r += 1
    return residual, grads


@njit(cache=True, nogil=True, inline='always')
def velocity_residual(p, v, k: Coefficients):
    """Velocity-level residuals, dPhi/dt (holonomic rows) or Psi (first-order rows), and their gradients
    with respect to v, Phi_p or Psi_v (m, 3)."""
    Q, g, c, order = k.Q, k.g, k.c, k.order
    m = order.size
    residual = np.empty(m)
    grads = np.empty((m, 3))
    for i in range(m):
        if order[i] == 0:
            residual[i] = _holonomic_rate(Q, g, c, i, p, v, grads, i)
        else:
            residual[i] = _rate_value(Q, g, c, i, p, v, grads, i)
    return residual, grads


@njit(cache=True, nogil=True, inline='always')
def acceleration_terms(p, v, C, d, k: Coefficients):
    """A = gradients C and c of the acceleration-level constraints A qdd = c."""
    Q, g, c, order = k.Q, k.g, k.c, k.order
    m = order.size
    grads = np.empty((m, 3))
    c_acc = np.empty(m)
    for i in range(m):
        if order[i] == 0:
            c_acc[i] = _holonomic_acceleration(Q, g, c, i, p, v, d, grads, i)
        else:
            c_acc[i] = _rate_acceleration(Q, g, c, i, p, v, d, grads, i)
    return matmul(grads, C), c_acc


@njit(cache=True, nogil=True, inline='always')
def constraint_values(p, v, k: Coefficients):
    """Residuals (Phi or Psi), gradients (Phi_p or Psi_v), distances |residual| / |gradient| and the
    velocity-level residuals (dPhi/dt or Psi)."""
    Q, g, c, order = k.Q, k.g, k.c, k.order
    m = order.size
    residual = np.empty(m)
    rate, grads = velocity_residual(p, v, k)
    scratch = np.empty((1, 3))
    for i in range(m):
        # a first-order row's residual Psi is its velocity-level residual already
        residual[i] = _holonomic_value(Q, g, c, i, p, scratch, 0) if order[i] == 0 else rate[i]
    distance = np.empty(m)
    for i in range(m):
        distance[i] = abs(residual[i]) / np.sqrt(grads[i, 0] ** 2 + grads[i, 1] ** 2 + grads[i, 2] ** 2)
    return residual, grads, distance, rate


@njit(cache=True, nogil=True)
def surface_offsets(positions, k: Coefficients):
    """Phi / |Phi_p| of the holonomic rows at E's positions (N, 3), with the coefficients ``k`` stacked per
    position: E's signed distance to each row's surface, to first order in Phi (N, n_h) [m]."""
    rows = 0
    for i in range(k.order.size):
        rows += k.order[i] == 0
    out = np.empty((positions.shape[0], rows))
    for i in range(positions.shape[0]):
        residual, grads = holonomic_values(positions[i], Coefficients(k.Q[i], k.g[i], k.c[i], k.order))
        for r in range(rows):
            out[i, r] = residual[r] / np.sqrt(grads[r, 0] ** 2 + grads[r, 1] ** 2 + grads[r, 2] ** 2)
    return out

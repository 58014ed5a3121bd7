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
def _quadratic_form(Q, x, y):
    """x^T Q y over the leading len(x) x len(y) block of Q."""
    total = 0.0
    for a in range(x.size):
        for b in range(y.size):
            total += x[a] * Q[a, b] * y[b]
    return total


@njit(cache=True, nogil=True)
def _form_gradient(Q, g, x):
    """2 Q x + g over the leading len(x) block."""
    n = x.size
    out = np.empty(n)
    for a in range(n):
        total = g[a]
        for b in range(n):
            total += 2.0 * Q[a, b] * x[b]
        out[a] = total
    return out


@njit(cache=True, nogil=True)
def holonomic_value(Q, g, c, p):
    """Phi and Phi_p (3,) of one holonomic row at p."""
    return _quadratic_form(Q[0], p, p) + g[0, :3] @ p + c[0], _form_gradient(Q[0], g[0], p)


@njit(cache=True, nogil=True)
def holonomic_rate(Q, g, c, p, v):
    """dPhi/dt = Phi_p v + Phi_t and Phi_p of one holonomic row at (p, v)."""
    gradient = _form_gradient(Q[0], g[0], p)
    return gradient @ v + _quadratic_form(Q[1], p, p) + g[1, :3] @ p + c[1], gradient


@njit(cache=True, nogil=True)
def holonomic_acceleration(Q, g, c, p, v, d):
    """Phi_p and the right-hand side -(Phi_p d + convective) of one holonomic row at (p, v) with bias d."""
    gradient = _form_gradient(Q[0], g[0], p)
    convective = (2.0 * _quadratic_form(Q[0], v, v) + 2.0 * (_form_gradient(Q[1], g[1], p) @ v)
                  + _quadratic_form(Q[2], p, p) + g[2, :3] @ p + c[2])
    return gradient, -(gradient @ d + convective)


@njit(cache=True, nogil=True)
def rate_value(Q, g, c, p, v):
    """Psi and Psi_v (3,) of one first-order row at (p, v)."""
    z = np.concatenate((p, v))
    return _quadratic_form(Q[0], z, z) + g[0] @ z + c[0], _form_gradient(Q[0], g[0], z)[3:]


@njit(cache=True, nogil=True)
def rate_acceleration(Q, g, c, p, v, d):
    """Psi_v and the right-hand side -(Psi_v d + Psi_p v + Psi_t) of one first-order row at (p, v)."""
    z = np.concatenate((p, v))
    full = _form_gradient(Q[0], g[0], z)
    gradient = full[3:]
    psi_t = _quadratic_form(Q[1], z, z) + g[1] @ z + c[1]
    return gradient, -(gradient @ d + full[:3] @ v + psi_t)


@njit(cache=True, nogil=True)
def holonomic_values(p, k: Coefficients):
    """Phi (n_h,) and Phi_p (n_h, 3) of the holonomic rows at p."""
    rows = np.flatnonzero(k.order == 0)
    residual = np.empty(rows.size)
    grads = np.empty((rows.size, 3))
    for r in range(rows.size):
        i = rows[r]
        residual[r], grads[r] = holonomic_value(k.Q[i], k.g[i], k.c[i], p)
    return residual, grads


@njit(cache=True, nogil=True)
def velocity_residual(p, v, k: Coefficients):
    """Velocity-level residuals, dPhi/dt (holonomic rows) or Psi (first-order rows), and their gradients
    with respect to v, Phi_p or Psi_v (m, 3)."""
    m = k.order.size
    residual = np.empty(m)
    grads = np.empty((m, 3))
    for i in range(m):
        if k.order[i] == 0:
            residual[i], grads[i] = holonomic_rate(k.Q[i], k.g[i], k.c[i], p, v)
        else:
            residual[i], grads[i] = rate_value(k.Q[i], k.g[i], k.c[i], p, v)
    return residual, grads


@njit(cache=True, nogil=True)
def acceleration_terms(p, v, C, d, k: Coefficients):
    """A = gradients C and c of the acceleration-level constraints A qdd = c."""
    m = k.order.size
    grads = np.empty((m, 3))
    c_acc = np.empty(m)
    for i in range(m):
        if k.order[i] == 0:
            grads[i], c_acc[i] = holonomic_acceleration(k.Q[i], k.g[i], k.c[i], p, v, d)
        else:
            grads[i], c_acc[i] = rate_acceleration(k.Q[i], k.g[i], k.c[i], p, v, d)
    return matmul(grads, C), c_acc


@njit(cache=True, nogil=True)
def constraint_values(p, v, k: Coefficients):
    """Residuals (Phi or Psi), gradients (Phi_p or Psi_v), distances |residual| / |gradient| and the
    velocity-level residuals (dPhi/dt or Psi)."""
    m = k.order.size
    residual = np.empty(m)
    rate, grads = velocity_residual(p, v, k)
    for i in range(m):
        residual[i] = (holonomic_value(k.Q[i], k.g[i], k.c[i], p)[0] if k.order[i] == 0
                       else rate_value(k.Q[i], k.g[i], k.c[i], p, v)[0])
    distance = np.empty(m)
    for i in range(m):
        distance[i] = abs(residual[i]) / np.sqrt(grads[i] @ grads[i])
    return residual, grads, distance, rate

"""Mass matrix, velocity terms and gravity forces from pseudo-inertia matrices (compiled with numba).

With T_i^(l) = S_i T^(l) (see :mod:`crane_reference.dynamics.kinematics`) the paper's mass matrix entries are

    m_ij = sum_l tr(T_i^(l) H^(l) T_j^(l)T) = tr(S_i Hc_max(i,j) S_j^T),

where Hc_k = sum_{l after joint k} T^(l) H^(l) T^(l)T is the composite world pseudo-inertia of all
bodies beyond joint k.  Lagrange's equations of E_k = 1/2 sum_l tr(dT^(l) H^(l) dT^(l)T) give the
generalized inertia force sum_l tr(T_i^(l) H^(l) d2T^(l)T) = sum_j m_ij qdd_j + h_i, so the velocity
terms are

    h_i = sum_{l after i} tr(T_i^(l) H^(l) (sum_mn T_mn^(l) qd_m qd_n)^T) = tr(S_i G_i),
    G_k = sum_{l after k} T^(l) H^(l) T^(l)T B^(l)T,

with B = A + V V the velocity-product term of the body's frame.  With the accelerations added to it,
B + W_k, W_k = sum_{j<=k} S_j qdd_j (so that d2T = (W + B) T), the same suffix sums give the whole
inertia force M qdd + h in O(n), and with the gravity acceleration added, M qdd + h - Q_g (inverse
dynamics, the Newton residual of the integrator).

Gravity: E_p,g = sum_l m^(l) g
J_3 T^(l) r_C^(l) (eq. (4)); its generalized force -dE_p,g/dq_i = -g J_3 S_i Hc_i e_4, because the
last column of Hc_i is sum_l m^(l) [c^(l); 1] in world coordinates.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def world_pseudo_inertias(T, body_joint, body_H):
    """Each body's pseudo-inertia in world coordinates, T^(l) H^(l) T^(l)T (bodies, 4, 4)."""
    Hw = np.empty((body_joint.size, 4, 4))
    TH = np.empty((4, 4))
    for body in range(body_joint.size):
        Tk, H = T[body_joint[body]], body_H[body]
        for a in range(4):
            for b in range(4):
                TH[a, b] = Tk[a, 0] * H[0, b] + Tk[a, 1] * H[1, b] + Tk[a, 2] * H[2, b] + Tk[a, 3] * H[3, b]
        for a in range(4):
            for b in range(a, 4):
                Hw[body, a, b] = TH[a, 0] * Tk[b, 0] + TH[a, 1] * Tk[b, 1] + TH[a, 2] * Tk[b, 2] + TH[a, 3] * Tk[b, 3]
                Hw[body, b, a] = Hw[body, a, b]
    return Hw


@njit(cache=True)
def _suffix_sums(X):
    """X[k] += X[k + 1] from the last joint back, in place (X of shape (n, 4, 4))."""
    for k in range(X.shape[0] - 2, -1, -1):
        for a in range(4):
            for b in range(4):
                X[k, a, b] += X[k + 1, a, b]


@njit(cache=True)
def composite_inertias(Hw, body_joint, n):
    """Suffix sums Hc_k of the world pseudo-inertias over the bodies beyond joint k."""
    Hc = np.zeros((n, 4, 4))
    for body in range(body_joint.size):
        k = body_joint[body]
        for a in range(4):
            for b in range(4):
                Hc[k, a, b] += Hw[body, a, b]
    _suffix_sums(Hc)
    return Hc


@njit(cache=True)
def composite_velocity_products(Hw, B, body_joint, n):
    """Suffix sums G_k of T H T^T B^T over the bodies beyond joint k (B of each body's frame)."""
    G = np.zeros((n, 4, 4))
    for body in range(body_joint.size):
        k = body_joint[body]
        H, Bk = Hw[body], B[k]
        for a in range(4):
            for b in range(4):
                G[k, a, b] += H[a, 0] * Bk[b, 0] + H[a, 1] * Bk[b, 1] + H[a, 2] * Bk[b, 2] + H[a, 3] * Bk[b, 3]
    _suffix_sums(G)
    return G


@njit(cache=True)
def add_joint_accelerations(B, S, qdd, gravity):
    """B_k + W_k + G with W_k = sum_{j<=k} S_j qdd_j: the frames' whole acceleration term (d2T_k = (W_k + B_k)
    T_k), plus G = g e_3 e_4^T, an upward acceleration g of the world frame (d'Alembert: the suffix sums of
    Hw G^T give -Q_g, the gravity forces of the module docstring with their sign reversed)."""
    out = np.empty_like(B)
    W = np.zeros((4, 4))
    for k in range(qdd.size):
        for a in range(3):
            for b in range(4):
                W[a, b] += S[k, a, b] * qdd[k]
                out[k, a, b] = B[k, a, b] + W[a, b]
        out[k, 2, 3] += gravity
        out[k, 3] = B[k, 3]
    return out


@njit(cache=True)
def trace_product(X, Y):
    """tr(X Y) for 4x4 matrices."""
    total = 0.0
    for a in range(4):
        for b in range(4):
            total += X[a, b] * Y[b, a]
    return total


@njit(cache=True)
def mass_matrix(S, Hc):
    """M with m_ij = tr(S_i Hc_max(i,j) S_j^T)."""
    n = S.shape[0]
    M = np.empty((n, n))
    Y = np.empty((4, 4))
    for j in range(n):
        for a in range(4):
            for b in range(4):
                Y[a, b] = Hc[j, a, 0] * S[j, b, 0] + Hc[j, a, 1] * S[j, b, 1] + Hc[j, a, 2] * S[j, b, 2] \
                    + Hc[j, a, 3] * S[j, b, 3]
        for i in range(j + 1):
            total = 0.0
            for a in range(3):
                for b in range(4):
                    total += S[i, a, b] * Y[b, a]
            M[i, j] = total
            M[j, i] = total
    return M


@njit(cache=True)
def velocity_forces(S, G):
    """h_i = tr(S_i G_i)."""
    n = S.shape[0]
    h = np.empty(n)
    for i in range(n):
        h[i] = trace_product(S[i], G[i])
    return h


@njit(cache=True)
def gravity_forces(S, Hc, gravity):
    """Q_g,i = -g J_3 S_i Hc_i e_4 (gravity of magnitude g along world -z)."""
    n = S.shape[0]
    Q = np.empty(n)
    for i in range(n):
        Q[i] = -gravity * (S[i, 2, 0] * Hc[i, 0, 3] + S[i, 2, 1] * Hc[i, 1, 3]
                           + S[i, 2, 2] * Hc[i, 2, 3] + S[i, 2, 3] * Hc[i, 3, 3])
    return Q

"""Homogeneous-transformation kinematics of the serial chain (compiled with numba).

For joint k with constant offset ``origin_k`` the frame after the joint is
``T_k = T_{k-1} origin_k motion_k(q_k)`` (world frame {0}).  Its partial derivative with respect to
an earlier coordinate q_i (i <= k) is, for joints about/along fixed local axes,

    T_k,i = dT_k / dq_i = S_i T_k,

where S_i is the 4x4 world-frame twist of joint i (Legnani et al., "A homogeneous matrix approach to
3D kinematics and dynamics", Mech. Mach. Theory 31 (1996)): for a revolute joint with world axis w
through point p, S_i = [[w^, -w^ p], [0, 0]]; for a prismatic joint along w, S_i = [[0, w], [0, 0]].
Hence the velocity and acceleration of the frame are

    dT_k/dt   = V_k T_k,                 V_k = sum_{i<=k} S_i qd_i,
    d2T_k/dt2 = (sum_{i<=k} S_i qdd_i + A_k + V_k V_k) T_k,
    A_k = A_{k-1} + (V_{k-1} S_k - S_k V_{k-1}) qd_k,

since S_k moves with the body before joint k (dS_k/dt = [V_{k-1}, S_k]).  With qdd = 0 the term
(A_k + V_k V_k) T_k is the paper's sum_ij T_ij qd_i qd_j, which enters d in (6.4) and h in (8).
"""

from __future__ import annotations

import numpy as np
from numba import njit

PRISMATIC = 0


@njit(cache=True)
def matmul4(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """4x4 product without BLAS call overhead."""
    out = np.zeros((4, 4))
    for i in range(4):
        for k in range(4):
            aik = a[i, k]
            if aik != 0.0:
                for j in range(4):
                    out[i, j] += aik * b[k, j]
    return out


@njit(cache=True)
def joint_motion(kind: int, axis: int, value: float) -> np.ndarray:
    """Homogeneous transform of one joint: translation along or rotation about local ``axis``."""
    M = np.eye(4)
    if kind == PRISMATIC:
        M[axis, 3] = value
        return M
    c, s = np.cos(value), np.sin(value)
    i, j = (axis + 1) % 3, (axis + 2) % 3
    M[i, i] = c
    M[j, j] = c
    M[i, j] = -s
    M[j, i] = s
    return M


@njit(cache=True)
def forward_kinematics(q: np.ndarray, kinds: np.ndarray, axes: np.ndarray, origins: np.ndarray):
    """World transforms T_k (n,4,4) of the frames after each joint and the joint twists S_k (n,4,4)."""
    n = q.size
    T = np.empty((n, 4, 4))
    S = np.zeros((n, 4, 4))
    previous = np.eye(4)
    for k in range(n):
        frame = matmul4(previous, origins[k])
        a = axes[k]
        if kinds[k] == PRISMATIC:
            S[k, 0, 3] = frame[0, a]
            S[k, 1, 3] = frame[1, a]
            S[k, 2, 3] = frame[2, a]
        else:
            wx, wy, wz = frame[0, a], frame[1, a], frame[2, a]
            px, py, pz = frame[0, 3], frame[1, 3], frame[2, 3]
            S[k, 0, 1] = -wz
            S[k, 0, 2] = wy
            S[k, 1, 0] = wz
            S[k, 1, 2] = -wx
            S[k, 2, 0] = -wy
            S[k, 2, 1] = wx
            # -w^ p = p x w
            S[k, 0, 3] = py * wz - pz * wy
            S[k, 1, 3] = pz * wx - px * wz
            S[k, 2, 3] = px * wy - py * wx
        T[k] = matmul4(frame, joint_motion(kinds[k], a, q[k]))
        previous = T[k]
    return T, S


@njit(cache=True)
def velocity_terms(qd: np.ndarray, S: np.ndarray):
    """Frame velocity twists V_k and the velocity-product acceleration terms B_k = A_k + V_k V_k."""
    n = qd.size
    V = np.zeros((n, 4, 4))
    B = np.zeros((n, 4, 4))
    V_prev = np.zeros((4, 4))
    A_prev = np.zeros((4, 4))
    for k in range(n):
        A_k = A_prev + (matmul4(V_prev, S[k]) - matmul4(S[k], V_prev)) * qd[k]
        V[k] = V_prev + S[k] * qd[k]
        B[k] = A_k + matmul4(V[k], V[k])
        V_prev = V[k]
        A_prev = A_k
    return V, B


@njit(cache=True)
def point_kinematics(T: np.ndarray, S: np.ndarray, B: np.ndarray, joint: int, point: np.ndarray):
    """Position p, Jacobian C (3,n) and velocity-product acceleration d (3) of a point fixed in the
    frame after ``joint`` (the paper's C = J[T_1 r ... T_n r], d = J sum_ij T_ij qd_i qd_j r)."""
    n = S.shape[0]
    r = np.array([point[0], point[1], point[2], 1.0])
    p_h = T[joint] @ r
    C = np.zeros((3, n))
    for i in range(joint + 1):
        C[:, i] = (S[i] @ p_h)[:3]
    d = (B[joint] @ p_h)[:3]
    return p_h[:3].copy(), C, d


@njit(cache=True)
def point_position_jacobian(q, kinds, axes, origins, joint, point):
    """Position and Jacobian of a point fixed after ``joint``, without velocity terms (for projection)."""
    T, S = forward_kinematics(q, kinds, axes, origins)
    n = q.size
    r = np.array([point[0], point[1], point[2], 1.0])
    p_h = T[joint] @ r
    C = np.zeros((3, n))
    for i in range(joint + 1):
        C[:, i] = (S[i] @ p_h)[:3]
    return p_h[:3].copy(), C

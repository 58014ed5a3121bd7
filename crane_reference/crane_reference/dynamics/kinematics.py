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
def _is_identity(origins, k):
    """Whether the offset of joint k is the identity (no rotation, no translation)."""
    return (origins[k, 0, 0] == 1.0 and origins[k, 1, 1] == 1.0 and origins[k, 2, 2] == 1.0
            and origins[k, 0, 3] == 0.0 and origins[k, 1, 3] == 0.0 and origins[k, 2, 3] == 0.0)


@njit(cache=True)
def forward_kinematics(q: np.ndarray, kinds: np.ndarray, axes: np.ndarray, origins: np.ndarray):
    """World transforms T_k (n,4,4) of the frames after each joint and the joint twists S_k (n,4,4)
    (:func:`forward_kinematics_into` new arrays)."""
    n = q.size
    T, S = np.empty((n, 4, 4)), np.zeros((n, 4, 4))
    forward_kinematics_into(q, kinds, axes, origins, T, S)
    return T, S


@njit(cache=True)
def forward_kinematics_into(q: np.ndarray, kinds: np.ndarray, axes: np.ndarray, origins: np.ndarray, T: np.ndarray,
                            S: np.ndarray):
    """:func:`forward_kinematics` into T and S (n, 4, 4), for a caller that computes them again and again (no
    allocation).  It writes every entry of T and the entries of S a joint of its kind sets; the others stay as
    they are: S must be zero there, as :func:`forward_kinematics` makes it or a call before for the same chain
    left it.

    The joint motion is applied column-wise (a rotation about local axis a mixes the two other
    columns; a translation adds q times column a to the position), and identity offsets are skipped.
    Elements are addressed by index throughout (no array views: each would cost a reference count)."""
    n = q.size
    for k in range(n):
        # T[k] = T[k - 1] origin_k (the frame before the joint; T[-1] = I)
        if k == 0:
            for r in range(4):
                for c in range(4):
                    T[k, r, c] = origins[k, r, c]
        elif _is_identity(origins, k):
            for r in range(4):
                for c in range(4):
                    T[k, r, c] = T[k - 1, r, c]
        else:
            for r in range(4):
                for c in range(4):
                    T[k, r, c] = (T[k - 1, r, 0] * origins[k, 0, c] + T[k - 1, r, 1] * origins[k, 1, c]
                                  + T[k - 1, r, 2] * origins[k, 2, c] + T[k - 1, r, 3] * origins[k, 3, c])
        a = axes[k]
        if kinds[k] == PRISMATIC:
            for r in range(3):
                S[k, r, 3] = T[k, r, a]
                T[k, r, 3] += T[k, r, a] * q[k]
            continue
        wx, wy, wz = T[k, 0, a], T[k, 1, a], T[k, 2, a]
        px, py, pz = T[k, 0, 3], T[k, 1, 3], T[k, 2, 3]
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
        c, s = np.cos(q[k]), np.sin(q[k])
        i, j = (a + 1) % 3, (a + 2) % 3
        for r in range(3):
            fi, fj = T[k, r, i], T[k, r, j]
            T[k, r, i] = c * fi + s * fj
            T[k, r, j] = c * fj - s * fi


@njit(cache=True)
def velocity_terms(qd: np.ndarray, S: np.ndarray):
    """The velocity-product acceleration terms B_k = A_k + V_k V_k of the frames (V_k their velocity twists).

    Twists are handled as 6-vectors (w, v) with X = [[w^, v], [0, 0]]; the matrix commutator is
    [X1, X2] = (w1 x w2, w1 x v2 - w2 x v1), and V V = [[w^ w^, w x v], [0, 0]].
    """
    n = qd.size
    B = np.empty((n, 4, 4))
    wx = wy = wz = vx = vy = vz = 0.0
    awx = awy = awz = avx = avy = avz = 0.0
    for k in range(n):
        u = qd[k]
        sx, sy, sz = S[k, 2, 1], S[k, 0, 2], S[k, 1, 0]
        tx, ty, tz = S[k, 0, 3], S[k, 1, 3], S[k, 2, 3]
        # A_k = A_{k-1} + [V_{k-1}, S_k] qd_k
        awx += (wy * sz - wz * sy) * u
        awy += (wz * sx - wx * sz) * u
        awz += (wx * sy - wy * sx) * u
        avx += ((wy * tz - wz * ty) - (sy * vz - sz * vy)) * u
        avy += ((wz * tx - wx * tz) - (sz * vx - sx * vz)) * u
        avz += ((wx * ty - wy * tx) - (sx * vy - sy * vx)) * u
        wx += sx * u
        wy += sy * u
        wz += sz * u
        vx += tx * u
        vy += ty * u
        vz += tz * u
        ww = wx * wx + wy * wy + wz * wz
        B[k, 0, 0], B[k, 1, 1], B[k, 2, 2] = wx * wx - ww, wy * wy - ww, wz * wz - ww
        B[k, 0, 1], B[k, 0, 2] = wx * wy - awz, wx * wz + awy
        B[k, 1, 0], B[k, 1, 2] = wy * wx + awz, wy * wz - awx
        B[k, 2, 0], B[k, 2, 1] = wz * wx - awy, wz * wy + awx
        B[k, 0, 3] = avx + wy * vz - wz * vy
        B[k, 1, 3] = avy + wz * vx - wx * vz
        B[k, 2, 3] = avz + wx * vy - wy * vx
        B[k, 3, 0] = B[k, 3, 1] = B[k, 3, 2] = B[k, 3, 3] = 0.0
    return B


@njit(cache=True)
def point_position(F: np.ndarray, point: np.ndarray) -> np.ndarray:
    """World position F [point; 1] of a point given in the frame F (4x4)."""
    p = np.empty(3)
    point_position_into(F, point, p)
    return p


@njit(cache=True)
def point_position_into(F: np.ndarray, point: np.ndarray, p: np.ndarray):
    """:func:`point_position` into p (3,)."""
    for r in range(3):
        p[r] = F[r, 0] * point[0] + F[r, 1] * point[1] + F[r, 2] * point[2] + F[r, 3]


@njit(cache=True)
def point_jacobian(T: np.ndarray, S: np.ndarray, joint: int, point: np.ndarray):
    """World position p of a point fixed after ``joint`` and its Jacobian C = J [S_1 p ... S_n p] (3, n)
    (the paper's C = J [T_1 r ... T_n r])."""
    p, C = np.empty(3), np.zeros((3, S.shape[0]))
    point_jacobian_into(T, S, joint, point, p, C)
    return p, C


@njit(cache=True)
def point_jacobian_into(T: np.ndarray, S: np.ndarray, joint: int, point: np.ndarray, p: np.ndarray, C: np.ndarray):
    """:func:`point_jacobian` into p (3,) and C (3, n) (no allocation): it writes C's columns up to ``joint``; the
    others must be zero, as :func:`point_jacobian` makes them or a call before for the same joint left them."""
    point_position_into(T[joint], point, p)
    for i in range(joint + 1):
        for r in range(3):
            C[r, i] = S[i, r, 0] * p[0] + S[i, r, 1] * p[1] + S[i, r, 2] * p[2] + S[i, r, 3]


@njit(cache=True)
def point_bias(B: np.ndarray, joint: int, p: np.ndarray):
    """Velocity-product acceleration d = B_joint [p; 1] of a point at p fixed after ``joint`` (the
    paper's d = J sum_ij T_ij qd_i qd_j r)."""
    Bj = B[joint]
    d = np.empty(3)
    for r in range(3):
        d[r] = Bj[r, 0] * p[0] + Bj[r, 1] * p[1] + Bj[r, 2] * p[2] + Bj[r, 3]
    return d


@njit(cache=True, nogil=True)
def quaternion(R):
    """The unit quaternion (x, y, z, w), w >= 0, of the rotation matrix R (3, 3) (Shepperd's method: from the
    largest of 1 + trace and 1 + 2 R_ii - trace, so that no square root is taken of a small number)."""
    trace = R[0, 0] + R[1, 1] + R[2, 2]
    out = np.empty(4)
    largest = max(trace, R[0, 0], R[1, 1], R[2, 2])
    if largest == trace:
        s = 2.0 * np.sqrt(1.0 + trace)
        out[:] = (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s
    elif largest == R[0, 0]:
        s = 2.0 * np.sqrt(1.0 + 2.0 * R[0, 0] - trace)
        out[:] = 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s
    elif largest == R[1, 1]:
        s = 2.0 * np.sqrt(1.0 + 2.0 * R[1, 1] - trace)
        out[:] = (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s
    else:
        s = 2.0 * np.sqrt(1.0 + 2.0 * R[2, 2] - trace)
        out[:] = (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s, (R[1, 0] - R[0, 1]) / s
    if out[3] < 0.0:
        out *= -1.0
    return out / np.sqrt(out @ out)

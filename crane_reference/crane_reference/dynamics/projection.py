"""Compiled projection on the task constraints: the solution set of the acceleration constraints (7), the rows
of the dynamics (8) keeps, Newton on the position constraints and the dependent velocities (the mathematics:
:mod:`crane_reference.motion.programmed_motion`)."""

from __future__ import annotations

import numpy as np
from numba import njit

from .kinematics import forward_kinematics_into, point_jacobian_into
from .linalg import largest_magnitude, matmul, matvec, smallest_singular_value, solve_small_in_place
from .quadrics import holonomic_values, velocity_residual
from .structures import ChainData, Coefficients, Projection


@njit(cache=True, nogil=True, inline='always')
def constraint_map(A, c_acc, independent, dependent):
    """The solution set of the acceleration constraints A qdd = c (eq. (7)): qdd = B qdd_ic + e with the
    velocity map B = d qd / d qd_ic (n, n_ic) (identity rows on ic, Gamma = -K_dc^-1 K_ic rows on dc)
    and the particular solution e (e_ic = 0, K_dc e_dc = c); returns B and e_dc."""
    n_ic, m = independent.size, dependent.size
    K_dc = np.empty((m, m))
    solution = np.empty((m, n_ic + 1))  # [K_ic c], then K_dc^-1 [K_ic c]
    for row in range(m):
        for j in range(m):
            K_dc[row, j] = A[row, dependent[j]]
        for j in range(n_ic):
            solution[row, j] = A[row, independent[j]]
        solution[row, n_ic] = c_acc[row]
    solve_small_in_place(K_dc, solution)
    B = np.zeros((A.shape[1], n_ic))
    for col in range(n_ic):
        B[independent[col], col] = 1.0
    for row in range(m):
        for col in range(n_ic):
            B[dependent[row], col] = -solution[row, col]
    return B, solution[:, n_ic]


@njit(cache=True, nogil=True)
def projection_matrix(B, independent, servo):
    """Rows of the dynamics kept in (8): P = B for ideal constraints (projection on the directions the
    constraints allow), P = E_ic (the unactuated coordinates' own rows) for servo-constraints."""
    if not servo:
        return B
    P = np.zeros_like(B)
    for col in range(independent.size):
        P[independent[col], col] = 1.0
    return P


ROUND_OFF_STEP = 1e-15
"""[rad or m]: a Newton correction of the position constraints this small is at the round-off of q."""


PROJECTION_ITERATIONS = 25
"""Newton iterations on the position constraints at most, at an iterate of a step."""


@njit(cache=True, nogil=True, inline='always')
def project_positions(q, k: Coefficients, holonomic_dependent, chain: ChainData, tolerance, max_iterations,
                      exact_frames=True):
    """q with the holonomically dependent coordinates solved from Phi(q) = 0 by Newton (Jacobian
    Phi_p C[:, hd]) until a correction of at most ``tolerance`` (:class:`Projection`).  The frames are those
    at the returned q itself, or with ``exact_frames`` False those before the last correction (off by at most
    ``tolerance``, one forward kinematics less: enough for the Newton iterates of a step)."""
    q = q.copy()
    n = q.size
    T, S, p, C = np.empty((n, 4, 4)), np.zeros((n, 4, 4)), np.empty(3), np.zeros((3, n))  # filled at each iterate
    for _ in range(max_iterations):
        forward_kinematics_into(q, chain.kinds, chain.axes, chain.origins, T, S)
        point_jacobian_into(T, S, chain.ee_joint, chain.ee_point, p, C)
        if holonomic_dependent.size == 0:
            return Projection(q, T, S, p, C, True)
        step, grads = holonomic_values(p, k)  # the residual, solved in place for the Newton step
        solve_small_in_place(matmul(grads, C, holonomic_dependent), step.reshape((step.size, 1)))
        size = largest_magnitude(step)
        if size <= ROUND_OFF_STEP:
            return Projection(q, T, S, p, C, True)
        for i in range(holonomic_dependent.size):
            q[holonomic_dependent[i]] -= step[i]
        if size <= tolerance:
            if exact_frames:
                forward_kinematics_into(q, chain.kinds, chain.axes, chain.origins, T, S)
                point_jacobian_into(T, S, chain.ee_joint, chain.ee_point, p, C)
            return Projection(q, T, S, p, C, True)
    return Projection(q, T, S, p, C, False)


@njit(cache=True, nogil=True)
def held_points(q, points, k: Coefficients, holonomic_dependent, chain: ChainData, slew, tolerance, max_iterations):
    """E held at each of ``points`` (N, 3) [m] in turn on the position constraints ``k``, by continuation: each
    from the solution at the point before (the first from ``q``) with the slew joint's angle set to the point's
    azimuth (``slew`` = (joint, sign, offset) of :class:`~crane_reference.motion.simulation.Slew`: q[joint] =
    sign (atan2(y, x) - offset)) and q_hd from :func:`project_positions` (exact frames).  Returns the solution at the
    last point held and, per point, whether Newton converged (a singular K_dc counts as not converged), E's
    position there and the smallest singular value of K_dc = Phi_p C[:, hd]; it stops at the first point not
    held (the rows from there on False and NaN)."""
    count = points.shape[0]
    held = np.zeros(count, dtype=np.bool_)
    positions = np.full((count, 3), np.nan)
    singular_values = np.full(count, np.nan)
    q = q.copy()
    for i in range(count):
        trial = q.copy()
        trial[int(slew[0])] = slew[1] * (np.arctan2(points[i, 1], points[i, 0]) - slew[2])
        try:
            at = project_positions(trial, k, holonomic_dependent, chain, tolerance, max_iterations)
        except Exception:  # numba catches no narrower class: a singular K_dc
            break
        if not at.solved:
            break
        grads = holonomic_values(at.ee_position, k)[1]
        singular_values[i] = smallest_singular_value(matmul(grads, at.ee_jacobian, holonomic_dependent))
        positions[i] = at.ee_position
        held[i] = True
        q = at.q
    return q, held, positions, singular_values


@njit(cache=True, nogil=True, inline='always')
def dependent_velocities(qd, p, C, k: Coefficients, dependent):
    """qd with qd_dc solved from the velocity-level constraints (eq. (7): K_dc qd_dc = b - K_ic qd_ic for
    rows linear in qd); Newton on qd_dc (Jacobian K_dc = A[:, dc]), one step when every row is linear in
    qd, until the step is below 1e-14 otherwise.  Also whether it converged."""
    linear = True
    order, Q = k.order, k.Q
    for i in range(order.size):
        if order[i] == 1:
            for a in range(3, 6):
                for b in range(3, 6):
                    linear = linear and Q[i, 0, a, b] == 0.0
    qd = qd.copy()
    for _ in range(1 if linear else 30):
        step, grads = velocity_residual(p, matvec(C, qd), k)  # the residual, solved in place for the step
        solve_small_in_place(matmul(grads, C, dependent), step.reshape((step.size, 1)))
        for i in range(dependent.size):
            qd[dependent[i]] -= step[i]
        if linear or largest_magnitude(step) <= 1e-14:
            return qd, True
    return qd, False

"""Equations of programmed motion (7)-(8) with independent / dependent coordinates (2)-(3).

Partition q into independent q_ic and dependent q_dc (the paper: q_dc = [psi(3,0), psi4], eq. (3.2)).
The velocity form of the constraints, A qd = b (eqs. (6.1)-(6.2), A = Phi_q, b = -Phi_t), split into
K_dc = A[:, dc] and K_ic = A[:, ic], gives the dependent velocities (7)

    qd_dc = K_dc^-1 (b - K_ic qd_ic),   d qd_dc / d qd_ic = Gamma = -K_dc^-1 K_ic.

(The paper prints k_a = [0, dz_E,a/dt] and the rows u, c_1j; the second row must be C_3, from (6.2).)
With B = d qd / d qd_ic (identity on ic, Gamma on dc), the programmed motion equations (8) are

    [ B^T M ]          [ B^T (Q - h) ]
    [   A   ] qdd  =   [      c      ]

i.e. the dynamic equations projected on the independent directions plus the constraint accelerations
(6.3)-(6.4), A qdd = c.  This is equivalent to the Lagrange-multiplier (KKT) form
M qdd + h = Q + A^T lambda, A qdd = c; lambda follows from the solution and A^T lambda is the
generalized constraint force.  Positions of the dependent coordinates are not integrated: they are
found from the position constraints Phi(q_ic, q_dc, t) = 0 by Newton's method with Jacobian K_dc
(coordinate partitioning), so the motion never drifts off the constraints.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from .constraints import ConstraintSet, ConstraintTerms
from .dynamics import CraneDynamics, DynamicsTerms


class ConstraintSingularityError(RuntimeError):
    """K_dc is (nearly) singular: the dependent coordinates cannot be solved for (stretch / fold)."""


class ProjectionError(RuntimeError):
    """The position constraints could not be solved for the dependent coordinates."""


@dataclass(frozen=True)
class MotionSolution:
    """The result of (8) at one state."""

    qdd: np.ndarray
    multipliers: np.ndarray
    dynamics: DynamicsTerms
    constraints: ConstraintTerms
    velocity_map: np.ndarray
    kdc_min_singular_value: float

    @property
    def constraint_forces(self) -> np.ndarray:
        """Generalized constraint forces A^T lambda (n,)."""
        return self.constraints.A.T @ self.multipliers


@njit(cache=True)
def velocity_map(A: np.ndarray, independent: np.ndarray, dependent: np.ndarray) -> np.ndarray:
    """B = d qd / d qd_ic (n, n_ic): identity rows on ic, Gamma = -K_dc^-1 K_ic rows on dc."""
    n_ic = independent.size
    B = np.zeros((A.shape[1], n_ic))
    for col in range(n_ic):
        B[independent[col], col] = 1.0
    gamma = -np.linalg.solve(np.ascontiguousarray(A[:, dependent]), np.ascontiguousarray(A[:, independent]))
    for row in range(dependent.size):
        B[dependent[row]] = gamma[row]
    return B


@njit(cache=True)
def programmed_accelerations(M, h, Q, A, c, B):
    """Solve (8) for qdd, then lambda from A A^T lambda = A (M qdd + h - Q)."""
    lhs = np.vstack((B.T @ M, A))
    rhs = np.concatenate((B.T @ (Q - h), c))
    qdd = np.linalg.solve(lhs, rhs)
    multipliers = np.linalg.solve(A @ A.T, A @ (M @ qdd + h - Q))
    return qdd, multipliers


def smallest_singular_value(K: np.ndarray) -> float:
    """Smallest singular value of a square matrix (closed form for 2 x 2, the paper's K_dc)."""
    if K.shape == (2, 2):
        gram = K.T @ K
        half_trace = 0.5 * (gram[0, 0] + gram[1, 1])
        det = gram[0, 0] * gram[1, 1] - gram[0, 1] ** 2
        return float(np.sqrt(max(half_trace - np.sqrt(max(half_trace**2 - det, 0.0)), 0.0)))
    return float(np.linalg.svd(K, compute_uv=False)[-1])


class ProgrammedMotion:
    """Equations (7)-(8) of a crane model under a :class:`ConstraintSet`."""

    def __init__(self, dynamics: CraneDynamics, constraints: ConstraintSet,
                 dependent: tuple[int, ...] | None = None, min_singular_value: float = 1e-3):
        model = dynamics.model
        self.dynamics = dynamics
        self.constraints = constraints
        self.dependent = np.array(model.dependent_joints if dependent is None else dependent)
        self.independent = np.array([k for k in range(model.dof) if k not in self.dependent])
        if len(self.dependent) != constraints.size:
            raise ValueError(f"{constraints.size} constraints need as many dependent coordinates, "
                             f"got {len(self.dependent)}")
        self.min_singular_value = min_singular_value

    @property
    def dof(self) -> int:
        return self.dynamics.model.dof

    def _check_kdc(self, K_dc: np.ndarray) -> float:
        sigma = smallest_singular_value(K_dc)
        if not sigma >= self.min_singular_value:
            raise ConstraintSingularityError(
                f"smallest singular value of K_dc = {sigma:.3g} m/rad is below {self.min_singular_value:g}: "
                "the end-effector task is at or near a stretch/fold singularity")
        return sigma

    def dependent_velocities(self, t: float, q: np.ndarray, qd: np.ndarray,
                             kinematics: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """qd with its dependent part replaced by eq. (7); ``kinematics`` = (p_E, C) at q if known."""
        p, C = self.dynamics.end_effector(q) if kinematics is None else kinematics
        A = self.constraints.position_jacobian(t, p) @ C
        b = -np.array([c.time_derivative(t, p) for c in self.constraints.constraints])
        qd = qd.copy()
        qd[self.dependent] = np.linalg.solve(A[:, self.dependent], b - A[:, self.independent] @ qd[self.independent])
        return qd

    def project_positions(self, t: float, q: np.ndarray, tolerance: float = 1e-13,
                          max_iterations: int = 25) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
        """q with q_dc solved from Phi(q, t) = 0 (Newton, Jacobian K_dc = Phi_p C[:, dc]), and (p_E, C)
        from the last Newton iterate (within ``tolerance`` of the returned q)."""
        q = q.copy()
        for _ in range(max_iterations):
            p, C = self.dynamics.end_effector(q)
            residual = self.constraints.residual(t, p)
            K_dc = self.constraints.position_jacobian(t, p) @ C[:, self.dependent]
            step = np.linalg.solve(K_dc, residual)
            q[self.dependent] -= step
            if np.max(np.abs(step)) <= tolerance:
                return q, (p, C)
        raise ProjectionError(f"position constraints not met after {max_iterations} Newton iterations at t = {t:.6g} s "
                              f"(residual {np.max(np.abs(residual)):.3g}): the target is not reachable from here")

    def solve(self, t: float, q: np.ndarray, qd: np.ndarray, left_limit: bool = False) -> MotionSolution:
        """qdd from the programmed motion equations (8) and the multipliers lambda (drive taken just
        before t with ``left_limit``)."""
        dyn = self.dynamics.terms(t, q, qd, left_limit)
        con = self.constraints.terms(t, dyn.ee_position, dyn.ee_jacobian, dyn.ee_bias, qd)
        sigma = self._check_kdc(con.A[:, self.dependent])
        B = velocity_map(con.A, self.independent, self.dependent)
        qdd, multipliers = programmed_accelerations(dyn.M, dyn.h, dyn.Q, con.A, con.c, B)
        return MotionSolution(qdd, multipliers, dyn, con, B, sigma)

"""Time integration of the programmed motion: generalized-alpha on the independent coordinates.

Why this scheme: the RFE springs put constrained natural frequencies up to ~1.7 kHz into the default
crane, and the undamped torque steps excite all of them.  An explicit integrator must resolve them all
(millions of steps for 10 s); flexible multibody codes use an implicit, second-order scheme with
controllable high-frequency numerical dissipation instead.  We use the generalized-alpha method of
Chung and Hulbert (1993) in the form of Arnold and Brüls (2007) on the independent coordinates x = q_ic:

    x_{n+1} = x_n + h v_n + h^2 (1/2 - beta) a~_n + h^2 beta a~_{n+1}
    v_{n+1} = v_n + h (1 - gamma) a~_n + h gamma a~_{n+1}
    (1 - alpha_m) a~_{n+1} + alpha_m a~_n = (1 - alpha_f) a_{n+1} + alpha_f a_n
    a_{n+1} = qdd_ic(t_{n+1}, q_{n+1}, qd_{n+1})       from (8)

with alpha_m = (2 rho - 1)/(rho + 1), alpha_f = rho/(rho + 1), gamma = 1/2 + alpha_f - alpha_m,
beta = (gamma + 1/2)^2 / 4: second-order accurate, unconditionally stable, and the spectral radius at
infinite frequency is rho (rho = 1: no dissipation; rho < 1 damps the modes with omega h >> 1, while
the slow motion is unaffected to second order).  The dependent coordinates are never integrated:
q_dc comes from the position constraints and qd_dc from (7) at every evaluation, so the constraints
hold to the Newton tolerance at every step, with no drift.

The nonlinear step equation for a_{n+1} is solved by a modified Newton method whose iteration matrix
is M_r + beta' K_r + gamma' D_r (B^T M B, B^T K B, B^T D B: reduced mass, spring stiffness and
damping; beta' = h^2 beta (1 - alpha_f)/(1 - alpha_m), gamma' = h gamma (1 - alpha_f)/(1 - alpha_m)):
exact for the stiff linear springs, approximate for gravity and velocity terms.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import lu_factor, lu_solve

from .programmed_motion import MotionSolution, ProgrammedMotion


class IntegrationError(RuntimeError):
    """A step of the integrator did not converge."""


@dataclass(frozen=True)
class GeneralizedAlphaParameters:
    """Coefficients of the generalized-alpha method for a spectral radius ``rho_inf`` in [0, 1]."""

    alpha_m: float
    alpha_f: float
    gamma: float
    beta: float

    @classmethod
    def from_spectral_radius(cls, rho_inf: float) -> GeneralizedAlphaParameters:
        if not 0.0 <= rho_inf <= 1.0:
            raise ValueError(f"rho_inf = {rho_inf}: must lie in [0, 1]")
        alpha_m = (2.0 * rho_inf - 1.0) / (rho_inf + 1.0)
        alpha_f = rho_inf / (rho_inf + 1.0)
        gamma = 0.5 + alpha_f - alpha_m
        return cls(alpha_m, alpha_f, gamma, 0.25 * (gamma + 0.5) ** 2)


@dataclass(frozen=True)
class StepState:
    """Integrator state at t: full q, qd, the solution of (8) there and the pseudo-acceleration a~."""

    t: float
    q: np.ndarray
    qd: np.ndarray
    solution: MotionSolution
    pseudo_acceleration: np.ndarray

    @property
    def qdd(self) -> np.ndarray:
        return self.solution.qdd


class GeneralizedAlpha:
    """Generalized-alpha stepper for a :class:`ProgrammedMotion`."""

    def __init__(self, motion: ProgrammedMotion, rho_inf: float = 0.8, tolerance: float = 1e-12,
                 max_iterations: int = 30):
        self.motion = motion
        self.coefficients = GeneralizedAlphaParameters.from_spectral_radius(rho_inf)
        self.tolerance = tolerance
        self.max_iterations = max_iterations
        model = motion.dynamics.model
        self._stiffness = model.stiffness
        self._damping = motion.dynamics.damping_matrix

    def start(self, t: float, q: np.ndarray, qd: np.ndarray) -> StepState:
        """Consistent start: q_dc from the position constraints, qd_dc from (7), qdd from (8)."""
        q, kinematics = self.motion.project_positions(t, q)
        qd = self.motion.dependent_velocities(t, q, qd, kinematics)
        solution = self.motion.solve(t, q, qd)
        return StepState(t, q, qd, solution, solution.qdd[self.motion.independent].copy())

    def restart(self, state: StepState) -> StepState:
        """Re-solve (8) at ``state`` with the drive's value from t on (after a jump) and restart the
        method's acceleration history there (a~ = a), as at a start."""
        solution = self.motion.solve(state.t, state.q, state.qd)
        return StepState(state.t, state.q, state.qd, solution, solution.qdd[self.motion.independent].copy())

    def _evaluate(self, t: float, q_guess: np.ndarray, x: np.ndarray, v: np.ndarray, left_limit: bool):
        motion = self.motion
        q = q_guess.copy()
        q[motion.independent] = x
        q, kinematics = motion.project_positions(t, q)
        qd = np.zeros_like(q)
        qd[motion.independent] = v
        qd = motion.dependent_velocities(t, q, qd, kinematics)
        return q, qd, motion.solve(t, q, qd, left_limit)

    def step(self, state: StepState, h: float, ends_on_jump: bool = False) -> StepState:
        """Advance ``state`` by h [s].  A step ending on a drive jump (``ends_on_jump``) uses the
        drive's left limit there; continue with :meth:`restart` at the jump."""
        c = self.coefficients
        ic = self.motion.independent
        x0, v0 = state.q[ic], state.qd[ic]
        a0, at0 = state.qdd[ic], state.pseudo_acceleration
        ratio = (1.0 - c.alpha_f) / (1.0 - c.alpha_m)
        beta_p, gamma_p = h * h * c.beta * ratio, h * c.gamma * ratio
        t1 = state.t + h
        B = state.solution.velocity_map
        iteration = lu_factor(B.T @ state.solution.dynamics.M @ B + beta_p * (B.T @ self._stiffness @ B)
                              + gamma_p * (B.T @ self._damping @ B))
        M_r = B.T @ state.solution.dynamics.M @ B
        q_guess = state.q + h * state.qd + 0.5 * h * h * state.qdd
        a1 = a0.copy()
        for _ in range(self.max_iterations):
            at1 = ((1.0 - c.alpha_f) * a1 + c.alpha_f * a0 - c.alpha_m * at0) / (1.0 - c.alpha_m)
            x1 = x0 + h * v0 + h * h * ((0.5 - c.beta) * at0 + c.beta * at1)
            v1 = v0 + h * ((1.0 - c.gamma) * at0 + c.gamma * at1)
            q1, qd1, solution = self._evaluate(t1, q_guess, x1, v1, ends_on_jump)
            q_guess = q1
            correction = -lu_solve(iteration, M_r @ (a1 - solution.qdd[ic]))
            a1 = a1 + correction
            if beta_p * np.max(np.abs(correction)) <= self.tolerance:
                break
        else:
            raise IntegrationError(f"generalized-alpha step from t = {state.t:.6g} s with h = {h:g} s did not converge "
                                   f"in {self.max_iterations} iterations")
        return StepState(t1, q1, qd1, solution, at1)

"""Time integration of the programmed motion: generalized-alpha on the integrated coordinates.

Why this scheme: the RFE springs put constrained natural frequencies up to ~1.7 kHz into the default
crane, and the undamped torque steps excite all of them.  An explicit integrator must resolve them all
(millions of steps for 10 s); flexible multibody codes use an implicit, second-order scheme with
controllable high-frequency numerical dissipation instead.  We use the generalized-alpha method of
Chung and Hulbert (1993) in the form of Arnold and Brüls (2007) on the independent coordinates x = q_ic
(plus q_vd, below):

    x_{n+1} = x_n + h v_n + h^2 (1/2 - beta) a~_n + h^2 beta a~_{n+1}
    v_{n+1} = v_n + h (1 - gamma) a~_n + h gamma a~_{n+1}
    (1 - alpha_m) a~_{n+1} + alpha_m a~_n = (1 - alpha_f) a_{n+1} + alpha_f a_n
    a_{n+1} = qdd_x(t_{n+1}, q_{n+1}, qd_{n+1})        from (8)

with alpha_m = (2 rho - 1)/(rho + 1), alpha_f = rho/(rho + 1), gamma = 1/2 + alpha_f - alpha_m,
beta = (gamma + 1/2)^2 / 4: second-order accurate, unconditionally stable, and the spectral radius at
infinite frequency is rho (rho = 1: no dissipation; rho < 1 damps the modes with omega h >> 1, while
the slow motion is unaffected to second order).  The holonomically dependent coordinates are never
integrated: q_hd comes from the position constraints and qd_dc from (7) at every evaluation, so the
constraints hold to the Newton tolerance at every step, with no drift.  A coordinate made dependent
by a first-order constraint (q_vd) has no position constraint: its position is integrated with the
formulas above (x = (q_ic, q_vd)), its velocity comes from the constraints.

The nonlinear step equation for a_{n+1} is solved by a modified Newton method on the residual of (8),
P^T (M qdd + h - Q) with qdd = B a_ic + e (from inverse dynamics, without forming M), whose iteration
matrix is M_r + beta' K_r + gamma' D_r (B^T M B, B^T K B, B^T D B at the start of the step: reduced
mass, spring stiffness and damping; beta' = h^2 beta (1 - alpha_f)/(1 - alpha_m), gamma' = h gamma
(1 - alpha_f)/(1 - alpha_m)): exact for the stiff linear springs, approximate for gravity, velocity and
constraint-curvature terms, so each correction shrinks the next by a factor of about 1e-3; the q_vd
accelerations are iterated as a fixed point.  Each evaluation's correction is applied, and the step
ends at the state of the corrected accelerations: after at least ``evaluations`` evaluations, once the
last correction in velocities (gamma' |da|) is at most ``tolerance`` [rad/s or m/s] (the error left
is then about 1e-3 of it).  The bound is on velocities, not positions: a velocity error persists and
makes the positions drift, for ever on the undamped crane.

Two uses (printed by benchmarks/bench_core.py, [iterations]): the online default,
:data:`EVALUATIONS` evaluations with the loose :data:`ONLINE_TOLERANCE` (a fixed cost per step, the
controller-band accuracy of the converged iteration), and a converged iteration (``tolerance`` 1e-9 or
below, ``evaluations`` 2) for offline studies of the discrete method itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..dynamics import kernels
from ..dynamics.structures import AlphaSettings, StepRows
from .programmed_motion import MotionSolution, ProgrammedMotion, ProjectionError

EVALUATIONS = 3
"""Newton evaluations per step of the online default: with two, the velocity error left per step
(~1e-3 of the second correction) drifts psi2 by about 1e-4 rad over 10 s; with three it is at the
level of the converged iteration (benchmarks/bench_core.py, [iterations])."""

ONLINE_TOLERANCE = 1e-4
"""[rad/s or m/s]: after :data:`EVALUATIONS` evaluations, a step goes on only while its last velocity
correction is larger than this (rare: sudden target changes, drive jumps)."""

PROJECTION_TOLERANCE = 1e-9
"""Newton on the position constraints inside a step stops after a correction of at most this [rad]:
Newton converges quadratically, so the residual left is ~|Phi_qq| 1e-18, far below 1e-15 m; the
velocities and (8) are then evaluated at the projected q itself."""


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
    """Integrator state at t: full q, qd, the solution of (8) there and the pseudo-acceleration a~ of
    the integrated coordinates (:attr:`ProgrammedMotion.integrated`)."""

    t: float
    q: np.ndarray
    qd: np.ndarray
    solution: MotionSolution
    pseudo_acceleration: np.ndarray

    @property
    def qdd(self) -> np.ndarray:
        return self.solution.qdd


class GeneralizedAlpha:
    """Generalized-alpha stepper for a :class:`ProgrammedMotion` (one compiled call per step)."""

    def __init__(self, motion: ProgrammedMotion, rho_inf: float = 0.8, tolerance: float = ONLINE_TOLERANCE,
                 max_iterations: int = 30, evaluations: int = EVALUATIONS):
        self.motion = motion
        self.coefficients = GeneralizedAlphaParameters.from_spectral_radius(rho_inf)
        self.evaluations = evaluations
        self.tolerance = tolerance
        self.max_iterations = max_iterations
        self.last_iterations = 0
        """Newton iterations of the last step (a diagnostic)."""

    @property
    def settings(self) -> AlphaSettings:
        """The method and its stopping rules in the layout of the compiled kernels."""
        c = self.coefficients
        return AlphaSettings(c.alpha_m, c.alpha_f, c.gamma, c.beta, self.evaluations, self.tolerance,
                             self.max_iterations, PROJECTION_TOLERANCE)

    def start(self, t: float, q: np.ndarray, qd: np.ndarray) -> StepState:
        """Consistent start: q_dc from the position constraints, qd_dc from (7), qdd from (8)."""
        q, kinematics = self.motion.project_positions(t, q)
        qd = self.motion.dependent_velocities(t, q, qd, kinematics)
        solution = self.motion.solve(t, q, qd)
        return StepState(t, q, qd, solution, solution.qdd[self.motion.integrated].copy())

    def restart(self, state: StepState) -> StepState:
        """Re-solve (8) at ``state`` with the drive's value from t on (after a jump) and restart the
        method's acceleration history there (a~ = a), as at a start."""
        solution = self.motion.solve(state.t, state.q, state.qd)
        return StepState(state.t, state.q, state.qd, solution, solution.qdd[self.motion.integrated].copy())

    def step(self, state: StepState, t1: float, ends_on_jump: bool = False) -> StepState:
        """Advance ``state`` to time t1 > state.t [s] (one step of :meth:`run`).  A step ending on a drive
        jump (``ends_on_jump``) uses the drive's left limit there; continue with :meth:`restart` at the jump."""
        return self.run(state, np.array([t1], dtype=float), ends_on_jump)[0]

    def run(self, state: StepState, times: np.ndarray, ends_on_jump: bool = False) -> tuple[StepState, StepRows]:
        """Advance ``state`` through the increasing ``times`` [s] in one compiled call (the steps of
        :meth:`step`); the last one ends on a drive jump with ``ends_on_jump``.  Returns the final state
        and the per-step rows."""
        motion = self.motion
        drive = motion.dynamics.drive
        times = np.asarray(times, dtype=float)
        drives = drive.kernel_parameters(times)
        if ends_on_jump:
            drives[-1] = drive.kernel_parameters(times[-1], left_limit=True)
        previous = state.solution
        run = kernels.generalized_alpha_run(
            state.q, state.qd, previous.qdd, state.pseudo_acceleration, previous.dynamics.M, previous.velocity_map,
            state.t, times, motion.constraints.coefficients_at(times), drives,
            motion.partition, motion.dynamics.chain, self.settings)
        self._check(run.status, times[run.completed - 1] if run.completed else state.t,
                    times[min(run.completed, len(times) - 1)])
        rows = run.rows
        motion.check_singularity(float(np.min(rows.accounts[:, 6])))
        self.last_iterations = int(rows.iterations[-1])
        return StepState(float(times[-1]), rows.q[-1], rows.qd[-1],
                         motion.solution_from_evaluation(run.last.evaluation), run.last.pseudo_acceleration), rows

    def _check(self, status: int, t0: float, t1: float) -> None:
        """Raise for a step from t0 to t1 that did not converge (status 1) or could not meet the
        constraints (status 2)."""
        if status == 2:
            raise ProjectionError(f"position or velocity constraints cannot be met at t = {t1:.6g} s: the target is "
                                  "not reachable")
        if status == 1:
            raise IntegrationError(f"generalized-alpha step from t = {t0:.6g} s with h = {t1 - t0:g} s did not "
                                   f"converge in {self.max_iterations} iterations")

"""Time integration of the programmed motion: the trapezoidal rule with exact modal frequencies.

Why this scheme.  The RFE springs put constrained natural frequencies far above the step's into the
crane, and the undamped torque steps excite them; the boom keeps vibrating for ever, and that vibration
is what the paper studies.  Any second-order scheme (generalized-alpha, the trapezoidal or the midpoint
rule) turns a mode of frequency omega by omega h (1 - O((omega h)^2)) per step.  On the crane that error
matters far beyond its size: along the ellipse the modes pass through internal resonances (2 f9 = f8 +
f10 of the column-slew, torsion and luffing-bending modes, and f9 + f10 = f11), where the energy that the
large column-slew vibration hands to the luffing bending depends on the modes' relative phases.  Shifted
frequencies shift those resonances and pump the luffing vibration (with or without numerical damping,
converged Newton or not), while numerical damping that hides it removes the vibration the paper is
about.  The README's method section gives the evidence (benchmarks/bench_accuracy.py, [mechanism]).

The method.  On the integrated coordinates x = q_ic (plus q_vd, below) the trapezoidal rule

    x_{n+1} = x_n + h v_n + h^2/4 (a_n + a_{n+1}),   v_{n+1} = v_n + h/2 (a_n + a_{n+1}),

with a_{n+1} solving the residual of (8) at t_{n+1}, corrected per mode:

    P^T (M qdd + h - Q) - Delta M_r a_ic + D_u v_ic = 0.

Every spring of the model (supports, RFE, the drive) acts on independent coordinates, so the reduced
stiffness K_r is constant, and the configuration dependence sits in the reduced mass M_r = B^T M B.  For
the modes K_r phi_i = omega_i^2 M_r phi_i (Phi^T M_r Phi = I) the trapezoidal rule with the mass
m_i (1 - c_i) turns mode i by 2 arctan(omega_hat_i h / 2) per step, omega_hat_i^2 = omega_i^2 / (1 - c_i);
c_i = 1 - ((omega_i h / 2) / tan(omega_i h / 2))^2 makes that exactly omega_i h (the bilinear transform
with pre-warping of digital filter design, per mode), i.e. Delta M_r = M_r Phi diag(c) Phi^T M_r.  The
linear spring-mass part is then exact at the steps in amplitude and phase, with no numerical damping;
the slow motion (omega h -> 0, c -> 0) keeps the trapezoidal rule's second order, and so do the gravity,
velocity and constraint terms.  Velocities of a vibrating mode come out larger than the exact ones by
tan(omega h / 2) / (omega h / 2) (the positions are exact).  With the model's damping D (modal damping
d_i = phi_i^T D_r phi_i) the same idea maps both roots lambda of each mode exactly: the rule turns a root
lambda_hat of its equation into z = (1 + lambda_hat h / 2) / (1 - lambda_hat h / 2), which is exp(lambda h)
for lambda_hat = (2 / h) tanh(lambda h / 2), and a mass and a damping correction per mode make those the
roots (:func:`crane_reference.dynamics.modal_correction.modal_correction`): each damped mode turns and decays per
step as the model's does.

Modes with omega h at or above the cutoff (0.8 pi: the output sampled every step cannot show them; at h = 1 ms those
above 400 Hz) cannot be turned exactly (tan has a pole at pi) and are not resolved, nor are modes above the resolved
bandwidth (:data:`RESOLVED_BANDWIDTH`: those the node's step resolves, up to 800 Hz): a step h resolves the modes
below omega_c = min(cutoff / h, bandwidth)
(:func:`~crane_reference.dynamics.modal_correction.cutoff_angular_frequency`).  The velocities of a resolved mode
come out larger than the exact ones by tan(omega h / 2) / (omega h / 2) (2.4 at 0.8 pi, 1.08 at 0.3 pi).  With the
bandwidth, every step below the node's resolves the node's modes, and a finer step converges to the same model of
them; with the cutoff alone, each finer step resolves new modes close to omega h = pi, which drifts the slow
motion's phase along the task over a minute by an amount erratic in h (docs/performance.md, "Over a minute, by
step").  An infinite bandwidth resolves every mode below the cutoff (a study of the model's high modes).  The
unresolved modes get D_u = M_r Phi_u diag(beta omega^2) Phi_u^T M_r with beta = 2 zeta / omega_c, which damps each
with the ratio zeta omega / omega_c, zeta = 1 at omega_c and more above it (they keep their static deflection), so
that no such mode rings at a frequency it does not have.  Being stiffness-proportional, that part is beta (K_r - M_r
Phi_r diag(omega_r^2) Phi_r^T M_r): the constant springs less a term of the resolved modes' rank, which an
articulated-body solve of the iteration matrix can take (docs/performance.md, "The articulated iteration matrix").

M_r moves with the configuration.  Delta M_r and D_u are computed afresh every :data:`REFRESH_INTERVAL` of motion:
from the eigenproblem of the n_ic x n_ic reduced matrices, or, from :data:`ARTICULATED_FROM` independent coordinates,
by subspace iteration from the last refresh's modes with articulated solves
(:func:`~crane_reference.dynamics.modal_correction.refreshed_correction`, which falls back to the eigenproblem); stale
ones leak damping into resolved modes, the more the lower the cutoff.  Between refreshes the resolved modes can be
tracked to the configuration every :data:`MODE_TRACKING_INTERVAL` (one shift-inverted subspace iteration from the last
ones and a Rayleigh-Ritz step, :func:`~crane_reference.dynamics.modal_correction.tracked_correction`), with Delta M_r
from them and the unresolved damping beta K_r less their part, which removes that leak: what a cutoff of 0.3 pi needs
to keep the vibration over an hour (off by default: it costs the node's solver the margin it needs,
docs/performance.md).  These terms are coefficients of the equation, like M itself: they change from the next step's
end on, and the carried accelerations are not converted (a conversion treats the slow motion's accelerations as free
vibration and kicks it at every refresh, which made the slow motion's error depend on the refresh cadence).  Only a
new equation (a start, a restart, another step size) solves its start's accelerations from the corrected equation.
Servo-constraints (P = E_ic) have no symmetric reduced mass and use the plain trapezoidal rule.

The holonomically dependent coordinates are never integrated: q_hd comes from the position constraints
and qd_dc from (7) at every evaluation, so the constraints hold to the Newton tolerance at every step,
with no drift.  A coordinate made dependent by a first-order constraint (q_vd) has no position
constraint: its position is integrated with the formulas above (x = (q_ic, q_vd)), its velocity comes
from the constraints.

The step's nonlinear equation is solved by a modified Newton method on the residual (from O(n) inverse
dynamics, without forming M), from the accelerations of the integrated coordinates at the two previous
steps' starts and this one's extrapolated quadratically, a_1 = 3 a_0 - 3 a_-1 + a_-2
(:func:`~crane_reference.dynamics.step.predicted_accelerations`; linearly, or a_0 itself, after a start,
a restart or a new step size, until there are three), with the iteration matrix B^T (M + h^2/4 K + h/2 D) B -
Delta M_r + h/2 D_u with M and B at the step's predicted end (its first iterate): exact for the stiff
linear springs, to first order in h for the configuration's change over the step, approximate for gravity,
velocity and constraint-curvature terms, so each correction shrinks the next by a factor of about 1e-3
(taken at the step's start instead, an error of the slewing accelerations comes back as a boom-tip bending
correction of the same size); the q_vd accelerations are iterated as a fixed point. Each evaluation's
correction is applied, and the step ends at the state of the corrected accelerations: after at least
``evaluations`` evaluations, once the last correction in velocities (h/2 |da|) is at most ``tolerance``
[rad/s or m/s].

Two uses (benchmarks/bench_accuracy.py): the online default, :data:`EVALUATIONS` evaluations with the
loose :data:`ONLINE_TOLERANCE`, and a converged iteration (``tolerance`` 1e-9 or below, ``evaluations``
2) for studies of the discrete method itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..dynamics.modal_correction import corrected_accelerations, cutoff_angular_frequency, no_correction
from ..dynamics.runs import integration_run
from ..dynamics.structures import (
    CONSTRAINTS_UNSOLVABLE,
    CONVERGED,
    SINGULAR_VALUE,
    STATUS_MESSAGES,
    ModalCorrection,
    StepRows,
    StepSettings,
    StepStart,
)
from .programmed_motion import MotionSolution, ProgrammedMotion, ProjectionError
from .steps import ONLINE_STEP

EVALUATIONS = 2
"""Newton evaluations per step of the online default (benchmarks/bench_accuracy.py, [iterations]): from the
extrapolated predictor, two leave the converged iteration's error on the controller band."""

ONLINE_TOLERANCE = 1e-4
"""[rad/s or m/s]: after :data:`EVALUATIONS` evaluations, a step goes on only while its last velocity
correction is larger than this (rare: sudden target changes, drive jumps)."""

PROJECTION_TOLERANCE = 1e-9
"""Newton on the position constraints inside a step stops after a correction of at most this [rad]:
Newton converges quadratically, so the residual left is ~|Phi_qq| 1e-18, far below 1e-15 m; the
velocities and (8) are then evaluated at the projected q itself."""

REFRESH_INTERVAL = 0.01
"""[s] of motion after which the modal correction is computed again at the current configuration."""

CUTOFF = 0.8 * math.pi
"""omega h [rad] from which a mode counts as not resolved by the step (damped, not turned exactly)."""

RESOLVED_BANDWIDTH = CUTOFF / ONLINE_STEP
"""[rad/s] (2 pi 800 Hz) from which a mode counts as not resolved by any step: those the node's step resolves."""

MODE_TRACKING_INTERVAL = math.inf
"""[s] of motion after which the resolved modes are tracked to the configuration between refreshes
(:func:`~crane_reference.dynamics.modal_correction.tracked_correction`; 0: every step, inf: never)."""

ARTICULATED_FROM = 60
"""Independent coordinates from which the Newton iteration matrix is solved by the articulated-body recursion and
Woodbury's identity (:mod:`~crane_reference.dynamics.iteration_matrix`), O(n) in the chain, instead of formed and
factored densely, O(n^3): where the articulated one is the cheaper (docs/performance.md, "The articulated
iteration matrix")."""

UNRESOLVED_DAMPING = 1.0
"""Damping ratio given to a mode the step does not resolve at omega_c; above it the ratio grows as omega."""

METHOD = "trapezoidal rule with exact modal frequencies (crane_reference.motion.integration)"
"""How reports name the method."""


def resolved_below(step: float) -> float:
    """[Hz]: the package's integrator at ``step`` [s] turns the modes below this at their own frequencies and damps
    those above (:data:`CUTOFF`, :data:`RESOLVED_BANDWIDTH`)."""
    return cutoff_angular_frequency(step, CUTOFF, RESOLVED_BANDWIDTH) / (2.0 * math.pi)


class IntegrationError(RuntimeError):
    """A step of the integrator did not converge."""


def stop_flag() -> np.ndarray:
    """A stop flag for :meth:`ExactFrequencyTrapezoidal.run`, cleared: one byte (uint8), nonzero to stop; any
    such byte array works, e.g. one over shared memory that another process sets."""
    return np.zeros(1, dtype=np.uint8)


@dataclass(frozen=True)
class StepState:
    """Integrator state at t: full q, qd, the solution of (8) there, the modal correction in use and the
    integrated coordinates' accelerations at the two previous steps' starts (2, n_x; NaN where unknown: the
    predictor's, :func:`~crane_reference.dynamics.step.predicted_accelerations`)."""

    t: float
    q: np.ndarray
    qd: np.ndarray
    solution: MotionSolution
    correction: ModalCorrection
    earlier: np.ndarray

    @property
    def qdd(self) -> np.ndarray:
        return self.solution.qdd

    def step_start(self) -> StepStart:
        """The state as the compiled steps start from it."""
        return StepStart(self.t, self.q, self.qd, self.solution.qdd, self.solution.velocity_map, self.earlier,
                         self.correction)


class ExactFrequencyTrapezoidal:
    """The trapezoidal rule with exact modal frequencies for a :class:`ProgrammedMotion` (one compiled
    call per run of steps)."""

    def __init__(self, motion: ProgrammedMotion, tolerance: float = ONLINE_TOLERANCE, max_iterations: int = 30,
                 evaluations: int = EVALUATIONS, modal: bool = True):
        self.motion = motion
        self.modal = modal
        """False: the plain trapezoidal rule (no modal correction), for comparison."""
        self.refresh_interval = REFRESH_INTERVAL
        """[s] of motion after which the modal correction is computed again."""
        self.cutoff = CUTOFF
        """omega h [rad] from which a mode is not resolved (damped, not turned exactly)."""
        self.resolved_bandwidth = RESOLVED_BANDWIDTH
        """[rad/s] from which a mode is not resolved at any step (inf: the cutoff alone decides)."""
        self.mode_tracking_interval = MODE_TRACKING_INTERVAL
        """[s] of motion after which the resolved modes are tracked to the configuration between refreshes."""
        self.articulated = len(motion.independent) >= ARTICULATED_FROM
        """Whether the Newton iteration matrix is solved by the articulated-body recursion (else densely)."""
        self.subspace_refresh = self.articulated
        """Whether a refresh iterates the last modes by articulated solves (else solves the full eigenproblem)."""
        self.evaluations = evaluations
        self.tolerance = tolerance
        self.max_iterations = max_iterations
        self.last_iterations = 0
        """Newton iterations of the last step (a diagnostic)."""

    @property
    def settings(self) -> StepSettings:
        """The method and its stopping rules in the layout of the compiled kernels."""
        return StepSettings(self.evaluations, self.tolerance, self.max_iterations, PROJECTION_TOLERANCE,
                            self.refresh_interval, self.cutoff, self.resolved_bandwidth, UNRESOLVED_DAMPING,
                            self.mode_tracking_interval, self.modal, self.articulated, self.subspace_refresh)

    def _fresh(self) -> ModalCorrection:
        """No modal correction yet: the first step computes it."""
        return no_correction(len(self.motion.independent))

    def no_earlier(self) -> np.ndarray:
        """No earlier accelerations (a start, a restart: the predictor begins anew)."""
        return np.full((2, len(self.motion.partition.integrated)), np.nan)

    def start(self, t: float, q: np.ndarray, qd: np.ndarray) -> StepState:
        """Consistent start: q_dc from the position constraints, qd_dc from (7), qdd from (8)."""
        q, kinematics = self.motion.project_positions(t, q)
        qd = self.motion.dependent_velocities(t, q, qd, kinematics)
        solution = self.motion.solve(t, q, qd)
        return StepState(t, q, qd, solution, self._fresh(), self.no_earlier())

    def resolve(self, state: StepState, keep_modes: bool = False) -> StepState:
        """Re-solve (8) at ``state`` with the drive's value from t on (after a jump) or under new
        constraints, as at a start; with ``keep_modes`` (the configuration did not move, only the forces
        jumped, e.g. a controller's new command) the modal correction in use is kept and the accelerations
        are those of the corrected equation under the new forces, which saves its eigenproblem."""
        solution = self.motion.solve(state.t, state.q, state.qd)
        if not keep_modes or not math.isfinite(state.correction.time):
            return StepState(state.t, state.q, state.qd, solution, self._fresh(), self.no_earlier())
        qdd = corrected_accelerations(solution.dynamics.M, solution.velocity_map, solution.qdd, state.qd,
                                              state.correction, self.motion.partition)
        return StepState(state.t, state.q, state.qd, replace(solution, qdd=qdd), state.correction, self.no_earlier())

    def failure(self, status: int, t0: float, t1: float) -> Exception:
        """The error of a step from t0 to t1 [s] that ended with ``status`` (:data:`STATUS_MESSAGES`)."""
        message = STATUS_MESSAGES[status].format(t0=t0, t1=t1, h=t1 - t0, iterations=self.max_iterations)
        return ProjectionError(message) if status == CONSTRAINTS_UNSOLVABLE else IntegrationError(message)

    def _unsolvable_step(self, state: StepState, times: np.ndarray, ends_on_jump: bool,
                         error: np.linalg.LinAlgError) -> IntegrationError:
        """The error of a run that met a linear system it cannot solve (a singular K_dc, an indefinite
        iteration matrix), naming the step: the run's steps taken again one by one (they are deterministic)."""
        if times.size == 1:
            return IntegrationError(f"the step from t = {state.t:.6g} s with h = {times[0] - state.t:g} s met a "
                                    f"linear system it cannot solve: {error}")
        at = state
        for k in range(times.size):
            try:
                at = self.step(at, float(times[k]), ends_on_jump and k == times.size - 1)
            except (IntegrationError, ProjectionError) as failure:
                return failure
        return IntegrationError(f"the steps from t = {state.t:.6g} s to {times[-1]:.6g} s: {error}")

    def step(self, state: StepState, t1: float, ends_on_jump: bool = False) -> StepState:
        """Advance ``state`` to time t1 > state.t [s] (one step of :meth:`run`).  A step ending on a drive
        jump (``ends_on_jump``) uses the drive's left limit there; continue with :meth:`resolve` at the jump."""
        return self.run(state, np.array([t1], dtype=float), ends_on_jump)[0]

    def run(self, state: StepState, times: np.ndarray, ends_on_jump: bool = False,
            every_row: bool = True, stop: np.ndarray | None = None) -> tuple[StepState, StepRows]:
        """Advance ``state`` through the increasing ``times`` [s] in one compiled call (the steps of
        :meth:`step`); the last one ends on a drive jump with ``ends_on_jump``.  Returns the final state
        and the per-step rows, each with its full evaluation (reactions, residuals, accounts), or with
        ``every_row`` False only the last (the others read later with
        :meth:`~.programmed_motion.ProgrammedMotion.evaluated_rows`).  ``stop``, a flag of one byte that
        another thread or process may set meanwhile (:func:`stop_flag`), ends the run after the step in
        progress: then the state and rows are those of the steps taken, at least one."""
        motion = self.motion
        drive = motion.dynamics.drive
        times = np.asarray(times, dtype=float)
        drives = drive.kernel_parameters(times)
        if ends_on_jump:
            drives[-1] = drive.kernel_parameters(times[-1], left_limit=True)
        try:
            run = integration_run(state.step_start(), times, motion.constraints.coefficients_at(times), drives,
                                  motion.partition, motion.dynamics.chain, self.settings,
                                  np.full(times.size, every_row), stop_flag() if stop is None else stop)
        except np.linalg.LinAlgError as error:
            raise self._unsolvable_step(state, times, ends_on_jump, error) from error
        if run.status != CONVERGED:
            t0 = times[run.completed - 1] if run.completed else state.t
            raise self.failure(run.status, t0, times[min(run.completed, len(times) - 1)])
        rows = run.rows if run.completed == times.size else StepRows(*(a[:run.completed] for a in run.rows))
        motion.check_singularity(float(np.min(rows.accounts[:, SINGULAR_VALUE])))
        self.last_iterations = int(rows.iterations[-1])
        last = run.last
        return StepState(float(times[run.completed - 1]), rows.q[-1], rows.qd[-1],
                         motion.solution_from_evaluation(last.evaluation), last.correction, last.earlier), rows

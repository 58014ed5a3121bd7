"""Online reference: the programmed motion computed ahead of time and served at any instant.

Two clocks appear here.  *Publish time* tau [s] counts from the stream's (re)start and includes time
spent paused; every method takes publish times.  *Motion time* t = tau - (time paused) is the time
of the programmed motion (the drive's torque profile and the z quintic run on it).

* :meth:`ReferenceStream.compute` advances the integrator (never raises: a solver failure or a
  singular task switches the stream to ``ERROR`` and holds the last valid reference).
* :meth:`ReferenceStream.sample` interpolates the computed motion (cubic Hermite in q with qd, and in
  qd with qdd; E's pose from the kinematics at the interpolated q).  Held samples (paused or error)
  keep the position and have zero velocity and acceleration.
* :meth:`ReferenceStream.retarget` changes the ellipse or z target from a grid instant at or after
  the given time: the motion computed beyond it is discarded and the constraint parameters move to the
  new values along a C2 quintic blend (:class:`~crane_reference.profiles.Blend`), so q, qd and qdd
  stay continuous and E reaches the new ellipse / height when the blend ends.
"""

from __future__ import annotations

import bisect
import math
import time
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from ..model.parameters import CraneParameters, FlexibleDrive, Task, TorqueDrive
from ..model.profiles import Blend, Constant, Profile, QuinticRise
from ..motion.constraints import ConstraintSet, EllipseXY, HeightZ, paper_constraints
from ..motion.equilibrium import static_equilibrium
from ..motion.integration import IntegrationError
from ..motion.programmed_motion import ConstraintSingularityError, ProgrammedMotion, ProjectionError
from ..motion.simulation import MotionStepper, Scenario
from ..motion.trajectory import generalized_effort, unstack_samples

RUNNING, PAUSED, ERROR = "RUNNING", "PAUSED", "ERROR"
CHUNK_STEPS = 20
"""Steps computed per compiled run; the wall budget of :meth:`ReferenceStream.compute` is checked between runs."""
SOLVER_FAILURES = (ConstraintSingularityError, ProjectionError, IntegrationError, np.linalg.LinAlgError,
                   FloatingPointError)


class UnreachableTargetError(ValueError):
    """A requested ellipse / z target leaves the crane's workspace (or comes too near a singularity)."""


@dataclass(frozen=True)
class TaskTargets:
    """The programmed constraints' parameters: ellipse semi-axes a, b [m]; E's final height
    z_E,s + z_increment [m], approached along the quintic (5.2) over rise_time t_c [s]."""

    ellipse_a: float
    ellipse_b: float
    z_increment: float
    rise_time: float

    @classmethod
    def from_task(cls, task: Task) -> TaskTargets:
        return cls(task.ellipse_a, task.ellipse_b, task.z_increment, task.rise_time)


@dataclass(frozen=True)
class ReferenceSample:
    """One instant of the reference (units SI, world frame {0}); ``t`` is motion time."""

    t: float
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    effort: np.ndarray
    ee_position: np.ndarray
    ee_quaternion: np.ndarray
    residual_distance: float
    held: bool


def _settled(profile: Profile, t: float) -> Profile:
    """Drop blends that have finished by t, so repeated re-targeting does not nest profiles forever."""
    while isinstance(profile, Blend) and t >= profile.t0 + profile.duration:
        profile = profile.new
    return profile


class ReferenceStream:
    """The programmed motion of one crane variant, computed ahead and sampled on demand."""

    def __init__(self, params: CraneParameters, variant: str = "flexible", step: float = 1e-3,
                 blend_time: float = 2.0, targets: TaskTargets | None = None,
                 drive: TorqueDrive | FlexibleDrive | None = None, rho_inf: float = 0.8,
                 singular_value_margin: float = 0.1):
        self.params = params if drive is None else replace(params, drive=drive)
        self.targets = targets or TaskTargets.from_task(params.task)
        self.scenario = Scenario(self.params, variant, self._task(self.targets))
        self.model = self.scenario.model
        self.joint_names = self.model.joint_names
        self.step = step
        self.rho_inf = rho_inf
        self.singular_value_margin = singular_value_margin
        self.set_blend_time(blend_time)
        self.restart()

    @staticmethod
    def _task(targets: TaskTargets) -> Task:
        return Task(targets.ellipse_a, targets.ellipse_b, targets.z_increment, targets.rise_time)

    # -- clocks and state ---------------------------------------------------------------------------

    def restart(self, tau: float = 0.0) -> None:
        """Back to the static-equilibrium start of the current targets; motion time 0 at publish time tau."""
        constraints = self._target_constraints(self.targets)
        motion = ProgrammedMotion(self.scenario.dynamics, constraints, min_singular_value=1e-3)
        start = static_equilibrium(motion, self.model.initial_q).q
        self._stepper = MotionStepper(motion, 0.0, start, np.zeros_like(start), self.step, self.rho_inf)
        self._history = [self._stepper.snapshot()]
        self._times = [0.0]
        self._origin = tau
        self._paused_total = 0.0
        self._pause_started: float | None = None
        self._hold: ReferenceSample | None = None
        self.state = RUNNING
        self.last_error = ""

    def motion_time(self, tau: float) -> float:
        """Motion time at publish time tau."""
        if self._pause_started is not None:
            tau = self._pause_started
        return tau - self._origin - self._paused_total

    @property
    def computed_until(self) -> float:
        """Publish time up to which samples are available (infinite while held)."""
        if self.state != RUNNING:
            return math.inf
        return self._times[-1] + self._origin + self._paused_total

    def set_blend_time(self, seconds: float) -> None:
        if not (math.isfinite(seconds) and seconds > 0.0):
            raise ValueError(f"blend_time = {seconds}: must be a finite number > 0 s")
        self.blend_time = seconds

    def pause(self, tau: float) -> None:
        """Hold the reference at publish time tau (zero velocity; the position does not jump)."""
        if self.state == RUNNING:
            self._hold = self._held(self.sample(tau))
            self._pause_started = tau
            self.state = PAUSED

    def resume(self, tau: float) -> None:
        """Continue the motion from where it was paused (motion time resumes at the paused instant)."""
        if self.state == PAUSED:
            self._paused_total += tau - self._pause_started
            self._pause_started = None
            self._hold = None
            self.state = RUNNING

    # -- computing and sampling ---------------------------------------------------------------------

    def compute(self, until: float, wall_budget: float | None = None) -> None:
        """Advance the solver until samples up to publish time ``until`` are available, or until
        ``wall_budget`` seconds of wall time are spent.  Failures switch to ERROR and hold."""
        if self.state != RUNNING:
            return
        deadline = None if wall_budget is None else time.perf_counter() + wall_budget
        target = until - self._origin - self._paused_total
        while self._times[-1] < target:
            if deadline is not None and time.perf_counter() > deadline:
                return
            try:
                chunk_end = min(target, self._times[-1] + CHUNK_STEPS * self.step)
                rows = self._stepper.advance_until(max(chunk_end, self._times[-1] + 0.5 * self.step))
                if not (np.all(np.isfinite(rows["q"])) and np.all(np.isfinite(rows["qd"]))):
                    raise FloatingPointError(f"non-finite state before t = {rows['t'][-1]:.6g} s")
            except SOLVER_FAILURES as failure:
                self._fail(failure)
                return
            samples = unstack_samples(rows)
            motion = self._stepper.motion
            self._history += [(None, None, None, sample, motion) for sample in samples[:-1]]
            self._history.append(self._stepper.snapshot())
            self._times += [sample.t for sample in samples]

    def _rewind(self, k: int) -> None:
        """Forget the motion after the k-th computed instant and put the solver back there.  Instants
        inside a compiled run keep their samples only: the solver restarts from the last kept state
        before k and steps to k again, one step at a time (the same steps, bit for bit)."""
        start = max(i for i in range(k + 1) if self._history[i][0] is not None)
        self._stepper.rewind(self._history[start])
        for i in range(start + 1, k + 1):
            self._stepper.advance()
            self._history[i] = self._stepper.snapshot()
        del self._history[k + 1:]
        del self._times[k + 1:]

    def _fail(self, failure: Exception) -> None:
        last = self._history[-1][3]
        self._stepper.rewind(self._history[-1])
        self._hold = self._held(self._from_sample(last))
        self.state = ERROR
        self.last_error = f"{type(failure).__name__}: {failure}"

    def _held(self, sample: ReferenceSample) -> ReferenceSample:
        zero = np.zeros_like(sample.qd)
        return replace(sample, qd=zero, qdd=zero.copy(), held=True)

    def _from_sample(self, s) -> ReferenceSample:
        effort = generalized_effort(s.constraint_forces, s.drive_torque, self.model.drive_joint)
        quaternion = Rotation.from_matrix(s.ee_rotation).as_quat()
        return ReferenceSample(s.t, s.q, s.qd, s.qdd, effort, s.ee_position, quaternion,
                               float(np.max(s.residual_distance)), False)

    def sample(self, tau: float) -> ReferenceSample:
        """The reference at publish time tau (which must not exceed :attr:`computed_until`)."""
        if self._hold is not None:
            return self._hold
        t = self.motion_time(tau)
        if t > self._times[-1] + 1e-12:
            raise ValueError(f"t = {t:.6g} s is beyond the computed motion ({self._times[-1]:.6g} s): call compute()")
        k = min(max(bisect.bisect_right(self._times, t) - 1, 0), len(self._times) - 1)
        a = self._from_sample(self._history[k][3])
        if k + 1 == len(self._times) or t <= self._times[k] + 1e-12:
            return a
        b = self._from_sample(self._history[k + 1][3])
        h = b.t - a.t
        s = (t - a.t) / h
        h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
        q = h00 * a.q + h10 * h * a.qd + h01 * b.q + h11 * h * b.qd
        qd = h00 * a.qd + h10 * h * a.qdd + h01 * b.qd + h11 * h * b.qdd
        p, R = self.scenario.dynamics.end_effector_pose(q)
        return ReferenceSample(t, q, qd, (1 - s) * a.qdd + s * b.qdd, (1 - s) * a.effort + s * b.effort, p,
                               Rotation.from_matrix(R).as_quat(), max(a.residual_distance, b.residual_distance), False)

    def preview(self, tau: float, horizon: float, count: int) -> list[ReferenceSample]:
        """``count`` samples over (tau, tau + horizon], strictly increasing in time."""
        self.compute(tau + horizon)
        return [self.sample(min(tau + horizon * (i + 1) / count, self.computed_until)) for i in range(count)]

    def release(self, tau: float, keep: float = 1.0) -> None:
        """Forget computed states older than ``keep`` seconds before publish time tau."""
        t = self.motion_time(tau) - keep
        k = bisect.bisect_left(self._times, t) - 1
        while k > 0 and self._history[k][0] is None:  # keep a state to restart from (see _rewind)
            k -= 1
        if k > 0:
            del self._history[:k]
            del self._times[:k]

    # -- targets ------------------------------------------------------------------------------------

    def _target_constraints(self, targets: TaskTargets) -> ConstraintSet:
        return paper_constraints(Constant(targets.ellipse_a), Constant(targets.ellipse_b),
                                 QuinticRise(self.scenario.z_static, targets.z_increment, 0.0, targets.rise_time))

    def check_targets(self, targets: TaskTargets) -> None:
        """Raise :class:`UnreachableTargetError` unless E can follow the whole new ellipse at every height
        between its present target and the new final height, with the smallest singular value of K_dc
        (the task Jacobian of the dependent coordinates) above the margin.  Checked with the model's
        own position constraints: walking around the ellipse with the column azimuth, solving for the
        luff and knuckle angles by continuation from the present configuration."""
        for name in ("ellipse_a", "ellipse_b", "z_increment", "rise_time"):
            value = getattr(targets, name)
            if not math.isfinite(value):
                raise UnreachableTargetError(f"{name} = {value}: must be a finite number")
        if targets.ellipse_a <= 0 or targets.ellipse_b <= 0 or targets.rise_time <= 0:
            raise UnreachableTargetError("ellipse_a, ellipse_b and rise_time must be > 0")
        z_now = self._stepper.motion.constraints.constraints[1].z(self._times[-1])[0]
        z_end = self.scenario.z_static + targets.z_increment
        q = self.model.initial_q.copy()
        for z in np.linspace(z_now, z_end, 3):
            check = ProgrammedMotion(self.scenario.dynamics, paper_constraints(
                Constant(targets.ellipse_a), Constant(targets.ellipse_b), Constant(z)), min_singular_value=0.0)
            for phi in np.linspace(-0.5 * np.pi, 1.5 * np.pi, 145):
                x, y = targets.ellipse_a * np.cos(phi), targets.ellipse_b * np.sin(phi)
                q[self.model.drive_joint] = np.arctan2(y, x)
                where = f"ellipse point ({x:.3f}, {y:.3f}) m at z = {z:.3f} m"
                try:
                    q, (p, C) = check.project_positions(0.0, q)
                except (ProjectionError, np.linalg.LinAlgError) as failure:
                    raise UnreachableTargetError(f"{where} is out of the crane's reach") from failure
                grads = check.constraints.position_jacobian(0.0, p)
                sigma = np.linalg.svd(grads @ C[:, check.dependent], compute_uv=False)[-1]
                if not sigma >= self.singular_value_margin:
                    raise UnreachableTargetError(f"{where} is too near a stretch/fold singularity (smallest singular "
                                                 f"value of K_dc {sigma:.3g} < {self.singular_value_margin:g})")

    def retarget(self, tau: float, targets: TaskTargets, checked: bool = False) -> None:
        """Blend the constraint parameters to ``targets`` from the first computed instant at or after
        publish time tau (C2, over the blend time).  Unless the caller has just run
        :meth:`check_targets` itself (``checked``), it does so first and may raise UnreachableTargetError."""
        if not checked:
            self.check_targets(targets)
        t = self.motion_time(tau)
        self.compute(tau)
        k = min(bisect.bisect_left(self._times, t - 1e-12), len(self._times) - 1)
        self._rewind(k)
        t_b = self._times[k]
        old = self._stepper.motion.constraints.constraints
        ellipse, height = old[0], old[1]
        assert isinstance(ellipse, EllipseXY) and isinstance(height, HeightZ)
        new = self._target_constraints(targets).constraints

        def blend(old_profile: Profile, new_profile: Profile) -> Profile:
            return Blend(_settled(old_profile, t_b), new_profile, t_b, self.blend_time)

        self._stepper.retarget(ConstraintSet((
            EllipseXY(blend(ellipse.a, new[0].a), blend(ellipse.b, new[0].b)),
            HeightZ(blend(height.z, new[1].z)),
        )))
        self._history[k] = self._stepper.snapshot()
        self.targets = targets

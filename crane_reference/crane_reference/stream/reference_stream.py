"""Online reference: the programmed motion computed ahead of time and served at any instant.

Two clocks appear here.  *Publish time* tau [s] counts from the stream's (re)start and includes time
spent paused or slowed down; every method takes publish times.  *Motion time* t is the time of the
programmed motion (the drive's torque profile and the z quintic run on it); t(tau) is a
:class:`~.time_warp.TimeWarp` whose rate dt/dtau is the speed scaling in [0, 1], changed along C2 ramps
(:meth:`ReferenceStream.set_speed_scaling`; :meth:`ReferenceStream.pause` ramps it to 0 and
:meth:`ReferenceStream.resume` back), so the published position, velocity and acceleration stay continuous.

* :meth:`ReferenceStream.compute` advances the integrator into the :class:`~.history.History` (never
  raises: a solver failure or a singular task switches the stream to ``ERROR`` and holds the last
  valid reference).
* :meth:`ReferenceStream.sample` interpolates the computed motion (:func:`~.sample.between`) at t(tau)
  and scales its velocity and acceleration by the time warp (:func:`~.sample.warped`).  Held samples
  (error) keep the position and have zero velocity and acceleration.
* :meth:`ReferenceStream.retarget` changes the :class:`Task` from a computed instant at or after the
  given time: the motion computed beyond it is discarded and the constraints move to the new ones along
  a C2 blend (:func:`~.targets.blend_constraints`), so q, qd and qdd stay continuous.

The programmed constraints of a task come from ``task_constraints`` (default: the paper's ellipse and
height, :func:`~crane_reference.motion.simulation.paper_task_constraints`), with the coordinates
``dependent`` solved from them; any :class:`ConstraintSet` whose constraints have profile parameters
streams and re-targets, first-order ones included.  The stream starts from the static equilibrium
under the holonomic constraints of the set.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from ..model.chain import REVOLUTE
from ..model.description import CraneDescription
from ..model.drive import SpringDrive
from ..model.parameters import FlexibleDrive, Task, TorqueDrive
from ..motion.constraints import ConstraintSet
from ..motion.equilibrium import static_equilibrium
from ..motion.programmed_motion import ProgrammedMotion
from ..motion.simulation import SOLVER_FAILURES, MotionStepper, Scenario, TaskConstraints, paper_task_constraints
from ..motion.steps import ONLINE_STEP
from ..motion.trajectory import MotionRows
from .history import History
from .sample import ReferenceRows, ReferenceSample, between, warped
from .targets import blend_constraints, check_task
from .time_warp import TimeWarp, check_rate

RUNNING, PAUSED, ERROR = "RUNNING", "PAUSED", "ERROR"
CHUNK_STEPS = 500
"""Steps of a compiled run at most (:meth:`ReferenceStream.compute`): long runs keep the kernels' data in the
cache and Python out of the way; a stop flag ends one at the next step."""
PACE_STEPS = 10
"""Runs of at least this many steps give the pace by which :meth:`ReferenceStream.compute` sizes its runs."""
MIN_SINGULAR_VALUE = 1e-3
"""sigma_min(K_dc) below which the computed motion stops with an error (a singular task)."""


class ReferenceStream:
    """The programmed motion of one crane variant, computed ahead and sampled on demand."""

    def __init__(self, params: CraneDescription, variant: str = "flexible", step: float = ONLINE_STEP,
                 blend_time: float = 2.0, targets: Task | None = None,
                 drive: TorqueDrive | FlexibleDrive | None = None,
                 singular_value_margin: float = 0.1, task_constraints: TaskConstraints = paper_task_constraints,
                 dependent: tuple[int, ...] | None = None, speed_scaling: float = 1.0, ramp_time: float = 1.0):
        self.params = replace(params, drive=drive or params.drive)
        self.targets = targets or params.task
        self.task_constraints = task_constraints
        self.scenario = Scenario(self.params, variant, self.targets)
        self.model = self.scenario.model
        self.joint_names = self.model.joint_names
        self.dependent = tuple(self.model.dependent_joints) if dependent is None else tuple(dependent)
        self.step = step
        self.singular_value_margin = singular_value_margin
        self.blend_time = self._checked_blend_time(blend_time)
        self.speed_scaling = check_rate(speed_scaling)
        self._warp = TimeWarp(ramp_time, self.speed_scaling)
        self.restart()

    # -- clocks and state ---------------------------------------------------------------------------

    def _motion(self, constraints: ConstraintSet) -> ProgrammedMotion:
        return ProgrammedMotion(self.scenario.dynamics, constraints, self.dependent, MIN_SINGULAR_VALUE)

    def _static_start(self, constraints: ConstraintSet) -> np.ndarray:
        """The static equilibrium under the holonomic constraints of ``constraints``."""
        rows = [i for i, c in enumerate(constraints.constraints) if c.order == 0]
        holonomic = ProgrammedMotion(self.scenario.dynamics, ConstraintSet(tuple(constraints.constraints[i]
                                                                                 for i in rows)),
                                     tuple(self.dependent[i] for i in rows), MIN_SINGULAR_VALUE)
        return static_equilibrium(holonomic, self.model.initial_q).q

    def whole_turn_coordinates(self) -> np.ndarray:
        """Which coordinates matter only modulo a whole turn (2 pi rad): the revolute ones on which no spring
        acts, neither the chain's nor a spring drive's (which holds the column to its motor's angle)."""
        model = self.model
        free = np.array([joint.kind == REVOLUTE and not np.any(model.stiffness[i])
                         for i, joint in enumerate(model.joints)])
        if isinstance(self.scenario.dynamics.drive, SpringDrive):
            free[model.drive_joint] = False
        return free

    def restart(self, tau: float = 0.0, near: np.ndarray | None = None) -> None:
        """Back to the static-equilibrium start of the current targets; motion time 0 at publish time tau,
        moving at the speed scaling.  With ``near`` (q now), each of the :meth:`whole_turn_coordinates` starts
        the whole turns from its start value that are nearest ``near``: the same pose, reached the shortest
        way (the motion from it is the same, shifted by those turns)."""
        constraints = self.task_constraints(self.targets, self.scenario.z_static)
        start = self._static_start(constraints)
        if near is not None:
            turns = np.where(self.whole_turn_coordinates(), np.round((near - start) / (2.0 * np.pi)), 0.0)
            start = start + 2.0 * np.pi * turns
        self._stepper = MotionStepper(self._motion(constraints), 0.0, start, np.zeros_like(start), self.step,
                                      every_row=False)
        self._history = History(self._stepper.snapshot(), self.model.drive_joint)
        self._warp = TimeWarp(self._warp.ramp_time, self.speed_scaling, tau)
        self._hold: ReferenceSample | None = None
        self._forgotten: list[list] = []  # motion discarded by commands, freed off their critical path
        self._pace = 0.0  # wall time [s] per step of the last compiled run (0: none yet)
        self.state = RUNNING
        self.last_error = ""

    def motion_time(self, tau: float) -> float:
        """Motion time at publish time tau."""
        return self._warp.at(tau)[0]

    @property
    def target_speed(self) -> float:
        """The speed scaling the stream is at or moving to (0 while paused)."""
        return self._warp.target

    @property
    def ramp_time(self) -> float:
        return self._warp.ramp_time

    def settled_at(self) -> float:
        """Publish time at which the speed scaling reaches the rate it is moving to."""
        return self._warp.settled_at()

    @property
    def computed_until(self) -> float:
        """Publish time up to which samples are available (infinite while held, or at rest before the end
        of the computed motion)."""
        if self._hold is not None:
            return math.inf
        end = self._history.end_time
        if self._warp.target == 0.0 and end >= self.motion_time(self.settled_at()):  # the ramp to rest is computed
            return math.inf
        return self._warp.publish_time(end)

    @staticmethod
    def _checked_blend_time(seconds: float) -> float:
        if not (math.isfinite(seconds) and seconds > 0.0):
            raise ValueError(f"blend_time = {seconds}: must be a finite number > 0 s")
        return seconds

    def pause(self, tau: float) -> None:
        """Bring the motion to rest from publish time tau along a speed-scaling ramp (C2: no step in
        velocity or acceleration); returns when the ramp starts (see :class:`~.time_warp.TimeWarp`)."""
        if self.state == RUNNING:
            self._warp.set_rate(tau, 0.0)
            self.state = PAUSED

    def resume(self, tau: float) -> None:
        """Ramp the motion back to the speed scaling from publish time tau."""
        if self.state == PAUSED:
            self._warp.set_rate(tau, self.speed_scaling)
            self.state = RUNNING

    def set_speed_scaling(self, tau: float, rate: float) -> None:
        """Re-time the motion to ``rate`` in [0, 1] of its own speed from publish time tau (a C2 ramp;
        while paused, the rate resumed to)."""
        self.speed_scaling = check_rate(rate)
        if self.state == RUNNING:
            self._warp.set_rate(tau, self.speed_scaling)

    # -- computing and sampling ---------------------------------------------------------------------

    def compute(self, until: float, wall_budget: float | None = None, stop: np.ndarray | None = None) -> None:
        """Advance the solver until samples up to publish time ``until`` are available, or until about
        ``wall_budget`` seconds of wall time are spent (compiled runs of up to CHUNK_STEPS steps, each no
        longer than the budget left at the pace of the run before), or until the ``stop`` flag
        (:func:`~crane_reference.motion.integration.stop_flag`) is set, which ends a run at its next step;
        also while PAUSED, along the ramp to rest.  Failures switch to ERROR and hold."""
        if self.state == ERROR:
            return
        deadline = None if wall_budget is None else time.perf_counter() + wall_budget
        target = self.motion_time(until)
        history = self._history
        while history.end_time < target and not (stop is not None and stop[0]):
            steps = CHUNK_STEPS
            started = time.perf_counter()
            if deadline is not None:
                if started > deadline:
                    return
                if self._pace:
                    steps = max(1, min(CHUNK_STEPS, int((deadline - started) / self._pace)))
            end = history.end_time
            until = max(min(target, end + steps * self.step), end + 0.5 * self.step)
            try:
                rows = self._advance(until, stop)
            except SOLVER_FAILURES as failure:
                self._fail(failure, until)
                return
            if rows.t.size >= PACE_STEPS:  # a shorter run's fixed costs would make the pace too slow
                self._pace = (time.perf_counter() - started) / rows.t.size
            history.extend(rows, self._stepper.snapshot())

    def _advance(self, until: float, stop: np.ndarray | None = None) -> MotionRows:
        """The stepper's rows through motion time ``until`` (FloatingPointError for a non-finite state)."""
        rows = self._stepper.advance_until(until, stop)
        if not (np.all(np.isfinite(rows.q)) and np.all(np.isfinite(rows.qd))):
            raise FloatingPointError(f"non-finite state before t = {rows.t[-1]:.6g} s")
        return rows

    def free_forgotten(self) -> None:
        """Free the motion that commands discarded since the last call (a server that answers commands
        does it after answering, off their critical path)."""
        self._forgotten.clear()

    def _fail(self, failure: Exception, until: float) -> None:
        """ERROR, holding the last valid step: the failed run's steps before the failing one are taken again one
        at a time (the steps are deterministic) and kept, so none of that run's valid motion is lost."""
        history = self._history
        self._stepper.rewind(history.last_snapshot)
        try:
            while history.end_time < until:
                history.extend(self._advance(history.end_time + 0.5 * self.step), self._stepper.snapshot())
        except SOLVER_FAILURES:
            self._stepper.rewind(history.last_snapshot)
        self._hold = history.read(np.array([len(history) - 1])).rows()[0].hold()
        self.state = ERROR
        self.last_error = f"{type(failure).__name__}: {failure}"

    def sample(self, tau: float) -> ReferenceSample:
        """The reference at publish time tau (which must not exceed :attr:`computed_until`)."""
        return self.samples([tau]).rows()[0]

    def samples(self, taus) -> ReferenceRows:
        """The references at the publish times ``taus`` (none beyond :attr:`computed_until`): the computed
        steps themselves, or interpolated between two of them (:func:`~.sample.between`, all at once); in ERROR,
        the held sample at the times beyond the last valid step."""
        t, rate, rate_change = self._warp.at_times(taus)
        history = self._history
        end = history.end_time
        held = t > end + 1e-12
        if self._hold is not None and held.all():
            return ReferenceRows.repeated(self._hold, len(taus))
        if self._hold is None and held.any():
            raise ValueError(f"t = {t.max():.6g} s is beyond the computed motion ({end:.6g} s): call compute()")
        k, exact = history.locate(np.minimum(t, end))
        made = history.read(k)
        inside = np.flatnonzero(~exact)
        if inside.size:
            interpolated = between(made.take(inside), history.read(k[inside] + 1), t[inside],
                                   self.scenario.dynamics.end_effector_poses)
            for field, values in zip(made, interpolated, strict=True):
                field[inside] = values
        samples = warped(made, rate, rate_change)
        if held.any():
            for field, values in zip(samples, ReferenceRows.repeated(self._hold, int(held.sum())), strict=True):
                field[held] = values
        return samples

    def preview_times(self, taus, horizon: float, count: int) -> np.ndarray:
        """The publish times (len(taus), count) of ``count`` samples over (tau, tau + horizon] for each of ``taus``,
        increasing, none beyond :attr:`computed_until`."""
        ahead = np.asarray(taus, dtype=float)[:, None] + horizon * np.arange(1, count + 1) / count
        return np.minimum(ahead, self.computed_until)

    def preview(self, tau: float, horizon: float, count: int) -> ReferenceRows:
        """``count`` samples over (tau, tau + horizon] (:meth:`preview_times`), computed first if need be."""
        self.compute(tau + horizon)
        return self.samples(self.preview_times([tau], horizon, count)[0])

    def release(self, tau: float, keep: float = 1.0) -> None:
        """Forget computed states older than ``keep`` seconds of motion before publish time tau."""
        self._history.release(self.motion_time(tau) - keep)
        self._warp.release(tau)

    # -- targets ------------------------------------------------------------------------------------

    def check_targets(self, targets: Task) -> None:
        """Raise :class:`~.targets.UnreachableTargetError` unless the whole new ellipse is reachable, away
        from singularities, at every height from E's present one to the new final height
        (:func:`~.targets.check_task`)."""
        check_task(self.scenario, targets, float(self._history.last_snapshot.sample.ee_position[2]),
                   self.singular_value_margin)

    def retarget(self, tau: float, targets: Task, checked: bool = False, blend_time: float | None = None) -> float:
        """Blend the constraints to those of ``targets`` from the first computed instant at or after
        publish time tau (C2, over ``blend_time`` s of motion time, default the stream's blend time).  Unless the
        caller has just run :meth:`check_targets` itself (``checked``), it does so first and may raise
        UnreachableTargetError.  Returns the motion time [s] the blend begins at."""
        duration = self.blend_time if blend_time is None else self._checked_blend_time(blend_time)
        if not checked:
            self.check_targets(targets)
        t = self.motion_time(tau)
        self.compute(tau)
        k = self._history.first_at_or_after(t)
        at = self._history.instant(k)
        new = self.task_constraints(targets, self.scenario.z_static)
        self._stepper.retarget(blend_constraints(at.motion.constraints, new, at.t, duration), at.t, at.q, at.qd)
        self._forgotten.append(self._history.truncate(k))
        self._history.set_snapshot(k, self._stepper.snapshot())
        self.targets = targets
        return at.t

"""The paper's scenario and its time integration, offline (whole runs) and step by step (online).

:class:`Scenario` assembles model -> dynamics -> programmed constraints -> consistent start from a
:class:`~crane_reference.model.description.CraneDescription`.  :class:`MotionStepper` advances the integrator
(:mod:`.integration`) on a fixed grid t_k = t0 + k h, lands exactly on the drive's jumps (restarting the method
there) and accumulates the work of the drive, the constraint forces and the dampers with the trapezoidal rule
(second order, like the integrator).  :func:`simulate` runs it to an end time; :func:`simulate_reference`
integrates the same equations with scipy's DOP853 at tight tolerances (resolving every RFE mode), as
the converged reference for accuracy checks.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import replace
from itertools import pairwise
from typing import NamedTuple

import numpy as np
from scipy.integrate import solve_ivp

from ..dynamics.chain_dynamics import CraneDynamics
from ..dynamics.kinematics import forward_kinematics
from ..dynamics.structures import ACCOUNTS, DRIVE_TORQUE, POWERS
from ..model.chain import REVOLUTE, ChainModel, build_model
from ..model.config import ConfigError
from ..model.description import BASE_JOINTS, CraneDescription
from ..model.drive import make_drive
from ..model.parameters import Task
from ..model.profiles import Constant, QuinticRise
from .constraints import ConstraintSet, paper_constraints
from .equilibrium import Equilibrium, EquilibriumError, static_equilibrium
from .integration import EVALUATIONS, ONLINE_TOLERANCE, ExactFrequencyTrapezoidal, IntegrationError, StepState
from .programmed_motion import (
    ConstraintSingularityError,
    ProgrammedMotion,
    ProjectionError,
    check_dependent,
    choose_dependent,
)
from .steps import ANALYSIS_STEP, ONLINE_STEP
from .trajectory import MotionRows, MotionSample, Trajectory, make_sample

SAMPLED_ACCOUNTS = ("kinetic_energy", "potential_energy", "drive_torque", "kdc_min_singular_value")
"""Accounts a sample carries under their own names."""

VERTICAL_TOLERANCE = 1e-9
"""How far from 1 |z . axis| of a slew joint may be (:attr:`Scenario.slew`)."""
AXIS_OFFSET_TOLERANCE = 1e-9
"""How far [m] from the world z axis the slew joint's axis may pass (:attr:`Scenario.slew`)."""
Progress = Callable[[float], None]
TaskConstraints = Callable[[Task, float], ConstraintSet]
"""Builds the programmed constraints of a :class:`Task` given E's static height z_E,s [m]."""
SOLVER_FAILURES = (ConstraintSingularityError, ProjectionError, IntegrationError, EquilibriumError,
                   np.linalg.LinAlgError, FloatingPointError)
"""What a failed computation of the programmed motion raises (singular task, unreachable target, no
convergence, no static equilibrium, a singular linear system, a non-finite state)."""


def paper_task_constraints(task: Task, z_static: float) -> ConstraintSet:
    """(5.1)-(5.2): ellipse a x b and z_E,a rising by z_inc from z_E,s over [0, t_c]."""
    return paper_constraints(Constant(task.ellipse_a), Constant(task.ellipse_b),
                             QuinticRise(z_static, task.z_increment, 0.0, task.rise_time))


class Slew(NamedTuple):
    """A slew joint: E's azimuth atan2(y_E, x_E) = ``sign`` q[``joint``] + ``offset`` [rad] as the joint turns
    (``sign`` +1 where its axis points up, -1 down)."""

    joint: int
    sign: float
    offset: float


class Scenario:
    """The crane of ``params`` (``variant`` flexible or rigid) under the programmed constraints of
    ``task`` (default: the description's), started from its static equilibrium (the actuated independent
    joints held at their initial positions, E at the height z_E,s that the initial configuration gives it;
    for the paper's crane configuration (9)).  Dependent coordinates the description leaves to be chosen
    are chosen here (:func:`~.programmed_motion.choose_dependent`); named ones are checked
    (:func:`~.programmed_motion.check_dependent`): a ConfigError names the field."""

    def __init__(self, params: CraneDescription, variant: str = "flexible", task: Task | None = None):
        self.params = params
        model = build_model(params, variant)
        self.task = task or params.task
        drive = make_drive(params.drive, params.drive_start)
        dynamics = CraneDynamics(model, drive)
        self.z_static = float(dynamics.end_effector(model.initial_q)[0][2])
        constraints = paper_task_constraints(self.task, self.z_static)
        if model.dependent_joints is None:
            model = replace(model, dependent_joints=choose_dependent(dynamics, constraints, model.initial_q))
            dynamics = CraneDynamics(model, drive)
        else:
            check_dependent(dynamics, constraints, model.initial_q, model.dependent_joints)
        self.model: ChainModel = model
        self.dynamics = dynamics
        self.motion = ProgrammedMotion(self.dynamics, constraints)
        self._equilibrium: Equilibrium | None = None

    @property
    def slew(self) -> Slew:
        """The slew joint: the first independent revolute joint (the drive's, if it is one) whose axis is the
        world z axis at the initial configuration (vertical and through the origin, the ellipse's centre).
        The task checks walk the ellipse with it (:func:`crane_reference.stream.targets.check_task`);
        ConfigError naming ``links`` if the crane has none."""
        model, q = self.model, self.model.initial_q
        T, _ = forward_kinematics(np.ascontiguousarray(q, dtype=float), self.dynamics.chain.kinds,
                                  self.dynamics.chain.axes, self.dynamics.chain.origins)
        order = [model.drive_joint, *range(model.dof)]
        for k in order:
            joint = model.joints[k]
            if (joint.kind == REVOLUTE and k in self.motion.independent and joint.name not in BASE_JOINTS
                    and abs(T[k, 2, joint.axis]) >= 1.0 - VERTICAL_TOLERANCE
                    and np.hypot(T[k, 0, 3], T[k, 1, 3]) <= AXIS_OFFSET_TOLERANCE):
                p = self.dynamics.end_effector(q)[0]
                sign = float(np.sign(T[k, 2, joint.axis]))
                offset = np.arctan2(p[1], p[0]) - sign * q[k]
                return Slew(k, sign, float((offset + np.pi) % (2.0 * np.pi) - np.pi))
        raise ConfigError("links: the ellipse task needs a slew joint, a revolute joint (not a dependent one) "
                          "whose axis is the world z axis (vertical, through the ellipse's centre at x = y = 0) at the "
                          "initial configuration; the crane has none")

    @property
    def equilibrium(self) -> Equilibrium:
        """Static equilibrium at t = 0 (computed once)."""
        if self._equilibrium is None:
            self._equilibrium = static_equilibrium(self.motion, self.model.initial_q)
        return self._equilibrium


class StepperSnapshot(NamedTuple):
    """A :class:`MotionStepper` at one step: integrator state, grid index, work accounts [J], the sample
    and the programmed motion in force."""

    state: StepState
    k: int
    work: np.ndarray
    sample: MotionSample
    motion: ProgrammedMotion


class StepPlan(NamedTuple):
    """Steps planned by :meth:`MotionStepper.step_plan`: their end times [s], whether each ends on a drive jump,
    the index of the first step towards each end (and their count last), and the time [s] and grid index after
    them."""

    times: np.ndarray
    on_jump: np.ndarray
    first: np.ndarray
    t: float
    k: int


class MotionStepper:
    """Online integration (:mod:`.integration`) of a :class:`ProgrammedMotion` with work bookkeeping.

    With ``every_row`` False only the last step of each compiled run is evaluated in full: the rows'
    reactions, constraint forces, residuals and accounts but sigma_min(K_dc) are NaN elsewhere (a reader
    completes the rows it reads with :meth:`~.programmed_motion.ProgrammedMotion.evaluated_rows`), and the
    work accounts, integrals of every step's powers, are not kept (NaN)."""

    def __init__(self, motion: ProgrammedMotion, t0: float, q0: np.ndarray, qd0: np.ndarray,
                 step: float = ONLINE_STEP, tolerance: float = ONLINE_TOLERANCE, evaluations: int = EVALUATIONS,
                 every_row: bool = True):
        if not step > 0.0:
            raise ValueError(f"step = {step}: must be > 0 s")
        self.step_size = step
        self.every_row = every_row
        self.integrator = ExactFrequencyTrapezoidal(motion, tolerance=tolerance, evaluations=evaluations)
        self._t0 = t0
        self._k = 0
        self.state: StepState = self.integrator.start(t0, q0, qd0)
        self._work = np.zeros(3) if every_row else np.full(3, np.nan)
        self._breakpoints = sorted(motion.dynamics.drive.breakpoints)
        self.sample: MotionSample = make_sample(self.state.t, self.state.q, self.state.qd, self.state.solution,
                                                self._work)

    @property
    def motion(self) -> ProgrammedMotion:
        return self.integrator.motion

    def _next_times(self, t_end: float, t: float | None = None, k: int | None = None) -> tuple[np.ndarray, bool, int]:
        """Step ends from the current state (or from time t at grid index k) through the first grid time >=
        t_end, cut at the first drive jump on the way (then the last end is the jump); also whether it is cut
        and how many grid times it covers."""
        h, t, k = self.step_size, self.state.t if t is None else t, self._k if k is None else k
        slack = 1e-9 * h
        last = max(k + 1, int(np.ceil((t_end - self._t0) / h - 1e-9)))
        grid = self._t0 + np.arange(k + 1, last + 1) * h
        jump = next((b for b in self._breakpoints if t < b <= grid[-1] + slack), None)
        if jump is None:
            return grid, False, grid.size
        before = grid[grid < jump - slack]
        covered = before.size + int(before.size < grid.size and grid[before.size] <= jump + slack)
        return np.append(before, jump), True, covered

    def step_plan(self, ends: np.ndarray, after: StepPlan | None = None) -> StepPlan:
        """The steps :meth:`advance_until` would take from the current state (or from the end of the plan
        ``after``) through each of ``ends`` (increasing [s]) in turn, without taking them."""
        t, k = (self.state.t, self._k) if after is None else (after.t, after.k)
        ends = np.asarray(ends, dtype=float)
        h, slack = self.step_size, 1e-9 * self.step_size
        times, jumps, first, i = [], [], [0], 0
        while i < ends.size:
            # the ends ahead whose steps end on the grid before the next drive jump: at once, the last grid time
            # at or after each (later than the one before, or no step for it)
            lasts = np.ceil((ends[i:] - self._t0) / h - 1e-9)
            jump = min((b for b in self._breakpoints if b > t), default=np.inf)
            count = int(np.count_nonzero(self._t0 + lasts * h + slack < jump)) if ends[i] > t + slack else 0
            if count:
                grid = self._t0 + np.arange(k + 1, int(lasts[count - 1]) + 1) * h
                times.append(grid)
                jumps.append(np.zeros(grid.size, bool))
                first.extend((first[-1] + lasts[:count] - k).astype(np.int64))
                t, k, i = float(grid[-1]), int(lasts[count - 1]), i + count
                continue
            t_end, total = ends[i], first[-1]
            while t < t_end - slack:
                block, on_jump, covered = self._next_times(t_end, t, k)
                times.append(block)
                jumps.append(np.arange(block.size) == block.size - 1 if on_jump else np.zeros(block.size, bool))
                t, k, total = float(block[-1]), k + covered, total + block.size
            first.append(total)
            i += 1
        return StepPlan(np.concatenate([np.empty(0), *times]), np.concatenate([np.zeros(0, bool), *jumps]),
                        np.array(first, dtype=np.int64), t, k)

    def continue_from(self, state: StepState, k: int, work: np.ndarray, sample: MotionSample) -> None:
        """Continue from ``state`` at grid index k with the work accounts and sample there (steps taken
        elsewhere, e.g. a compiled closed loop, along a :meth:`step_plan`)."""
        self.state, self._k, self._work, self.sample = state, k, work.copy(), sample

    def advance(self) -> MotionSample:
        """One step to the next grid time, or to a drive jump before it (then restart there)."""
        self._run_block(self._t0 + (self._k + 1) * self.step_size)
        return self.sample

    def advance_until(self, t_end: float, stop: np.ndarray | None = None) -> MotionRows:
        """Steps through the first grid time >= t_end in compiled runs (cut at drive jumps, restarting
        there): their rows (none if the state is there already).  A ``stop`` flag set meanwhile
        (:func:`~.integration.stop_flag`) ends it after the step in progress (at least one is taken)."""
        blocks = []
        while self.state.t < t_end - 1e-9 * self.step_size and not (blocks and stop is not None and stop[0]):
            blocks.append(self._run_block(t_end, stop))
        return MotionRows.joined(blocks) if blocks else MotionRows.stacked([self.sample]).take(slice(0, 0))

    def _run_block(self, t_end: float, stop: np.ndarray | None = None) -> MotionRows:
        """One compiled run towards t_end, up to the first drive jump (restarting there) or a ``stop``; the
        trapezoidal work accounts; the samples' fields stacked per step."""
        start = self.state
        times, on_jump, covered = self._next_times(t_end)
        new, rows = self.integrator.run(start, times, ends_on_jump=on_jump, every_row=self.every_row, stop=stop)
        if rows.q.shape[0] < times.size:  # stopped on the way: every step taken ends on a grid time
            times, on_jump, covered = times[:rows.q.shape[0]], False, rows.q.shape[0]
        self._k += covered
        powers = np.vstack((start.solution.powers, rows.accounts[:, POWERS]))
        steps = np.diff(np.concatenate(([start.t], times)))
        work = self._work + np.cumsum(0.5 * steps[:, None] * (powers[:-1] + powers[1:]), axis=0)
        self._work = work[-1].copy()
        self.state = self.integrator.resolve(new) if on_jump else new
        self.sample = make_sample(self.state.t, self.state.q, self.state.qd, self.state.solution, self._work)
        accounts = rows.accounts.copy()
        qdd, reactions, forces = rows.qdd.copy(), rows.reactions.copy(), rows.constraint_forces.copy()
        if on_jump:  # the sample at a jump shows the motion from the jump on, as after a restart
            solution = self.state.solution
            qdd[-1], reactions[-1], forces[-1] = solution.qdd, solution.reactions, solution.constraint_forces
            accounts[-1, DRIVE_TORQUE] = solution.drive_torque
        columns = {name: accounts[:, i] for i, name in enumerate(ACCOUNTS) if name in SAMPLED_ACCOUNTS}
        return MotionRows(t=times, q=rows.q, qd=rows.qd, qdd=qdd, reactions=reactions, constraint_forces=forces,
                          ee_position=rows.ee_position, ee_rotation=rows.ee_rotation, ee_velocity=rows.ee_velocity,
                          residual=rows.residual, residual_distance=rows.residual_distance, **columns,
                          work_drive=work[:, 0], work_constraints=work[:, 1], work_damping=work[:, 2])

    def forces_changed(self) -> None:
        """The forces jumped at the current time (a new command of an :class:`~crane_reference.model.drive.Actuated`
        drive): re-solve (8) there under the forces from now on, keeping the modal correction (the
        configuration did not move); the sample shows the motion from now on."""
        self.state = self.integrator.resolve(self.state, keep_modes=True)
        self.sample = make_sample(self.state.t, self.state.q, self.state.qd, self.state.solution, self._work)

    def snapshot(self) -> StepperSnapshot:
        """Everything needed to continue from the current step later (see :meth:`rewind`)."""
        return StepperSnapshot(self.state, self._k, self._work.copy(), self.sample, self.integrator.motion)

    def rewind(self, snapshot: StepperSnapshot) -> None:
        """Return to a state saved by :meth:`snapshot` (the motion after it is recomputed)."""
        self.state, self._k, work, self.sample, self.integrator.motion = snapshot
        self._work = work.copy()

    def retarget(self, constraints: ConstraintSet, t: float, q: np.ndarray, qd: np.ndarray,
                 work: np.ndarray | None = None) -> None:
        """Continue from a computed step (t, q, qd and the work accounts [J] there, e.g. a row of
        :meth:`advance_until`; None where they are not kept, ``every_row`` False) under new constraints that
        hold there (e.g. a C2 blend that starts at t).  The method restarts there
        (:meth:`~.integration.ExactFrequencyTrapezoidal.resolve`: (8) solved again at (t, q, qd), a fresh modal
        correction), which is all a continuation under new constraints keeps of the step, so no step is
        integrated again."""
        self.integrator.motion = ProgrammedMotion(self.motion.dynamics, constraints, tuple(self.motion.dependent),
                                                  self.motion.min_singular_value)
        self._k = int(np.floor((t - self._t0) / self.step_size + 1e-9))  # grid times at or before t
        self._work = np.full(3, np.nan) if work is None else work.copy()
        self.state = self.integrator.resolve(StepState(t, q, qd, self.state.solution, self.state.correction,
                                                       self.integrator.no_earlier()))
        self.sample = make_sample(t, q, qd, self.state.solution, self._work)


def simulate(motion: ProgrammedMotion, q0: np.ndarray, t_end: float, step: float = ANALYSIS_STEP, t0: float = 0.0,
             qd0: np.ndarray | None = None, progress: Progress | None = None, chunk: float = 0.25,
             tolerance: float = ONLINE_TOLERANCE, evaluations: int = EVALUATIONS, every_row: bool = True) -> Trajectory:
    """Programmed motion from (t0, q0, qd0) to t_end with the integrator (Newton ``evaluations`` and
    ``tolerance``, see :mod:`.integration`); one sample per step, computed in compiled runs
    of ``chunk`` seconds (``progress`` is called after each).  With ``every_row`` False only the motion
    and E's pose are kept: the reactions, residuals, energies and work are NaN but at each run's last step
    (:class:`MotionStepper`)."""
    parts = []
    for part in simulated_runs(motion, q0, t_end, step, t0, qd0, chunk, tolerance, evaluations, every_row):
        parts.append(part)
        if progress is not None and len(parts) > 1:
            progress(float(part.t[-1]))
    return joined(motion, parts)


def simulated_runs(motion: ProgrammedMotion, q0: np.ndarray, t_end: float, step: float = ANALYSIS_STEP,
                   t0: float = 0.0, qd0: np.ndarray | None = None, chunk: float = 0.25,
                   tolerance: float = ONLINE_TOLERANCE, evaluations: int = EVALUATIONS,
                   every_row: bool = True) -> Iterator[MotionRows]:
    """What :func:`simulate` computes, as it is computed: the start's sample, then the samples of each compiled run
    of ``chunk`` seconds, stacked (:func:`joined` makes them the :class:`Trajectory`)."""
    qd0 = np.zeros_like(q0) if qd0 is None else qd0
    stepper = MotionStepper(motion, t0, q0, qd0, step, tolerance, evaluations, every_row)
    yield MotionRows.stacked([stepper.sample])
    while stepper.state.t < t_end - 1e-9 * step:
        yield stepper.advance_until(min(stepper.state.t + chunk, t_end))


def joined(motion: ProgrammedMotion, parts: list[MotionRows]) -> Trajectory:
    """The :class:`Trajectory` of ``motion`` from consecutive rows (:func:`simulated_runs`)."""
    model = motion.dynamics.model
    return Trajectory.from_rows(model.variant, model.joint_names, model.drive_joint, MotionRows.joined(parts))


def simulate_reference(motion: ProgrammedMotion, q0: np.ndarray, t_end: float, sample_times: np.ndarray,
                       rtol: float = 1e-10, atol: float = 1e-12, t0: float = 0.0) -> Trajectory:
    """Converged reference: DOP853 on the independent coordinates (dependent ones projected at every
    evaluation), the three work integrals as extra states, integrated piecewise between drive jumps."""
    dyn = motion.dynamics
    model = dyn.model
    ic = motion.independent
    n_ic = len(ic)
    start = ExactFrequencyTrapezoidal(motion).start(t0, q0, np.zeros_like(q0))
    guess = [start.q]

    def full_state(t: float, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = guess[0].copy()
        q[ic] = y[:n_ic]
        q, kinematics = motion.project_positions(t, q)
        guess[0] = q
        qd = np.zeros_like(q)
        qd[ic] = y[n_ic:2 * n_ic]
        return q, motion.dependent_velocities(t, q, qd, kinematics)

    edges = sorted({t0, t_end, *(b for b in dyn.drive.breakpoints if t0 < b < t_end)})
    y = np.concatenate([start.q[ic], start.qd[ic], np.zeros(3)])
    samples: list[MotionSample] = []
    for a, b in pairwise(edges):
        def rhs(t: float, y: np.ndarray, b: float = b) -> np.ndarray:
            q, qd = full_state(t, y)
            solution = motion.solve(t, q, qd, left_limit=t >= b)
            return np.concatenate([qd[ic], solution.qdd[ic], solution.powers])

        inside = sample_times[(sample_times >= a) & ((sample_times < b) | (b == edges[-1]) & (sample_times <= b))]
        result = solve_ivp(rhs, (a, b), y, method="DOP853", rtol=rtol, atol=atol, dense_output=True)
        if not result.success:
            raise RuntimeError(f"DOP853 failed on [{a}, {b}] s: {result.message}")
        for t in inside:
            ys = result.sol(t)
            q, qd = full_state(t, ys)
            samples.append(make_sample(t, q, qd, motion.solve(t, q, qd), ys[2 * n_ic:]))
        y = result.y[:, -1]
    return Trajectory.from_samples(model.variant, model.joint_names, model.drive_joint, samples)


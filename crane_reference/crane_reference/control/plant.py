"""The actuated crane: the plant a controller makes follow the reference.

The crane of a config (supports, RFE boom, payload, damping, column drive) without programmed
constraints: every coordinate is independent and nothing holds E but the crane itself, so the payload
loads the boom and the base.  Actuators add torques tau [N m, or N on a prismatic joint] on the model's
actuated joints (``ChainModel.actuated_joints``, positive along +q); on the drive's joint they act beside the
drive (for a flexible drive that is the same as offsetting the
motor angle by tau / s_dr).  The plant is integrated with the package's integrator
(:mod:`crane_reference.motion.integration`) through an :class:`~crane_reference.model.drive.Actuated`
drive: a command holds over one controller period, linear in time on it, and the integrator restarts at
its start, where the forces jump (keeping its modal correction).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..dynamics.chain_dynamics import CraneDynamics
from ..dynamics.closed_loop import closed_loop_run
from ..dynamics.evaluation import accelerations_at
from ..dynamics.structures import ACCOUNTS, CONVERGED, Accelerations, LoopRows, PlannedSteps, PlantModel, Ticks
from ..model.chain import build_model
from ..model.description import CraneDescription
from ..model.drive import Actuated, make_drive
from ..motion.constraints import ConstraintSet
from ..motion.equilibrium import static_equilibrium
from ..motion.integration import StepState
from ..motion.programmed_motion import ProgrammedMotion
from ..motion.simulation import SAMPLED_ACCOUNTS, MotionStepper, Scenario
from ..motion.trajectory import MotionRows, Trajectory, make_sample
from .controller import JointController, JointGains, bandwidth_gains


def servo_motion(scenario: Scenario) -> ProgrammedMotion:
    """The scenario's task realised by the dependent joints' torques (the paper's luff and knuckle;
    servo-constraints) instead of a force at E: the motion an actuated crane can follow exactly where that motion
    exists (the rigid boom)."""
    return ProgrammedMotion(scenario.dynamics, scenario.motion.constraints, realisation="servo")


@dataclass(frozen=True)
class HeldStart:
    """A start of the plant at rest: q and the actuator torques [N m or N] (order of the model's actuated
    joints) that hold it."""

    q: np.ndarray
    torques: np.ndarray


def held_start(scenario: Scenario) -> HeldStart:
    """Static equilibrium with E on the task's start point, the payload carried by the crane: the dependent
    joints' torques of the servo-constraint equilibrium (the paper's luff and knuckle) and the holding torques
    of the other actuated joints (the paper's column)."""
    motion = servo_motion(scenario)
    equilibrium = static_equilibrium(motion, scenario.model.initial_q)
    solution = motion.solve(0.0, equilibrium.q, np.zeros_like(equilibrium.q), left_limit=True)
    names = scenario.model.joint_names
    torques = dict(equilibrium.holding_forces)
    torques.update({names[j]: float(tau) for j, tau in zip(motion.dependent, solution.reactions, strict=True)})
    return HeldStart(equilibrium.q, np.array([torques[name] for name in scenario.model.actuated_joints]))


BANDWIDTH = 2.0
"""[Hz] the default closed-loop bandwidth of each joint (as ``crane-reference track``)."""

DAMPING_RATIO = 0.7


def held_inertia(scenario: Scenario, joints: Sequence[str], start: HeldStart | None = None) -> np.ndarray:
    """J per joint of ``joints``: the diagonal of M at the held start (``start``, default :func:`held_start`)
    [kg m^2]."""
    q = (start if start is not None else held_start(scenario)).q
    inertia = scenario.dynamics.terms(0.0, q, np.zeros_like(q)).M
    return np.array([inertia[j, j] for j in map(scenario.model.index, joints)])


def default_gains(scenario: Scenario, joints: Sequence[str]) -> list[JointGains]:
    """PD gains per joint of ``joints`` for :data:`BANDWIDTH` and :data:`DAMPING_RATIO` with J of
    :func:`held_inertia` (:func:`~.controller.bandwidth_gains`, as ``crane-reference track``)."""
    return [bandwidth_gains(J, BANDWIDTH, DAMPING_RATIO) for J in held_inertia(scenario, joints)]


class Plant:
    """The actuated crane of ``params`` (``variant`` flexible or rigid) from ``start`` at t0, integrated with
    the step ``step`` [s]; the joint drives' velocity loops add ``joint_damping`` kd [N m s/rad] (order of the
    model's actuated joints): the actuator torque is the command minus kd qd.  With ``keep`` False the run is
    not kept (a plant that runs for ever: no :meth:`trajectory`)."""

    def __init__(self, params: CraneDescription, variant: str, start: HeldStart, step: float,
                 joint_damping: np.ndarray | None = None, t0: float = 0.0, keep: bool = True):
        self.model = build_model(params, variant)
        self.drive = Actuated(make_drive(params.drive, params.drive_start), self.model.dof)
        self.actuated = np.array([self.model.index(name) for name in self.model.actuated_joints], dtype=np.int64)
        self.joint_damping = np.zeros(self.actuated.size) if joint_damping is None else np.asarray(joint_damping)
        damping = np.zeros(self.model.dof)
        damping[self.actuated] = self.joint_damping
        self.dynamics = CraneDynamics(self.model, self.drive, damping)
        motion = ProgrammedMotion(self.dynamics, ConstraintSet(()), dependent=())
        self.stepper = MotionStepper(motion, t0, start.q, np.zeros(self.model.dof), step)
        self.keep = keep
        self._samples = [MotionRows.stacked([self.stepper.sample])]
        self._torque_rows = [np.zeros((1, self.actuated.size))]

    def actuate(self, end: float, torque_start: np.ndarray, torque_end: np.ndarray) -> None:
        """Command the joint drives [N m] from now to ``end`` [s] (on the step grid), linear from
        ``torque_start`` to ``torque_end`` (their torques are these minus kd qd), and advance there."""
        start = self.stepper.state.t
        self.drive.command(start, end, self._forces(torque_start), self._forces(torque_end))
        self.stepper.forces_changed()
        if len(self._samples) == 1:  # the start's sample under the first command
            self._samples[0] = MotionRows.stacked([self.stepper.sample])
            self._torque_rows[0] = (np.asarray(torque_start, dtype=float)
                                    - self.joint_damping * self.stepper.state.qd[self.actuated])[None, :]
        rows = self.stepper.advance_until(end)
        if not self.keep:
            return
        self._samples.append(rows)
        self._torque_rows.append(self.drive.forces(rows.t)[:, self.actuated]
                                 - self.joint_damping * rows.qd[:, self.actuated])

    def follow(self, ends: np.ndarray, reference_q: np.ndarray, reference_qd: np.ndarray,
               feedforward_start: np.ndarray, feedforward_end: np.ndarray, controller: JointController) -> None:
        """Ticks of ``controller`` in one compiled call (:func:`~crane_reference.dynamics.closed_loop.closed_loop_run`):
        tick k commands, from now (then from ``ends`` [k - 1]) to ``ends`` [k] (K,) [s, on the step grid], the
        controller's u_k on the errors to ``reference_q`` [k] and ``reference_qd`` [k] (K, 3) with the
        feedforward ``feedforward_start`` [k], linear to u_k + feedforward_end[k + 1] - feedforward_start[k]
        (within the limits) at its end: the ticks of :meth:`actuate` with a :class:`JointController`, steps and
        accounts the same."""
        if len(ends) == 0:
            raise ValueError("ends: no tick; follow takes one end time [s] per tick, at least one")
        stepper, motion = self.stepper, self.stepper.motion
        plan = stepper.step_plan(ends)
        inner = self.drive.drive
        left = inner.kernel_parameters(plan.times, left_limit=True)
        after = inner.kernel_parameters(np.concatenate(([stepper.state.t], plan.times)))
        state = stepper.state
        ticks = Ticks(np.asarray(ends, dtype=float), plan.first, np.ascontiguousarray(reference_q, dtype=float),
                      np.ascontiguousarray(reference_qd, dtype=float),
                      np.ascontiguousarray(feedforward_start, dtype=float),
                      np.ascontiguousarray(feedforward_end, dtype=float))
        run = closed_loop_run(state.q, state.qd, self.terms(), state.correction, stepper.snapshot().work, state.t,
                              ticks, PlannedSteps(plan.times, plan.on_jump, left, after), self.compiled_model(),
                              controller.arrays)
        controller.ticks += run.ticks
        if run.status != CONVERGED:  # the plant stays where it was; the controller went on to the failed tick
            raise stepper.integrator.failure(run.status, run.t, float(plan.times[run.steps]))
        rows = run.rows
        if self.keep:
            self._keep(np.concatenate(([state.t], plan.times)), rows)
        solution = motion.solution_from_evaluation(run.last)
        last = StepState(run.t, rows.q[-1], rows.qd[-1], solution, run.correction, run.earlier)
        stepper.continue_from(last, plan.k, rows.work[-1], make_sample(run.t, last.q, last.qd, solution, rows.work[-1]))
        last_start = plan.first[-2]
        self.drive.command(float(plan.times[last_start - 1]) if last_start else state.t, float(ends[-1]),
                           *(self._forces(torques) for torques in run.command))

    def compiled_model(self) -> PlantModel:
        """The plant as the compiled loop steps it."""
        motion = self.stepper.motion
        return PlantModel(motion.constraints.coefficients(self.stepper.state.t), motion.partition, self.dynamics.chain,
                          self.stepper.integrator.settings, self.actuated, self.joint_damping)

    def terms(self) -> Accelerations:
        """The position and velocity terms of (8) at the plant's state now (an evaluation there, with the column
        drive's parameters of now and no actuator force)."""
        stepper, motion = self.stepper, self.stepper.motion
        state = stepper.state
        drive = np.concatenate((self.drive.drive.kernel_parameters(state.t), np.zeros(self.model.dof)))
        return accelerations_at(state.q, state.qd, motion.constraints.coefficients(state.t), drive, motion.partition,
                                self.dynamics.chain)

    def _keep(self, times: np.ndarray, rows: LoopRows) -> None:
        """Keep the rows of a :meth:`follow` (from its start, at ``times``) for :meth:`trajectory`."""
        accounts = {name: rows.accounts[:, i] for i, name in enumerate(ACCOUNTS) if name in SAMPLED_ACCOUNTS}
        empty = np.zeros((times.size, 0))
        kept = MotionRows(t=times, q=rows.q, qd=rows.qd, qdd=rows.qdd, reactions=empty,
                          constraint_forces=rows.constraint_forces,
                          ee_position=rows.ee_position, ee_rotation=rows.ee_rotation, ee_velocity=rows.ee_velocity,
                          residual=empty, residual_distance=empty, **accounts, work_drive=rows.work[:, 0],
                          work_constraints=rows.work[:, 1], work_damping=rows.work[:, 2])
        if len(self._samples) == 1:  # the start's sample under the first command
            self._samples[0] = kept.take(slice(0, 1))
            self._torque_rows[0] = rows.torques[:1]
        self._samples.append(kept.take(slice(1, None)))
        self._torque_rows.append(rows.torques[1:])

    def _forces(self, torques: np.ndarray) -> np.ndarray:
        forces = np.zeros(self.model.dof)
        forces[self.actuated] = torques
        return forces

    @property
    def t(self) -> float:
        return self.stepper.state.t

    @property
    def q(self) -> np.ndarray:
        return self.stepper.state.q

    @property
    def qd(self) -> np.ndarray:
        return self.stepper.state.qd

    def trajectory(self) -> tuple[Trajectory, np.ndarray]:
        """The run so far, one sample per step (work_drive includes the commands' work, work_damping the
        drives' velocity loops'), and the actuator torques at the samples (N, 3) [N m] (at a command's
        start: under the new command)."""
        return (Trajectory.from_rows(self.model.variant, list(self.model.joint_names), self.model.drive_joint,
                                     MotionRows.joined(self._samples)), np.concatenate(self._torque_rows))

"""A closed-loop run: the actuated crane (:mod:`crane_reference.control.plant`) made to follow the reference by
joint-space feedback (:mod:`crane_reference.control.controller`) with optional feedforward
(:mod:`crane_reference.control.feedforward`).

The reference is the programmed motion the node publishes (ideal constraints; or realised by the dependent
joints' torques, the paper's luff and knuckle, ``realisation="servo"``) of the same crane, integrated with the
node's step (``reference_step``); the controller reads it as a downstream controller does, one sample per tick:
q_ref, qd_ref of the actuated joints at t_k.  Its command holds over the period (zero-order hold; the D action
acts in the joint drives, see :mod:`crane_reference.control.controller`).  The ``rigid`` feedforward runs
linearly from its value at t_k to that at t_k+1 (the reference is known ahead, as a joint_trajectory_controller
interpolates its points); the ``reference`` feedforward, the reference's constraint forces at t_k, holds with the
command, as the example controller node adds the preview's efforts (so ``crane-reference loop --feedforward
reference`` is this loop).
The plant starts at rest, held by its actuators with E on the task's start point
(:func:`crane_reference.control.plant.held_start`).

Results (:class:`TrackingRun`): E's deviation from the programmed path (its distance to the ellipse in
XY and its height error, the task's holonomic constraints in that order, first order in their residuals:
Phi / |Phi_p|), the joint tracking
errors, the first flexible link's tip deflection (flexible model) and its 40-250 Hz RMS over the run's second half (and
the reference's own, for comparison), the actuator torques and powers, the saturated share of ticks, and
the plant's energy balance.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from ...control.controller import CONTROLLERS, JointController, JointGains, bandwidth_gains
from ...control.feedforward import FEEDFORWARDS, RigidInverseDynamics
from ...control.plant import BANDWIDTH, DAMPING_RATIO, Plant, held_inertia, held_start, servo_motion
from ...dynamics.deflection import tip_deflection
from ...interface.bringup import LoopRecording
from ...model.chain import VARIANTS
from ...model.description import CraneDescription
from ...motion.constraints import ConstraintSet
from ...motion.programmed_motion import REALISATIONS, ProgrammedMotion
from ...motion.simulation import Scenario, simulated_runs
from ...motion.steps import ONLINE_STEP, PLANT_STEP
from ...motion.trajectory import Trajectory
from ..bands import vibration_band
from .ahead import ComputedAhead


@dataclass(frozen=True)
class TrackingSpec:
    """What to run: the crane ``variant``, the reference's ``realisation``, the ``controller`` (pd or pid) with
    gains from the closed-loop ``bandwidth`` [Hz] (or ``joint_bandwidths`` by joint name) and
    ``damping_ratio`` per joint unless ``gains`` gives them by joint name, ``feedforward`` (none, rigid or
    reference), torque ``limits`` [N m] by joint name (none: no limit), the controller ``rate`` [Hz],
    ``duration`` [s] and the plant's integrator ``step`` [s]; the reference is integrated with
    ``reference_step`` [s], a divisor of ``step`` (default: the node's, ONLINE_STEP, where it divides ``step``, so
    that the reference is the node's; else ``step``)."""

    variant: str = "flexible"
    realisation: str = "ideal"
    controller: str = "pd"
    bandwidth: float = BANDWIDTH
    damping_ratio: float = DAMPING_RATIO
    joint_bandwidths: dict[str, float] = field(default_factory=dict)
    gains: dict[str, JointGains] = field(default_factory=dict)
    feedforward: str = "rigid"
    limits: dict[str, float] = field(default_factory=dict)
    rate: float = 1000.0
    duration: float = 5.0
    step: float = PLANT_STEP
    reference_step: float | None = None

    def __post_init__(self) -> None:
        for name, value, allowed in (("variant", self.variant, VARIANTS), ("realisation", self.realisation,
                                     REALISATIONS), ("controller", self.controller, CONTROLLERS),
                                     ("feedforward", self.feedforward, FEEDFORWARDS)):
            if value not in allowed:
                raise ValueError(f"{name} = {value!r}: must be one of {', '.join(allowed)}")
        for name in ("rate", "duration", "step"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} = {value}: must be a finite number > 0")
        if self.reference_step is None:
            object.__setattr__(self, "reference_step", ONLINE_STEP if _divides(ONLINE_STEP, self.step) else self.step)
        if not (self.reference_step > 0.0 and _divides(self.reference_step, self.step)):
            raise ValueError(f"reference_step = {self.reference_step} s: must divide step = {self.step} s")
        if not abs(self.steps_per_tick * self.step * self.rate - 1.0) <= 1e-9:
            raise ValueError(f"rate = {self.rate} Hz with step = {self.step} s: the controller period must be a "
                             "whole number of integrator steps")

    @property
    def steps_per_tick(self) -> int:
        return max(1, round(1.0 / (self.rate * self.step)))

    @property
    def reference_stride(self) -> int:
        """Reference steps per plant step."""
        return max(1, round(self.step / self.reference_step))

    def check_joints(self, joints: tuple[str, ...]) -> None:
        """ValueError unless the joints named in gains, limits and bandwidths are among ``joints`` (the actuated
        ones)."""
        for name in (*self.gains, *self.limits, *self.joint_bandwidths):
            if name not in joints:
                raise ValueError(f"joint {name!r} in gains or limits: must be one of {', '.join(joints)}")

    def joint_gains(self, joints: tuple[str, ...], inertia: np.ndarray) -> list[JointGains]:
        """The gains per joint of ``joints`` (the actuated ones): given, or from the bandwidth with J =
        ``inertia`` (diagonal of M)."""
        self.check_joints(joints)
        out = []
        for name, J in zip(joints, inertia, strict=True):
            limit = self.limits.get(name, math.inf)
            gains = self.gains.get(name) or bandwidth_gains(J, self.joint_bandwidths.get(name, self.bandwidth),
                                                            self.damping_ratio, self.controller == "pid")
            out.append(JointGains(gains.kp, gains.kd, gains.ki if self.controller == "pid" else 0.0, limit))
        return out


JOINT_METRICS = ("error_max_rad", "error_rms_rad", "torque_peak_nm", "power_peak_w", "saturated_share")
"""The metrics of each actuated joint in :meth:`TrackingRun.summary`, named ``<joint>_<metric>`` (on a prismatic
joint the units are m and N)."""


def summary_names(joints: tuple[str, ...]) -> tuple[str, ...]:
    """The names of :meth:`TrackingRun.summary` for a crane with the actuated ``joints``, in order."""
    return ("ellipse_distance_max_m", "ellipse_distance_rms_m", "height_error_max_m", "height_error_rms_m",
            *(f"{joint}_{metric}" for joint in joints for metric in JOINT_METRICS),
            "tip_deflection_max_m", "tip_vibration_rms_m", "reference_tip_vibration_rms_m", "energy_balance_error_j",
            "real_time_factor")


@dataclass(frozen=True)
class TrackingRun:
    """A closed-loop run: the spec, the actuated ``joints`` and their gains, the plant's trajectory and actuator
    torques (N, a) [N m] per step, the reference on the same times (its motion and E's pose; forces and energies
    not evaluated), E's distance to the programmed path (N, 2) [m] (ellipse in XY, height), the first flexible
    link's tip deflection of the plant and of the reference (N, 3) [m] (zeros for the rigid model), the saturated
    share of ticks per joint, the wall time [s] and the part of it spent in the compiled closed loop (NaN where
    not measured: a recorded run)."""

    spec: TrackingSpec
    joints: tuple[str, ...]
    gains: list[JointGains]
    plant: Trajectory
    torques: np.ndarray
    reference: Trajectory
    path_error: np.ndarray
    tip_deflection: np.ndarray
    reference_tip_deflection: np.ndarray
    saturated_share: np.ndarray
    wall: float
    loop_wall: float = math.nan

    @property
    def t(self) -> np.ndarray:
        return self.plant.t

    def joint_errors(self) -> np.ndarray:
        """q_ref - q of the actuated joints (N, a) [rad or m]."""
        columns = [self.plant.joint_names.index(name) for name in self.joints]
        return self.reference.q[:, columns] - self.plant.q[:, columns]

    def powers(self) -> np.ndarray:
        """tau qd of each actuator (N, a) [W]."""
        columns = [self.plant.joint_names.index(name) for name in self.joints]
        return self.torques * self.plant.qd[:, columns]

    def summary(self) -> dict[str, float]:
        """The metrics of the module docstring, by name (SI units in the names)."""
        late = self.t >= 0.5 * self.t[-1]
        out = {"ellipse_distance_max_m": float(np.abs(self.path_error[:, 0]).max()),
               "ellipse_distance_rms_m": float(np.sqrt(np.mean(self.path_error[:, 0] ** 2))),
               "height_error_max_m": float(np.abs(self.path_error[:, 1]).max()),
               "height_error_rms_m": float(np.sqrt(np.mean(self.path_error[:, 1] ** 2)))}
        errors, powers = self.joint_errors(), self.powers()
        for k, name in enumerate(self.joints):
            out[f"{name}_error_max_rad"] = float(np.abs(errors[:, k]).max())
            out[f"{name}_error_rms_rad"] = float(np.sqrt(np.mean(errors[:, k] ** 2)))
            out[f"{name}_torque_peak_nm"] = float(np.abs(self.torques[:, k]).max())
            out[f"{name}_power_peak_w"] = float(np.abs(powers[:, k]).max())
            out[f"{name}_saturated_share"] = float(self.saturated_share[k])
        deflection = np.linalg.norm(self.tip_deflection, axis=1)
        out["tip_deflection_max_m"] = float(deflection.max())
        for name, deflection in (("tip", self.tip_deflection), ("reference_tip", self.reference_tip_deflection)):
            vibration = vibration_band(deflection, self.spec.step)[late]
            out[f"{name}_vibration_rms_m"] = float(np.sqrt(np.mean(np.sum(vibration**2, axis=1))))
        out["energy_balance_error_j"] = float(np.abs(self.plant.energy_balance_error).max())
        out["real_time_factor"] = float(self.t[-1] / self.wall)
        return {name: out[name] for name in summary_names(self.joints)}


Progress = Callable[[float], None]
TaskMotion = Callable[[Scenario], tuple[ProgrammedMotion, np.ndarray]]
"""The programmed motion of a scenario in the spec's realisation and its start q (e.g. a study case's)."""


def run_tracking(params: CraneDescription, spec: TrackingSpec, progress: Progress | None = None,
                 task: TaskMotion | None = None) -> TrackingRun:
    """The closed-loop run of ``spec`` on the crane ``params`` (``progress`` gets the simulated time); the
    reference is the programmed motion ``task`` gives (default: the scenario's paper task).  The reference, and
    the rigid feedforward's own on a flexible crane, are computed ahead of the loop in a thread
    (:class:`~.ahead.ComputedAhead`), 0.25 s of motion at a time."""
    started = time.perf_counter()
    task = task or (lambda scenario: _paper_task(scenario, spec.realisation))
    scenario = Scenario(params, spec.variant)
    start = held_start(scenario)
    tasks = [task(scenario)]
    if spec.feedforward == "rigid" and spec.variant != "rigid":
        tasks.append(task(Scenario(params, "rigid")))  # the rigid feedforward follows its own reference
    ahead = ComputedAhead([motion for motion, _ in tasks],
                          [simulated_runs(motion, q0, spec.duration, step=spec.reference_step, every_row=False)
                           for motion, q0 in tasks])
    joints = scenario.model.actuated_joints
    gains = spec.joint_gains(joints, held_inertia(scenario, joints, start))
    controller = JointController(gains, 1.0 / spec.rate)
    plant = Plant(params, spec.variant, start, spec.step, controller.damping)
    actuated = plant.actuated
    per = spec.steps_per_tick
    inverse = (RigidInverseDynamics(params, tasks[-1][0].dynamics.model.joint_names) if spec.feedforward == "rigid"
               else None)
    chunk = max(1, round(0.25 * spec.rate))  # ticks per compiled call: progress every 0.25 s
    try:
        first, looped, reference, finished, samples = 0, 0.0, None, False, 0
        while True:  # tick k runs from the reference's sample k per to sample (k + 1) per
            end = (first + chunk) * per  # the sample this chunk's last tick ends on
            if reference is None or (samples <= end and not finished):  # all computed so far, joined once
                references, finished = ahead.through(end * spec.step * (1.0 - 1e-9))
                reference, feedforward_reference = (r.subsampled(spec.reference_stride) for r in (references[0],
                                                                                                    references[-1]))
                samples = len(reference.t)
                if len(feedforward_reference.t) != samples:  # both on one grid, computed as far
                    raise RuntimeError("the feedforward's reference and the task's do not share their samples")
            k = np.arange(first, min(first + chunk, (samples - 1) // per))
            if k.size == 0:
                if finished:
                    break
                continue
            i = k * per
            at = np.append(i, i[-1] + per)  # the ticks' starts and the last one's end
            if spec.feedforward == "reference":
                starts, ends = _reference_feedforward(reference, tasks[0][0], joints, at)
            else:
                starts, ends = _feedforward(inverse, spec.step, feedforward_reference, tasks[-1][0], at)
            loop_start = time.perf_counter()
            plant.follow(reference.t[i + per], reference.q[np.ix_(i, actuated)], reference.qd[np.ix_(i, actuated)],
                         starts, ends, controller)
            looped += time.perf_counter() - loop_start
            first = k[-1] + 1
            if progress is not None:
                progress(plant.t)
    finally:
        ahead.close()
    trajectory, torques = plant.trajectory()
    reference = reference.subsampled(count=len(trajectory.t))
    reference_motion = tasks[0][0]
    constraints = ConstraintSet(tuple(c for c in reference_motion.constraints.constraints if c.order == 0))
    path_error = constraints.surface_offsets(trajectory.t, trajectory.ee_position)
    deflections = [tip_deflection(plant.model, plant.dynamics.chain, q)
                   if spec.variant == "flexible" and plant.model.flexible_links else np.zeros((len(trajectory.t), 3))
                   for q in (trajectory.q, reference.q)]
    return TrackingRun(spec, joints, gains, trajectory, torques, reference, path_error, *deflections,
                       controller.saturated_ticks / max(1, controller.ticks), time.perf_counter() - started, looped)


def recorded_run(params: CraneDescription, spec: TrackingSpec, recording: LoopRecording) -> TrackingRun:
    """The :class:`TrackingRun` of a closed loop over ROS (``crane-reference loop``: the example controller with
    the default gains and ``spec``'s feedforward) from what it recorded: the plant's motion, efforts,
    E's pose and tip deflection, and the reference node's samples (their q and qd; the reference's E and tip
    deflection from the kinematics of its q), at the plant's times (in lock-step its steps' k h, of which the
    stamps are the nanosecond roundings; in real time the stamps).  What the messages do not carry is NaN: the
    accelerations, the energies and works (so the energy balance), E's velocity; no torque limit, so nothing
    saturates."""
    scenario = Scenario(params, spec.variant)
    model, dynamics = scenario.model, scenario.dynamics
    if tuple(recording.joint_names) != tuple(model.joint_names):
        raise ValueError(f"the recording's coordinates {list(recording.joint_names)} are not the {spec.variant} "
                         f"model's {list(model.joint_names)}")
    t = np.round(recording.t / spec.step) * spec.step  # lock-step: the plant's time, k steps (stamps: to the ns)
    if not np.all(np.abs(t - recording.t) <= 1e-9):  # real time: stamped by the wall clock
        t = recording.t
    N, n = recording.q.shape

    def trajectory(q, qd, ee_position, ee_quaternion) -> Trajectory:
        unknown = np.full((N, n), np.nan)
        scalar = np.full(N, np.nan)
        return Trajectory(spec.variant, model.joint_names, model.drive_joint, t, q, qd, unknown, np.zeros((N, 0)),
                          unknown, scalar, ee_position, ee_quaternion, np.full((N, 3), np.nan), np.zeros((N, 0)),
                          np.zeros((N, 0)), scalar, scalar, scalar, scalar, scalar, scalar)

    positions, rotations = dynamics.end_effector_poses(recording.reference_q)
    plant = trajectory(recording.q, recording.qd, recording.ee_position, recording.ee_quaternion)
    reference = trajectory(recording.reference_q, recording.reference_qd, positions,
                           Rotation.from_matrix(rotations).as_quat())
    joints = model.actuated_joints
    actuated = [model.index(name) for name in joints]
    constraints = ConstraintSet(tuple(c for c in scenario.motion.constraints.constraints if c.order == 0))
    gains = spec.joint_gains(joints, held_inertia(scenario, joints))
    reference_deflection = (tip_deflection(model, dynamics.chain, recording.reference_q)
                            if spec.variant == "flexible" and model.flexible_links else np.zeros((N, 3)))
    path_error = constraints.surface_offsets(t, recording.ee_position)
    return TrackingRun(spec, joints, gains, plant, recording.effort[:, actuated], reference, path_error,
                       recording.deflection, reference_deflection, np.zeros(len(joints)), recording.wall)


def _paper_task(scenario: Scenario, realisation: str) -> tuple[ProgrammedMotion, np.ndarray]:
    """The scenario's own task in ``realisation`` and its start (for servo-constraints the held start)."""
    if realisation == "servo":
        return servo_motion(scenario), held_start(scenario).q
    return scenario.motion, scenario.equilibrium.q


def _divides(step: float, interval: float) -> bool:
    """Whether ``step`` [s] divides ``interval`` [s] (to round-off)."""
    return abs(max(1, round(interval / step)) * step / interval - 1.0) <= 1e-9


def _reference_feedforward(reference: Trajectory, motion: ProgrammedMotion, joints: tuple[str, ...],
                           at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The reference's constraint forces at the ``joints`` (the actuated ones) at its samples ``at`` (ticks'
    starts; :meth:`~crane_reference.motion.programmed_motion.ProgrammedMotion.evaluated_rows`, as the node's
    samples have them for the preview's efforts), held over each tick: as ``(starts, ends)`` of :func:`_feedforward`
    (len(at), a) with each tick's end equal to its start."""
    forces = motion.evaluated_rows(reference.t[at], reference.q[at], reference.qd[at], reference.qdd[at])[0]
    starts = forces[:, [reference.joint_names.index(name) for name in joints]]
    ends = np.vstack((starts[:1], starts[:-1]))  # ends[k + 1] = starts[k]: no change over tick k
    return starts, ends


def _feedforward(inverse: RigidInverseDynamics | None, step: float, reference: Trajectory,
                 motion: ProgrammedMotion, at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """tau_ff of ``inverse`` (None: no feedforward) at the samples ``at`` (ticks' starts) of ``reference``, the
    programmed motion ``motion`` at the plant's ``step`` (len(at), a) [N m or N], as a command starts there and as
    one ends there: they differ at a jump of the drive's torque, where the end takes the drive and the reference's
    qdd from before it.  (A jump between ticks reaches the feedforward at the next tick.)"""
    starts = np.zeros((at.size, len(motion.dynamics.model.actuated_joints)))
    if inverse is None:
        return starts, starts
    jumps = np.asarray(motion.dynamics.drive.breakpoints, dtype=float)
    starts = inverse(reference.t[at], reference.q[at], reference.qd[at], reference.qdd[at])
    ends = starts.copy()
    on_jump = np.any(np.abs(reference.t[at, np.newaxis] - jumps) <= 1e-9 * step, axis=1)
    for k in np.flatnonzero(on_jump):
        i = at[k]
        t, q, qd = reference.t[i], reference.q[i], reference.qd[i]
        ends[k] = inverse(t, q, qd, motion.solve(t, q, qd, left_limit=True).qdd, left_limit=True)
    return starts, ends

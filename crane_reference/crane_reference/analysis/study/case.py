"""One case of a study: the crane and task of a parameter setting, simulated, reduced to design metrics.

Metrics (SI units), per case:

* ``feasible`` and ``reason``: E reaches the whole target ellipse at every height of the rise with
  sigma_min(K_dc) above :data:`SINGULARITY_MARGIN` (the stream's reachability check), and the motion could
  be computed; otherwise the reason (out of reach, near a stretch/fold singularity, solver failure);
* ``kdc_min_singular_value``: the smallest singular value of K_dc along the computed path;
* ``tip_deflection_m``: the largest tip deflection of the first flexible link relative to its rigid chord
  (flexible model);
* ``vibration_rms_m``: RMS of the tip deflection above :data:`BAND` Hz over the second half of the run;
* ``constraint_force_n``: the largest force at E that realises the task constraints (F with C^T F equal to
  the constraints' generalized force);
* ``drive_power_w``: the largest power the drive feeds in; ``ee_speed_m_s``: the largest |v_E|;
* ``diff_<joint>_rad`` (variant both): the largest flexible-minus-rigid difference of each actuated joint (the
  paper's psi2, psi(3,0), psi4) below :data:`BAND` Hz (4th-order Butterworth, forward-backward);
* ``residual_m`` the largest constraint distance, ``energy_error_j`` the largest energy-balance error,
  ``wall_s`` the wall time;
* with tracking (a spec's ``tracking`` block or a varied closed-loop parameter), ``track_<metric>``: the
  metrics of the actuated crane following the case's reference under the spec's controller (for the first
  variant; :func:`tracked`).  A closed loop that cannot be computed (unstable) makes the case infeasible.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from ...dynamics.deflection import tip_deflection
from ...model.chain import VARIANTS
from ...model.config import load_config
from ...model.description import CraneDescription
from ...model.drive import column_drive
from ...model.parameters import Task
from ...model.profiles import Constant, QuinticRise
from ...motion.constraints import ArealRate, ConstraintSet, EllipseXY, HeightZ
from ...motion.programmed_motion import ProgrammedMotion
from ...motion.simulation import SOLVER_FAILURES, Scenario, simulate
from ...motion.trajectory import Trajectory
from ...stream.targets import UnreachableTargetError, check_task
from ..bands import CONTROLLER_BAND, controller_band
from ..tracking.closed_loop import TrackingSpec, run_tracking, summary_names
from .spec import PATH_SPEED_RISE, Case, StudySpec

BAND = CONTROLLER_BAND  # [Hz]
SINGULARITY_MARGIN = 0.1  # smallest sigma_min(K_dc) accepted by the reachability check (the node's)


def tracked(joints: tuple[str, ...]) -> tuple[str, ...]:
    """The closed loop's metrics as columns (a spec with tracking) for a crane with the actuated ``joints``."""
    return tuple(f"track_{name}" for name in summary_names(joints) if name != "real_time_factor")


def metrics(spec: StudySpec) -> tuple[str, ...]:
    """The metrics of a case of ``spec`` (module docstring), in order: the deflection's with a flexible model, the
    differences with both models, the closed loop's with tracking."""
    flexible = ("tip_deflection_m", "vibration_rms_m") if spec.variant != "rigid" else ()
    differences = tuple(f"diff_{joint}_rad" for joint in spec.joints) if spec.variant == "both" else ()
    return ("feasible", "reason", "kdc_min_singular_value", *flexible, "constraint_force_n", "drive_power_w",
            "ee_speed_m_s", *differences, "residual_m", "energy_error_j",
            *(tracked(spec.joints) if spec.tracking else ()), "wall_s")


class ClosedLoopError(RuntimeError):
    """The case's reference exists, but the closed loop following it failed (e.g. it is unstable)."""


def case_parameters(base: CraneDescription, values: dict[str, float]) -> CraneDescription:
    """The crane description with the case's values."""
    task = dataclasses.replace(base.task, **{name: values[name] for name in
                                             ("ellipse_a", "ellipse_b", "z_increment", "rise_time") if name in values})
    params = dataclasses.replace(base, task=task)
    if "drive_torque" in values or "drive_duration" in values:
        params = dataclasses.replace(params, drive=column_drive(base, values.get("drive_torque"),
                                                                values.get("drive_duration")))
    if "payload_mass" in values:
        params = dataclasses.replace(params, payload=values["payload_mass"])
    if "n_rfe" in values:
        params = params.with_rfe_count(int(values["n_rfe"]))
    if "damping_boom" in values:
        params = params.with_beam_damping(values["damping_boom"])
    return params


def path_speed_constraints(task: Task, z_static: float, omega: float) -> ConstraintSet:
    """Ellipse, height and the areal rate x y' - y x' = a b omega(t): E runs along the ellipse with the
    parametric-angle rate omega(t), rising from 0 along a quintic over PATH_SPEED_RISE."""
    rise = QuinticRise(0.0, omega, 0.0, PATH_SPEED_RISE)
    ab = task.ellipse_a * task.ellipse_b

    def rate(t: float) -> tuple[float, float, float]:
        return tuple(ab * value for value in rise(t))

    return ConstraintSet((EllipseXY(Constant(task.ellipse_a), Constant(task.ellipse_b)),
                          HeightZ(QuinticRise(z_static, task.z_increment, 0.0, task.rise_time)), ArealRate(rate)))


def _motion(scenario: Scenario, values: dict[str, float], realisation: str) -> tuple[ProgrammedMotion, np.ndarray]:
    """The programmed motion of the case and its start (the static equilibrium under the paper's pair); with a path
    speed the areal rate makes the drive's joint (the slew) velocity-dependent."""
    start = scenario.equilibrium.q
    if "path_speed" not in values:
        motion = scenario.motion
        if realisation != "ideal":
            motion = ProgrammedMotion(scenario.dynamics, motion.constraints, realisation=realisation)
        return motion, start
    dependent = (*scenario.model.dependent_joints, scenario.model.drive_joint)
    constraints = path_speed_constraints(scenario.task, scenario.z_static, values["path_speed"])
    return ProgrammedMotion(scenario.dynamics, constraints, dependent, realisation=realisation), start


def _metrics(scenario: Scenario, motion: ProgrammedMotion, trajectory: Trajectory, step: float) -> dict[str, float]:
    model = scenario.model
    out = {"kdc_min_singular_value": float(trajectory.kdc_min_singular_value.min()),
           "residual_m": float(trajectory.residual_distance.max()),
           "energy_error_j": float(np.abs(trajectory.energy_balance_error).max()),
           "ee_speed_m_s": float(np.linalg.norm(trajectory.ee_velocity, axis=1).max())}
    forces = [np.linalg.lstsq(motion.dynamics.end_effector(q)[1].T, f, rcond=None)[0]
              for q, f in zip(trajectory.q, trajectory.constraint_forces, strict=True)]
    out["constraint_force_n"] = float(np.linalg.norm(forces, axis=1).max())
    out["drive_power_w"] = float(np.max(np.gradient(trajectory.work_drive, trajectory.t)))
    if model.variant == "flexible" and model.flexible_links:
        w = tip_deflection(model, motion.dynamics.chain, trajectory.q)
        out["tip_deflection_m"] = float(np.linalg.norm(w, axis=1).max())
        late = trajectory.t >= 0.5 * trajectory.t[-1]
        vibration = w - controller_band(w, step)
        out["vibration_rms_m"] = float(np.sqrt(np.mean(np.sum(vibration[late] ** 2, axis=1))))
    return out


def _tracking(spec: StudySpec, params: CraneDescription, values: dict[str, float], variant: str) -> dict[str, float]:
    """The closed loop of the spec's tracking settings (the case's values where it varies them) following
    the case's reference: its metrics as ``track_*`` columns."""
    settings = spec.tracking
    limit = values.get("torque_limit", settings["torque_limit"])
    feedforward = ("none", "rigid")[int(values["feedforward"])] if "feedforward" in values else settings["feedforward"]
    tracking = TrackingSpec(
        variant=variant, realisation=spec.realisation, controller=settings["controller"],
        bandwidth=values.get("bandwidth", settings["bandwidth"]),
        damping_ratio=values.get("damping_ratio", settings["damping_ratio"]),
        joint_bandwidths={j: values[f"bandwidth_{j}"] for j in params.actuated if f"bandwidth_{j}" in values},
        feedforward=feedforward, limits=dict.fromkeys(params.actuated, limit) if math.isfinite(limit) else {},
        rate=settings["rate"], duration=spec.duration, step=spec.step)
    run = run_tracking(params, tracking, task=lambda scenario: _motion(scenario, values, spec.realisation))
    return {f"track_{name}": value for name, value in run.summary().items() if name != "real_time_factor"}


def run_case(spec: StudySpec, case: Case) -> dict[str, object]:
    """The metrics of one case (never raises for a solver failure or an unreachable target: the case is
    then infeasible and ``reason`` says why)."""
    started = time.perf_counter()
    row: dict[str, object] = {"case": case.index, "key": case.key, **case.values,
                              **dict.fromkeys(metrics(spec), math.nan), "feasible": False, "reason": ""}
    params = case_parameters(load_config(spec.config or None), case.values)
    variants = list(VARIANTS) if spec.variant == "both" else [spec.variant]
    runs = {}
    try:
        for variant in variants:
            scenario = Scenario(params, variant)
            check_task(scenario, scenario.task, scenario.z_static, SINGULARITY_MARGIN)
            motion, start = _motion(scenario, case.values, spec.realisation)
            trajectory = simulate(motion, start, spec.duration, step=spec.step)
            runs[variant] = trajectory
            if variant == variants[0]:
                row.update(_metrics(scenario, motion, trajectory, spec.step))
                if spec.tracking:
                    try:
                        row.update(_tracking(spec, params, case.values, variant))
                    except SOLVER_FAILURES as failure:
                        raise ClosedLoopError(f"the closed loop could not be computed ({type(failure).__name__}: "
                                                f"{failure}); an unstable loop makes the torques grow") from failure
    except (UnreachableTargetError, ClosedLoopError, *SOLVER_FAILURES) as failure:
        row["reason"] = f"{type(failure).__name__}: {failure}"
    else:
        row["feasible"] = True
        if len(runs) == 2:
            flexible, rigid = runs["flexible"], runs["rigid"]
            for joint in params.actuated:
                difference = flexible.coordinate(joint) - rigid.coordinate(joint)
                row[f"diff_{joint}_rad"] = float(np.abs(controller_band(difference, spec.step)).max())
    row["wall_s"] = time.perf_counter() - started
    return row

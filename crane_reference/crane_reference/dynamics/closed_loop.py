"""Compiled closed loop: a joint controller's ticks and the actuated plant's integration steps in one call.

The controller is :mod:`crane_reference.control.controller`'s (its tick is :func:`controller_tick`,
which the Python controller calls too); the plant is the crane without programmed constraints driven by an
:class:`~crane_reference.model.drive.Actuated` drive (:mod:`crane_reference.control.plant`), stepped
by :func:`~.kernels.integration_step` exactly as :class:`~crane_reference.motion.simulation.MotionStepper`
steps it: at each tick the command's forces jump and (8) is solved again there keeping the modal correction
(:func:`~.kernels.corrected_accelerations`), on the position and velocity terms of the step that ended there
(:func:`~.kernels.forces_jumped`: the state did not move; a call's first tick evaluates its state afresh); at a
jump of the column drive's torque the step
ends on it and the integrator restarts there; every step is evaluated in full and its powers integrated by the
trapezoidal rule into the work accounts.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .kernels import corrected_accelerations, evaluate, forces_jumped, integration_step, step_evaluation
from .structures import (
    ACCOUNTS,
    CONVERGED,
    DRIVE_TORQUE,
    POWERS,
    ChainData,
    Coefficients,
    LoopRows,
    LoopRun,
    ModalCorrection,
    Partition,
    PlantCarry,
    StepSettings,
)


@njit(cache=True, nogil=True)
def controller_tick(kp, kd, ki, limit, period, integral, saturated, error, reference_rate, rate, feedforward):
    """One tick of the joint controller: with e = ``error``, u = clip(tau_ff + kp e + ki I + kd (qd_ref - qd),
    +-limit) + kd qd (the drive's velocity loop subtracts kd qd again); a joint cut to its limit is counted in
    ``saturated`` and its integral I held, the others' I grows by e ``period`` (both updated in place)."""
    u = np.empty(kp.size)
    for j in range(kp.size):
        wanted = feedforward[j] + kp[j] * error[j] + ki[j] * integral[j] + kd[j] * (reference_rate[j] - rate[j])
        torque = min(max(wanted, -limit[j]), limit[j])
        if torque != wanted:
            saturated[j] += 1
        else:
            integral[j] += error[j] * period
        u[j] = torque + kd[j] * rate[j]
    return u


@njit(cache=True, nogil=True, inline='always')
def _drive_at(inner, t, start, end, first, last, actuated, n):
    """The drive parameters at t: the column drive's ``inner`` followed by the actuators' forces, linear from
    ``first`` at ``start`` to ``last`` at ``end`` on the ``actuated`` coordinates (as
    :meth:`~crane_reference.model.drive.Actuated.forces`)."""
    drive = np.zeros(inner.size + n)
    drive[:inner.size] = inner
    share = (t - start) / (end - start)
    for j in range(actuated.size):
        drive[inner.size + actuated[j]] = (1.0 - share) * first[j] + share * last[j]
    return drive


@njit(cache=True, nogil=True)
def closed_loop_run(q, qd, correction: ModalCorrection, work, t0, tick_ends, first_step, step_times, on_jump, inner,
                    inner_after, k: Coefficients, partition: Partition, chain: ChainData, settings: StepSettings,
                    actuated, joint_damping, period, reference_q, reference_qd, feedforward_start, feedforward_end, kp,
                    kd, ki, limit, integral, saturated):
    """Ticks of the controller from the plant state (t0, q, qd) with its modal ``correction`` and ``work``
    accounts (3,) [J]; tick k runs from the plant's time then to ``tick_ends`` [k] (K,) [s] over the steps
    first_step[k] .. first_step[k + 1] - 1 ending at ``step_times`` (S,), ``on_jump`` where a step ends on a
    jump of the column drive (``inner`` (S, 4): the column drive's parameters at the step ends, left limits
    there; ``inner_after`` (S + 1, 4): right limits at t0 and at the step ends, where the integrator
    restarts; K >= 1).  Tick k commands u_k (:func:`controller_tick` every ``period`` [s] on ``reference_q`` [k]
    - q and ``reference_qd`` [k] of the ``actuated`` coordinates, feedforward ``feedforward_start`` [k]) at its
    start, linear to clip(u_k + feedforward_end[k + 1] - feedforward_start[k], +-limit) at its end;
    ``integral`` and ``saturated`` are updated in place; the actuator torques are the commands minus
    ``joint_damping`` qd (the joint drives' velocity loops, in the plant's damping).  Stops at the first
    step that fails; returns a :class:`LoopRun` (its rows: the start under the first command, then every
    step; at a drive jump qdd, the constraint forces and the drive torque from after it, as
    ``MotionStepper``'s)."""
    n, S, na = q.size, step_times.size, actuated.size
    rows = LoopRows(np.empty((S + 1, n)), np.empty((S + 1, n)), np.empty((S + 1, n)), np.empty((S + 1, n)),
                    np.empty((S + 1, len(ACCOUNTS))), np.empty((S + 1, 3)), np.empty((S + 1, 3)),
                    np.empty((S + 1, 3, 3)), np.empty((S + 1, 3)), np.empty((S + 1, na)))
    fresh = ModalCorrection(np.zeros_like(correction.inertia), np.zeros_like(correction.damping), -np.inf, 0.0)
    work, t, done = work.copy(), t0, 0
    earlier = np.full((2, partition.integrated.size), np.nan)
    command = np.zeros((2, na))
    for tick in range(tick_ends.size):
        start, end = t, tick_ends[tick]
        error, rate = np.empty(na), np.empty(na)
        for j in range(na):
            error[j], rate[j] = reference_q[tick, j] - q[actuated[j]], qd[actuated[j]]
        first = controller_tick(kp, kd, ki, limit, period, integral, saturated, error, reference_qd[tick], rate,
                                feedforward_start[tick])
        last = np.empty(na)
        for j in range(na):
            change = feedforward_end[tick + 1, j] - feedforward_start[tick, j]  # first: none held exactly
            last[j] = min(max(first[j] + change, -limit[j]), limit[j])
        command[0], command[1] = first, last
        # the forces jump: (8) solved again at the tick's start, the modal correction kept
        s0 = first_step[tick]
        drive = _drive_at(inner_after[s0], start, start, end, first, last, actuated, n)
        if tick == 0:
            e = evaluate(q, qd, k, drive, partition, chain)
        else:  # on the terms of the step that ended here, the previous tick's last
            e = forces_jumped(e, q, qd, k, drive, partition, chain)
        qdd, B = e.terms.qdd, e.terms.velocity_map
        if np.isfinite(correction.time):
            qdd = corrected_accelerations(e.terms.M, B, qdd, qd, correction, partition)
        else:
            correction = fresh
        earlier = np.full((2, partition.integrated.size), np.nan)
        powers = e.accounts[POWERS]
        if tick == 0:
            _store(rows, 0, q, qd, qdd, e, work, e.terms.ee_position, e.terms.ee_rotation,
                   e.terms.ee_jacobian @ qd)
            for j in range(na):
                rows.torques[0, j] = first[j] - joint_damping[j] * qd[actuated[j]]
        for s in range(s0, first_step[tick + 1]):
            drive = _drive_at(inner[s], step_times[s], start, end, first, last, actuated, n)
            h = step_times[s] - t
            step = integration_step(q, qd, qdd, B, earlier, correction, t, h, k, drive, partition, chain, settings)
            if step.status != CONVERGED:
                return LoopRun(done, s, step.status, _first_rows(rows, s + 1), t, e, correction, earlier, command)
            t, q, qd, qdd, B, earlier, correction = (step_times[s], step.q, step.qd, step.qdd, step.velocity_map,
                                                     step.earlier, step.correction)
            e = step_evaluation(q, qd, qdd, k, drive, partition, chain)
            row_powers = e.accounts[POWERS]
            for i in range(3):
                work[i] += 0.5 * h * (powers[i] + row_powers[i])
            powers = row_powers
            _store(rows, s + 1, q, qd, qdd, e, work, step.ee_position, step.ee_rotation, step.ee_velocity)
            for j in range(na):
                rows.torques[s + 1, j] = drive[inner.shape[1] + actuated[j]] - joint_damping[j] * qd[actuated[j]]
            if on_jump[s]:  # restart at the drive's jump: the motion from it on, a fresh modal correction
                e = forces_jumped(e, q, qd, k, _drive_at(inner_after[s + 1], t, start, end, first, last, actuated,
                                                         n), partition, chain)
                qdd, B, correction = e.terms.qdd, e.terms.velocity_map, fresh
                earlier = np.full((2, partition.integrated.size), np.nan)
                powers = e.accounts[POWERS]
                rows.qdd[s + 1], rows.constraint_forces[s + 1] = qdd, e.constraint_forces
                rows.accounts[s + 1, DRIVE_TORQUE] = e.accounts[DRIVE_TORQUE]
        done += 1
    return LoopRun(done, S, CONVERGED, rows, t, e, correction, earlier, command)


@njit(cache=True, nogil=True)
def held_period(carry: PlantCarry, end, start_step, end_step, step_times, on_jump, inner, inner_after,
                k: Coefficients, partition: Partition, chain: ChainData, settings: StepSettings, actuated,
                joint_damping, efforts):
    """One control period of the plant from its ``carry`` to ``end`` [s] under the efforts u [N m] (n_a,) held
    over it (the actuator torques u - ``joint_damping`` qd): a tick of :func:`closed_loop_run` whose controller
    commands u (no feedback), over the steps ``start_step`` .. ``end_step`` - 1 of a plan of steps
    (``step_times``, ``on_jump``, ``inner`` (S, 4) and ``inner_after`` (S + 1, 4) as there, the latter's row
    ``start_step`` at the period's start).  The carry is updated in place when every step converged; returns the
    status, the time reached and the end of the step that failed (that of the last step if none did)."""
    na, s0, s1 = actuated.size, start_step, end_step
    zeros, held = np.zeros(na), np.empty((2, na))
    held[0], held[1] = efforts, efforts  # the feedforward at the period's start and at the next one's
    correction = ModalCorrection(carry.inertia, carry.damping, carry.modal[0], carry.modal[1])
    run = closed_loop_run(carry.q, carry.qd, correction, carry.work, carry.clock[0], np.array([end]),
                          np.array([0, s1 - s0]), step_times[s0:s1], on_jump[s0:s1], inner[s0:s1],
                          inner_after[s0:s1 + 1], k, partition, chain, settings, actuated, joint_damping, 1.0,
                          zeros.reshape(1, na), zeros.reshape(1, na), held, held, zeros, zeros, zeros,
                          np.full(na, np.inf), zeros.copy(), np.zeros(na, np.int64))
    failed_at = step_times[min(s0 + run.steps, s1 - 1)]
    if run.status != CONVERGED:
        return run.status, run.t, failed_at
    rows = run.rows
    carry.clock[0] = run.t
    carry.q[:], carry.qd[:], carry.work[:] = rows.q[-1], rows.qd[-1], rows.work[-1]
    carry.inertia[:], carry.damping[:] = run.correction.inertia, run.correction.damping
    carry.modal[0], carry.modal[1] = run.correction.time, run.correction.step
    carry.ee_position[:], carry.ee_rotation[:] = rows.ee_position[-1], rows.ee_rotation[-1]
    return run.status, run.t, failed_at


@njit(cache=True, nogil=True)
def _first_rows(rows: LoopRows, count):
    """The first ``count`` rows."""
    return LoopRows(rows.q[:count], rows.qd[:count], rows.qdd[:count], rows.constraint_forces[:count],
                    rows.accounts[:count], rows.work[:count], rows.ee_position[:count], rows.ee_rotation[:count],
                    rows.ee_velocity[:count], rows.torques[:count])


@njit(cache=True, nogil=True)
def _store(rows: LoopRows, i, q, qd, qdd, e, work, ee_position, ee_rotation, ee_velocity):
    """Row i from (q, qd), the integrator's qdd, the evaluation ``e`` there, the work and E's kinematics."""
    rows.q[i], rows.qd[i], rows.qdd[i], rows.constraint_forces[i] = q, qd, qdd, e.constraint_forces
    rows.accounts[i], rows.work[i] = e.accounts, work
    rows.ee_position[i], rows.ee_rotation[i], rows.ee_velocity[i] = ee_position, ee_rotation, ee_velocity

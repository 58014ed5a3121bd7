"""Compiled closed loop: a joint controller's ticks and the actuated plant's integration steps in one call.

The controller is :mod:`crane_reference.control.controller`'s (its tick is :func:`controller_tick`,
which the Python controller calls too); the plant is the crane without programmed constraints driven by an
:class:`~crane_reference.model.drive.Actuated` drive (:mod:`crane_reference.control.plant`), stepped
by :func:`~.step.integration_step` exactly as :class:`~crane_reference.motion.simulation.MotionStepper`
steps it: at each tick the command's forces jump and (8) is solved again there keeping the modal correction
(:func:`~.modal_correction.corrected_accelerations`), on the position and velocity terms of the step that ended there
(:func:`~.evaluation.forces_jumped`: the state did not move; at a call's first tick, on the terms it is given at
its start); at a jump of the column drive's torque the step ends on it and the integrator restarts there; every
step is evaluated in full and its powers integrated by the trapezoidal rule into the work accounts.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .deflection import deflection_at
from .evaluation import forces_jumped, step_evaluation
from .kinematics import quaternion
from .modal_correction import corrected_accelerations, no_correction
from .step import integration_step
from .structures import (
    ACCOUNTS,
    CONVERGED,
    DRIVE_TORQUE,
    POWERS,
    Accelerations,
    ChainData,
    Coefficients,
    ControllerArrays,
    LinkTip,
    LoopRows,
    LoopRun,
    ModalCorrection,
    Partition,
    PlannedSteps,
    PlantCarry,
    PlantModel,
    StepSettings,
    StepStart,
    Ticks,
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
def closed_loop_run(q, qd, start_terms: Accelerations, correction: ModalCorrection, work, t0, ticks: Ticks,
                    steps: PlannedSteps, plant: PlantModel, controller: ControllerArrays):
    """The controller's ``ticks`` from the plant state (t0, q, qd), the position and velocity terms ``start_terms``
    there (an evaluation's at (q, qd): its Q and qdd are not read), its modal ``correction`` and ``work`` accounts
    (3,) [J]; tick k runs from the plant's time then to ``ticks.ends`` [k] over its planned ``steps`` (K >= 1).
    Tick k commands u_k (:func:`controller_tick` of ``controller`` on ``ticks.reference_q`` [k] - q and
    ``ticks.reference_qd`` [k] of the plant's actuated coordinates, feedforward ``ticks.feedforward_start`` [k]) at
    its start, linear to clip(u_k + feedforward_end[k + 1] - feedforward_start[k], +-limit) at its end (the
    controller's integral and saturated ticks updated in place); the actuator torques are the commands minus the
    plant's ``joint_damping`` qd (the joint drives' velocity loops, in the plant's damping).  Stops at the first
    step that fails; returns a :class:`LoopRun` (its rows: the start under the first command, then every step; at
    a drive jump qdd, the constraint forces and the drive torque from after it, as ``MotionStepper``'s)."""
    k, partition, chain, settings, actuated, joint_damping = plant
    step_times, on_jump, inner, inner_after = steps
    first_step, limit = ticks.first_step, controller.limit
    n, S, na = q.size, step_times.size, actuated.size
    rows = LoopRows(np.empty((S + 1, n)), np.empty((S + 1, n)), np.empty((S + 1, n)), np.empty((S + 1, n)),
                    np.empty((S + 1, len(ACCOUNTS))), np.empty((S + 1, 3)), np.empty((S + 1, 3)),
                    np.empty((S + 1, 3, 3)), np.empty((S + 1, 3)), np.empty((S + 1, na)))
    fresh = no_correction(correction.inertia.shape[0])
    work, t, done = work.copy(), t0, 0
    earlier = np.full((2, partition.integrated.size), np.nan)
    command = np.zeros((2, na))
    for tick in range(ticks.ends.size):
        start, end = t, ticks.ends[tick]
        error, rate = np.empty(na), np.empty(na)
        for j in range(na):
            error[j], rate[j] = ticks.reference_q[tick, j] - q[actuated[j]], qd[actuated[j]]
        first = controller_tick(controller.kp, controller.kd, controller.ki, limit, controller.period,
                                controller.integral, controller.saturated, error, ticks.reference_qd[tick], rate,
                                ticks.feedforward_start[tick])
        last = np.empty(na)
        for j in range(na):
            change = ticks.feedforward_end[tick + 1, j] - ticks.feedforward_start[tick, j]  # first: none held exactly
            last[j] = min(max(first[j] + change, -limit[j]), limit[j])
        command[0], command[1] = first, last
        # the forces jump: (8) solved again at the tick's start, the modal correction kept
        s0 = first_step[tick]
        drive = _drive_at(inner_after[s0], start, start, end, first, last, actuated, n)
        if tick == 0:  # on the terms given
            e = forces_jumped(start_terms, q, qd, k, drive, partition, chain)
        else:  # on the terms of the step that ended here, the previous tick's last
            e = forces_jumped(e.terms, q, qd, k, drive, partition, chain)
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
            step = integration_step(StepStart(t, q, qd, qdd, B, earlier, correction), h, k, drive, partition, chain,
                                    settings)
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
                e = forces_jumped(e.terms, q, qd, k, _drive_at(inner_after[s + 1], t, start, end, first, last,
                                                               actuated, n), partition, chain)
                qdd, B, correction = e.terms.qdd, e.terms.velocity_map, fresh
                earlier = np.full((2, partition.integrated.size), np.nan)
                powers = e.accounts[POWERS]
                rows.qdd[s + 1], rows.constraint_forces[s + 1] = qdd, e.constraint_forces
                rows.accounts[s + 1, DRIVE_TORQUE] = e.accounts[DRIVE_TORQUE]
        done += 1
    return LoopRun(done, S, CONVERGED, rows, t, e, correction, earlier, command)


@njit(cache=True, nogil=True)
def held_period(carry: PlantCarry, end, start_step, end_step, steps: PlannedSteps, plant: PlantModel, tip: LinkTip,
                efforts):
    """One control period of the ``plant`` from its ``carry`` to ``end`` [s] under the efforts u [N m or N] (n_a,)
    held over it (the actuator torques u - kd qd): a tick of :func:`closed_loop_run` whose controller commands u
    (no feedback), over the steps ``start_step`` .. ``end_step`` - 1 of the planned ``steps``, on the terms the
    carry holds; the carry's deflection is the link ``tip``'s.  The carry is updated in place when every step
    converged; returns the status, the time reached and the end of the step that failed (that of the last step if
    none did)."""
    na, s0, s1 = plant.actuated.size, start_step, end_step
    zeros, held = np.zeros(na), np.empty((2, na))
    held[0], held[1] = efforts, efforts  # the feedforward at the period's start and at the next one's
    correction = ModalCorrection(carry.inertia, carry.damping, carry.modes, int(carry.modal[2]), carry.modal[0],
                                 carry.modal[1], carry.modal[3], carry.on_resolved, carry.inertia_weights,
                                 carry.damping_weights, carry.modal[4])
    empty = np.empty(0)  # Q and qdd: not read
    terms = Accelerations(carry.M, carry.h, empty, carry.gravity_forces, carry.gravity_potential[0],
                          carry.ee_position, carry.ee_rotation, carry.ee_jacobian, carry.ee_bias, carry.A, carry.c,
                          carry.velocity_map, empty)
    period = PlannedSteps(steps.times[s0:s1], steps.on_jump[s0:s1], steps.inner[s0:s1], steps.inner_after[s0:s1 + 1])
    no_feedback = ControllerArrays(zeros, zeros, zeros, np.full(na, np.inf), 1.0, zeros.copy(),
                                   np.zeros(na, np.int64))
    run = closed_loop_run(carry.q, carry.qd, terms, correction, carry.work, carry.clock[0],
                          Ticks(np.array([end]), np.array([0, s1 - s0]), zeros.reshape(1, na), zeros.reshape(1, na),
                                held, held), period, plant, no_feedback)
    failed_at = steps.times[min(s0 + run.steps, s1 - 1)]
    if run.status != CONVERGED:
        return run.status, run.t, failed_at
    rows, terms = run.rows, run.last.terms
    carry.clock[0] = run.t
    carry.q[:], carry.qd[:], carry.work[:] = rows.q[-1], rows.qd[-1], rows.work[-1]
    carry.inertia[:], carry.damping[:] = run.correction.inertia, run.correction.damping
    carry.modes[:], carry.on_resolved[:] = run.correction.modes, run.correction.on_resolved
    carry.inertia_weights[:], carry.damping_weights[:] = run.correction.inertia_weights, run.correction.damping_weights
    carry.modal[0], carry.modal[1] = run.correction.time, run.correction.step
    carry.modal[2], carry.modal[3] = run.correction.resolved, run.correction.tracked
    carry.modal[4] = run.correction.unresolved_beta
    carry.M[:], carry.h[:], carry.gravity_forces[:] = terms.M, terms.h, terms.gravity_forces
    carry.gravity_potential[0] = terms.gravity_potential
    carry.ee_position[:], carry.ee_rotation[:] = terms.ee_position, terms.ee_rotation
    carry.ee_jacobian[:], carry.ee_bias[:] = terms.ee_jacobian, terms.ee_bias
    carry.A[:], carry.c[:], carry.velocity_map[:] = terms.A, terms.c, terms.velocity_map
    carry.torques[:] = rows.torques[-1]
    carry.ee_quaternion[:] = quaternion(terms.ee_rotation)
    chain = plant.chain
    carry.deflection[:] = deflection_at(carry.q, tip, chain.kinds, chain.axes, chain.origins)
    return run.status, run.t, failed_at


@njit(cache=True, nogil=True)
def held_period_of_fields(carry, end, start_step, end_step, steps, plant, tip, efforts):
    """:func:`held_period` with its structures given as plain tuples of their fields (``plant``: those of its
    coefficients, partition, chain and settings too): numba types a plain tuple of arrays from its fingerprint in
    C, a named one field by field in Python, and the plant calls this once per control period."""
    model = PlantModel(Coefficients(*plant[0]), Partition(*plant[1]), ChainData(*plant[2]), StepSettings(*plant[3]),
                       plant[4], plant[5])
    return held_period(PlantCarry(*carry), end, start_step, end_step, PlannedSteps(*steps), model, LinkTip(*tip),
                       efforts)


def plant_carry(t, q, qd, work, correction: ModalCorrection, terms: Accelerations, torques, tip: LinkTip,
                chain: ChainData) -> PlantCarry:
    """The carry of the plant at time t [s] in the state (q, qd) with its ``work`` accounts (3,) [J], modal
    ``correction``, the evaluation's ``terms`` there and the actuator ``torques`` (n_a,) [N m or N] (copies of
    them all)."""
    return PlantCarry(np.array([t]), q.copy(), qd.copy(), work.copy(), correction.inertia.copy(),
                      correction.damping.copy(), correction.modes.copy(), correction.on_resolved.copy(),
                      correction.inertia_weights.copy(), correction.damping_weights.copy(),
                      np.array([correction.time, correction.step, correction.resolved, correction.tracked,
                                correction.unresolved_beta]),
                      terms.M.copy(),
                      terms.h.copy(), terms.gravity_forces.copy(), np.array([terms.gravity_potential]),
                      np.array(terms.ee_position, dtype=float), np.array(terms.ee_rotation, dtype=float),
                      terms.ee_jacobian.copy(), terms.ee_bias.copy(), terms.A.copy(), terms.c.copy(),
                      terms.velocity_map.copy(), np.array(torques, dtype=float), quaternion(terms.ee_rotation),
                      deflection_at(q, tip, chain.kinds, chain.axes, chain.origins))


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

"""Compiled runs of integration steps in one call (:func:`integration_run`, with a stop flag another thread or process
may set) and the evaluation, afterwards, of the rows a run left unevaluated."""

from __future__ import annotations

import numpy as np
from numba import njit

from .evaluation import evaluate, imbalance_at, reactions_to, step_evaluation
from .kinematics import point_bias, point_jacobian
from .linalg import matvec
from .quadrics import acceleration_terms, constraint_values
from .step import integration_step
from .structures import (
    ACCOUNTS,
    CONVERGED,
    SINGULAR_VALUE,
    ChainData,
    Coefficients,
    EvaluatedStep,
    Evaluation,
    Partition,
    Run,
    StepRows,
    StepSettings,
    StepStart,
)
from .terms import drive_torque


@njit(cache=True, nogil=True)
def _at_step(k: Coefficients, i):
    """The coefficients of step i of a run (``k`` stacked on a leading step axis)."""
    return Coefficients(k.Q[i], k.g[i], k.c[i], k.order)


@njit(cache=True, nogil=True)
def integration_run(start: StepStart, times, k: Coefficients, drives, partition: Partition, chain: ChainData,
                    settings: StepSettings, evaluated, stop):
    """:func:`integration_step` from the ``start`` at t0 through ``times`` (N,) in one call, with the constraint
    coefficients ``k`` (stacked per step) and drive parameters ``drives`` (N, 4) of each step's end.
    The rows of the steps where ``evaluated`` (N,) is True, and of the last one, carry the full evaluation
    (:func:`step_evaluation`: reactions, residuals, accounts); the others NaN there but for sigma_min(K_dc)
    in the accounts (every step's; :func:`evaluated_rows` completes them later).
    Stops at the first step that fails, or after a step once ``stop[0]`` (a flag another thread or process may
    set while the run is in progress) is nonzero: then fewer than N steps completed, all converged.  Returns a
    :class:`Run`."""
    N, n, m = times.size, start.q.size, k.order.size
    rows = StepRows(np.empty((N, n)), np.empty((N, n)), np.empty((N, n)), np.full((N, m), np.nan),
                    np.full((N, n), np.nan), np.empty((N, 3)), np.empty((N, 3, 3)), np.empty((N, 3)),
                    np.full((N, m), np.nan), np.full((N, m), np.nan), np.full((N, len(ACCOUNTS)), np.nan),
                    np.empty(N, dtype=np.int64))
    step = integration_step(start, times[0] - start.t, _at_step(k, 0), drives[0], partition, chain, settings)
    completed = 0
    while step.status == CONVERGED:
        rows.q[completed], rows.qd[completed], rows.qdd[completed] = step.q, step.qd, step.qdd
        rows.ee_position[completed], rows.ee_rotation[completed] = step.ee_position, step.ee_rotation
        rows.ee_velocity[completed], rows.iterations[completed] = step.ee_velocity, step.iterations
        rows.accounts[completed, SINGULAR_VALUE] = step.kdc_min_singular_value
        if evaluated[completed] and completed < N - 1:
            _evaluated_row(rows, completed, step_evaluation(step.q, step.qd, step.qdd, _at_step(k, completed),
                                                            drives[completed], partition, chain))
        completed += 1
        if completed == N or stop[0]:
            break
        step = integration_step(StepStart(times[completed - 1], step.q, step.qd, step.qdd, step.velocity_map,
                                          step.earlier, step.correction),
                                times[completed] - times[completed - 1], _at_step(k, completed), drives[completed],
                                partition, chain, settings)
    if step.status == CONVERGED:
        i = completed - 1
        last = step_evaluation(step.q, step.qd, step.qdd, _at_step(k, i), drives[i], partition, chain)
        _evaluated_row(rows, i, last)
    else:  # the evaluation at the failed step's start
        last = evaluate(step.q, step.qd, _at_step(k, completed), drives[completed], partition, chain)
    return Run(completed, step.status, rows, EvaluatedStep(step.q, step.qd, last, step.earlier, step.correction,
                                                           step.status, step.iterations))


@njit(cache=True, nogil=True)
def evaluated_rows(q, qd, qdd, k: Coefficients, drives, partition: Partition, chain: ChainData):
    """What a reader of computed steps that :func:`integration_run` left unevaluated needs of their full
    evaluation (:func:`step_evaluation`), without M: rows of q, qd and the integrator's qdd (N, n) with the
    constraint coefficients ``k`` (stacked per row) and the drive parameters ``drives`` of each; returns the
    generalized force of the constraints (N, n; :func:`reactions_to` to M qdd + h - Q by O(n) inverse
    dynamics), the drive torque (N,) [N m] and the constraint distances (N, m) [m]."""
    N, n, m = q.shape[0], q.shape[1], k.order.size
    forces, torques, distances = np.empty((N, n)), np.empty(N), np.empty((N, m))
    for i in range(N):
        k_i = _at_step(k, i)
        imbalance, T, S, velocity_term = imbalance_at(q[i], qd[i], qdd[i], drives[i], chain)
        p, C = point_jacobian(T, S, chain.ee_joint, chain.ee_point)
        v = matvec(C, qd[i])
        A = acceleration_terms(p, v, C, point_bias(velocity_term, chain.ee_joint, p), k_i)[0]
        forces[i] = reactions_to(A, imbalance, partition)[1]
        torques[i] = drive_torque(drives[i], q[i, chain.drive_joint])
        distances[i] = constraint_values(p, v, k_i)[2]
    return forces, torques, distances


@njit(cache=True, nogil=True)
def _evaluated_row(rows: StepRows, i, e: Evaluation):
    """Row i of a run's rows from the full evaluation of its step."""
    rows.reactions[i], rows.constraint_forces[i] = e.reactions, e.constraint_forces
    rows.residual[i], rows.residual_distance[i] = e.residual, e.distance
    rows.accounts[i] = e.accounts

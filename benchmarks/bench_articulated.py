"""The O(n) solve an O(n) step needs (:mod:`crane_reference.dynamics.articulated`), against the dense factor the step
uses today.

    python benchmarks/bench_articulated.py [--rfe 6 12 24 48] [--states 5] [--only solve refresh] [--duration 1]

The Newton iteration matrix of a step is B^T X B (plus the modal terms) with X = M + h^2/4 K + h/2 D and the column
drive's spring s_dr on psi2 (:func:`~crane_reference.dynamics.modal_correction.iteration_factor`); today it is
formed (M, then B^T X B) and factored by Cholesky, O(n^3).  The articulated solve takes X by the articulated-body
recursion, with the base's coupled joints as a dense root block, and the task constraints by a Schur complement
on m + 1 solves (m the dependent coordinates).

Per crane of ``--rfe`` (the flexible model, n_rfe elements per flexible link) it prints the largest difference of
the reduced solution from numpy's dense solve of B^T X B at ``--states`` random states (relative to the solution's
largest entry: the check), and, in ABA of its own chain (Pinocchio, this run), the cost of: the articulated
factorization with the constraints' Schur complement; one solve of the reduced system; today's M and iteration
factor; a Cholesky solve with it; and the factorization with a solve of r columns side by side, what a modal
correction of rank r (the resolved modes, Woodbury) adds.

[refresh] Per crane of ``--rfe``, the modal correction refreshed by subspace iteration from the last refresh's modes
(:func:`~crane_reference.dynamics.modal_correction.refreshed_correction`, as the integrator chains it) against the
full eigenproblem, at the states of ``--duration`` seconds of the paper's task at the node's step one
REFRESH_INTERVAL apart: the largest difference of Delta M_r and D_u from the full eigenproblem's (relative to its
largest entry: the check), beside how much the full terms change over one interval (what the step holds between
refreshes); how many refreshes fell back to the full eigenproblem; and the cost of either, in ABA (at the last
state).
"""

from __future__ import annotations

import argparse
from typing import NamedTuple

import numpy as np
from common import aba_time, call_seconds
from numba import njit

from crane_reference.dynamics.articulated import constrained_factor, reduced_solve
from crane_reference.dynamics.evaluation import accelerations_at
from crane_reference.dynamics.inertia import world_pseudo_inertias
from crane_reference.dynamics.kinematics import forward_kinematics
from crane_reference.dynamics.linalg import cholesky_solve
from crane_reference.dynamics.modal_correction import (
    GUARD_MODES,
    iteration_factor,
    modal_correction,
    reduced_mass_matrix,
    refreshed_correction,
)
from crane_reference.dynamics.step import mass_at, refresh_inputs
from crane_reference.model.config import load_config
from crane_reference.motion.integration import REFRESH_INTERVAL, ExactFrequencyTrapezoidal
from crane_reference.motion.simulation import MotionStepper, Scenario
from crane_reference.motion.steps import ONLINE_STEP


class Case(NamedTuple):
    """A state of a crane and what the solves need there."""

    S: np.ndarray
    Hw: np.ndarray
    A: np.ndarray
    B: np.ndarray
    M: np.ndarray


def random_case(scenario: Scenario, rng: np.random.Generator) -> Case:
    """A random state near the static equilibrium (every coordinate moved by up to 0.05 rad or m; velocities up to
    0.5 rad/s or m/s): the frames, A, B and M there."""
    motion = scenario.motion
    chain, partition = motion.dynamics.chain, motion.partition
    q = scenario.equilibrium.q + rng.uniform(-0.05, 0.05, scenario.equilibrium.q.size)
    qd = rng.uniform(-0.5, 0.5, q.size)
    acc = accelerations_at(q, qd, motion.constraints.coefficients(0.5), motion.dynamics.drive.kernel_parameters(0.5),
                           partition, chain)
    T, S = forward_kinematics(q, chain.kinds, chain.axes, chain.origins)
    return Case(S, world_pseudo_inertias(T, chain.body_joint, chain.body_H), acc.A, acc.velocity_map, acc.M)


@njit
def _repeat_articulated(S, Hw, A, spring_weight, damper_weight, drive_spring, chain, n):
    total = 0.0
    for _ in range(n):
        total += constrained_factor(S, Hw, A, spring_weight, damper_weight, drive_spring, chain).schur[0, 0]
    return total


@njit
def _repeat_reduced_solve(factor, independent, r, n):
    total = 0.0
    for _ in range(n):
        total += reduced_solve(factor, independent, r)[0, 0]
    return total


@njit
def _repeat_dense(S, Hw, B, correction, drive, partition, chain, h, n):
    total = 0.0
    for _ in range(n):
        total += iteration_factor(mass_at(S, Hw, chain), B, h, correction, drive, partition, chain)[0, 0]
    return total


@njit
def _repeat_dense_solve(factor, r, n):
    total = 0.0
    for _ in range(n):
        total += cholesky_solve(factor, r)[0]
    return total


def cost(repeat: int, function, *arguments) -> float:
    """[s] of one call of the compiled loop ``function(*arguments, n)``: n = ``repeat`` calls, median of a run, best of
    5 (after a warm-up of 2)."""
    function(*arguments, 2)
    return min(call_seconds(lambda: function(*arguments, repeat), 1, median=True) for _ in range(5)) / repeat


def crane(n_rfe: int, states: int, repeat: int) -> None:
    """The check and the costs for the flexible crane with ``n_rfe`` elements per flexible link."""
    scenario = Scenario(load_config().with_rfe_count(n_rfe), "flexible")
    motion = scenario.motion
    chain, partition = motion.dynamics.chain, motion.partition
    independent = partition.independent
    drive, h = motion.dynamics.drive.kernel_parameters(0.5), ONLINE_STEP
    weights = 0.25 * h * h, 0.5 * h  # X = M + h^2/4 (K + s_dr on psi2) + h/2 D
    matrix = weights[0] * chain.stiffness + weights[1] * chain.damping
    matrix[chain.drive_joint, chain.drive_joint] += weights[0] * drive[1]
    rng = np.random.default_rng(n_rfe)
    worst = 0.0
    for _ in range(states):
        case = random_case(scenario, rng)
        r = rng.normal(size=(independent.size, 1))
        dense = np.linalg.solve(case.B.T @ (case.M + matrix) @ case.B, r)
        factor = constrained_factor(case.S, case.Hw, case.A, *weights, weights[0] * drive[1], chain)
        worst = max(worst, np.abs(reduced_solve(factor, independent, r) - dense).max() / np.abs(dense).max())
    aba = aba_time(scenario)
    correction = modal_correction(reduced_mass_matrix(case.M, case.B, partition), h, 0.0, drive, partition, chain,
                                  ExactFrequencyTrapezoidal(motion).settings)
    dense_factor = iteration_factor(case.M, case.B, h, correction, drive, partition, chain)

    factor_cost = cost(repeat, _repeat_articulated, case.S, case.Hw, case.A, *weights, weights[0] * drive[1], chain)
    rank = correction.resolved
    solve_cost = cost(repeat, _repeat_reduced_solve, factor, independent, r)
    columns_cost = cost(repeat, _repeat_reduced_solve, factor, independent, rng.normal(size=(independent.size, rank)))
    dense_cost = cost(repeat, _repeat_dense, case.S, case.Hw, case.B, correction, drive, partition, chain, h)
    dense_solve_cost = cost(repeat, _repeat_dense_solve, dense_factor, r[:, 0].copy())
    print(f"n_rfe={n_rfe:2d} dof={chain.kinds.size:3d} n_ic={independent.size:3d} root block {chain.root_size}: "
          f"articulated against dense {worst:.1e} (largest, relative, {states} random states); ABA {aba * 1e6:.2f} us; "
          f"in ABA: articulated factor with the constraints {factor_cost / aba:.2f}, a reduced solve "
          f"{solve_cost / aba:.3f}, the factor with Woodbury's {rank} resolved columns solved side by side "
          f"{(factor_cost + columns_cost) / aba:.2f}; "
          f"today M and the iteration factor {dense_cost / aba:.2f}, a Cholesky solve {dense_solve_cost / aba:.3f}")


@njit
def _repeat_full(reduced_mass, h, drive, partition, chain, settings, n):
    total = 0.0
    for _ in range(n):
        total += modal_correction(reduced_mass, h, 0.0, drive, partition, chain, settings).inertia[0, 0]
    return total


@njit
def _repeat_refreshed(reduced_mass, S, Hw, B, correction, h, drive, partition, chain, settings, n):
    total = 0.0
    for _ in range(n):
        total += refreshed_correction(reduced_mass, S, Hw, B, correction, h, 0.0, drive, partition, chain,
                                      settings).inertia[0, 0]
    return total


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    """max |a - b| / max |b|."""
    return float(np.abs(a - b).max() / np.abs(b).max())


def refresh(n_rfe: int, duration: float, repeat: int) -> None:
    """[refresh] The iterated refresh against the full eigenproblem along the paper's task (see the module)."""
    scenario = Scenario(load_config().with_rfe_count(n_rfe), "flexible")
    motion, h = scenario.motion, ONLINE_STEP
    chain, partition = motion.dynamics.chain, motion.partition
    settings = ExactFrequencyTrapezoidal(motion).settings
    stepper = MotionStepper(motion, 0.0, scenario.equilibrium.q, np.zeros_like(scenario.equilibrium.q), h)
    difference, change, fallbacks, refreshes = 0.0, 0.0, 0, 0
    full = iterated = None
    for t in np.arange(1, round(duration / REFRESH_INTERVAL) + 1) * REFRESH_INTERVAL:
        stepper.advance_until(float(t))
        state, drive = stepper.state, motion.dynamics.drive.kernel_parameters(float(t))
        B = state.solution.velocity_map
        reduced_mass, S, Hw = refresh_inputs(state.q, B, partition, chain)
        previous, full = full, modal_correction(reduced_mass, h, float(t), drive, partition, chain, settings)
        if previous is None:
            iterated = full
            continue
        arguments = (reduced_mass, S, Hw, B, iterated, h, drive, partition, chain, settings)
        iterated = refreshed_correction(reduced_mass, S, Hw, B, iterated, h, float(t), drive, partition, chain,
                                        settings)
        refreshes += 1
        iterated_count = iterated.resolved + GUARD_MODES  # the full eigenproblem fills every column of the modes
        fallbacks += iterated_count >= partition.independent.size or bool(np.any(iterated.modes[:, iterated_count:]))
        difference = max(difference, _relative(iterated.inertia, full.inertia), _relative(iterated.damping,
                                                                                          full.damping))
        change = max(change, _relative(previous.inertia, full.inertia), _relative(previous.damping, full.damping))
    aba = aba_time(scenario)

    full_cost = cost(repeat, _repeat_full, reduced_mass, h, drive, partition, chain, settings)
    iterated_cost = cost(repeat, _repeat_refreshed, *arguments)
    print(f"[refresh] n_rfe={n_rfe:2d} n_ic={partition.independent.size:3d} resolved={full.resolved}: iterated "
          f"against the full eigenproblem {difference:.1e} (largest, relative, {refreshes} refreshes over "
          f"{duration:g} s; the full terms change by up to {change:.1e} over {REFRESH_INTERVAL * 1e3:g} ms); "
          f"fell back {fallbacks} times; ABA {aba * 1e6:.2f} us; in ABA: full eigenproblem {full_cost / aba:.1f}, "
          f"iterated {iterated_cost / aba:.1f}")


SECTIONS = ("solve", "refresh")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rfe", nargs="+", type=int, default=[6, 12, 24, 48])
    parser.add_argument("--states", type=int, default=5)
    parser.add_argument("--only", nargs="+", choices=SECTIONS, default=SECTIONS, help="sections to run")
    parser.add_argument("--duration", type=float, default=1.0, help="[refresh]: seconds of the paper's task")
    args = parser.parse_args()
    if args.states < 1:
        parser.error("--states: at least 1 random state")
    if args.duration < 2 * REFRESH_INTERVAL:
        parser.error(f"--duration: at least {2 * REFRESH_INTERVAL:g} s (two refreshes)")
    for n_rfe in args.rfe:
        if "solve" in args.only:
            crane(n_rfe, args.states, 3000 if n_rfe <= 12 else 500)
        if "refresh" in args.only:
            refresh(n_rfe, args.duration, 200 if n_rfe <= 12 else 20)


if __name__ == "__main__":
    main()

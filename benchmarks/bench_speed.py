"""Speed of the simulation core; prints the figures quoted in the README and the closing notes.

    python benchmarks/bench_speed.py [--duration 10] [--repeats 3] [--only eval profile speed] [--rfe 6 24]
                                     [--cutoff 0.3] [--mode-tracking 0.002]

The machine's speed drifts between days, so every time is also given as a multiple of one call of
Pinocchio's ABA (forward dynamics) on the URDF that crane-reference exports for the same chain, measured in
the same run.

1. [eval] Time of M(q) with h, gravity and E's kinematics, and of one full qdd from (8), at 24 DOF; the cost
   of calling a compiled function with the ChainData named tuple.
2. [profile] Per crane of ``--rfe`` (default 6), the compiled cost of the parts of one step (timed in compiled
   loops, also in ABA calls): M alone, the modal correction (an eigenproblem, every REFRESH_INTERVAL of motion), the
   same refreshed by subspace iteration from the modes one REFRESH_INTERVAL before (at 1.01 s of the paper's task
   from those at 1 s; the full eigenproblem where no guard mode fits), the tracking of its resolved modes (every
   MODE_TRACKING_INTERVAL), the iteration factor, per Newton evaluation a projection and a residual, a full
   evaluation (on the rows a caller reads) and what the node reads of a row (its effort and constraint distance, by
   inverse dynamics: ``evaluated_rows``); beside ABA, in the same run, Pinocchio's counterparts of three of them:
   inverse dynamics (RNEA: a Newton residual), the mass matrix (CRBA: M) and forward kinematics.
3. [speed] Per case (rigid; flexible with n_rfe = 6, 12, 24): Pinocchio's ABA per call; at
   the node's default ``ONLINE_STEP`` and at 1 ms the steps alone per step (compiled runs of
   0.25 s, best of ``--repeats``), as a multiple of one ABA call and as a real-time factor, and with every
   row's full evaluation (what simulate records); single steps (one compiled call each, from 1 s on):
   median, worst and 99.9 % quantile; the mean Newton evaluations per step and the largest constraint residual.
4. [scaling] (not by default) The step at ONLINE_STEP in ABA of its own chain at n_rfe = 6, 12, 24 and 48, with
   the iteration matrix factored densely and solved by the articulated-body recursion (and which of the two the
   integrator chooses), their growth from n_rfe = 12, and the parts of a dense step in ABA with their growth
   (where the cost is not O(n)).
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from common import aba_time, call_seconds, newton_iterations, pinocchio_times, run_times
from numba import njit

from crane_reference.dynamics.evaluation import accelerations_at, evaluate
from crane_reference.dynamics.inertia import world_pseudo_inertias
from crane_reference.dynamics.kinematics import forward_kinematics
from crane_reference.dynamics.modal_correction import (
    iteration_factor,
    modal_correction,
    reduced_mass_matrix,
    refreshed_correction,
    tracked_correction,
)
from crane_reference.dynamics.projection import project_positions
from crane_reference.dynamics.runs import evaluated_rows, integration_run
from crane_reference.dynamics.step import mass_at, newton_residual, refresh_inputs
from crane_reference.dynamics.structures import Coefficients, StepSettings, StepStart
from crane_reference.dynamics.terms import chain_terms, end_effector_jacobian, position_terms
from crane_reference.model.config import load_config
from crane_reference.model.description import CraneDescription
from crane_reference.motion import integration
from crane_reference.motion.integration import REFRESH_INTERVAL, ExactFrequencyTrapezoidal, stop_flag
from crane_reference.motion.simulation import MotionStepper, Scenario, simulate
from crane_reference.motion.steps import ONLINE_STEP


@njit
def _read_chain(chain):
    return chain.gravity


@njit
def _read_fields(kinds, axes, origins, body_joint, body_H, gravity, ee_joint, ee_point, stiffness, damping,
                 damped, drive_joint):
    return gravity


def evaluation_times(params: CraneDescription) -> None:
    scenario = Scenario(params, "flexible")
    q = scenario.equilibrium.q
    qd = np.full_like(q, 0.01)
    d, m = scenario.dynamics, scenario.model
    t_m = call_seconds(lambda: chain_terms(q, qd, d.chain), 2000)
    t_qdd = call_seconds(lambda: scenario.motion.solve(0.5, q, qd), 2000)
    print(f"[eval] {m.dof} DOF: M(q) with h, gravity and E kinematics {t_m * 1e6:.1f} us; "
          f"full qdd from (8) incl. constraints and Python wrapper {t_qdd * 1e6:.1f} us")
    t_named = min(call_seconds(lambda: _read_chain(d.chain), 2000) for _ in range(5))
    t_fields = min(call_seconds(lambda: _read_fields(*d.chain), 2000) for _ in range(5))
    print(f"[eval] calling a compiled function from Python with the ChainData named tuple {t_named * 1e6:.2f} us, "
          f"with its 11 fields as arguments {t_fields * 1e6:.2f} us (best of 5)")


def step_times(scenario: Scenario, step: float, duration: float, after: float = 1.0) -> np.ndarray:
    """Wall time [s] of each step over ``duration`` seconds from t = ``after`` (past the drive's jumps), each
    step one compiled call from Python with its inputs prepared beforehand (what one step costs a caller
    that steps one at a time, call included)."""
    stepper = MotionStepper(scenario.motion, 0.0, scenario.equilibrium.q, np.zeros_like(scenario.equilibrium.q),
                            step)
    stepper.advance_until(after)
    state, motion, settings = stepper.state, scenario.motion, stepper.integrator.settings
    times = state.t + step * np.arange(1, round(duration / step) + 1)
    k, drives = motion.constraints.coefficients_at(times), motion.dynamics.drive.kernel_parameters(times)
    q, qd, qdd, B, earlier, correction, t0 = state.q, state.qd, state.solution.qdd, state.solution.velocity_map, \
        state.earlier, state.correction, state.t
    evaluated = np.zeros(1, dtype=np.bool_)
    walls = np.empty(times.size)
    for i in range(times.size):
        k_i = Coefficients(k.Q[i:i + 1], k.g[i:i + 1], k.c[i:i + 1], k.order)
        start = time.perf_counter()
        run = integration_run(StepStart(t0, q, qd, qdd, B, earlier, correction), times[i:i + 1], k_i,
                              drives[i:i + 1], motion.partition, motion.dynamics.chain, settings, evaluated,
                              stop_flag())
        walls[i] = time.perf_counter() - start
        last = run.last
        q, qd, qdd, earlier, correction, t0 = last.q, last.qd, run.rows.qdd[0], last.earlier, last.correction, times[i]
        B = last.evaluation.terms.velocity_map
    return walls


def speed(params: CraneDescription, duration: float, repeats: int) -> None:
    """[speed] Per case (the crane rigid, with its own RFE counts, with 12 and 24 in every flexible link): the
    steps alone (compiled runs of 0.25 s from rest, past the drive's torque jumps of the task, best of
    ``repeats``) per step as a multiple of one Pinocchio ABA call on the same chain, measured in this run,
    and as a real-time factor; the same with every row evaluated (``simulate``'s records); single steps (one
    compiled call each, from 1 s on): median, worst and 99.9 % quantile; the mean Newton evaluations per
    step and the largest constraint residual."""
    own = tuple(link.beam.rfe_count for link in params.flexible_links)
    cases = [("rigid", params), ("flexible", params),
             *(("flexible", params.with_rfe_count(n)) for n in (12, 24) if own != (n,) * len(own))]
    for variant, p in cases:
        scenario = Scenario(p, variant)
        q0 = scenario.equilibrium.q
        simulate(scenario.motion, q0, 0.01, step=1e-3)  # compile / load the kernels
        aba = aba_time(scenario)
        counts = [link.beam.rfe_count if variant == "flexible" else 1 for link in p.flexible_links]
        rfe = "/".join(map(str, counts)) or "-"
        label = f"[speed] {p.name} {variant:8s} n_rfe={rfe:>5} dof={scenario.model.dof:2d}"
        print(f"{label}: Pinocchio ABA on the exported URDF {aba * 1e6:.2f} us/call")
        for step in (ONLINE_STEP, 1e-3):
            steps = round(duration / step)
            alone = min(run_times(scenario, step, duration, False) for _ in range(repeats)) / steps
            recorded = min(run_times(scenario, step, duration, True) for _ in range(repeats)) / steps
            single = step_times(scenario, step, 2.0)
            residual = simulate(scenario.motion, q0, min(duration, 2.0), step=step).residual_distance.max()
            print(f"{label} h={step * 1e3:.2f} ms: steps alone {alone * 1e6:6.1f} us/step = {alone / aba:4.1f} ABA, "
                  f"real-time factor {step / alone:5.1f}; every row evaluated {recorded * 1e6:6.1f} us/step = "
                  f"{recorded / aba:4.1f} ABA; single steps median {np.median(single) * 1e6:.1f} us, worst "
                  f"{single.max() * 1e6:.1f} us ({single.max() / np.median(single):.1f}x median), 99.9 % below "
                  f"{np.quantile(single, 0.999) * 1e6:.1f} us; Newton evaluations "
                  f"{newton_iterations(scenario, step):.2f}/step, max residual {residual:.1e} m")


@njit
def _repeat_position_terms(q, chain, n):
    total = 0.0
    for _ in range(n):
        total += position_terms(q, chain)[3][0, 0]
    return total


@njit
def _repeat_mass(q, chain, n):
    T, S = forward_kinematics(q, chain.kinds, chain.axes, chain.origins)
    Hw = world_pseudo_inertias(T, chain.body_joint, chain.body_H)
    total = 0.0
    for _ in range(n):
        total += mass_at(S, Hw, chain)[0, 0]
    return total


@njit
def _repeat_end_effector(q, chain, n):
    total = 0.0
    for _ in range(n):
        total += end_effector_jacobian(q, chain)[0][0]
    return total


@njit
def _repeat_projection(q, k, holonomic_dependent, chain, n):
    total = 0.0
    for _ in range(n):
        total += project_positions(q, k, holonomic_dependent, chain, 1e-9, 25).q[0]
    return total


@njit
def _repeat_accelerations(q, qd, k, drive, partition, chain, n):
    total = 0.0
    for _ in range(n):
        total += accelerations_at(q, qd, k, drive, partition, chain).qdd[0]
    return total


@njit
def _repeat_residual(q, qd, a, k, drive, partition, chain, n):
    at = project_positions(q, k, partition.holonomic_dependent, chain, 1e-9, 25)
    total = 0.0
    for _ in range(n):
        Hw = world_pseudo_inertias(at.T, chain.body_joint, chain.body_H)
        total += newton_residual(q, qd, a, at.T, at.S, Hw, at.ee_position, at.ee_jacobian, k, drive,
                                         partition, chain)[1][0]
    return total


@njit
def _repeat_factor(M, B, correction, drive, partition, chain, n):
    total = 0.0
    for _ in range(n):
        total += iteration_factor(M, B, 1e-3, correction, drive, partition, chain)[0, 0]
    return total


@njit
def _repeat_correction(reduced_mass, drive, partition, chain, settings, n):
    total = 0.0
    for _ in range(n):
        total += modal_correction(reduced_mass, 1e-3, 0.0, drive, partition, chain, settings).inertia[0, 0]
    return total


@njit
def _repeat_refresh(reduced_mass, S, Hw, B, correction, drive, partition, chain, settings, n):
    total = 0.0
    for _ in range(n):
        total += refreshed_correction(reduced_mass, S, Hw, B, correction, ONLINE_STEP, 0.0, drive, partition, chain,
                                      settings).inertia[0, 0]
    return total


@njit
def _repeat_tracking(reduced_mass, correction, drive, partition, chain, settings, n):
    total = 0.0
    for _ in range(n):
        total += tracked_correction(reduced_mass, correction, 0.0, drive, partition, chain, settings).inertia[0, 0]
    return total


@njit
def _repeat_evaluation(q, qd, k, drive, partition, chain, n):
    total = 0.0
    for _ in range(n):
        total += evaluate(q, qd, k, drive, partition, chain).accounts[0]
    return total


@njit
def _repeat_read_row(q, qd, qdd, k, drives, partition, chain, n):
    total = 0.0
    for _ in range(n):
        total += evaluated_rows(q, qd, qdd, k, drives, partition, chain)[1][0]
    return total


PART_NAMES = {
    "position_terms": "M, gravity, E's Jacobian (position_terms)",
    "mass": "M alone, from the frames (mass_at)",
    "kinematics": "E's position and Jacobian (kinematics only)",
    "projection": "projection on the position constraints",
    "residual": "Newton residual of (8) by inverse dynamics",
    "correction": f"modal correction (eigenproblem, every {REFRESH_INTERVAL * 1e3:g} ms)",
    "refresh": f"modal correction iterated from {REFRESH_INTERVAL * 1e3:g} ms old modes",
    "tracking": "resolved modes tracked (tracked_correction)",
    "factor": "iteration matrix and its Cholesky factor",
    "accelerations": "qdd from (8) solved (accelerations_at)",
    "evaluation": "full evaluation (+ residuals, reactions, accounts)",
    "read_row": "a read row's effort and distance (evaluated_rows)",
}


def _refresh_arguments(scenario: Scenario, drive: np.ndarray, settings: StepSettings) -> tuple:
    """[profile] What a refresh of the paper's task at t = 1.01 s reads (``refreshed_correction``): M_r, the twists,
    world pseudo-inertias and velocity map there, and the modal correction of t = 1 s (at the node's step)."""
    motion = scenario.motion
    stepper = MotionStepper(motion, 0.0, scenario.equilibrium.q, np.zeros_like(scenario.equilibrium.q), ONLINE_STEP)
    chain, partition, states = motion.dynamics.chain, motion.partition, []
    for t in (1.0, 1.0 + REFRESH_INTERVAL):
        stepper.advance_until(t)
        B = stepper.state.solution.velocity_map
        states.append((*refresh_inputs(stepper.state.q, B, partition, chain), B))
    old = modal_correction(states[0][0], ONLINE_STEP, 0.0, drive, partition, chain, settings)
    return (*states[1], old, drive, partition, chain, settings)


def part_calls(scenario: Scenario) -> list[tuple[str, Callable, tuple]]:
    """Each part of :data:`PART_NAMES` on the flexible ``scenario`` as (name, its compiled loop, the loop's arguments
    but the count of calls)."""
    motion = scenario.motion
    q, chain, partition = scenario.equilibrium.q, motion.dynamics.chain, motion.partition
    qd = np.full_like(q, 0.01)
    k, drive = motion.constraints.coefficients(0.5), motion.dynamics.drive.kernel_parameters(0.5)
    off = q.copy()
    off[motion.holonomic_dependent] += 1e-6  # a predictor 1e-6 rad off the constraints
    acc = accelerations_at(q, qd, k, drive, partition, chain)
    settings = ExactFrequencyTrapezoidal(motion).settings
    B = acc.velocity_map
    reduced_mass = B.T @ acc.M @ B
    correction = modal_correction(reduced_mass, ONLINE_STEP, 0.0, drive, partition, chain, settings)
    return [("position_terms", _repeat_position_terms, (q, chain)),
            ("mass", _repeat_mass, (q, chain)),
            ("kinematics", _repeat_end_effector, (q, chain)),
            ("projection", _repeat_projection, (off, k, motion.holonomic_dependent, chain)),
            ("residual", _repeat_residual, (q, qd, acc.qdd[partition.integrated], k, drive, partition, chain)),
            ("correction", _repeat_correction, (reduced_mass, drive, partition, chain, settings)),
            ("refresh", _repeat_refresh, _refresh_arguments(scenario, drive, settings)),
            ("tracking", _repeat_tracking, (reduced_mass, correction, drive, partition, chain, settings)),
            ("factor", _repeat_factor, (acc.M, acc.velocity_map, correction, drive, partition, chain)),
            ("accelerations", _repeat_accelerations, (q, qd, k, drive, partition, chain)),
            ("evaluation", _repeat_evaluation, (q, qd, k, drive, partition, chain)),
            ("read_row", _repeat_read_row,
             (q[None], qd[None], acc.qdd[None], Coefficients(k.Q[None], k.g[None], k.c[None], k.order),
              drive[None], partition, chain))]


def part_times(scenario: Scenario, repeat: int) -> dict[str, float]:
    """The compiled cost [s] of each part of :data:`PART_NAMES` on the flexible ``scenario`` (:func:`part_calls`),
    each timed in a compiled loop of ``repeat`` calls (no Python call overhead), best of 5."""
    times = {}
    for name, function, arguments in part_calls(scenario):
        function(*arguments, 10)
        timed = lambda f=function, a=arguments: f(*a, repeat)  # noqa: E731 (one compiled loop of repeat calls)
        times[name] = min(call_seconds(timed, 1, median=True) for _ in range(5)) / repeat
    return times


def component_times(params: CraneDescription, rfe_count: int, repeat: int = 3000) -> None:
    """[profile] Compiled cost of the parts of a step (flexible, ``rfe_count`` RFEs; :func:`part_times`), also as
    a multiple of one Pinocchio ABA call on the same chain in this run, with Pinocchio's RNEA, CRBA and forward
    kinematics beside it (:func:`common.pinocchio_times`; RNEA and CRBA compute their own kinematics, the residual
    and M here are given the frames): a step is a factor, per Newton evaluation a projection and a residual, and at
    its end a projection and a full evaluation with the integrator's qdd; every REFRESH_INTERVAL of motion the modal
    correction."""
    scenario = Scenario(params.with_rfe_count(rfe_count), "flexible")
    partition = scenario.motion.partition
    peer = pinocchio_times(scenario, 20000 if rfe_count <= 12 else 5000)
    aba = peer.aba
    print(f"[profile] n_rfe={rfe_count:2d} dof={scenario.model.dof:2d} n_ic={partition.independent.size:2d}: "
          f"Pinocchio ABA {aba * 1e6:.2f} us/call; its counterparts of the parts below, in ABA: inverse dynamics "
          f"(RNEA) {peer.rnea / aba:.2f}, the mass matrix (CRBA) {peer.crba / aba:.2f}, forward kinematics "
          f"{peer.forward_kinematics / aba:.2f}")
    for name, seconds in part_times(scenario, repeat).items():
        print(f"[profile] n_rfe={rfe_count:2d} {PART_NAMES[name]:<52} {seconds * 1e6:7.2f} us = "
              f"{seconds / aba:6.2f} ABA")


SCALING_RFE = (6, 12, 24, 48)
"""[scaling]: the boom's RFE counts of the table."""


class ScalingRow(NamedTuple):
    """[scaling]: one crane's row: its size, Pinocchio's ABA and the step [s], and the parts in ABA."""

    n_rfe: int
    dof: int
    n_ic: int
    resolved: int
    aba: float
    step: float
    articulated_step: float
    chosen: bool
    parts: dict[str, float]


def resolved_modes(scenario: Scenario, step: float) -> int:
    """How many modes of the reduced pencil (K_r, M_r) at the equilibrium have omega h below the cutoff: the rank of
    the modal inertia correction Delta M_r; the others make up the unresolved damping D_u."""
    motion = scenario.motion
    q, chain, partition = scenario.equilibrium.q, motion.dynamics.chain, motion.partition
    drive = motion.dynamics.drive.kernel_parameters(0.0)
    acc = accelerations_at(q, np.zeros_like(q), motion.constraints.coefficients(0.0), drive, partition, chain)
    return modal_correction(reduced_mass_matrix(acc.M, acc.velocity_map, partition), step, 0.0, drive, partition,
                            chain, ExactFrequencyTrapezoidal(motion).settings).resolved


def scaling(params: CraneDescription, duration: float, repeats: int) -> None:
    """[scaling] Per n_rfe of :data:`SCALING_RFE` (every flexible link): the step at the node's ONLINE_STEP (the
    steps alone, compiled runs of 0.25 s from rest, best of ``repeats``) with the dense iteration matrix and with
    the articulated one, in ABA of its own chain (Pinocchio, this run), and their growth from n_rfe = 12 (a step of
    O(n) cost would not grow); beside them the parts of a dense step (:func:`part_times`) in ABA, with the modal
    correction per step (the integrator's refresh, iterated or the full eigenproblem, times ONLINE_STEP /
    REFRESH_INTERVAL), and how each part grows from 12 to the row's n_rfe."""
    rows = []
    for n_rfe in SCALING_RFE:
        scenario = Scenario(params.with_rfe_count(n_rfe), "flexible")
        simulate(scenario.motion, scenario.equilibrium.q, 0.01, step=1e-3)  # compile / load the kernels
        aba = aba_time(scenario)
        steps = round(duration / ONLINE_STEP)
        step, articulated = (min(run_times(scenario, ONLINE_STEP, duration, False, articulated=articulated)
                                 for _ in range(repeats)) / steps for articulated in (False, True))
        parts = part_times(scenario, 3000 if n_rfe <= 12 else 300)
        integrator = ExactFrequencyTrapezoidal(scenario.motion)
        parts["modal"] = parts["refresh" if integrator.subspace_refresh else "correction"] * (
            ONLINE_STEP / REFRESH_INTERVAL)
        rows.append(ScalingRow(n_rfe, scenario.model.dof, scenario.motion.partition.independent.size,
                               resolved_modes(scenario, ONLINE_STEP), aba, step, articulated, integrator.articulated,
                               {name: parts[name] / aba for name in ("factor", "position_terms", "residual",
                                                                     "projection", "modal")}))
    base = next((row for row in rows if row.n_rfe == 12), rows[0])
    print(f"[scaling] h = {ONLINE_STEP * 1e3:g} ms; each cost in ABA of its own chain (x: growth from "
          f"n_rfe = {base.n_rfe}); the step with the iteration matrix dense, then articulated (*: the integrator's "
          f"choice, articulated from n_ic = {integration.ARTICULATED_FROM}); parts of the dense step: "
          f"iteration factor / M (position_terms) / a Newton residual / a projection / "
          f"modal correction per step (the integrator's refresh: iterated from the last modes from n_ic = "
          f"{integration.ARTICULATED_FROM}, else the full eigenproblem); modes resolved "
          f"(omega h < {integration.CUTOFF / math.pi:g} pi) of n_ic; "
          f"the rest: the step less those three (its Newton residuals and projections, the solves with the factor, "
          f"the modal terms' products, the step's end)")
    for n_rfe, dof, n_ic, resolved, aba, step, articulated, chosen, parts in rows:
        growth = " / ".join(f"{value:.2f} ({value / base.parts[name]:.1f}x)" for name, value in parts.items())
        dense = parts["factor"] + parts["position_terms"] + parts["modal"]
        print(f"[scaling] n_rfe={n_rfe:2d} dof={dof:3d} n_ic={n_ic:3d} resolved={resolved:2d}: ABA "
              f"{aba * 1e6:6.2f} us; step dense{' ' if chosen else '*'} {step * 1e6:7.1f} us = {step / aba:4.1f} ABA "
              f"({step / aba / (base.step / base.aba):.2f}x), articulated{'*' if chosen else ' '} "
              f"{articulated * 1e6:7.1f} us = {articulated / aba:4.1f} ABA "
              f"({articulated / aba / (base.articulated_step / base.aba):.2f}x), real-time factor "
              f"{ONLINE_STEP / min(step, articulated):5.1f}; parts {growth}; the rest {step / aba - dense:.2f} ABA")


SECTIONS = ("eval", "profile", "speed", "scaling")
DEFAULT_SECTIONS = ("eval", "profile", "speed")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--only", nargs="+", choices=SECTIONS, default=DEFAULT_SECTIONS, help="sections to run")
    parser.add_argument("--rfe", nargs="+", type=int, default=[6], help="[profile]: the cranes' RFE counts")
    parser.add_argument("--config", help="crane file (default: the packaged crane, the paper's); a crane's step is "
                        "stated in ABA of its own chain")
    parser.add_argument("--cutoff", type=float, help="omega h [pi rad] from which every integrator made damps a mode "
                        "instead of resolving it (default: integration.CUTOFF; the resolved bandwidth, 800 Hz, "
                        "stays: above 0.8 it has no effect at the node's step)")
    parser.add_argument("--mode-tracking", type=float, help="[s] of motion after which every integrator made tracks "
                        "its resolved modes (0: every step, inf: never; default: integration.MODE_TRACKING_INTERVAL)")
    args = parser.parse_args()
    if args.cutoff is not None:
        integration.CUTOFF = args.cutoff * math.pi  # what every integrator made from now on resolves below
    if args.mode_tracking is not None:
        integration.MODE_TRACKING_INTERVAL = args.mode_tracking
    params = load_config(args.config)
    if "eval" in args.only:
        evaluation_times(params)
    if "profile" in args.only:
        for rfe_count in args.rfe:
            component_times(params, rfe_count, repeat=3000 if rfe_count <= 12 else 300)
    if "speed" in args.only:
        speed(params, args.duration, args.repeats)
    if "scaling" in args.only:
        scaling(params, min(args.duration, 2.0), args.repeats)


if __name__ == "__main__":
    main()

"""Heap allocations of the compiled step: how many arrays numba's runtime (NRT) allocates per integration step and per
part of a step.  Counts, not times: they do not drift with the machine.

    python benchmarks/bench_allocations.py [--rfe 6 24 48] [--duration 1]

Every array a kernel makes (``np.empty``, ``np.zeros``, a copy, an arithmetic result) is one allocation and one free
by the C allocator, and passing it on costs reference counts; on a step of a few ABA these add up.

1. [step] Per crane (every flexible link with ``--rfe`` elements): allocations per step of the integrator's compiled
   runs at the node's ``ONLINE_STEP`` (the steps alone, as ``bench_speed.py --only speed`` times them), counted over
   ``--duration`` seconds of the paper's task after the first ``--duration`` (the drive's torque jumps and the first
   modal correction behind).
2. [parts] Per crane, allocations per call of each part of ``bench_speed.py --only profile`` (``part_calls``): a
   compiled loop of 11 calls less one of 1, over 10.
"""

from __future__ import annotations

import os

os.environ["NUMBA_NRT_STATS"] = "1"  # before numba is imported: the runtime counts its allocations

import argparse

import numpy as np
from bench_speed import PART_NAMES, part_calls
from numba.core.runtime import rtsys

from crane_reference.model.config import load_config
from crane_reference.motion.integration import ExactFrequencyTrapezoidal
from crane_reference.motion.simulation import Scenario
from crane_reference.motion.steps import ONLINE_STEP


def allocations() -> int:
    """NRT allocations so far in this process."""
    return rtsys.get_allocation_stats().alloc


def step_allocations(scenario: Scenario, duration: float) -> tuple[float, bool]:
    """Allocations per step of the integrator's compiled runs over ``duration`` s of the task after the first
    ``duration`` s from rest, and whether the integrator chose the articulated iteration matrix."""
    integrator = ExactFrequencyTrapezoidal(scenario.motion)
    state = integrator.start(0.0, scenario.equilibrium.q, np.zeros_like(scenario.equilibrium.q))
    steps = round(duration / ONLINE_STEP)
    state, _ = integrator.run(state, ONLINE_STEP * np.arange(1, steps + 1), every_row=False)
    before = allocations()
    integrator.run(state, ONLINE_STEP * np.arange(steps + 1, 2 * steps + 1), every_row=False)
    return (allocations() - before) / steps, integrator.articulated


def part_allocations(scenario: Scenario) -> dict[str, float]:
    """Allocations per call of each part of :func:`bench_speed.part_calls`."""
    counts = {}
    for name, function, arguments in part_calls(scenario):
        function(*arguments, 1)
        before = allocations()
        function(*arguments, 1)
        once = allocations() - before
        before = allocations()
        function(*arguments, 11)
        counts[name] = (allocations() - before - once) / 10
    return counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rfe", nargs="+", type=int, default=[6, 24, 48], help="the cranes' RFE counts")
    parser.add_argument("--duration", type=float, default=1.0, help="[s] of motion counted (after as much again)")
    args = parser.parse_args()
    params = load_config()
    for n_rfe in args.rfe:
        scenario = Scenario(params.with_rfe_count(n_rfe), "flexible")
        per_step, articulated = step_allocations(scenario, args.duration)
        label = f"n_rfe={n_rfe:2d} dof={scenario.model.dof:3d}"
        print(f"[step] {label}: {per_step:.1f} allocations per step at h = {ONLINE_STEP * 1e3:g} ms "
              f"({'articulated' if articulated else 'dense'} iteration matrix)", flush=True)
        for name, count in part_allocations(scenario).items():
            print(f"[parts] {label} {PART_NAMES[name]:<52} {count:6.1f} per call", flush=True)


if __name__ == "__main__":
    main()

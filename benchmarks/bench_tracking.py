"""Closed-loop runs (crane-reference track): the figures quoted in the README.

    python benchmarks/bench_tracking.py [--duration 5] [--only speed exact energy inertia]

1. [speed] Per crane (rigid; flexible, the default) and controller rate (1000 Hz, 100 Hz), PD with rigid
inverse-dynamics feedforward following the ideal reference: the wall time of the whole run, of its
references computed alone (the reference and the feedforward's rigid reference; the run computes them in a
thread beside the loop) and of the compiled closed loop within the run (``TrackingRun.loop_wall``), the
closed-loop simulated seconds per wall second, and the loop's cost per integrator step as a multiple of
one call of Pinocchio's ABA on the exported URDF of the same chain, measured in the same run (the machine's
speed drifts between days).
2. [exact] The rigid crane under the exact feedforward alone (reference realised by the luff and knuckle
   torques, zero gains, 2 s across the drive's jump): the largest |(x/a)^2 + (y/b)^2 - 1| and |z - z_a(t)|
   of the plant's E at h = 1 and 0.5 ms.
3. [energy] The energy-balance error of the default closed loop (flexible crane, 5 s) at h = 1 and
   0.5 ms, beside the work the drive and commands feed in and the dampers (the joint drives' velocity
   loops among them) take out.
4. [inertia] Per actuated joint of the flexible crane at the start: diag M, the inertia it carries at high
   frequency 1 / (M^-1)_jj, and kd h / J for the default gains at h = 1 ms (a D term held over the step
   is unstable beyond 2).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from common import aba_time

from crane_reference.analysis.tracking.closed_loop import TrackingSpec, run_tracking
from crane_reference.control.controller import JointGains
from crane_reference.control.plant import held_start
from crane_reference.model.config import load_config
from crane_reference.model.description import CraneDescription
from crane_reference.motion.simulation import Scenario, simulate

SECTIONS = ("speed", "exact", "energy", "inertia")


def speed(params: CraneDescription, duration: float) -> None:
    """[speed] of the module docstring."""
    args = argparse.Namespace(duration=duration)
    for variant in ("rigid", "flexible"):
        scenario = Scenario(params, variant)
        run_tracking(params, TrackingSpec(variant=variant, duration=0.05))  # compile / load the kernels
        aba = aba_time(scenario)
        references = 0.0  # the reference, and on the flexible crane the rigid feedforward's own, alone
        for s in (scenario, Scenario(params, "rigid")) if variant == "flexible" else (scenario,):
            start = time.perf_counter()
            simulate(s.motion, s.equilibrium.q, args.duration, step=1e-3, every_row=False)
            references += time.perf_counter() - start
        for rate in (1000.0, 100.0):
            spec = TrackingSpec(variant=variant, rate=rate, duration=args.duration)
            start = time.perf_counter()
            run = run_tracking(params, spec)
            wall = time.perf_counter() - start
            loop = run.loop_wall
            steps = round(args.duration / spec.step)
            summary = run.summary()
            print(f"[tracking] {variant:8s} dof={scenario.model.dof:2d} controller {rate:6.0f} Hz, step "
                  f"{spec.step * 1e3:.0f} ms, {args.duration:g} s: {wall:.2f} s wall = {args.duration / wall:.2f}x "
                  f"real time (its references alone {references:.2f} s, computed beside the loop; the compiled "
                  f"closed loop {loop:.2f} s = {args.duration / loop:.2f}x real time, {loop / steps * 1e6:.0f} "
                  f"us/step = {loop / steps / aba:.0f} ABA of {aba * 1e6:.1f} us); E off the ellipse <= "
                  f"{summary['ellipse_distance_max_m'] * 1e3:.2f} mm, height error <= "
                  f"{summary['height_error_max_m'] * 1e3:.2f} mm")


def exact(params: CraneDescription) -> None:
    """[exact] of the module docstring (the task written out as in crane_reference/test/test_simulation.py)."""
    zero = {name: JointGains(0.0, 0.0) for name in params.actuated}
    scenario, task = Scenario(params, "rigid"), params.task
    for step in (1e-3, 5e-4):
        run = run_tracking(params, TrackingSpec(variant="rigid", realisation="servo", gains=zero, duration=2.0,
                                                step=step, rate=1.0 / step, reference_step=step))
        x, y, z = run.plant.ee_position.T
        s = np.clip(run.t / task.rise_time, 0.0, 1.0)
        z_a = scenario.z_static + task.z_increment * (10 * s**3 - 15 * s**4 + 6 * s**5)
        print(f"[exact] h={step * 1e3:.1f} ms: |(x/a)^2 + (y/b)^2 - 1| <= "
              f"{np.abs((x / task.ellipse_a) ** 2 + (y / task.ellipse_b) ** 2 - 1).max():.2e}, "
              f"|z - z_a| <= {np.abs(z - z_a).max():.2e} m")


def energy(params: CraneDescription, duration: float) -> None:
    """[energy] of the module docstring."""
    for step in (1e-3, 5e-4):
        plant = run_tracking(params, TrackingSpec(duration=duration, step=step, rate=1.0 / step,
                                                  reference_step=step)).plant
        print(f"[energy] flexible, {duration:g} s, h={step * 1e3:.1f} ms: balance error <= "
              f"{np.abs(plant.energy_balance_error).max():.3g} J; drive and commands fed in "
              f"{plant.work_drive[-1]:.4g} J, dampers took {-plant.work_damping[-1]:.4g} J")


def inertia(params: CraneDescription) -> None:
    """[inertia] of the module docstring."""
    scenario = Scenario(params, "flexible")
    start = held_start(scenario)
    M = scenario.dynamics.terms(0.0, start.q, np.zeros_like(start.q)).M
    diagonal = np.array([M[j, j] for j in map(scenario.model.index, params.actuated)])
    gains = TrackingSpec().joint_gains(params.actuated, diagonal)
    inverse = np.linalg.inv(M)
    for name, J, g in zip(params.actuated, diagonal, gains, strict=True):
        local = 1.0 / inverse[scenario.model.index(name), scenario.model.index(name)]
        print(f"[inertia] {name}: diag M {J:.4g} kg m^2, 1/(M^-1)_jj {local:.4g} kg m^2, kd {g.kd:.4g} N m s/rad, "
              f"kd h / J at 1 ms {g.kd * 1e-3 / local:.3g}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=5.0)
    parser.add_argument("--only", nargs="+", choices=SECTIONS, default=SECTIONS, help="sections to run")
    args = parser.parse_args()
    params = load_config()
    if "speed" in args.only:
        speed(params, args.duration)
    if "exact" in args.only:
        exact(params)
    if "energy" in args.only:
        energy(params, args.duration)
    if "inertia" in args.only:
        inertia(params)


if __name__ == "__main__":
    main()

"""Speed of closed-loop runs (crane-reference track); prints the figures quoted in the README.

    python benchmarks/bench_tracking.py [--duration 5]

Per crane (rigid; flexible, the default) and controller rate (1000 Hz, 100 Hz), PD with rigid
inverse-dynamics feedforward following the ideal reference: the wall time of the whole run and of its
parts (the reference and the feedforward's rigid reference, computed first; the closed loop), the
closed-loop simulated seconds per wall second, and the loop's cost per integrator step as a multiple of
one call of Pinocchio's ABA on the exported URDF of the same chain, measured in the same run (the machine's
speed drifts between days).
"""

from __future__ import annotations

import argparse
import time

from bench_speed import aba_time

from crane_reference.analysis.tracking.closed_loop import TrackingSpec, run_tracking
from crane_reference.model.config import load_config
from crane_reference.motion.simulation import Scenario, simulate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=5.0)
    args = parser.parse_args()
    params = load_config()
    for variant in ("rigid", "flexible"):
        scenario = Scenario(params, variant)
        run_tracking(params, TrackingSpec(variant=variant, duration=0.05))  # compile / load the kernels
        aba = aba_time(scenario)
        start = time.perf_counter()
        simulate(scenario.motion, scenario.equilibrium.q, args.duration, step=1e-3)
        reference = time.perf_counter() - start
        for rate in (1000.0, 100.0):
            spec = TrackingSpec(variant=variant, rate=rate, duration=args.duration)
            start = time.perf_counter()
            run = run_tracking(params, spec)
            wall = time.perf_counter() - start
            references = reference * (1 if variant == "rigid" else 2)  # the rigid feedforward's own reference
            loop = wall - references
            steps = round(args.duration / spec.step)
            summary = run.summary()
            print(f"[tracking] {variant:8s} dof={scenario.model.dof:2d} controller {rate:6.0f} Hz, step "
                  f"{spec.step * 1e3:.0f} ms, {args.duration:g} s: {wall:.2f} s wall = {args.duration / wall:.2f}x "
                  f"real time (references {references:.2f} s; closed loop {loop:.2f} s = "
                  f"{args.duration / loop:.2f}x real time, {loop / steps * 1e6:.0f} us/step = "
                  f"{loop / steps / aba:.0f} ABA of {aba * 1e6:.1f} us); E off the ellipse <= "
                  f"{summary['ellipse_distance_max_m'] * 1e3:.2f} mm, height error <= "
                  f"{summary['height_error_max_m'] * 1e3:.2f} mm")


if __name__ == "__main__":
    main()

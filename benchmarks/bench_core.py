"""Speed and accuracy of the simulation core; prints the figures quoted in the closing notes.

    python benchmarks/bench_core.py [--duration 10] [--reference-duration 10] [--skip-reference]

1. Time of one M(q) (chain terms) and of one full qdd evaluation (eq. (8), compiled) at 24 DOF.
2. Wall time and real-time factor of the default motion (rigid; flexible with n_rfe = 6, 12, 24) with
   generalized-alpha at h = 1 ms and 2 ms, and the largest constraint residual.
3. Accuracy of psi2, psi(3,0), psi4 and E against a converged DOP853 run (rtol 1e-10) of the same
   equations: raw, and after a 0.1 s moving mean (the undamped boom rings at 80-200 Hz and 1.7 kHz for
   ever; no step that runs faster than real time resolves those phases).  Repeated with 1 % structural
   damping at the first boom bending mode, where the ringing decays and the raw error becomes meaningful.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np
from scipy.ndimage import uniform_filter1d

from crane_reference.config import load_config
from crane_reference.dynamics import chain_terms
from crane_reference.parameters import Damping
from crane_reference.simulation import Scenario, simulate, simulate_reference

COORDINATES = ("column_slew", "boom_luff", "knuckle")


def per_call(function, repeat: int = 2000) -> float:
    function()
    start = time.perf_counter()
    for _ in range(repeat):
        function()
    return (time.perf_counter() - start) / repeat


def evaluation_times(params) -> None:
    scenario = Scenario(params, "flexible")
    q = scenario.equilibrium.q
    qd = np.full_like(q, 0.01)
    d, m = scenario.dynamics, scenario.model
    t_m = per_call(lambda: chain_terms(q, qd, d._kinds, d._axes, d._origins, d._body_joint, d._body_H, m.gravity,
                                       m.end_effector_joint, m.end_effector_point))
    t_qdd = per_call(lambda: scenario.motion.solve(0.5, q, qd))
    print(f"[eval] {m.dof} DOF: M(q) with h, gravity and E kinematics {t_m * 1e6:.1f} us; "
          f"full qdd from (8) incl. constraints and Python wrapper {t_qdd * 1e6:.1f} us")


def speed(params, duration: float) -> None:
    cases = [("rigid", params), *(("flexible", replace(params, boom=replace(params.boom, rfe_count=n)))
                                  for n in (6, 12, 24))]
    for variant, p in cases:
        scenario = Scenario(p, variant)
        q0 = scenario.equilibrium.q
        simulate(scenario.motion, q0, 0.01, step=1e-3)  # compile / load the kernels
        for step in (1e-3, 2e-3):
            start = time.perf_counter()
            tr = simulate(scenario.motion, q0, duration, step=step)
            wall = time.perf_counter() - start
            print(f"[speed] {variant:8s} n_rfe={p.boom.rfe_count if variant == 'flexible' else 1:2d} "
                  f"dof={scenario.model.dof:2d} h={step * 1e3:.0f} ms: {duration:.0f} s in {wall:6.2f} s wall, "
                  f"real-time factor {duration / wall:6.1f}, max residual {tr.residual_distance.max():.1e} m, "
                  f"energy-balance error {np.max(np.abs(tr.energy_balance_error)):.2e} J "
                  f"(work {np.max(np.abs(tr.work_drive)):.0f} J)")


def accuracy(params, duration: float, label: str) -> None:
    scenario = Scenario(params, "flexible")
    q0 = scenario.equilibrium.q
    start = time.perf_counter()
    reference = simulate_reference(scenario.motion, q0, duration, np.round(np.arange(0.0, duration + 5e-4, 1e-3), 9),
                                   rtol=1e-10, atol=1e-12)
    print(f"[accuracy:{label}] DOP853 reference: {time.perf_counter() - start:.0f} s wall")
    index = [reference.joint_names.index(n) for n in COORDINATES]
    window = 100  # samples = 0.1 s
    for step, rho in ((1e-3, 0.8), (2e-3, 0.8), (1e-3, 0.5)):
        tr = simulate(scenario.motion, q0, duration, step=step, rho_inf=rho)
        q = np.array([np.interp(reference.t, tr.t, tr.q[:, k]) for k in index]).T
        e = np.array([np.interp(reference.t, tr.t, tr.ee_position[:, k]) for k in range(3)]).T
        raw = np.abs(q - reference.q[:, index]).max(axis=0)
        mean = np.abs(uniform_filter1d(q - reference.q[:, index], window, axis=0)).max(axis=0)
        ee = np.linalg.norm(e - reference.ee_position, axis=1)
        ee_mean = np.linalg.norm(uniform_filter1d(e - reference.ee_position, window, axis=0), axis=1)
        print(f"[accuracy:{label}] h={step * 1e3:.0f} ms rho_inf={rho}: max |error| psi2/psi30/psi4 = "
              f"{raw[0]:.1e}/{raw[1]:.1e}/{raw[2]:.1e} rad, E {ee.max():.1e} m; 0.1 s mean error "
              f"{mean[0]:.1e}/{mean[1]:.1e}/{mean[2]:.1e} rad, E {ee_mean.max():.1e} m")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--reference-duration", type=float, default=10.0)
    parser.add_argument("--skip-reference", action="store_true")
    args = parser.parse_args()
    params = load_config()
    evaluation_times(params)
    speed(params, args.duration)
    if not args.skip_reference:
        accuracy(params, args.reference_duration, "undamped")
        # 1 % of critical damping at the first boom bending mode (~87 Hz): beta = 2 zeta / omega
        beta = 2 * 0.01 / (2 * np.pi * 87.0)
        accuracy(replace(params, damping=Damping(support=0.0, boom=beta)), args.reference_duration,
                 f"boom beta={beta:.2e} s")


if __name__ == "__main__":
    main()

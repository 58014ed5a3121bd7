"""Speed and accuracy of the simulation core; prints the figures quoted in the closing notes.

    python benchmarks/bench_core.py [--duration 10] [--repeats 3] [--cache results/bench_core]
                                    [--only eval speed first-order newton accuracy] [--check-reference]

1. [eval] Time of M(q) with h, gravity and E's kinematics, and of one full qdd from (8), at 24 DOF.
   [profile] The compiled cost of the parts of one Newton iteration (timed in compiled loops).
2. [speed] Wall time per step and real-time factor (best of ``--repeats``) of the default motion
   (rigid; flexible with n_rfe = 6, 12, 24) with generalized-alpha at h = 1 and 2 ms, the mean number
   of Newton iterations and the largest constraint residual.
3. [accuracy] psi2, psi(3,0), psi4 and E against a converged DOP853 run (rtol 1e-10) of the same
   equations over ``--duration`` seconds, at h = 2, 1, 0.5, 0.25 ms: the largest raw error, and the
   largest error of the motion below 10 Hz (the error low-passed by a 4th-order Butterworth filter,
   forward-backward; the crane's working motion and the lower base modes).  Twice: the paper's
   undamped crane, and the same crane with 1 % structural damping at 87 Hz in the boom (stiffness-
   proportional).  The DOP853 runs take minutes and are cached as NPZ in ``--cache``.
4. [vibration] The part of the converged psi2, psi(3,0), psi4 above 40 Hz (4th-order Butterworth
   high-pass, forward-backward) after 5 s: largest value, RMS and the strongest spectral peak.  An
   integrator that does not follow the phase of this vibration is off by about its amplitude.
   With ``--check-reference`` the undamped reference is repeated at rtol 1e-9 ([reference]): their
   difference bounds the reference's own error.
5. [first-order] The paper's ellipse and height plus the first-order constraint x y' - y x' = a b omega(t)
   (E runs along the ellipse with the parametric-angle rate omega, a quintic rise to 0.8 rad/s over
   1 s; the column slew becomes dependent), rigid crane, 2 s: the largest error of E's parametric angle
   against the integral of omega at h = 2, 1, 0.5 ms, the largest velocity-constraint residual and the
   energy-balance error relative to the work of the constraint forces.
7. [iterations] Speed and accuracy against the DOP853 reference of looser Newton stopping rules, down to
   one correction per step (two evaluations).
6. [newton] Largest difference of psi2, psi(3,0), psi4 over the run between Newton tolerances (on the
   accepted velocity correction, m/s or rad/s) of 1e-8, 1e-9 (the default) and 1e-10 and a run at
   1e-12, at h = 1 ms: the Newton error must stay far below the discretisation error.
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from numba import njit
from scipy.integrate import quad
from scipy.signal import butter, sosfiltfilt, welch

from crane_reference.analysis.modal import modes_at
from crane_reference.dynamics import kernels
from crane_reference.dynamics.terms import chain_terms, end_effector_jacobian, position_terms
from crane_reference.model.config import load_config
from crane_reference.model.parameters import CraneParameters, Damping
from crane_reference.model.profiles import Constant, QuinticRise
from crane_reference.motion.constraints import ArealRate, ConstraintSet, EllipseXY, HeightZ
from crane_reference.motion.programmed_motion import ProgrammedMotion
from crane_reference.motion.simulation import MotionStepper, Scenario, simulate, simulate_reference
from crane_reference.motion.trajectory import Trajectory

COORDINATES = ("column_slew", "boom_luff", "knuckle")
REFERENCE_SAMPLE = 1e-4  # [s]
BOOM_DAMPING_RATIO, BASE_DAMPING_RATIO = 0.02, 0.05  # of critical, at the first boom bending / base mode


def realistic_damping(params: CraneParameters) -> Damping:
    """Stiffness-proportional damping (beta = 2 zeta / omega) with zeta = 2 % at the first boom bending mode
    (boom springs) and 5 % at the first base mode (support springs), the modes taken from the constrained
    modal analysis at the static equilibrium: the first whose strain energy is mostly boom bending, resp.
    support springs."""
    modes, _ = modes_at(params)

    def first(share) -> float:
        return float(modes.frequencies[next(k for k in range(modes.frequencies.size)
                                             if modes.frequencies[k] > 0.0 and share(k) >= 0.5)])

    f_boom = first(lambda k: sum(v[k] for name, v in modes.strain_energy.items() if name.startswith("boom bending")))
    f_base = first(lambda k: modes.strain_energy["support springs"][k])
    return Damping(support=2.0 * BASE_DAMPING_RATIO / (2.0 * np.pi * f_base),
                   boom=2.0 * BOOM_DAMPING_RATIO / (2.0 * np.pi * f_boom))


def per_call(function, repeat: int = 2000) -> float:
    function()
    start = time.perf_counter()
    for _ in range(repeat):
        function()
    return (time.perf_counter() - start) / repeat


@njit
def _read_chain(chain):
    return chain.gravity


@njit
def _read_fields(kinds, axes, origins, body_joint, body_H, gravity, ee_joint, ee_point, stiffness, damping,
                 drive_joint):
    return gravity


def evaluation_times(params: CraneParameters) -> None:
    scenario = Scenario(params, "flexible")
    q = scenario.equilibrium.q
    qd = np.full_like(q, 0.01)
    d, m = scenario.dynamics, scenario.model
    t_m = per_call(lambda: chain_terms(q, qd, d.chain))
    t_qdd = per_call(lambda: scenario.motion.solve(0.5, q, qd))
    print(f"[eval] {m.dof} DOF: M(q) with h, gravity and E kinematics {t_m * 1e6:.1f} us; "
          f"full qdd from (8) incl. constraints and Python wrapper {t_qdd * 1e6:.1f} us")
    t_named = min(per_call(lambda: _read_chain(d.chain)) for _ in range(5))
    t_fields = min(per_call(lambda: _read_fields(*d.chain)) for _ in range(5))
    print(f"[eval] calling a compiled function from Python with the ChainData named tuple {t_named * 1e6:.2f} us, "
          f"with its 11 fields as arguments {t_fields * 1e6:.2f} us (best of 5)")


def newton_iterations(scenario: Scenario, step: float, duration: float = 1.0, tolerance: float = 1e-9) -> float:
    """Mean Newton iterations per step over the first ``duration`` seconds (one step at a time)."""
    q0 = scenario.equilibrium.q
    stepper = MotionStepper(scenario.motion, 0.0, q0, np.zeros_like(q0), step, tolerance=tolerance)
    counts = []
    while stepper.state.t < duration:
        stepper.advance()
        counts.append(stepper.integrator.last_iterations)
    return float(np.mean(counts))


def speed(params: CraneParameters, duration: float, repeats: int) -> None:
    cases = [("rigid", params), *(("flexible", replace(params, boom=replace(params.boom, rfe_count=n)))
                                  for n in (6, 12, 24))]
    for variant, p in cases:
        scenario = Scenario(p, variant)
        q0 = scenario.equilibrium.q
        simulate(scenario.motion, q0, 0.01, step=1e-3)  # compile / load the kernels
        for step in (1e-3, 2e-3):
            walls = []
            for _ in range(repeats):
                start = time.perf_counter()
                tr = simulate(scenario.motion, q0, duration, step=step)
                walls.append(time.perf_counter() - start)
            wall = min(walls)
            print(f"[speed] {variant:8s} n_rfe={p.boom.rfe_count if variant == 'flexible' else 1:2d} "
                  f"dof={scenario.model.dof:2d} h={step * 1e3:.0f} ms: {duration:.0f} s in {wall:6.2f} s wall "
                  f"(best of {repeats}; median {np.median(walls):.2f} s), {wall / tr.t.size * 1e6:6.1f} us/step, "
                  f"real-time factor {duration / wall:5.1f}, Newton iterations {newton_iterations(scenario, step):.2f}"
                  f"/step, max residual {tr.residual_distance.max():.1e} m")


def reference_run(params: CraneParameters, duration: float, cache: Path, label: str,
                  rtol: float = 1e-10) -> Trajectory:
    path = cache / f"dop853_{label}_{duration:g}s_rtol{rtol:g}.npz"
    if path.exists():
        return Trajectory.from_npz(path)
    scenario = Scenario(params, "flexible")
    times = np.round(np.arange(0.0, duration + 0.5 * REFERENCE_SAMPLE, REFERENCE_SAMPLE), 9)
    start = time.perf_counter()
    reference = simulate_reference(scenario.motion, scenario.equilibrium.q, duration, times, rtol=rtol,
                                   atol=rtol * 1e-2)
    print(f"[accuracy:{label}] DOP853 reference (rtol {rtol:g}) over {duration:g} s: "
          f"{time.perf_counter() - start:.0f} s wall")
    cache.mkdir(parents=True, exist_ok=True)
    reference.to_npz(path)
    return reference


def reference_check(params: CraneParameters, duration: float, cache: Path) -> None:
    tight = reference_run(params, duration, cache, "undamped")
    loose = reference_run(params, duration, cache, "undamped", rtol=1e-9)
    index = [tight.joint_names.index(n) for n in COORDINATES]
    difference = np.abs(tight.q[:, index] - loose.q[:, index]).max(axis=0)
    print(f"[reference] DOP853 rtol 1e-9 vs 1e-10 over {duration:g} s: psi2/psi30/psi4 differ by at most "
          + "/".join(f"{x:.1e}" for x in difference) + " rad")


def errors(reference: Trajectory, tr: Trajectory) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Largest raw and below-10-Hz errors of psi2, psi(3,0), psi4 [rad] and of E [m] on the reference's
    times (the filtered error away from the ends, where forward-backward filtering has transients)."""
    index = [reference.joint_names.index(n) for n in COORDINATES]
    low_pass = butter(4, 10.0, fs=1.0 / REFERENCE_SAMPLE, output="sos")
    inner = (reference.t > 0.05) & (reference.t < reference.t[-1] - 0.05)
    q = np.array([np.interp(reference.t, tr.t, tr.q[:, k]) for k in index]).T - reference.q[:, index]
    e = np.array([np.interp(reference.t, tr.t, tr.ee_position[:, k]) for k in range(3)]).T - reference.ee_position
    slow_q, slow_e = sosfiltfilt(low_pass, q, axis=0)[inner], sosfiltfilt(low_pass, e, axis=0)[inner]
    return (np.abs(q).max(axis=0), np.abs(slow_q).max(axis=0), float(np.linalg.norm(e, axis=1).max()),
            float(np.linalg.norm(slow_e, axis=1).max()))


def accuracy(params: CraneParameters, duration: float, cache: Path, label: str) -> Trajectory:
    reference = reference_run(params, duration, cache, label)
    scenario = Scenario(params, "flexible")
    q0 = scenario.equilibrium.q
    for step in (2e-3, 1e-3, 5e-4, 2.5e-4):
        start = time.perf_counter()
        tr = simulate(scenario.motion, q0, duration, step=step)
        wall = time.perf_counter() - start
        raw, slow, ee, ee_slow = errors(reference, tr)
        print(f"[accuracy:{label}] h={step * 1e3:.2f} ms ({duration / wall:4.1f}x real time): max |error| "
              f"psi2/psi30/psi4 = {raw[0]:.1e}/{raw[1]:.1e}/{raw[2]:.1e} rad, E {ee:.1e} m; below 10 Hz "
              f"{slow[0]:.1e}/{slow[1]:.1e}/{slow[2]:.1e} rad, E {ee_slow:.1e} m")
    return reference


def vibration_content(reference: Trajectory, label: str) -> None:
    high_pass = butter(4, 40.0, btype="highpass", fs=1.0 / REFERENCE_SAMPLE, output="sos")
    late = (reference.t > 5.0) & (reference.t < reference.t[-1] - 0.2)
    for name in COORDINATES:
        fast = sosfiltfilt(high_pass, reference.coordinate(name))[late]
        frequency, power = welch(fast, fs=1.0 / REFERENCE_SAMPLE, nperseg=8192)
        print(f"[vibration:{label}] {name}: above 40 Hz after 5 s max {np.abs(fast).max():.1e} rad, "
              f"rms {fast.std():.1e} rad, strongest at {frequency[np.argmax(power)]:.0f} Hz")


def newton_tolerance(params: CraneParameters, duration: float, step: float = 1e-3) -> None:
    scenario = Scenario(params, "flexible")
    q0 = scenario.equilibrium.q
    index = [scenario.model.joint_names.index(n) for n in COORDINATES]
    runs = {}
    for tolerance in (1e-8, 1e-9, 1e-10, 1e-12):
        stepper = MotionStepper(scenario.motion, 0.0, q0, np.zeros_like(q0), step)
        stepper.integrator.tolerance = tolerance
        start = time.perf_counter()
        runs[tolerance] = stepper.advance_until(duration)["q"][:, index], duration / (time.perf_counter() - start)
    for tolerance in (1e-8, 1e-9, 1e-10):
        difference = np.abs(runs[tolerance][0] - runs[1e-12][0]).max(axis=0)
        print(f"[newton] h={step * 1e3:.0f} ms, tolerance {tolerance:g} ({runs[tolerance][1]:.1f}x real time) "
              f"vs 1e-12: largest difference over {duration:g} s psi2/psi30/psi4 = "
              + "/".join(f"{x:.1e}" for x in difference) + " rad")


def iteration_rules(params: CraneParameters, duration: float, cache: Path) -> None:
    """[iterations] Speed and accuracy (against the DOP853 reference) of the Newton stopping rule at
    h = 1 ms: tolerances 1e-9 (the default), 1e-7, 1e-5 on the accepted velocity correction, and an
    infinite one (every step accepts after its first correction: two evaluations per step)."""
    reference = reference_run(params, duration, cache, "undamped")
    scenario = Scenario(params, "flexible")
    q0 = scenario.equilibrium.q
    simulate(scenario.motion, q0, 0.01)  # compile / load the kernels
    for tolerance in (1e-9, 1e-7, 1e-5, math.inf):
        start = time.perf_counter()
        tr = simulate(scenario.motion, q0, duration, step=1e-3, tolerance=tolerance)
        wall = time.perf_counter() - start
        raw, slow, _, ee_slow = errors(reference, tr)
        print(f"[iterations] tolerance {tolerance:g}: {wall / tr.t.size * 1e6:6.1f} us/step, Newton evaluations "
              f"{newton_iterations(scenario, 1e-3, tolerance=tolerance):.2f}/step; max |error| psi2/psi30/psi4 "
              f"{raw[0]:.1e}/{raw[1]:.1e}/{raw[2]:.1e} rad, below 10 Hz {slow[0]:.1e}/{slow[1]:.1e}/{slow[2]:.1e} "
              f"rad, E {ee_slow:.1e} m")


def first_order(params: CraneParameters, duration: float = 2.0) -> None:
    omega = QuinticRise(0.0, 0.8, 0.0, 1.0)
    a, b = params.task.ellipse_a, params.task.ellipse_b
    scenario = Scenario(params, "rigid")
    model = scenario.model
    task = ConstraintSet((EllipseXY(Constant(a), Constant(b)), HeightZ(QuinticRise(scenario.z_static, 0.2, 0.0, 5.0)),
                          ArealRate(lambda t: tuple(a * b * x for x in omega(t)))))
    dependent = tuple(model.joint_names.index(n) for n in ("boom_luff", "knuckle", "column_slew"))
    motion = ProgrammedMotion(scenario.dynamics, task, dependent=dependent)
    for step in (2e-3, 1e-3, 5e-4):
        start = time.perf_counter()
        tr = simulate(motion, scenario.equilibrium.q, duration, step=step)
        wall = time.perf_counter() - start
        x, y = tr.ee_position[:, 0], tr.ee_position[:, 1]
        theta = np.unwrap(np.arctan2(y / b, x / a))
        expected = [quad(lambda s: omega(s)[0], 0.0, t, points=[1.0], epsabs=1e-13, epsrel=1e-13)[0] for t in tr.t]
        work = np.max(np.abs(tr.work_constraints))
        print(f"[first-order] h={step * 1e3:.1f} ms ({duration / wall:.1f}x real time): parametric angle error "
              f"{np.max(np.abs(theta - theta[0] - expected)):.1e} rad after {expected[-1]:.2f} rad; velocity "
              f"residual {np.max(np.abs(tr.residual[:, 2])):.1e} m^2/s; energy balance "
              f"{np.max(np.abs(tr.energy_balance_error)) / work:.1e} of the constraint work {work:.0f} J")


@njit
def _repeat_position_terms(q, chain, n):
    total = 0.0
    for _ in range(n):
        total += position_terms(q, chain)[3][0, 0]
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
        total += kernels.project_positions(q, k, holonomic_dependent, chain, 1e-9, 25)[0][0]
    return total


@njit
def _repeat_accelerations(q, qd, k, drive, partition, chain, n):
    total = 0.0
    for _ in range(n):
        total += kernels.accelerations_at(q, qd, k, drive, partition, chain).qdd[0]
    return total


@njit
def _repeat_evaluation(q, qd, k, drive, partition, chain, n):
    total = 0.0
    for _ in range(n):
        total += kernels.evaluate(q, qd, k, drive, partition, chain).accounts[0]
    return total


def component_times(params: CraneParameters, repeat: int = 3000) -> None:
    """[profile] Compiled cost of the parts of one Newton iteration of a step (flexible, n_rfe = 6),
    each timed in a compiled loop (no Python call overhead), best of 5."""
    scenario = Scenario(params, "flexible")
    motion = scenario.motion
    q, chain, partition = scenario.equilibrium.q, motion.dynamics.chain, motion.partition
    qd = np.full_like(q, 0.01)
    k, drive = motion.constraints.coefficients(0.5), motion.dynamics.drive.kernel_parameters(0.5)
    off = q.copy()
    off[motion.holonomic_dependent] += 1e-6  # a predictor 1e-6 rad off the constraints
    parts = (("M, gravity, E's Jacobian (position_terms)", _repeat_position_terms, (q, chain)),
             ("E's position and Jacobian (kinematics only)", _repeat_end_effector, (q, chain)),
             ("projection on the position constraints", _repeat_projection,
              (off, k, motion.holonomic_dependent, chain)),
             ("qdd from (8) with qd_dc (accelerations_at)", _repeat_accelerations, (q, qd, k, drive, partition, chain)),
             ("full evaluation (+ residuals, reactions, accounts)", _repeat_evaluation,
              (q, qd, k, drive, partition, chain)))
    for name, function, arguments in parts:
        function(*arguments, 10)
        best = min(_timed(function, arguments, repeat) for _ in range(5))
        print(f"[profile] {name:<52} {best / repeat * 1e6:7.2f} us")


def _timed(function, arguments, repeat: int) -> float:
    start = time.perf_counter()
    function(*arguments, repeat)
    return time.perf_counter() - start


SECTIONS = ("eval", "profile", "speed", "first-order", "newton", "iterations", "accuracy")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--cache", type=Path, default=Path("results/bench_core"))
    parser.add_argument("--only", nargs="+", choices=SECTIONS, default=SECTIONS, help="sections to run")
    parser.add_argument("--check-reference", action="store_true")
    args = parser.parse_args()
    params = load_config()
    if "eval" in args.only:
        evaluation_times(params)
    if "profile" in args.only:
        component_times(params)
    if "speed" in args.only:
        speed(params, args.duration, args.repeats)
    if "first-order" in args.only:
        first_order(params)
    if "newton" in args.only:
        newton_tolerance(params, args.duration)
    if "iterations" in args.only:
        iteration_rules(params, args.duration, args.cache)
    if args.check_reference:
        reference_check(params, args.duration, args.cache)
    if "accuracy" in args.only:
        damping = realistic_damping(params)
        damped = replace(params, damping=damping)
        for label, p in (("undamped", params), (f"damped-base{damping.support:.3e}s-boom{damping.boom:.3e}s", damped)):
            vibration_content(accuracy(p, args.duration, args.cache, label), label)


if __name__ == "__main__":
    main()

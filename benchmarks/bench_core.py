"""Speed and accuracy of the simulation core; prints the figures quoted in the closing notes.

    python benchmarks/bench_core.py [--duration 10] [--repeats 3] [--cache results/bench_core] [--check-reference]
                                    [--only eval profile speed first-order newton iterations accuracy]

1. [eval] Time of M(q) with h, gravity and E's kinematics, and of one full qdd from (8), at 24 DOF.
   [profile] The compiled cost of the parts of one Newton iteration (timed in compiled loops).
2. [speed] Per case (rigid; flexible with n_rfe = 6, 12, 24): Pinocchio's ABA on the exported URDF
   (per call from Python); at h = 1 and 2 ms the throughput of simulate (best of ``--repeats``) per step,
   as a multiple of one ABA call and as a real-time factor; single steps (one compiled call each, 2 s
   after the drive's jumps): median, worst and 99.9 % quantile; the mean Newton evaluations per step and
   the largest constraint residual.
3. [accuracy] psi2, psi(3,0), psi4 and E of the online default against a converged DOP853 run (rtol
   1e-10) of the same equations over ``--duration`` seconds, at h = 2, 1, 0.5, 0.25 ms: the largest raw
   error, the controller-band error (the error on the 1 kHz grid low-passed at 10 Hz, 4th-order
   Butterworth, forward-backward; a run sampled faster is first low-passed at 400 Hz so the RFE modes do
   not alias into the band), and the 40-250 Hz RMS after 5 s relative to the reference's (each run
   band-passed at its own rate).  The paper's undamped crane at rho_inf = 0.8, 0.9, 1; a realistically
   damped crane (2 % at the first boom bending mode, 5 % at the first base mode, stiffness-proportional,
   from the constrained modal analysis) at 0.8.  The DOP853 runs take minutes and are cached as NPZ in
   ``--cache``.
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
6. [newton] Largest difference of psi2, psi(3,0), psi4 over the run between Newton tolerances (on the
   last velocity correction, m/s or rad/s) of 1e-8, 1e-9 and 1e-10 and a run at 1e-12, at h = 1 ms: the
   Newton error must stay far below the discretisation error.
7. [iterations] Speed and accuracy against the DOP853 reference of the converged iteration, two
   evaluations per step and the online default (three).
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pinocchio as pin
from numba import njit
from scipy.integrate import quad
from scipy.signal import butter, sosfiltfilt, welch

from crane_reference.analysis.modal import modes_at
from crane_reference.dynamics import kernels
from crane_reference.dynamics.structures import Coefficients
from crane_reference.dynamics.terms import chain_terms, end_effector_jacobian, position_terms
from crane_reference.model.config import load_config
from crane_reference.model.parameters import CraneParameters, Damping
from crane_reference.model.profiles import Constant, QuinticRise
from crane_reference.model.urdf import model_to_urdf
from crane_reference.motion.constraints import ArealRate, ConstraintSet, EllipseXY, HeightZ
from crane_reference.motion.integration import EVALUATIONS, ONLINE_TOLERANCE, GeneralizedAlpha
from crane_reference.motion.programmed_motion import ProgrammedMotion
from crane_reference.motion.simulation import MotionStepper, Scenario, simulate, simulate_reference
from crane_reference.motion.trajectory import Trajectory

COORDINATES = ("column_slew", "boom_luff", "knuckle")
REFERENCE_SAMPLE = 1e-4  # [s]
GRID = 1e-3  # [s]: the 1 kHz samples on which the errors are filtered
ANTI_ALIAS = 400.0  # [Hz]
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
                 damped, drive_joint):
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


def newton_iterations(scenario: Scenario, step: float, duration: float = 1.0, tolerance: float = ONLINE_TOLERANCE,
                      evaluations: int = EVALUATIONS) -> float:
    """Mean Newton evaluations per step over the first ``duration`` seconds (one step at a time)."""
    q0 = scenario.equilibrium.q
    stepper = MotionStepper(scenario.motion, 0.0, q0, np.zeros_like(q0), step, tolerance=tolerance,
                            evaluations=evaluations)
    counts = []
    while stepper.state.t < duration:
        stepper.advance()
        counts.append(stepper.integrator.last_iterations)
    return float(np.mean(counts))


def aba_time(scenario: Scenario, repeat: int = 20000) -> float:
    """Best per-call time [s] of Pinocchio's forward dynamics (ABA, called from Python) on the URDF that
    crane-reference exports for the scenario's chain, at a random state (continuous joints as cos/sin)."""
    model = pin.buildModelFromXML(model_to_urdf(scenario.model))
    data = model.createData()
    rng = np.random.default_rng(0)
    q, v, tau = pin.randomConfiguration(model), rng.normal(size=model.nv), rng.normal(size=model.nv)
    best = math.inf
    for _ in range(5):
        start = time.perf_counter()
        for _ in range(repeat):
            pin.aba(model, data, q, v, tau)
        best = min(best, (time.perf_counter() - start) / repeat)
    return best


def step_times(scenario: Scenario, step: float, duration: float, after: float = 1.0) -> np.ndarray:
    """Wall time [s] of each step over ``duration`` seconds from t = ``after`` (past the drive's jumps), each
    step one compiled call from Python with its inputs prepared beforehand (what one step costs the
    node, call included)."""
    stepper = MotionStepper(scenario.motion, 0.0, scenario.equilibrium.q, np.zeros_like(scenario.equilibrium.q),
                            step)
    stepper.advance_until(after)
    state, motion, settings = stepper.state, scenario.motion, stepper.integrator.settings
    times = state.t + step * np.arange(1, round(duration / step) + 1)
    k, drives = motion.constraints.coefficients_at(times), motion.dynamics.drive.kernel_parameters(times)
    q, qd, qdd, at = state.q, state.qd, state.solution.qdd, state.pseudo_acceleration
    M, B, t0 = state.solution.dynamics.M, state.solution.velocity_map, state.t
    walls = np.empty(times.size)
    for i in range(times.size):
        k_i = Coefficients(k.Q[i:i + 1], k.g[i:i + 1], k.c[i:i + 1], k.order)
        start = time.perf_counter()
        run = kernels.generalized_alpha_run(q, qd, qdd, at, M, B, t0, times[i:i + 1], k_i, drives[i:i + 1],
                                            motion.partition, motion.dynamics.chain, settings)
        walls[i] = time.perf_counter() - start
        last = run.last
        q, qd, qdd, at, t0 = last.q, last.qd, last.evaluation.terms.qdd, last.pseudo_acceleration, times[i]
        M, B = last.evaluation.terms.M, last.evaluation.terms.velocity_map
    return walls


def speed(params: CraneParameters, duration: float, repeats: int) -> None:
    """[speed] Throughput of simulate (compiled runs of 0.25 s), the cost of single steps (median and worst
    over 2 s) and both as multiples of one Pinocchio ABA call on the same chain, measured in this run."""
    cases = [("rigid", params), *(("flexible", replace(params, boom=replace(params.boom, rfe_count=n)))
                                  for n in (6, 12, 24))]
    for variant, p in cases:
        scenario = Scenario(p, variant)
        q0 = scenario.equilibrium.q
        simulate(scenario.motion, q0, 0.01, step=1e-3)  # compile / load the kernels
        aba = aba_time(scenario)
        label = f"[speed] {variant:8s} n_rfe={p.boom.rfe_count if variant == 'flexible' else 1:2d} " \
                f"dof={scenario.model.dof:2d}"
        print(f"{label}: Pinocchio ABA on the exported URDF {aba * 1e6:.2f} us/call")
        for step in (1e-3, 2e-3):
            walls = []
            for _ in range(repeats):
                start = time.perf_counter()
                tr = simulate(scenario.motion, q0, duration, step=step)
                walls.append(time.perf_counter() - start)
            wall, per_step = min(walls), min(walls) / (tr.t.size - 1)
            single = step_times(scenario, step, 2.0)
            print(f"{label} h={step * 1e3:.0f} ms: {duration:.0f} s in {wall:6.2f} s wall (best of {repeats}; median "
                  f"{np.median(walls):.2f} s), {per_step * 1e6:6.1f} us/step = {per_step / aba:4.1f} ABA, real-time "
                  f"factor {duration / wall:5.1f}; single steps median {np.median(single) * 1e6:.1f} us, worst "
                  f"{single.max() * 1e6:.1f} us ({single.max() / np.median(single):.1f}x median), 99.9 % below "
                  f"{np.quantile(single, 0.999) * 1e6:.1f} us; Newton evaluations "
                  f"{newton_iterations(scenario, step):.2f}/step, max residual {tr.residual_distance.max():.1e} m")


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


def filtered(t: np.ndarray, x: np.ndarray, btype: str, band: float | tuple[float, float]) -> np.ndarray:
    """x (samples on the uniform times t, first axis) through a 4th-order Butterworth filter run forward and
    backward at its own sample rate (no decimation before filtering, hence no aliasing of the RFE modes
    above the grid's Nyquist frequency)."""
    return sosfiltfilt(butter(4, band, btype=btype, fs=1.0 / (t[1] - t[0]), output="sos"), x, axis=0)


def _coordinates(tr: Trajectory) -> np.ndarray:
    return tr.q[:, [tr.joint_names.index(n) for n in COORDINATES]]


def on_grid(tr: Trajectory, x: np.ndarray, t: np.ndarray) -> np.ndarray:
    """x of ``tr`` on the 1 kHz grid t: where tr is sampled faster, first low-passed at 400 Hz (forward-
    backward, below the grid's Nyquist frequency: the RFE modes above it would otherwise alias into the
    band), then taken at the grid times; where it is sampled slower, interpolated linearly."""
    step = tr.t[1] - tr.t[0]
    if step < GRID * (1.0 - 1e-9):
        x = filtered(tr.t, x, "lowpass", ANTI_ALIAS)
    return np.array([np.interp(t, tr.t, x[:, k]) for k in range(x.shape[1])]).T


def errors(reference: Trajectory, tr: Trajectory) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Largest raw and controller-band errors of psi2, psi(3,0), psi4 [rad] and of E [m]: raw on the
    reference's samples (tr interpolated), controller band on the 1 kHz grid (:func:`on_grid`), the error
    low-passed at 10 Hz (4th-order Butterworth, forward-backward) away from the ends (where forward-backward
    filtering has transients)."""
    t = reference.t[::round(GRID / REFERENCE_SAMPLE)]
    inner = (t > 0.05) & (t < t[-1] - 0.05)
    raw, slow = [], []
    for x_ref, x in ((_coordinates(reference), _coordinates(tr)), (reference.ee_position, tr.ee_position)):
        raw.append(np.array([np.interp(reference.t, tr.t, x[:, k]) for k in range(x.shape[1])]).T - x_ref)
        slow.append(filtered(t, on_grid(tr, x, t) - on_grid(reference, x_ref, t), "lowpass", 10.0)[inner])
    return (np.abs(raw[0]).max(axis=0), np.abs(slow[0]).max(axis=0), float(np.linalg.norm(raw[1], axis=1).max()),
            float(np.linalg.norm(slow[1], axis=1).max()))


def accuracy(params: CraneParameters, duration: float, cache: Path, label: str,
             rho_infs: tuple[float, ...]) -> Trajectory:
    """[accuracy] The online default against the DOP853 reference at h = 2, 1, 0.5, 0.25 ms and each rho_inf:
    raw and controller-band errors, and the 40-250 Hz RMS kept (:func:`vibration_rms`, run / reference)."""
    reference = reference_run(params, duration, cache, label)
    kept_reference = vibration_rms(reference)
    scenario = Scenario(params, "flexible")
    q0 = scenario.equilibrium.q
    for rho_inf in rho_infs:
        for step in (2e-3, 1e-3, 5e-4, 2.5e-4):
            start = time.perf_counter()
            tr = simulate(scenario.motion, q0, duration, step=step, rho_inf=rho_inf)
            wall = time.perf_counter() - start
            raw, slow, ee, ee_slow = errors(reference, tr)
            if 0.5 / step > VIBRATION_BAND[1]:
                kept = vibration_rms(tr) / kept_reference
                vibration = f"{kept[0]:.0%}/{kept[1]:.0%}/{kept[2]:.0%} of the reference's"
            else:
                vibration = "not resolved (the band reaches the Nyquist frequency)"
            print(f"[accuracy:{label}] rho_inf={rho_inf:g} h={step * 1e3:.2f} ms ({duration / wall:4.1f}x real time): "
                  f"max |error| psi2/psi30/psi4 = {raw[0]:.1e}/{raw[1]:.1e}/{raw[2]:.1e} rad, E {ee:.1e} m; "
                  f"controller band {slow[0]:.1e}/{slow[1]:.1e}/{slow[2]:.1e} rad, E {ee_slow:.1e} m; 40-250 Hz RMS "
                  f"after 5 s {vibration}")
    return reference


VIBRATION_BAND = (40.0, 250.0)  # [Hz]


def vibration_rms(tr: Trajectory, after: float = 5.0) -> np.ndarray:
    """RMS of the 40-250 Hz band (4th-order Butterworth band-pass, forward-backward, at the run's own
    rate) of psi2, psi(3,0), psi4 after ``after`` seconds (and 0.2 s before the end, clear of the filter's
    edge effects)."""
    late = (tr.t > after) & (tr.t < tr.t[-1] - 0.2)
    return filtered(tr.t, _coordinates(tr), "bandpass", VIBRATION_BAND)[late].std(axis=0)


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
    """[iterations] Speed and accuracy (against the DOP853 reference) of the Newton rules at h = 1 ms:
    the converged iteration (tolerance 1e-9), two evaluations per step (tolerance 1e-4) and the online
    default (three evaluations, tolerance 1e-4)."""
    reference = reference_run(params, duration, cache, "undamped")
    scenario = Scenario(params, "flexible")
    q0 = scenario.equilibrium.q
    simulate(scenario.motion, q0, 0.01)  # compile / load the kernels
    for evaluations, tolerance, name in ((2, 1e-9, "converged"), (2, 1e-4, "two evaluations"),
                                         (EVALUATIONS, ONLINE_TOLERANCE, "online default")):
        start = time.perf_counter()
        tr = simulate(scenario.motion, q0, duration, step=1e-3, tolerance=tolerance, evaluations=evaluations)
        wall = time.perf_counter() - start
        raw, slow, _, ee_slow = errors(reference, tr)
        print(f"[iterations] {name} (at least {evaluations} evaluations, tolerance {tolerance:g}): "
              f"{wall / tr.t.size * 1e6:6.1f} us/step, Newton evaluations "
              f"{newton_iterations(scenario, 1e-3, tolerance=tolerance, evaluations=evaluations):.2f}/step; "
              f"max |error| psi2/psi30/psi4 {raw[0]:.1e}/{raw[1]:.1e}/{raw[2]:.1e} rad, controller band "
              f"{slow[0]:.1e}/{slow[1]:.1e}/{slow[2]:.1e} rad, E {ee_slow:.1e} m")


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
def _repeat_residual(q, qd, a, k, drive, partition, chain, n):
    _, T, S, p, C, _ = kernels.project_positions(q, k, partition.holonomic_dependent, chain, 1e-9, 25)
    total = 0.0
    for _ in range(n):
        total += kernels.newton_residual(q, qd, a, T, S, p, C, k, drive, partition, chain)[1][0]
    return total


@njit
def _repeat_factor(M, B, partition, chain, settings, n):
    total = 0.0
    for _ in range(n):
        total += kernels.iteration_factor(M, B, 1e-3, partition, chain, settings)[0, 0]
    return total


@njit
def _repeat_evaluation(q, qd, k, drive, partition, chain, n):
    total = 0.0
    for _ in range(n):
        total += kernels.evaluate(q, qd, k, drive, partition, chain).accounts[0]
    return total


def component_times(params: CraneParameters, repeat: int = 3000) -> None:
    """[profile] Compiled cost of the parts of a step (flexible, n_rfe = 6), each timed in a compiled loop
    (no Python call overhead), best of 5: a step is a factor, per Newton evaluation a projection and a
    residual, and at its end a projection and a full evaluation with the integrator's qdd."""
    scenario = Scenario(params, "flexible")
    motion = scenario.motion
    q, chain, partition = scenario.equilibrium.q, motion.dynamics.chain, motion.partition
    qd = np.full_like(q, 0.01)
    k, drive = motion.constraints.coefficients(0.5), motion.dynamics.drive.kernel_parameters(0.5)
    off = q.copy()
    off[motion.holonomic_dependent] += 1e-6  # a predictor 1e-6 rad off the constraints
    acc = kernels.accelerations_at(q, qd, k, drive, partition, chain)
    settings = GeneralizedAlpha(motion).settings
    parts = (("M, gravity, E's Jacobian (position_terms)", _repeat_position_terms, (q, chain)),
             ("E's position and Jacobian (kinematics only)", _repeat_end_effector, (q, chain)),
             ("projection on the position constraints", _repeat_projection,
              (off, k, motion.holonomic_dependent, chain)),
             ("Newton residual of (8) by inverse dynamics", _repeat_residual,
              (q, qd, acc.qdd[partition.integrated], k, drive, partition, chain)),
             ("iteration matrix and its Cholesky factor", _repeat_factor,
              (acc.M, acc.velocity_map, partition, chain, settings)),
             ("qdd from (8) solved (accelerations_at)", _repeat_accelerations, (q, qd, k, drive, partition, chain)),
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
        print(f"[accuracy] realistic damping: beta = {damping.support:.3e} s on the support springs, "
              f"{damping.boom:.3e} s on the boom springs")
        for label, p, rho_infs in (("undamped", params, (0.8, 0.9, 1.0)),
                                   (f"damped-base{damping.support:.3e}s-boom{damping.boom:.3e}s", damped, (0.8,))):
            vibration_content(accuracy(p, args.duration, args.cache, label, rho_infs), label)


if __name__ == "__main__":
    main()

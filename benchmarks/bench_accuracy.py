"""Accuracy of the integrator against converged runs; prints the figures the README and the closing notes quote.

    python benchmarks/bench_accuracy.py [--duration 10] [--cache results/bench_accuracy] [--hours 1]
                                        [--rfe 6 3 12] [--cutoff 0.8] [--bandwidth 800] [--refresh 0.01]
                                        [--mode-tracking 0]
                                        [--evaluations 2]
                                        [--only vibration growth long damped iterations matrix newton first-order
                                                mechanism sensitivity slow reference drift refined]

The converged run is scipy's DOP853 (rtol 1e-10) on the same equations (``simulate_reference``), sampled every
0.1 ms and cached as NPZ in ``--cache`` (the first run of a section takes minutes per crane).

1. [vibration] The paper's undamped crane with n_rfe = 6 (default), 3 and 12, at h = 1, 0.5 and 0.25 ms (the
   steps of the studies at 1 ms, of the node and of ``analyze``): the 40-250 Hz RMS of psi2, psi(3,0),
   psi4 (4th-order Butterworth band-pass, forward-backward, at each run's own rate) over 1-5 s and 5-10 s as a
   share of the converged run's (target: 90-110 %); the largest raw error, and the controller-band error (the
   error on the 1 kHz grid low-passed at 10 Hz; a run sampled faster is first low-passed at 400 Hz so the RFE
   modes do not alias into the band; target at the node's 0.5 ms: <= 5e-5 rad / m).
2. [growth] 60 s of the default crane at the same steps: the 40-250 Hz RMS of 50-60 s against that of 5-15 s
   (target: within 10 %), and the energy's mean over 5.5-7.5 s and 58-60 s (no drive, no dampers, fixed
   constraints after 5 s: it must stay).
   [long] (not by default) ``--hours`` (1) of the same crane at the node's step: the 40-250 Hz RMS and the
   mean energy over the last 10 s against those of 5-15 s.
3. [damped] The crane with realistic damping (2 % at the first boom bending mode, 5 % at the first base mode,
   stiffness-proportional, from the constrained modal analysis) at h = 1 and 0.5 ms: raw and controller-band errors
   (target: raw <= 1e-4 rad over 10 s) and the 40-250 Hz RMS kept over 5-10 s.
4. [iterations] The Newton rules at the node's step, per crane of ``--rfe``: converged (tolerance 1e-9), two
   evaluations and the online default (three), and exactly one or two evaluations whatever the correction:
   cost per step, evaluations per step, raw and controller-band errors.
5. [matrix] The Newton iteration's error operator I - F^-1 J (J by central differences) with the iteration
   matrix F at the step's first iterate (the integrator's) and at its start, at steps from 0.5, 1, 3, 6 s.
6. [newton] Largest difference of psi2, psi(3,0), psi4 between Newton tolerances 1e-8, 1e-9, 1e-10 and 1e-12.
7. [first-order] The paper's ellipse and height plus the first-order constraint x y' - y x' = a b omega(t)
   (rigid crane, 2 s): the parametric-angle error at h = 2, 1, 0.5 ms, the velocity residual and the
   energy-balance error relative to the constraint work.
8. [reference] The undamped reference at rtol 1e-9 against 1e-10: their difference bounds the reference's own
   error.
9. [mechanism] Why second-order schemes misreport the vibration: the constrained modes along the run (every
   0.5 s) with the detunings of the internal resonances 2 f9 = f8 + f10 and f9 + f10 = f11, which the slow
   motion sweeps through zero; and the luffing vibration (psi(3,0), 40-250 Hz RMS over 1-3, 3-5, 5-7, 7-10 s
   against the converged run) of the plain trapezoidal rule (turning mode i by 2 arctan(omega_i h / 2) per
   step) and of the integrator (exact frequencies) at h = 0.25 and 1 ms.
10. [sensitivity] The conditioning of the 40-250 Hz RMS: the model with its payload mass changed by +-0.5 and
   +-1 % and its boom's Young's modulus by +-1 % (h = 0.25 ms) against the nominal converged run, beside the
   nominal crane at h = 1, 0.5, 1/3 and 0.25 ms (converged Newton).
12. [drift] (not by default) 60 s of the default crane at h = 0.5, 0.4, 0.3125, 0.3, 1/3500 s, 0.25 and 0.2 ms: E's
    largest distance over 10, 30 and 60 s from two converged runs at 0.125 ms: the full model's, which resolves
    every mode (its own distance from the cached DOP853 run over 10 s printed first), and the one of the modes the
    integrator resolves (below the bandwidth: the limit a shrinking step converges to; its distance from the full
    model's and both runs' energy drift printed next); compared every 6 ms, on the
    times both reach (every 30 ms at 0.3125 ms), and the energy's mean over 50-60 s less that over 5-15 s (no drive
    torque after 1 s, no dampers, fixed constraints after 5 s); for the integrator as it is, so with the converged
    Newton iteration, without the resolved bandwidth (the cutoff alone), and, when --cutoff, --mode-tracking or
    --bandwidth change it, with the package's defaults.  0.3 ms is the one step whose grid misses the drive
    torque's end at t = 1 s (a cut step there, and a new step size twice).
13. [refined] (not by default) The refined cranes, n_rfe = 24 and 48 (the iteration matrix solved by the
    articulated-body recursion, integration.ARTICULATED_FROM), at the node's step against the same integrator at a
    quarter of it over ``--duration``: the 40-250 Hz RMS kept per window and the raw and controller-band errors
    (targets: RMS within 10 %, controller band <= 5e-5); then E's controller-band error of both against an eighth of
    the step (how far the quarter-step reference has converged).  ``--evaluations 3``: every run at three Newton
    evaluations a step.
11. [slow] The controller-band error at the node's 0.5 ms (ONLINE_STEP) and at 1 ms, undamped
    and damped crane: the integrator with its modal correction computed every step, every 5 ms, every
    REFRESH_INTERVAL (the default) and every 20 ms, and the plain trapezoidal rule; psi2's drift at 3, 5 and
    10 s.  A stiff flexible drive (1e8 N m/rad) against DOP853 over 0.1 s.
"""

from __future__ import annotations

import argparse
import functools
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from common import newton_iterations
from scipy.integrate import quad
from scipy.signal import butter, sosfiltfilt

from crane_reference.analysis.modal import linearise, modal_analysis, modes_at
from crane_reference.dynamics.modal_correction import iteration_factor
from crane_reference.dynamics.step import first_iterate, predicted_accelerations, step_residual
from crane_reference.model.config import load_config
from crane_reference.model.description import CraneDescription
from crane_reference.model.parameters import Damping, FlexibleDrive
from crane_reference.model.profiles import Constant, QuinticRise
from crane_reference.motion import integration
from crane_reference.motion.constraints import ArealRate, ConstraintSet, EllipseXY, HeightZ
from crane_reference.motion.integration import (
    EVALUATIONS,
    ONLINE_TOLERANCE,
    REFRESH_INTERVAL,
    ExactFrequencyTrapezoidal,
)
from crane_reference.motion.programmed_motion import ProgrammedMotion
from crane_reference.motion.simulation import MotionStepper, Scenario, simulate, simulate_reference
from crane_reference.motion.steps import ONLINE_STEP
from crane_reference.motion.trajectory import Trajectory

COORDINATES = ("column_slew", "boom_luff", "knuckle")
REFERENCE_SAMPLE = 1e-4  # [s]
GRID = 1e-3  # [s]: the 1 kHz samples on which the errors are filtered
ANTI_ALIAS = 400.0  # [Hz]
VIBRATION_BAND = (40.0, 250.0)  # [Hz]
WINDOWS = ((1.0, 5.0), (5.0, 10.0))  # [s]
STEPS = (1e-3, 5e-4, 2.5e-4)  # [s]
BOOM_DAMPING_RATIO, BASE_DAMPING_RATIO = 0.02, 0.05  # of critical, at the first boom bending / base mode


def realistic_damping(params: CraneDescription) -> Damping:
    """Stiffness-proportional damping (beta = 2 zeta / omega) with zeta = 2 % at the first boom bending mode
    (boom springs) and 5 % at the first base mode (support springs), the modes taken from the constrained
    modal analysis at the static equilibrium: the first whose strain energy is mostly boom bending, resp.
    support springs."""
    modes, _ = modes_at(params)

    def first(share) -> float:
        return float(modes.frequencies[next(k for k in range(modes.frequencies.size) if share(k) > 0.5)])

    f_boom = first(lambda k: sum(v[k] for name, v in modes.strain_energy.items() if name.startswith("boom bending")))
    f_base = first(lambda k: modes.strain_energy["support springs"][k])
    return Damping(support=2.0 * BASE_DAMPING_RATIO / (2.0 * np.pi * f_base),
                   boom=2.0 * BOOM_DAMPING_RATIO / (2.0 * np.pi * f_boom))


def with_rfe(params: CraneDescription, n_rfe: int) -> CraneDescription:
    return params.with_rfe_count(n_rfe)


def with_damping(params: CraneDescription, damping: Damping) -> CraneDescription:
    """The crane with the Rayleigh beta ``damping.support`` on its supports and ``damping.boom`` on its beams."""
    return replace(params, base=replace(params.base, damping=damping.support)).with_beam_damping(damping.boom)


def reference_run(params: CraneDescription, duration: float, cache: Path, label: str,
                  rtol: float = 1e-10) -> Trajectory:
    """The converged DOP853 run of the flexible crane over ``duration`` s (cached as NPZ under ``label``)."""
    path = cache / f"dop853_{label}_{duration:g}s_rtol{rtol:g}.npz"
    if path.exists():
        return Trajectory.from_npz(path)
    scenario = Scenario(params, "flexible")
    times = np.round(np.arange(0.0, duration + 0.5 * REFERENCE_SAMPLE, REFERENCE_SAMPLE), 9)
    start = time.perf_counter()
    reference = simulate_reference(scenario.motion, scenario.equilibrium.q, duration, times, rtol=rtol,
                                   atol=rtol * 1e-2)
    print(f"[reference:{label}] DOP853 (rtol {rtol:g}) over {duration:g} s: {time.perf_counter() - start:.0f} s wall")
    cache.mkdir(parents=True, exist_ok=True)
    reference.to_npz(path)
    return reference


def filtered(t: np.ndarray, x: np.ndarray, btype: str, band: float | tuple[float, float]) -> np.ndarray:
    """x (samples on the uniform times t, first axis) through a 4th-order Butterworth filter run forward and
    backward at its own sample rate."""
    return sosfiltfilt(butter(4, band, btype=btype, fs=1.0 / (t[1] - t[0]), output="sos"), x, axis=0)


def coordinates(tr: Trajectory) -> np.ndarray:
    return tr.q[:, [tr.joint_names.index(n) for n in COORDINATES]]


def band_rms(tr: Trajectory, window: tuple[float, float]) -> np.ndarray:
    """40-250 Hz RMS of psi2, psi(3,0), psi4 over ``window`` [s] (filtered over the whole run first)."""
    inside = (tr.t > window[0]) & (tr.t < min(window[1], tr.t[-1] - 0.2))
    return filtered(tr.t, coordinates(tr), "bandpass", VIBRATION_BAND)[inside].std(axis=0)


def on_grid(tr: Trajectory, x: np.ndarray, t: np.ndarray) -> np.ndarray:
    """x of ``tr`` on the 1 kHz grid t: where tr is sampled faster, first low-passed at 400 Hz (the RFE modes
    above the grid's Nyquist frequency would otherwise alias into the band), then taken at the grid times."""
    if tr.t[1] - tr.t[0] < GRID * (1.0 - 1e-9):
        x = filtered(tr.t, x, "lowpass", ANTI_ALIAS)
    return np.array([np.interp(t, tr.t, x[:, k]) for k in range(x.shape[1])]).T


def errors(reference: Trajectory, tr: Trajectory) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Largest raw and controller-band errors of psi2, psi(3,0), psi4 [rad] and of E [m]: raw on the
    reference's samples (tr interpolated), controller band on the 1 kHz grid, the error low-passed at 10 Hz
    away from the ends (where forward-backward filtering has transients)."""
    t = reference.t[::round(GRID / (reference.t[1] - reference.t[0]))]
    inner = (t > 0.05) & (t < t[-1] - 0.05)
    raw, slow = [], []
    for x_ref, x in ((coordinates(reference), coordinates(tr)), (reference.ee_position, tr.ee_position)):
        raw.append(np.array([np.interp(reference.t, tr.t, x[:, k]) for k in range(x.shape[1])]).T - x_ref)
        slow.append(filtered(t, on_grid(tr, x, t) - on_grid(reference, x_ref, t), "lowpass", 10.0)[inner])
    return (np.abs(raw[0]).max(axis=0), np.abs(slow[0]).max(axis=0), float(np.linalg.norm(raw[1], axis=1).max()),
            float(np.linalg.norm(slow[1], axis=1).max()))


def _triple(x: np.ndarray, form: str = ".1e") -> str:
    return "/".join(f"{v:{form}}" for v in x)


def undamped_crane(params: CraneDescription, n_rfe: int, duration: float, cache: Path) -> tuple[Trajectory, Scenario]:
    """The undamped crane with ``n_rfe`` boom elements: its converged run and its scenario (kernels ready)."""
    p = with_rfe(params, n_rfe)
    reference = reference_run(p, duration, cache, "undamped" if n_rfe == 6 else f"undamped-nrfe{n_rfe}")
    scenario = Scenario(p, "flexible")
    simulate(scenario.motion, scenario.equilibrium.q, 0.01)  # compile / load the kernels
    return reference, scenario


def vibration(params: CraneDescription, duration: float, cache: Path, rfe_counts: tuple[int, ...]) -> None:
    """[vibration] The 40-250 Hz RMS kept per window, raw and controller-band errors, per n_rfe."""
    for n_rfe in rfe_counts:
        reference, scenario = undamped_crane(params, n_rfe, duration, cache)
        q0 = scenario.equilibrium.q
        kept_reference = [band_rms(reference, w) for w in WINDOWS]
        for step in STEPS:
            start = time.perf_counter()
            tr = simulate(scenario.motion, q0, duration, step=step)
            wall = time.perf_counter() - start
            raw, slow, ee, ee_slow = errors(reference, tr)
            kept = [band_rms(tr, w) / r for w, r in zip(WINDOWS, kept_reference, strict=True)]
            shares = "; ".join(f"{a:g}-{b:g} s {_triple(k, '.0%')}" for (a, b), k in zip(WINDOWS, kept, strict=True))
            print(f"[vibration] n_rfe={n_rfe:2d} h={step * 1e3:.2f} ms ({duration / wall:4.1f}x real time): 40-250 Hz "
                  f"RMS kept psi2/psi30/psi4 {shares}; controller band {_triple(slow)} rad, E {ee_slow:.1e} m; "
                  f"max |error| {_triple(raw)} rad, E {ee:.1e} m")


REFINED_RFE = (24, 48)
"""[refined]: the refined cranes' n_rfe."""


def refined(params: CraneDescription, duration: float) -> None:
    """[refined] Per n_rfe of :data:`REFINED_RFE`: the undamped crane at ONLINE_STEP against the same integrator at
    ONLINE_STEP / 4 (its motion and E's pose only), the RMS kept and the errors as in [vibration]; then E's
    controller-band error of both against the same integrator at ONLINE_STEP / 8 (how far the reference has
    converged)."""
    for n_rfe in REFINED_RFE:
        scenario = Scenario(with_rfe(params, n_rfe), "flexible")
        q0 = scenario.equilibrium.q
        reference = simulate(scenario.motion, q0, duration, step=ONLINE_STEP / 4, every_row=False)
        start = time.perf_counter()
        tr = simulate(scenario.motion, q0, duration, step=ONLINE_STEP, every_row=False)
        wall = time.perf_counter() - start
        raw, slow, ee, ee_slow = errors(reference, tr)
        kept = [band_rms(tr, w) / band_rms(reference, w) for w in WINDOWS]
        shares = "; ".join(f"{a:g}-{b:g} s {_triple(k, '.0%')}" for (a, b), k in zip(WINDOWS, kept, strict=True))
        articulated = ExactFrequencyTrapezoidal(scenario.motion).articulated
        print(f"[refined] n_rfe={n_rfe:2d} dof={scenario.model.dof} iteration matrix "
              f"{'articulated' if articulated else 'dense'}, h={ONLINE_STEP * 1e3:.2f} ms against "
              f"{ONLINE_STEP * 250:.3f} ms ({duration / wall:4.1f}x real time): 40-250 Hz RMS kept psi2/psi30/psi4 "
              f"{shares}; controller band {_triple(slow)} rad, E {ee_slow:.1e} m; max |error| {_triple(raw)} rad, "
              f"E {ee:.1e} m")
        finer = simulate(scenario.motion, q0, duration, step=ONLINE_STEP / 8, every_row=False)
        print(f"[refined] n_rfe={n_rfe:2d} against {ONLINE_STEP * 125:.4f} ms, controller band at E: "
              f"h={ONLINE_STEP * 1e3:.2f} ms {errors(finer, tr)[3]:.1e} m, the reference at "
              f"{ONLINE_STEP * 250:.3f} ms {errors(finer, reference)[3]:.1e} m (how far the reference has converged)")


def growth(params: CraneDescription) -> None:
    """[growth] 60 s of the undamped default crane: the late vibration against the early one, and the energy."""
    scenario = Scenario(params, "flexible")
    q0 = scenario.equilibrium.q
    for step in STEPS:
        tr = simulate(scenario.motion, q0, 60.0, step=step)
        early, late = band_rms(tr, (5.0, 15.0)), band_rms(tr, (50.0, 60.0))
        energy = tr.kinetic_energy + tr.potential_energy
        means = [energy[(tr.t > a) & (tr.t < b)].mean() for a, b in ((5.5, 7.5), (58.0, 60.0))]
        print(f"[growth] h={step * 1e3:.2f} ms: 40-250 Hz RMS psi2/psi30/psi4 over 5-15 s {_triple(early)} rad, "
              f"over 50-60 s {_triple(late)} rad: {_triple(late / early, '.1%')}; energy mean 5.5-7.5 s "
              f"{means[0]:.4f} J, 58-60 s {means[1]:.4f} J")


def long_run(params: CraneDescription, hours: float, chunk: float = 10.0) -> None:
    """[long] ``hours`` of the undamped default crane at the node's step, computed in chunks and kept only
    around two 10 s windows: 5-15 s and the last 10 s (each recorded with 1 s on both sides for the
    filter): their 40-250 Hz RMS and mean energy."""
    scenario = Scenario(params, "flexible")
    q0 = scenario.equilibrium.q
    stepper = MotionStepper(scenario.motion, 0.0, q0, np.zeros_like(q0), ONLINE_STEP)
    end = hours * 3600.0
    windows = ((5.0, 15.0), (end - 10.0, end))
    start = time.perf_counter()
    results = []
    for a, b in windows:
        while stepper.state.t < a - 1.0 - 1e-9:  # the motion before the window, not kept
            stepper.advance_until(min(stepper.state.t + chunk, a - 1.0))
        run = Trajectory.from_rows("flexible", scenario.model.joint_names, scenario.model.drive_joint,
                                   stepper.advance_until(min(b + 1.0, end)))
        inside = (run.t > a) & (run.t < b)
        energy = (run.kinetic_energy + run.potential_energy)[inside]
        results.append((filtered(run.t, coordinates(run), "bandpass", VIBRATION_BAND)[inside].std(axis=0),
                        energy.mean()))
    (early, early_energy), (late, late_energy) = results
    print(f"[long] {hours:g} h at h={ONLINE_STEP * 1e3:g} ms ({time.perf_counter() - start:.0f} s wall): 40-250 Hz RMS "
          f"psi2/psi30/psi4 over 5-15 s {_triple(early)} rad, over the last 10 s {_triple(late)} rad: "
          f"{_triple(late / early, '.1%')}; energy mean {early_energy:.4f} J and {late_energy:.4f} J")


def damped(params: CraneDescription, duration: float, cache: Path) -> None:
    """[damped] Realistic damping, h = 1 ms and 0.5 ms."""
    damping = realistic_damping(params)
    p = with_damping(params, damping)
    label = f"damped-base{damping.support:.3e}s-boom{damping.boom:.3e}s"
    reference = reference_run(p, duration, cache, label)
    scenario = Scenario(p, "flexible")
    kept_reference = band_rms(reference, WINDOWS[1])
    for step in STEPS[:2]:
        tr = simulate(scenario.motion, scenario.equilibrium.q, duration, step=step)
        raw, slow, ee, ee_slow = errors(reference, tr)
        kept = band_rms(tr, WINDOWS[1]) / kept_reference
        print(f"[damped] beta {damping.support:.3e} s (supports) / {damping.boom:.3e} s (boom), h={step * 1e3:.2f} "
              f"ms: max |error| {_triple(raw)} rad, E {ee:.1e} m; controller band {_triple(slow)} rad, E "
              f"{ee_slow:.1e} m; 40-250 Hz RMS kept over 5-10 s {_triple(kept, '.0%')}")


def iteration_rules(params: CraneDescription, duration: float, cache: Path, rfe_counts: tuple[int, ...]) -> None:
    """[iterations] The Newton rules at the node's step (ONLINE_STEP) against the DOP853 reference, per n_rfe."""
    for n_rfe in rfe_counts:
        reference, scenario = undamped_crane(params, n_rfe, duration, cache)
        q0 = scenario.equilibrium.q
        for evaluations, tolerance, name in ((2, 1e-9, "converged"), (EVALUATIONS, ONLINE_TOLERANCE, "online default"),
                                             (3, ONLINE_TOLERANCE, "three evaluations"),
                                             (1, math.inf, "exactly one evaluation")):
            start = time.perf_counter()
            tr = simulate(scenario.motion, q0, duration, step=ONLINE_STEP, tolerance=tolerance,
                          evaluations=evaluations)
            wall = time.perf_counter() - start
            raw, slow, _, ee_slow = errors(reference, tr)
            kept = band_rms(tr, WINDOWS[1]) / band_rms(reference, WINDOWS[1])
            evaluated = newton_iterations(scenario, ONLINE_STEP, tolerance=tolerance, evaluations=evaluations)
            print(f"[iterations] n_rfe={n_rfe} h={ONLINE_STEP * 1e3:g} ms, {name} (at least {evaluations} "
                  f"evaluations, tolerance {tolerance:g}): {wall / tr.t.size * 1e6:6.1f} us/step, Newton evaluations "
                  f"{evaluated:.2f}/step; max |error| {_triple(raw)} rad, controller band {_triple(slow)} rad, E "
                  f"{ee_slow:.1e} m; 40-250 Hz RMS kept over 5-10 s {_triple(kept, '.0%')}")


def newton_matrix(params: CraneDescription) -> None:
    """[matrix] The Newton iteration of a step: the 2-norm and spectral radius of its error operator
    I - F^-1 J (J the Jacobian of the step's residual in a1, by central differences) for the iteration matrix F
    with M and B at the step's first iterate (the integrator's) and at its start, at steps from t = 0.5, 1, 3
    and 6 s at 0.5 and 1 ms."""
    scenario = Scenario(params, "flexible")
    motion = scenario.motion
    chain, partition = motion.dynamics.chain, motion.partition
    q0 = scenario.equilibrium.q
    for step in (ONLINE_STEP, 1e-3):
        stepper = MotionStepper(motion, 0.0, q0, np.zeros_like(q0), step)
        settings = stepper.integrator.settings
        for t in (0.5, 1.0, 3.0, 6.0):
            stepper.advance_until(t)
            state = stepper.state
            t1 = state.t + step
            k, drive = motion.constraints.coefficients(t1), motion.dynamics.drive.kernel_parameters(t1)
            a0 = state.solution.qdd[partition.integrated]
            jacobian = np.empty((a0.size, a0.size))
            for j in range(a0.size):
                delta = np.zeros_like(a0)
                delta[j] = 1e-3 * max(1.0, abs(a0[j]))
                plus, minus = (step_residual(a0 + sign * delta, state.q, state.qd, a0, state.correction, step,
                                                     k, drive, partition, chain, settings) for sign in (1.0, -1.0))
                jacobian[:, j] = (plus - minus) / (2.0 * delta[j])
            first = first_iterate(state.q, state.qd, state.qdd, a0,
                                          predicted_accelerations(a0, state.earlier), step, k, partition, chain,
                                          settings)
            at_first = motion.solve(t1, first.q, first.qd)
            factors = {
                "first iterate": iteration_factor(at_first.dynamics.M, at_first.velocity_map, step,
                                                          state.correction, drive, partition, chain),
                "step's start": iteration_factor(state.solution.dynamics.M, state.solution.velocity_map, step,
                                                         state.correction, drive, partition, chain)}
            parts = []
            for name, factor in factors.items():
                error = np.eye(a0.size) - np.linalg.solve(factor @ factor.T, jacobian)
                parts.append(f"M, B at the {name}: |I - F^-1 J| {np.linalg.norm(error, 2):.1e}, spectral radius "
                             f"{np.abs(np.linalg.eigvals(error)).max():.1e}")
            print(f"[matrix] h={step * 1e3:g} ms, step from t={t:g} s: " + "; ".join(parts))


def newton_tolerance(params: CraneDescription, duration: float, step: float = 1e-3) -> None:
    """[newton] Differences between Newton tolerances."""
    scenario = Scenario(params, "flexible")
    q0 = scenario.equilibrium.q
    index = [scenario.model.joint_names.index(n) for n in COORDINATES]
    runs = {}
    for tolerance in (1e-8, 1e-9, 1e-10, 1e-12):
        stepper = MotionStepper(scenario.motion, 0.0, q0, np.zeros_like(q0), step, tolerance=tolerance)
        start = time.perf_counter()
        runs[tolerance] = stepper.advance_until(duration).q[:, index], duration / (time.perf_counter() - start)
    for tolerance in (1e-8, 1e-9, 1e-10):
        difference = np.abs(runs[tolerance][0] - runs[1e-12][0]).max(axis=0)
        print(f"[newton] h={step * 1e3:.0f} ms, tolerance {tolerance:g} ({runs[tolerance][1]:.1f}x real time) "
              f"vs 1e-12: largest difference over {duration:g} s psi2/psi30/psi4 = {_triple(difference)} rad")


def first_order(params: CraneDescription, duration: float = 2.0) -> None:
    """[first-order] A first-order task constraint (E's speed along the ellipse)."""
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


def reference_check(params: CraneDescription, duration: float, cache: Path) -> None:
    """[reference] The reference's own error."""
    tight = reference_run(params, duration, cache, "undamped")
    loose = reference_run(params, duration, cache, "undamped", rtol=1e-9)
    difference = np.abs(coordinates(tight) - coordinates(loose)).max(axis=0)
    print(f"[reference] DOP853 rtol 1e-9 vs 1e-10 over {duration:g} s: psi2/psi30/psi4 differ by at most "
          f"{_triple(difference)} rad")


def sensitivity(params: CraneDescription, duration: float, cache: Path) -> None:
    """[sensitivity] How well-conditioned the 40-250 Hz RMS is: the crane with its payload mass changed by
    -1, -0.5, +0.5, +1 % and its boom's Young's modulus by -1, +1 % (h = 0.25 ms, converged Newton), as a
    share of the nominal converged run's; then the nominal crane at h = 1, 0.5, 1/3 and 0.25 ms (converged
    Newton) for comparison: a step's deviation is that of a model this many percent off."""
    reference = reference_run(params, duration, cache, "undamped")
    kept_reference = [band_rms(reference, w) for w in WINDOWS]
    changes = [(f"payload mass {100 * (s - 1):+.1f} %", replace(params, payload=params.payload * s))
               for s in (0.99, 0.995, 1.005, 1.01)]
    changes += [(f"boom Young's modulus {100 * (s - 1):+.0f} %",
                 params.with_beam_stiffness(s))
                for s in (0.99, 1.01)]
    runs = [(f"{name}, h=0.25 ms", p, 2.5e-4) for name, p in changes]
    runs += [(f"nominal, h={step * 1e3:.2f} ms", params, step) for step in (1e-3, 5e-4, 1e-3 / 3, 2.5e-4)]
    for name, p, step in runs:
        scenario = Scenario(p, "flexible")
        tr = simulate(scenario.motion, scenario.equilibrium.q, duration, step=step, tolerance=1e-9, evaluations=2)
        kept = [band_rms(tr, w) / r for w, r in zip(WINDOWS, kept_reference, strict=True)]
        shares = "; ".join(f"{a:g}-{b:g} s {_triple(k, '.0%')}" for (a, b), k in zip(WINDOWS, kept, strict=True))
        print(f"[sensitivity] {name}: 40-250 Hz RMS psi2/psi30/psi4 {shares} of the nominal converged run's")


def mechanism(params: CraneDescription, duration: float, cache: Path) -> None:
    """[mechanism] Internal resonances along the run; plain trapezoidal rule against exact frequencies."""
    scenario = Scenario(params, "flexible")
    q0 = scenario.equilibrium.q
    tr = simulate(scenario.motion, q0, duration, step=2.5e-4)
    for t in np.arange(0.5, duration + 1e-9, 0.5):
        i = int(np.argmin(np.abs(tr.t - t)))
        f = np.sort(modal_analysis(linearise(scenario.motion, tr.t[i], tr.q[i], tr.qd[i])).frequencies)
        print(f"[mechanism] t={t:4.1f} s: f8..f11 = {f[7]:6.2f} {f[8]:6.2f} {f[9]:6.2f} {f[10]:6.2f} Hz; "
              f"2 f9 - f8 - f10 = {2 * f[8] - f[7] - f[9]:+6.2f} Hz, f9 + f10 - f11 = {f[8] + f[9] - f[10]:+6.2f} Hz")
    reference = reference_run(params, duration, cache, "undamped")
    windows = ((1.0, 3.0), (3.0, 5.0), (5.0, 7.0), (7.0, 10.0))
    luffing = [band_rms(reference, w)[1] for w in windows]
    print("[mechanism] converged run: psi30 40-250 Hz RMS over 1-3/3-5/5-7/7-10 s " + _triple(np.array(luffing)))
    for step in (2.5e-4, 1e-3):
        for modal, name in ((False, "plain trapezoidal rule"), (True, "exact frequencies")):
            stepper = MotionStepper(scenario.motion, 0.0, q0, np.zeros_like(q0), step)
            stepper.integrator.modal = modal
            run = Trajectory.from_rows("flexible", scenario.model.joint_names, scenario.model.drive_joint,
                                       stepper.advance_until(duration))
            shares = np.array([band_rms(run, w)[1] for w in windows]) / luffing
            print(f"[mechanism] h={step * 1e3:.2f} ms, {name}: psi30 40-250 Hz RMS over 1-3/3-5/5-7/7-10 s "
                  f"{_triple(shares, '.0%')} of the converged run's")


def slow_motion(params: CraneDescription, duration: float, cache: Path) -> None:
    """[slow] Where the controller-band error comes from, on the undamped and the damped crane: the
    integrator at 0.5 and 1 ms with its modal correction computed every step, every 5 ms, every
    REFRESH_INTERVAL (default) and every 20 ms, and the plain trapezoidal rule; the controller-band error of
    psi2 (signed, at 3, 5 and 10 s: a drift of the column's progress grows linearly) and its largest value,
    and of E; the 40-250 Hz RMS of psi2, psi(3,0), psi4 over 5-10 s as a share of the converged run's (how
    stale a correction may get).  Then a stiff flexible drive (s_dr = 1e8 N m/rad)
    over 0.1 s against DOP853."""
    damping = realistic_damping(params)
    for label, p in (("undamped", params),
                     (f"damped-base{damping.support:.3e}s-boom{damping.boom:.3e}s", with_damping(params, damping))):
        reference = reference_run(p, duration, cache, label)
        scenario = Scenario(p, "flexible")
        q0 = scenario.equilibrium.q
        t = reference.t[::round(GRID / REFERENCE_SAMPLE)]
        slew = on_grid(reference, coordinates(reference), t)[:, 0]
        late = (5.0, duration)
        late_reference = band_rms(reference, late)
        runs = [(step, f"h={step * 1e3:g} ms, modal correction computed every {refresh * 1e3:g} ms", True, refresh)
                for step in (ONLINE_STEP, 1e-3)
                for refresh in dict.fromkeys((step, 5e-3, integration.REFRESH_INTERVAL, 2e-2))]
        runs.append((1e-3, "h=1 ms, plain trapezoidal rule", False, REFRESH_INTERVAL))
        for step, name, modal, refresh in runs:
            stepper = MotionStepper(scenario.motion, 0.0, q0, np.zeros_like(q0), step)
            stepper.integrator.modal, stepper.integrator.refresh_interval = modal, refresh
            run = Trajectory.from_rows("flexible", scenario.model.joint_names, scenario.model.drive_joint,
                                       stepper.advance_until(duration))
            _, slow, _, ee_slow = errors(reference, run)
            drift = filtered(t, on_grid(run, coordinates(run), t)[:, 0] - slew, "lowpass", 10.0)
            at = "/".join(f"{drift[np.argmin(np.abs(t - s))]:+.1e}" for s in (3.0, 5.0, duration - 0.1))
            kept = band_rms(run, late) / late_reference
            print(f"[slow] {label.split('-')[0]}, {name}: psi2 controller-band error at 3/5/{duration - 0.1:g} s {at} "
                  f"rad, largest {slow[0]:.1e} rad; E {ee_slow:.1e} m; 40-250 Hz RMS kept over 5-{duration:g} s "
                  f"{_triple(kept, '.0%')}")
    stiff = Scenario(replace(params, drive=FlexibleDrive(stiffness=1e8, travel=1.0, start=0.0, duration=2.0)),
                     "flexible")
    q0 = stiff.equilibrium.q
    run = simulate(stiff.motion, q0, 0.1, step=1e-3)
    converged = simulate_reference(stiff.motion, q0, 0.1, run.t)
    print(f"[slow] flexible drive s_dr = 1e8 N m/rad, h = 1 ms, 0.1 s: Newton evaluations "
          f"{newton_iterations(stiff, 1e-3, duration=0.1):.2f}/step, largest difference from DOP853 "
          f"{np.abs(run.q - converged.q).max():.1e} rad")


DRIFT_GRID = 6e-3  # [s]: a multiple of the steps [drift] compares but 0.3125 ms (compared every 30 ms)

DRIFT_STEPS = (0.5e-3, 0.4e-3, 0.3125e-3, 0.3e-3, 1 / 3500, 0.25e-3, 0.2e-3)
"""[s]: the steps of [drift]; 0.3 ms is the only one whose grid misses the torque's end at t = 1 s."""


def drift_run(scenario: Scenario, h: float, duration: float, cutoff: float | None = None,
              converged: bool = False, mode_tracking: float | None = None,
              resolved_bandwidth: float | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """E's positions on the DRIFT_GRID times the steps reach over ``duration`` at step h (and their grid indices),
    resolving modes below omega h = ``cutoff`` and ``resolved_bandwidth`` [rad/s] and tracking them every
    ``mode_tracking`` [s] if given, with the converged Newton iteration if ``converged``; and the energy's drift
    [J], its mean over the last 10 s less that over 5-15 s (on the grid: no drive torque after 1 s, no dampers,
    fixed constraints after 5 s: it must stay)."""
    q0 = scenario.equilibrium.q
    stepper = MotionStepper(scenario.motion, 0.0, q0, np.zeros_like(q0), h, every_row=False,
                            **({"tolerance": 1e-10} if converged else {}))
    if cutoff is not None:
        stepper.integrator.cutoff = cutoff
    if mode_tracking is not None:
        stepper.integrator.mode_tracking_interval = mode_tracking
    if resolved_bandwidth is not None:
        stepper.integrator.resolved_bandwidth = resolved_bandwidth
    grid, positions = [], []
    windows, energies = ((5.0, 15.0), (duration - 10.0, duration)), ([], [])
    while stepper.state.t < duration - 1e-9:
        rows = stepper.advance_until(min(stepper.state.t + 1.0, duration))
        k = np.round(rows.t / DRIFT_GRID)
        on_grid = np.abs(rows.t - k * DRIFT_GRID) < 1e-9
        grid.append(k[on_grid].astype(int))
        positions.append(rows.ee_position[on_grid])
        for (a, b), window in zip(windows, energies, strict=True):
            for i in np.flatnonzero(on_grid & (rows.t > a) & (rows.t < b)):
                solution = scenario.motion.solve(rows.t[i], rows.q[i], rows.qd[i])
                window.append(solution.kinetic_energy + solution.potential_energy)
    early, late = (np.mean(window) for window in energies)
    return np.concatenate(grid), np.concatenate(positions), late - early


PACKAGE_CUTOFF, PACKAGE_MODE_TRACKING = integration.CUTOFF, integration.MODE_TRACKING_INTERVAL
PACKAGE_BANDWIDTH = integration.RESOLVED_BANDWIDTH
"""[drift]: the package's defaults, before --cutoff, --mode-tracking or --bandwidth change them."""

DRIFT_REFERENCE_CUTOFF = 0.8 * math.pi
"""[drift]: the full model's 0.125 ms run resolves every mode of the default crane below 3.2 kHz (no bandwidth), as
DOP853 resolves every mode (not tracked: its modal correction is computed afresh every REFRESH_INTERVAL)."""


def drift_references(scenario: Scenario, duration: float, cache: Path) -> dict[str, list[np.ndarray]]:
    """[drift] The converged 0.125 ms runs on the DRIFT_GRID, by name: the full model's (every mode resolved; its own
    distance from the cached DOP853 run over that run's 10 s printed, errors(): raw and controller band), and, with a
    finite bandwidth, the one of the modes the integrator resolves as it is (the bandwidth, the cutoff at 0.125 ms
    and the mode tracking of this run's integrators: its limit as the step shrinks; its distance from the full
    model's over 10 / 30 / 60 s and both runs' energy drift printed)."""
    q0 = scenario.equilibrium.q
    stepper = MotionStepper(scenario.motion, 0.0, q0, np.zeros_like(q0), 0.125e-3, tolerance=1e-10)
    stepper.integrator.cutoff, stepper.integrator.mode_tracking_interval = DRIFT_REFERENCE_CUTOFF, math.inf
    stepper.integrator.resolved_bandwidth = math.inf
    check = Trajectory.from_rows("flexible", scenario.model.joint_names, scenario.model.drive_joint,
                                 stepper.advance_until(10.0))
    _, _, ee, ee_slow = errors(reference_run(scenario.params, 10.0, cache, "undamped"), check)
    print(f"[drift] the full model's 0.125 ms run against DOP853 (rtol 1e-10) over 10 s: E {ee:.1e} m raw, "
          f"{ee_slow:.1e} m in the controller band", flush=True)
    *full, full_energy = drift_run(scenario, 0.125e-3, duration, cutoff=DRIFT_REFERENCE_CUTOFF, converged=True,
                                   mode_tracking=math.inf, resolved_bandwidth=math.inf)
    if not math.isfinite(integration.RESOLVED_BANDWIDTH):  # the limit is the full model's run
        return {"the full model's": full}
    *limit, limit_energy = drift_run(scenario, 0.125e-3, duration, converged=True)
    label = f"the bandwidth's limit (modes below {integration.resolved_below(0.125e-3):.0f} Hz)"
    print(f"[drift] {label} against the full model over 10 / 30 / 60 s: {_largest_distances(limit, full, duration)} "
          f"m; energy over the last 10 s less over 5-15 s {limit_energy:+.4f} J (the full model's "
          f"{full_energy:+.4f} J)", flush=True)
    return {"the full model's": full, label: limit}


def _largest_distances(run, reference, duration: float) -> str:
    """E's largest distance of ``run`` from ``reference`` (each grid indices and E's positions there) over 10 / 30 /
    60 s, on the grid times both reach."""
    common, here, there = np.intersect1d(run[0], reference[0], return_indices=True)
    distance = np.linalg.norm(run[1][here] - reference[1][there], axis=1)
    t = common * DRIFT_GRID
    return " / ".join(f"{distance[t <= span].max():.1e}" for span in (10.0, 30.0, 60.0) if span <= duration)


def _tracking(interval: float) -> str:
    """How a report names a mode-tracking interval [s]."""
    return f"tracked every {interval * 1e3:g} ms" if interval < math.inf else "not tracked"


def step_drift(params: CraneDescription, cache: Path, duration: float = 60.0) -> None:
    """[drift] E's largest distance over 10 / 30 / 60 s from the converged 0.125 ms runs (:func:`drift_references`),
    per step of DRIFT_STEPS: the integrator as it is (online iteration), so with the converged iteration, without
    the resolved bandwidth (the cutoff alone: modes resolved up to omega h = cutoff at every step), and, when
    --cutoff, --mode-tracking or --bandwidth changed it, with the package's defaults."""
    scenario = Scenario(params, "flexible")
    references = drift_references(scenario, duration, cache)
    interval = integration.MODE_TRACKING_INTERVAL
    variants = [(f"as it is (cutoff {integration.CUTOFF / math.pi:g} pi, bandwidth "
                 f"{integration.RESOLVED_BANDWIDTH / (2 * math.pi):g} Hz, modes {_tracking(interval)})", {}),
                ("as it is, converged Newton", {"converged": True})]
    if math.isfinite(integration.RESOLVED_BANDWIDTH):
        variants.append(("without the bandwidth", {"resolved_bandwidth": math.inf}))
    if (integration.CUTOFF, interval, integration.RESOLVED_BANDWIDTH) != (PACKAGE_CUTOFF, PACKAGE_MODE_TRACKING,
                                                                          PACKAGE_BANDWIDTH):
        variants.append((f"the package's default: cutoff {PACKAGE_CUTOFF / math.pi:g} pi, bandwidth "
                         f"{PACKAGE_BANDWIDTH / (2 * math.pi):g} Hz, modes {_tracking(PACKAGE_MODE_TRACKING)}",
                         {"cutoff": PACKAGE_CUTOFF, "mode_tracking": PACKAGE_MODE_TRACKING,
                          "resolved_bandwidth": PACKAGE_BANDWIDTH}))
    for h in DRIFT_STEPS:
        for name, variant in variants:
            start = time.perf_counter()
            *run, energy_drift = drift_run(scenario, h, duration, **variant)
            worst = [_largest_distances(run, reference, duration) for reference in references.values()]
            print(f"[drift] h={h * 1e3:.4f} ms, {name}: E's largest distance over 10 / 30 / 60 s from "
                  + "; from ".join(f"{label} 0.125 ms run {w} m" for label, w in zip(references, worst, strict=True))
                  + f"; energy over the last 10 s less over 5-15 s {energy_drift:+.4f} J"
                  + f" ({time.perf_counter() - start:.0f} s wall)", flush=True)


SECTIONS = ("vibration", "growth", "long", "damped", "iterations", "matrix", "newton", "first-order", "mechanism",
            "sensitivity", "slow", "reference", "drift", "refined")
DEFAULT_SECTIONS = tuple(s for s in SECTIONS if s not in ("long", "reference", "drift", "refined"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--cache", type=Path, default=Path("results/bench_accuracy"))
    parser.add_argument("--only", nargs="+", choices=SECTIONS, default=DEFAULT_SECTIONS,
                        help="sections to run")
    parser.add_argument("--hours", type=float, default=1.0, help="[long]: hours of motion")
    parser.add_argument("--cutoff", type=float, help="omega h [pi rad] from which every integrator made damps a mode "
                        "instead of resolving it (default: integration.CUTOFF, 0.8; the bandwidth stays: --bandwidth)")
    parser.add_argument("--bandwidth", type=float, help="[Hz] from which every integrator made damps a mode at any "
                        "step (inf: the cutoff alone; default: integration.RESOLVED_BANDWIDTH, 800 Hz)")
    parser.add_argument("--refresh", type=float, help="[s] of motion after which every integrator made computes its "
                        "modal correction again (default: integration.REFRESH_INTERVAL, 0.01)")
    parser.add_argument("--mode-tracking", type=float, help="[s] of motion after which every integrator made tracks "
                        "its resolved modes (0: every step; default: integration.MODE_TRACKING_INTERVAL)")
    parser.add_argument("--evaluations", type=int, help="Newton evaluations a step of every simulate that does not "
                        "set its own (default: integration.EVALUATIONS, 2)")
    parser.add_argument("--rfe", nargs="+", type=int, default=[6, 3, 12],
                        help="[vibration], [iterations]: the cranes' n_rfe")
    args = parser.parse_args()
    if args.cutoff is not None:
        integration.CUTOFF = args.cutoff * math.pi  # what every integrator made from now on resolves below
    if args.bandwidth is not None:
        if not args.bandwidth > 0.0:
            parser.error(f"--bandwidth: {args.bandwidth}; a bandwidth is a frequency above 0 Hz (inf: none)")
        integration.RESOLVED_BANDWIDTH = 2.0 * math.pi * args.bandwidth
    if args.refresh is not None:
        integration.REFRESH_INTERVAL = args.refresh
    if args.mode_tracking is not None:
        integration.MODE_TRACKING_INTERVAL = args.mode_tracking
    if args.evaluations is not None:
        if args.evaluations < 1:
            parser.error(f"--evaluations: {args.evaluations}; a step takes at least 1 Newton evaluation")
        global simulate  # what every section calls from now on
        simulate = functools.partial(simulate, evaluations=args.evaluations)
    params = load_config()
    for section, run in (("vibration", lambda: vibration(params, args.duration, args.cache, tuple(args.rfe))),
                         ("growth", lambda: growth(params)),
                         ("long", lambda: long_run(params, args.hours)),
                         ("damped", lambda: damped(params, args.duration, args.cache)),
                         ("iterations", lambda: iteration_rules(params, args.duration, args.cache, tuple(args.rfe))),
                         ("matrix", lambda: newton_matrix(params)),
                         ("newton", lambda: newton_tolerance(params, args.duration)),
                         ("first-order", lambda: first_order(params)),
                         ("mechanism", lambda: mechanism(params, args.duration, args.cache)),
                         ("sensitivity", lambda: sensitivity(params, args.duration, args.cache)),
                         ("slow", lambda: slow_motion(params, args.duration, args.cache)),
                         ("reference", lambda: reference_check(params, args.duration, args.cache)),
                         ("drift", lambda: step_drift(params, args.cache)),
                         ("refined", lambda: refined(params, args.duration))):
        if section in args.only:
            run()


if __name__ == "__main__":
    main()

"""Vibration of the flexible boom during the programmed motion, and the rigid-vs-flexible report.

Signals of a run (:class:`~crane_reference.motion.trajectory.Trajectory`):

* the RFE angles psi, theta, phi of every spring-damping element of the boom;
* the boom-tip deflection relative to the rigid chord, in the frame of the first boom element (the frame
  after the luff joint: x along the unbent boom, y up in the luffing plane, z along the luff axis),

      w = R_0^T (r_tip(q) - r_tip(q with every RFE angle set to 0)),

  r_tip the origin of the knuckle frame; R_0 is the same in both terms because the RFE joints come after
  the luff joint.  w_y is the deflection in the luffing plane, w_z the horizontal one, w_x the
  (second-order) shortening;
* the tip torsion, the sum of the RFE twist angles (the twist of the tip element to first order).

Spectra: Welch's method (scipy.signal.welch: Hann windows of 2^k samples, at least four per run, 50 %
overlap, linear detrend per window), one-sided PSD, resolution df = fs / nperseg.

Agreement with the modal analysis (:mod:`crane_reference.analysis.modal`): the constrained modes are computed at
states of the run every ``modal_interval`` s (linearised with the state's velocities).  The crane's
configuration changes as E goes round the ellipse, so mode k sweeps a band [min_t f_k, max_t f_k].  The
integrator (:mod:`crane_reference.motion.integration`) reproduces a mode at its own frequency when omega h
is below its cutoff and damps the modes above, so only the resolved modes explain peaks.  A spectral peak
agrees with mode k if it lies in k's band widened by the tolerance

    delta = df + 0.01 f,

one bin of the spectrum plus 1 % for the frozen-time linearisation.  A peak no mode explains may be a
second-order combination f_i + f_j or |f_i - f_j| (e.g. 2 f_i: the vertical tip deflection has a
component quadratic in the horizontal one); it is reported as such.  Peaks below ``MIN_FREQUENCY`` are
the quasi-static response to the slewing (in the paper's scenario the drive torque acts for 1 s and E
takes about 10 s round the ellipse), not vibration, and are left out.

Realisations: the paper's ideal constraints (a force at E) and servo-constraints (luff and knuckle
torques, :class:`~crane_reference.motion.programmed_motion.ProgrammedMotion` with ``realisation="servo"``).
Each realisation starts from its own static equilibrium: with ideal constraints the height constraint's
force at E (6.0 kN) carries the payload and link 4, and the boom tip sits 0.05 mm above its chord; with
servo-constraints they hang on the boom, whose tip sags 2.05 mm.  On the flexible boom the servo
torques act at the luff, away from E, and the internal dynamics they leave are unstable (the luffing-plane
bending, exponents up to 6.6e3 1/s, see :mod:`crane_reference.analysis.modal`): such a run stops within a few
steps, and the report says so and lists the unstable modes.

Report (:func:`analyze`): both models under each realisation; joint differences flexible - rigid (per
realisation) and servo - ideal (per model) of psi2, psi(3,0), psi4, raw and as a 0.1 s moving mean (the
undamped boom rings for ever); deflection signals, spectra and peaks of the flexible runs; residuals and
energy-balance errors; the generalized forces of the realisations on the luff and knuckle.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import signal
from scipy.ndimage import uniform_filter1d

from ..dynamics.kinematics import forward_kinematics
from ..dynamics.structures import ChainData
from ..model.chain import VARIANTS, ChainModel
from ..model.parameters import CraneParameters
from ..motion.integration import CUTOFF, METHOD
from ..motion.programmed_motion import REALISATIONS, ProgrammedMotion
from ..motion.simulation import SOLVER_FAILURES, MotionStepper, Scenario
from ..motion.steps import ANALYSIS_STEP
from ..motion.trajectory import Trajectory, stack_samples
from .modal import Modes, linearise, modal_analysis, scenario_motion

MIN_FREQUENCY = 2.0  # [Hz] peaks below are the quasi-static response to the slewing
RELATIVE_TOLERANCE = 0.01  # of the peak frequency, besides one spectral bin
DIFFERENCE_COORDINATES = ("column_slew", "boom_luff", "knuckle")  # psi2, psi(3,0), psi4
SIGNALS = {"tip_vertical": "tip deflection $w_y$ (luffing plane) [m]",
           "tip_horizontal": "tip deflection $w_z$ (horizontal) [m]",
           "tip_torsion": r"tip torsion $\sum \varphi$ [rad]"}
MEAN_WINDOW = 0.1  # [s] moving mean that separates drift from ringing in the differences
RUN_CHUNK = 0.25  # [s] of motion per compiled run


def rfe_indices(model: ChainModel, suffix: str = "") -> np.ndarray:
    """Indices of the boom's RFE angles (all, or those whose name ends with ``suffix``)."""
    return np.array([k for k, name in enumerate(model.joint_names)
                     if name.startswith("boom_sde") and name.endswith(suffix)], dtype=np.int64)


def boom_tip_deflection(model: ChainModel, chain: ChainData, q: np.ndarray) -> np.ndarray:
    """w (N, 3) [m] for q (N, n), see the module docstring; ``chain`` is ``CraneDynamics.chain``."""
    kinds, axes, origins = chain.kinds, chain.axes, chain.origins
    luff, tip = model.index("boom_luff"), model.index("knuckle")
    rfe = rfe_indices(model)
    q = np.atleast_2d(q)
    out = np.empty((len(q), 3))
    for i, qi in enumerate(q):
        T, _ = forward_kinematics(np.ascontiguousarray(qi, dtype=float), kinds, axes, origins)
        chord = qi.copy()
        chord[rfe] = 0.0
        T0, _ = forward_kinematics(chord, kinds, axes, origins)
        out[i] = T[luff, :3, :3].T @ (T[tip, :3, 3] - T0[tip, :3, 3])
    return out


def deflection_signals(model: ChainModel, chain: ChainData, trajectory: Trajectory) -> dict[str, np.ndarray]:
    """The signals of :data:`SIGNALS` over a run."""
    w = boom_tip_deflection(model, chain, trajectory.q)
    return {"tip_vertical": w[:, 1], "tip_horizontal": w[:, 2],
            "tip_torsion": trajectory.q[:, rfe_indices(model, "_twist")].sum(axis=1)}


@dataclass(frozen=True)
class Spectrum:
    """One-sided power spectral density ``psd`` [unit^2/Hz] at ``frequency`` [Hz], bin width ``resolution``."""

    frequency: np.ndarray
    psd: np.ndarray
    resolution: float


def spectrum(t: np.ndarray, x: np.ndarray, segments: int = 4) -> Spectrum:
    """Welch PSD of x(t) (resampled on a uniform grid of the median step if needed) with the longest
    power-of-two Hann window that fits ``segments`` times into the run."""
    dt = float(np.median(np.diff(t)))
    grid = t[0] + dt * np.arange(round((t[-1] - t[0]) / dt) + 1)
    x = np.interp(grid, t, x)
    nperseg = 2 ** int(np.floor(np.log2(max(len(grid) / segments, 8))))
    f, psd = signal.welch(x, fs=1.0 / dt, window="hann", nperseg=nperseg, detrend="linear")
    return Spectrum(f, psd, float(f[1] - f[0]))


def spectral_peaks(spec: Spectrum, count: int = 4, min_frequency: float = MIN_FREQUENCY,
                   prominence: float = 1.0, dynamic_range: float = 1e-6) -> np.ndarray:
    """Frequencies of the ``count`` strongest peaks above ``min_frequency``: local maxima standing at
    least ``prominence`` decades above their surroundings and within ``dynamic_range`` of the
    strongest."""
    keep = spec.frequency >= min_frequency
    f, psd = spec.frequency[keep], spec.psd[keep]
    index, _ = signal.find_peaks(np.log10(np.maximum(psd, 1e-300)), prominence=prominence)
    index = index[psd[index] >= dynamic_range * psd[index].max()] if index.size else index
    index = index[np.argsort(-psd[index])][:count]
    return f[index]


@dataclass(frozen=True)
class ModalBands:
    """Constrained natural frequencies (len(times), m) [Hz] at states of a run (sorted per state), their
    characters, and ``resolved_below`` [Hz]: the integrator reproduces a mode below it at its own
    frequency and damps the modes above it (:data:`crane_reference.motion.integration.CUTOFF`)."""

    times: np.ndarray
    frequencies: np.ndarray
    resolved_below: float
    characters: list[list[str]]

    def band(self, k: int) -> tuple[float, float]:
        f = self.frequencies[:, k]
        return float(f.min()), float(f.max())

    def resolved(self) -> list[int]:
        """The modes the integrator resolves over the whole run."""
        return [k for k in range(self.frequencies.shape[1]) if self.frequencies[:, k].max() < self.resolved_below]


def modal_bands(motion: ProgrammedMotion, trajectory: Trajectory, interval: float, step: float) -> ModalBands:
    """Modes of the linearisation at the samples closest to every ``interval`` s of the run (integrated
    with the step ``step``)."""
    times, frequencies, characters = [], [], []
    for target in np.arange(trajectory.t[0], trajectory.t[-1] + 1e-9, interval):
        i = int(np.argmin(np.abs(trajectory.t - target)))
        modes = modal_analysis(linearise(motion, trajectory.t[i], trajectory.q[i], trajectory.qd[i]))
        times.append(trajectory.t[i])
        frequencies.append(modes.frequencies)
        characters.append([modes.character(k) for k in range(modes.frequencies.size)])
    return ModalBands(np.array(times), np.array(frequencies), CUTOFF / (2.0 * np.pi * step), characters)


def _distance(frequency: float, values: np.ndarray) -> float:
    """Distance of ``frequency`` from the band [min, max] of ``values`` (0 inside)."""
    return max(float(values.min()) - frequency, frequency - float(values.max()), 0.0)


def match_peak(frequency: float, bands: ModalBands, resolution: float) -> dict:
    """Explain a spectral peak by the modal analysis.  A mode k the integrator resolves
    (:meth:`ModalBands.resolved`) explains it if the peak lies within delta = df + 0.01 f of the band its
    frequency sweeps over the run.  Otherwise a second-order combination f_i + f_j or |f_i - f_j| of two
    resolved elastic modes (above :data:`MIN_FREQUENCY`; e.g. 2 f_i from the quadratic kinematic coupling
    of the deflections) may explain it; ``explained_by`` is "mode", "combination" or "none"."""
    tolerance = resolution + RELATIVE_TOLERANCE * frequency
    f = bands.frequencies
    resolved = bands.resolved()
    distances = {k: _distance(frequency, f[:, k]) for k in resolved}
    k = min(distances, key=distances.get)
    closest = int(np.argmin(np.abs(f[:, k] - frequency)))
    entry = {"peak_hz": float(frequency), "mode": k + 1, "band_hz": list(bands.band(k)), "distance_hz": distances[k],
             "tolerance_hz": float(tolerance), "character": bands.characters[closest][k], "explained_by": "mode"}
    if distances[k] <= tolerance:
        return entry
    elastic = [j for j in resolved if f[:, j].min() >= MIN_FREQUENCY]
    pairs = [(i, j, sign) for a, i in enumerate(elastic) for j in elastic[a:] for sign in (1, -1) if sign > 0 or i != j]
    if not pairs:
        entry["explained_by"] = "none"
        return entry

    def combine(values: np.ndarray, i: int, j: int, sign: int) -> np.ndarray:
        return np.abs(values[:, i] + sign * values[:, j])

    distance, i, j, sign = min((_distance(frequency, combine(f, i, j, sign)), i, j, sign) for i, j, sign in pairs)
    if distance > tolerance:
        entry["explained_by"] = "none"
        return entry
    combined = combine(f, i, j, sign)
    at = int(np.argmin(np.abs(combined - frequency)))
    return {**entry, "explained_by": "combination", "combination": f"f{i + 1} {'+' if sign > 0 else '-'} f{j + 1}",
            "mode": None, "band_hz": [float(combined.min()), float(combined.max())], "distance_hz": distance,
            "character": f"{bands.characters[at][i]} / {bands.characters[at][j]}"}


@dataclass
class Run:
    """One programmed-motion run; ``error`` says why it stopped early (``trajectory`` up to there)."""

    realisation: str
    variant: str
    motion: ProgrammedMotion
    trajectory: Trajectory | None
    wall: float
    error: str | None
    start_modes: Modes | None


def run(params: CraneParameters, variant: str, realisation: str, duration: float, step: float) -> Run:
    """Simulate one variant and realisation from its equilibrium; a failure keeps the samples so far."""
    scenario = Scenario(params, variant)
    wall = time.perf_counter()
    try:
        motion, q0 = scenario_motion(scenario, realisation)
    except SOLVER_FAILURES as error:
        return Run(realisation, variant, scenario.motion, None, time.perf_counter() - wall, str(error), None)
    start_modes = modal_analysis(linearise(motion, 0.0, q0))
    stepper = MotionStepper(motion, 0.0, q0, np.zeros_like(q0), step)
    parts, error = [stack_samples([stepper.sample])], None
    while error is None and stepper.state.t < duration - 1e-9 * step:
        before = stepper.snapshot()
        try:  # compiled runs of RUN_CHUNK seconds
            parts.append(stepper.advance_until(min(stepper.state.t + RUN_CHUNK, duration)))
        except SOLVER_FAILURES:  # again step by step from the run's start, to keep every step before the failure
            stepper.rewind(before)
            try:
                while stepper.state.t < duration - 1e-9 * step:
                    parts.append(stack_samples([stepper.advance()]))
            except SOLVER_FAILURES as failure:
                error = f"stopped at t = {stepper.state.t:.6g} s: {failure}"
    model = scenario.model
    arrays = {name: np.concatenate([part[name] for part in parts]) for name in parts[0]}
    trajectory = Trajectory.from_arrays(model.variant, model.joint_names, model.drive_joint, arrays)
    return Run(realisation, variant, motion, trajectory, time.perf_counter() - wall, error, start_modes)


def moving_mean(t: np.ndarray, x: np.ndarray, window: float = MEAN_WINDOW) -> np.ndarray:
    """Centred moving mean of x over ``window`` seconds."""
    return uniform_filter1d(x, max(1, round(window / float(np.median(np.diff(t))))), axis=0)


def differences(reference: Trajectory, other: Trajectory) -> dict[str, np.ndarray]:
    """``other`` minus ``reference`` psi2, psi(3,0), psi4 on ``other``'s times (common span)."""
    keep = other.t <= min(reference.t[-1], other.t[-1]) + 1e-12
    out = {"t": other.t[keep]}
    for name in DIFFERENCE_COORDINATES:
        out[name] = other.coordinate(name)[keep] - np.interp(other.t[keep], reference.t, reference.coordinate(name))
    return out


def _difference_summary(d: dict[str, np.ndarray]) -> dict:
    return {"span_s": float(d["t"][-1]),
            **{name: {"max_abs_rad": float(np.max(np.abs(d[name]))),
                      "max_abs_mean_rad": float(np.max(np.abs(moving_mean(d["t"], d[name])))),
                      "final_rad": float(d[name][-1])} for name in DIFFERENCE_COORDINATES}}


def _run_summary(r: Run) -> dict:
    summary = {"realisation": r.realisation, "variant": r.variant, "completed": r.error is None, "error": r.error,
               "wall_time_s": r.wall}
    if r.start_modes is not None:
        modes = r.start_modes
        unstable = np.flatnonzero(modes.growth_rates > 1.0)
        summary["unstable_modes_at_start"] = [
            {"mode": int(k + 1), "growth_rate_per_s": float(modes.growth_rates[k]),
             "frequency_hz": float(modes.frequencies[k]), "character": modes.character(k)} for k in unstable]
    tr = r.trajectory
    if tr is not None:
        summary.update(simulated_s=float(tr.t[-1]), max_residual_m=float(tr.residual_distance.max()),
                       max_energy_balance_error_j=float(np.max(np.abs(tr.energy_balance_error))))
        dependent = list(r.motion.dependent)
        summary["max_abs_reaction_torque_nm"] = (
            {tr.joint_names[j]: float(np.max(np.abs(tr.reactions[:, i]))) for i, j in enumerate(dependent)}
            if r.realisation == "servo" else None)
    return summary


def analyze(params: CraneParameters, out: str | Path, duration: float = 10.0, step: float = ANALYSIS_STEP,
            modal_interval: float = 0.25, realisations: tuple[str, ...] = REALISATIONS,
            log: Callable[[str], None] = print) -> dict:
    """Run both variants under each realisation, write the PNGs, ``summary.json`` and ``summary.md`` to
    ``out`` and return the summary."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    runs: dict[tuple[str, str], Run] = {}
    for realisation in realisations:
        for variant in VARIANTS[::-1]:
            r = run(params, variant, realisation, duration, step)
            runs[realisation, variant] = r
            reached = r.trajectory.t[-1] if r.trajectory is not None else 0.0
            log(f"{realisation:>5} {variant:>8}: {reached:.3f} s in {r.wall:.1f} s wall"
                + (f" - {r.error}" if r.error else ""))
    summary: dict = {"duration_s": duration, "step_s": step, "method": METHOD,
                     "resolved_below_hz": CUTOFF / (2.0 * np.pi * step),
                     "runs": [_run_summary(r) for r in runs.values()], "differences": {}, "spectra": {}}
    first = runs.get((realisations[0], "flexible"))
    if first is not None and first.start_modes is not None:
        modes = first.start_modes
        summary["modes_at_start"] = {
            "realisation": first.realisation,
            "modes": [{"mode": k + 1, "frequency_hz": float(modes.frequencies[k]),
                       "growth_rate_per_s": float(modes.growth_rates[k]), "character": modes.character(k),
                       "bodies": modes.moving_bodies(k)} for k in range(min(12, modes.frequencies.size))]}
    diffs = {}
    pairs = [(f"flexible - rigid, {r} constraints", (r, "rigid"), (r, "flexible")) for r in realisations]
    pairs += [(f"servo - ideal constraints, {v}", ("ideal", v), ("servo", v)) for v in VARIANTS[::-1]
              if {"ideal", "servo"} <= set(realisations)]
    for label, reference, other in pairs:
        if not (runs[reference].error or runs[other].error):
            diffs[label] = differences(runs[reference].trajectory, runs[other].trajectory)
            summary["differences"][label] = _difference_summary(diffs[label])
    spectra = {}
    for realisation in realisations:
        r = runs[realisation, "flexible"]
        tr = r.trajectory
        if r.error or tr.t[-1] < 1.0:
            continue
        signals = deflection_signals(r.motion.dynamics.model, r.motion.dynamics.chain, tr)
        bands = modal_bands(r.motion, tr, modal_interval, step)
        result = {"signals": signals, "bands": bands, "spectra": {}, "peaks": {}}
        entry = {"max_abs": {name: float(np.max(np.abs(x))) for name, x in signals.items()},
                 "max_abs_rfe_angle_rad": float(np.max(np.abs(tr.q[:, rfe_indices(r.motion.dynamics.model)]))),
                 "peaks": []}
        for name, x in signals.items():
            spec = spectrum(tr.t, x)
            result["spectra"][name] = spec
            result["peaks"][name] = spectral_peaks(spec)
            entry["resolution_hz"] = spec.resolution
            entry["peaks"] += [{"signal": name, **match_peak(f, bands, spec.resolution)} for f in result["peaks"][name]]
        entry["all_peaks_explained"] = all(p["explained_by"] != "none" for p in entry["peaks"])
        spectra[realisation] = result
        summary["spectra"][realisation] = entry
    _plot_deflection(runs, spectra, out / "deflection.png")
    _plot_spectra(spectra, out / "spectra.png")
    _plot_differences(diffs, out / "differences.png")
    _plot_efforts(runs, out / "efforts.png")
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    (out / "summary.md").write_text(summary_markdown(summary))
    return summary


def summary_markdown(summary: dict) -> str:
    """The short markdown report of :func:`analyze`'s summary."""
    lines = [f"# Vibration report ({summary['duration_s']:g} s, h = {summary['step_s']:g} s)", "",
             f"Integrator: {summary['method']}; modes above {summary['resolved_below_hz']:.0f} Hz are not resolved "
             "at this step (damped by the integrator).", "", "## Runs", "",
             "| realisation | model | simulated [s] | max residual [m] | max energy-balance error [J] | wall [s] "
             "| note |", "|---|---|---|---|---|---|---|"]
    nan = float("nan")
    for r in summary["runs"]:
        note = r["error"] or ""
        if r.get("unstable_modes_at_start"):
            worst = max(r["unstable_modes_at_start"], key=lambda m: m["growth_rate_per_s"])
            note += (f" {len(r['unstable_modes_at_start'])} unstable mode(s) of the linearisation at t = 0, "
                     f"fastest growth {worst['growth_rate_per_s']:.3g} 1/s ({worst['character']})")
        lines.append(f"| {r['realisation']} | {r['variant']} | {r.get('simulated_s', 0.0):.3f} | "
                     f"{r.get('max_residual_m', nan):.2e} | {r.get('max_energy_balance_error_j', nan):.2e} | "
                     f"{r['wall_time_s']:.1f} | {note.strip()} |")
    lines += ["", "## Joint differences (max |difference| [rad]; in brackets: of the 0.1 s moving mean)", "",
              "| difference | span [s] | psi2 | psi(3,0) | psi4 |", "|---|---|---|---|---|"]
    for label, d in summary["differences"].items():
        cells = " | ".join(f"{d[n]['max_abs_rad']:.3e} ({d[n]['max_abs_mean_rad']:.3e})"
                           for n in DIFFERENCE_COORDINATES)
        lines.append(f"| {label} | {d['span_s']:.3f} | {cells} |")
    if "modes_at_start" in summary:
        lines += ["", f"## Constrained modes at t = 0 ({summary['modes_at_start']['realisation']} constraints, "
                  "flexible)", "", "| # | f [Hz] | growth [1/s] | springs | bodies |", "|---|---|---|---|---|"]
        lines += [f"| {m['mode']} | {m['frequency_hz']:.3f} | {m['growth_rate_per_s']:.3g} | {m['character']} | "
                  f"{m['bodies']} |" for m in summary["modes_at_start"]["modes"]]
    for realisation, entry in summary["spectra"].items():
        lines += ["", f"## Dominant spectral peaks, {realisation} constraints (flexible boom; bin "
                  f"{entry['resolution_hz']:.3f} Hz, tolerance bin + 1 %)", "",
                  "| signal | peak [Hz] | explained by | modal band [Hz] | distance [Hz] | character |",
                  "|---|---|---|---|---|---|"]
        for p in entry["peaks"]:
            by = {"mode": f"mode {p['mode']}", "none": "NOTHING"}.get(p["explained_by"], p.get("combination"))
            band = p["band_hz"]
            lines.append(f"| {p['signal']} | {p['peak_hz']:.2f} | {by} | {band[0]:.2f} - {band[1]:.2f} | "
                         f"{p['distance_hz']:.2f} | {p['character']} |")
        largest = entry["max_abs"]
        lines.append(f"\nMax |w_y| = {largest['tip_vertical']:.3e} m, max |w_z| = {largest['tip_horizontal']:.3e} m, "
                     f"max |tip torsion| = {largest['tip_torsion']:.3e} rad, max |RFE angle| = "
                     f"{entry['max_abs_rfe_angle_rad']:.3e} rad.")
    return "\n".join(lines) + "\n"


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _plot_deflection(runs: dict, spectra: dict, path: Path) -> None:
    """Tip deflections and RFE angles over time, one column per realisation with an analysed flexible run."""
    plt = _pyplot()
    columns = list(spectra)
    fig, axes = plt.subplots(5, max(len(columns), 1), figsize=(7 * max(len(columns), 1), 13), squeeze=False,
                             constrained_layout=True, sharex="col")
    for c, realisation in enumerate(columns):
        r = runs[realisation, "flexible"]
        tr, model = r.trajectory, r.motion.dynamics.model
        signals = spectra[realisation]["signals"]
        for ax, name, label in zip(axes[:2, c], ("tip_vertical", "tip_horizontal"),
                                   ("$w_y$ (luffing plane)", "$w_z$ (horizontal)"), strict=True):
            ax.plot(tr.t, 1e3 * signals[name], lw=0.5, color="tab:blue")
            ax.set_ylabel(f"boom-tip deflection {label} [mm]", fontsize="small")
        axes[0, c].set_title(f"{realisation} constraints, flexible boom")
        for ax, suffix, label in zip(axes[2:, c], ("_bend_vertical", "_bend_lateral", "_twist"),
                                     (r"bending $\psi$ (luffing plane)", r"bending $\theta$ (horizontal)",
                                      r"torsion $\varphi$"), strict=True):
            for k in rfe_indices(model, suffix):
                ax.plot(tr.t, tr.q[:, k], lw=0.5, label=model.joint_names[k].split("_")[1])
            ax.set_ylabel(f"RFE {label} [rad]")
            ax.legend(fontsize="x-small", ncol=5)
        axes[-1, c].set_xlabel("t [s]")
        for ax in axes[:, c]:
            ax.grid(True, alpha=0.3)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_spectra(spectra: dict, path: Path) -> None:
    """PSDs of the deflection signals with the bands of the resolved modes (shaded: min-max over the run)
    and the peaks."""
    plt = _pyplot()
    columns = list(spectra)
    fig, axes = plt.subplots(len(SIGNALS), max(len(columns), 1), figsize=(8 * max(len(columns), 1), 10),
                             squeeze=False, constrained_layout=True)
    for c, realisation in enumerate(columns):
        result = spectra[realisation]
        bands = result["bands"]
        for ax, (name, label) in zip(axes[:, c], SIGNALS.items(), strict=True):
            spec = result["spectra"][name]
            ax.semilogy(spec.frequency, spec.psd, lw=0.8, color="k")
            top = min(spec.frequency[-1], 1.2 * max(float(np.max(result["peaks"][name], initial=0.0)), 250.0))
            for k in bands.resolved():
                low, high = bands.band(k)
                if high >= MIN_FREQUENCY and low <= top:
                    ax.axvspan(low, max(high, low + spec.resolution), color="tab:orange", alpha=0.3, lw=0)
            for f in result["peaks"][name]:
                ax.axvline(f, color="tab:red", lw=0.6, ls=":")
            ax.set_xlim(0.0, top)
            ax.set_ylabel(f"PSD of {label.split(' [')[0]} [{label.split('[')[-1].rstrip(']')}$^2$/Hz]",
                          fontsize="small")
            ax.set_title(f"{realisation} constraints: {label.split(' [')[0]} (orange: modal bands over the run, "
                         "red: peaks)", fontsize="small")
            ax.grid(True, alpha=0.3)
        axes[-1, c].set_xlabel("f [Hz]")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _label_time_axes(ax, title: str, ylabel: str, **title_style: str) -> None:
    """Title, time axis, y label, grid and legend of one time-course panel."""
    ax.set_title(title, **title_style)
    ax.set_xlabel("t [s]")
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small")


def _plot_differences(diffs: dict, path: Path) -> None:
    """Differences of psi2, psi(3,0), psi4 over time (raw grey, 0.1 s moving mean black), one row per pair
    (flexible - rigid per realisation, servo - ideal per model)."""
    plt = _pyplot()
    rows = max(len(diffs), 1)
    fig, axes = plt.subplots(rows, len(DIFFERENCE_COORDINATES), figsize=(15, 3.8 * rows), squeeze=False,
                             constrained_layout=True)
    labels = (r"$\psi^{(2)}$", r"$\psi^{(3,0)}$", r"$\psi^{(4)}$")
    for r, (pair, d) in enumerate(diffs.items()):
        for ax, name, label in zip(axes[r], DIFFERENCE_COORDINATES, labels, strict=True):
            ax.plot(d["t"], d[name], color="0.7", lw=0.5, label="raw")
            ax.plot(d["t"], moving_mean(d["t"], d[name]), color="k", lw=1.2, label=f"{MEAN_WINDOW:g} s mean")
            _label_time_axes(ax, f"{label}: {pair}", "[rad]", fontsize="medium")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_efforts(runs: dict, path: Path) -> None:
    """Generalized force of the constraint realisation on the luff and knuckle coordinates over the
    completed runs: the servo torques tau, and for ideal constraints the rows of A^T lambda (the moments
    of the ideal force at E about those joints)."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(14, 4.5), constrained_layout=True)
    completed = sorted(((v == "rigid", r, v), run_) for (r, v), run_ in runs.items() if not run_.error)
    for (rigid, realisation, variant), r in completed:  # flexible first, rigid dashed on top
        tr = r.trajectory
        for ax, name in zip(axes, ("boom_luff", "knuckle"), strict=True):
            k = tr.joint_names.index(name)
            ax.plot(tr.t, tr.constraint_forces[:, k], lw=0.6 if not rigid else 1.2, ls="--" if rigid else "-",
                    label=f"{realisation}, {variant}")
    for ax, name in zip(axes, ("luff joint psi(3,0)", "knuckle psi4"), strict=True):
        _label_time_axes(ax, f"constraint realisation's generalized force on the {name}", "[N m]")
    fig.savefig(path, dpi=110)
    plt.close(fig)

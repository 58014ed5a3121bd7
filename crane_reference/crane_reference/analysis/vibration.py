"""Vibration of the flexible links during the programmed motion: their signals, spectra and runs.

Signals of a run (:class:`~crane_reference.motion.trajectory.Trajectory`), per flexible link (the paper's
boom):

* the RFE angles psi, theta, phi of every spring-damping element of the link;
* the tip deflection w relative to the rigid chord
  (:func:`~crane_reference.dynamics.deflection.tip_deflection`): w_y in the beam's x-y plane (a boom's
  luffing plane), w_z across it;
* the tip torsion, the sum of the RFE twist angles (the twist of the tip element to first order).

Spectra: Welch's method (scipy.signal.welch: Hann windows of 2^k samples, at least four per run, 50 %
overlap, linear detrend per window), one-sided PSD, resolution df = fs / nperseg.

Agreement with the modal analysis (:mod:`crane_reference.analysis.modal`): the constrained modes are computed at
states of the run every ``modal_interval`` s (linearised with the state's velocities).  The crane's
configuration changes as E goes round the ellipse, so mode k sweeps a band [min_t f_k, max_t f_k].  The
integrator (:mod:`crane_reference.motion.integration`) reproduces a mode at its own frequency below
:func:`~crane_reference.motion.integration.resolved_below` and damps the modes above, so only the resolved modes
explain peaks.  A spectral peak agrees with mode k if it lies in k's band widened by the tolerance

    delta = df + 0.01 f,

one bin of the spectrum plus 1 % for the frozen-time linearisation.  A peak no mode explains may be a
second-order combination f_i + f_j or |f_i - f_j| (e.g. 2 f_i: the vertical tip deflection has a
component quadratic in the horizontal one); it is reported as such.  Peaks below ``MIN_FREQUENCY`` are
the quasi-static response to the slewing (in the paper's scenario the drive torque acts for 1 s and E
takes about 10 s round the ellipse), not vibration, and are left out.

Realisations: the paper's ideal constraints (a force at E) and servo-constraints (luff and knuckle
torques, :class:`~crane_reference.motion.programmed_motion.ProgrammedMotion` with ``realisation="servo"``).
Each realisation starts from its own static equilibrium: with ideal constraints the height constraint's
force at E carries the payload and link 4, and the boom tip stays near its chord; with servo-constraints
they hang on the boom, which sags.  On the flexible boom the servo torques act at the luff, away from E,
and the internal dynamics they leave can be unstable (luffing-plane bending, see
:mod:`crane_reference.analysis.modal`): such a run stops within a few steps, and the report
(:mod:`.vibration_report`) says so and lists the unstable modes.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy import signal
from scipy.ndimage import uniform_filter1d

from ..dynamics.deflection import rfe_indices, tip_deflection
from ..dynamics.structures import ChainData
from ..model.chain import ChainModel
from ..model.description import CraneDescription
from ..motion.integration import resolved_below
from ..motion.programmed_motion import ProgrammedMotion
from ..motion.simulation import SOLVER_FAILURES, MotionStepper, Scenario
from ..motion.trajectory import MotionRows, Trajectory
from .modal import Modes, linearise, modal_analysis, scenario_motion

MIN_FREQUENCY = 2.0  # [Hz] peaks below are the quasi-static response to the slewing
RELATIVE_TOLERANCE = 0.01  # of the peak frequency, besides one spectral bin
SIGNALS = {"tip_vertical": "tip deflection $w_y$ (luffing plane) [m]",
           "tip_horizontal": "tip deflection $w_z$ (horizontal) [m]",
           "tip_torsion": r"tip torsion $\sum \varphi$ [rad]"}
"""The signals of each flexible link, named ``<link>_<key>``, with their labels."""
MEAN_WINDOW = 0.1  # [s] moving mean that separates drift from ringing in the differences
RUN_CHUNK = 0.25  # [s] of motion per compiled run


def signal_labels(model: ChainModel) -> dict[str, str]:
    """The signals of the flexible links of ``model`` (:data:`SIGNALS` per link), with their labels."""
    return {f"{link.name}_{key}": f"{link.name} {label}" for link in model.flexible_links
            for key, label in SIGNALS.items()}


def deflection_signals(model: ChainModel, chain: ChainData, trajectory: Trajectory) -> dict[str, np.ndarray]:
    """The signals of :func:`signal_labels` over a run."""
    out = {}
    for link in model.flexible_links:
        w = tip_deflection(model, chain, trajectory.q, link.name)
        up = link.vertical
        out.update({f"{link.name}_tip_vertical": w[:, up], f"{link.name}_tip_horizontal": w[:, 3 - up],
                    f"{link.name}_tip_torsion": trajectory.q[:, rfe_indices(model, "_twist", link.name)].sum(axis=1)})
    return out


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
    frequency and damps the modes above it (:func:`crane_reference.motion.integration.resolved_below`)."""

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
    return ModalBands(np.array(times), np.array(frequencies), resolved_below(step), characters)


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


def run(params: CraneDescription, variant: str, realisation: str, duration: float, step: float) -> Run:
    """Simulate one variant and realisation from its equilibrium; a failure keeps the samples so far."""
    scenario = Scenario(params, variant)
    wall = time.perf_counter()
    try:
        motion, q0 = scenario_motion(scenario, realisation)
    except SOLVER_FAILURES as error:
        return Run(realisation, variant, scenario.motion, None, time.perf_counter() - wall, str(error), None)
    start_modes = modal_analysis(linearise(motion, 0.0, q0))
    stepper = MotionStepper(motion, 0.0, q0, np.zeros_like(q0), step)
    parts, error = [MotionRows.stacked([stepper.sample])], None
    while error is None and stepper.state.t < duration - 1e-9 * step:
        before = stepper.snapshot()
        try:  # compiled runs of RUN_CHUNK seconds
            parts.append(stepper.advance_until(min(stepper.state.t + RUN_CHUNK, duration)))
        except SOLVER_FAILURES:  # again step by step from the run's start, to keep every step before the failure
            stepper.rewind(before)
            try:
                while stepper.state.t < duration - 1e-9 * step:
                    parts.append(MotionRows.stacked([stepper.advance()]))
            except SOLVER_FAILURES as failure:
                error = f"stopped at t = {stepper.state.t:.6g} s: {failure}"
    model = scenario.model
    trajectory = Trajectory.from_rows(model.variant, model.joint_names, model.drive_joint, MotionRows.joined(parts))
    return Run(realisation, variant, motion, trajectory, time.perf_counter() - wall, error, start_modes)


def moving_mean(t: np.ndarray, x: np.ndarray, window: float = MEAN_WINDOW) -> np.ndarray:
    """Centred moving mean of x over ``window`` seconds."""
    return uniform_filter1d(x, max(1, round(window / float(np.median(np.diff(t))))), axis=0)


def differences(reference: Trajectory, other: Trajectory, joints: tuple[str, ...]) -> dict[str, np.ndarray]:
    """``other`` minus ``reference`` at ``joints`` (the actuated joints; the paper's psi2, psi(3,0), psi4) on
    ``other``'s times (common span)."""
    keep = other.t <= min(reference.t[-1], other.t[-1]) + 1e-12
    out = {"t": other.t[keep]}
    for name in joints:
        out[name] = other.coordinate(name)[keep] - np.interp(other.t[keep], reference.t, reference.coordinate(name))
    return out

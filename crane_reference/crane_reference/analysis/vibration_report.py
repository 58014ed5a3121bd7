"""The vibration report of ``crane-reference analyze``: both crane variants under each constraint realisation,
their differences, spectra against the constrained modes, written as PNGs, ``summary.json`` and ``summary.md``
(the signals, spectra and runs are :mod:`.vibration`'s)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..dynamics.deflection import rfe_indices
from ..model.chain import VARIANTS
from ..model.description import CraneDescription
from ..motion.integration import METHOD, resolved_below
from ..motion.programmed_motion import REALISATIONS
from ..motion.steps import ANALYSIS_STEP
from .figures import pyplot
from .vibration import (
    MEAN_WINDOW,
    MIN_FREQUENCY,
    Run,
    deflection_signals,
    differences,
    match_peak,
    modal_bands,
    moving_mean,
    run,
    signal_labels,
    spectral_peaks,
    spectrum,
)


def _difference_summary(d: dict[str, np.ndarray]) -> dict:
    return {"span_s": float(d["t"][-1]),
            **{name: {"max_abs_rad": float(np.max(np.abs(d[name]))),
                      "max_abs_mean_rad": float(np.max(np.abs(moving_mean(d["t"], d[name])))),
                      "final_rad": float(d[name][-1])} for name in d if name != "t"}}


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


def analyze(params: CraneDescription, out: str | Path, duration: float = 10.0, step: float = ANALYSIS_STEP,
            modal_interval: float = 0.25, realisations: tuple[str, ...] = REALISATIONS,
            log: Callable[[str], None] = print) -> dict:
    """Run both variants under each realisation, write the PNGs, ``summary.json`` and ``summary.md`` to
    ``out`` and return the summary (the joint differences at the actuated joints, the deflections of every
    flexible link)."""
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
    summary: dict = {"crane": params.name, "duration_s": duration, "step_s": step, "method": METHOD,
                     "joints": list(params.actuated), "flexible_links": [link.name for link in params.flexible_links],
                     "resolved_below_hz": resolved_below(step),
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
              if set(REALISATIONS) <= set(realisations)]
    for label, reference, other in pairs:
        if not (runs[reference].error or runs[other].error):
            diffs[label] = differences(runs[reference].trajectory, runs[other].trajectory, params.actuated)
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
    model = runs[realisations[0], "flexible"].motion.dynamics.model
    _plot_spectra(spectra, signal_labels(model), out / "spectra.png")
    _plot_differences(diffs, out / "differences.png")
    _plot_efforts(runs, model, out / "efforts.png")
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
    joints = summary["joints"]
    lines += ["", "## Joint differences (max |difference| [rad or m]; in brackets: of the 0.1 s moving mean)", "",
              f"| difference | span [s] | {' | '.join(joints)} |", "|---|---|" + "---|" * len(joints)]
    for label, d in summary["differences"].items():
        cells = " | ".join(f"{d[n]['max_abs_rad']:.3e} ({d[n]['max_abs_mean_rad']:.3e})"
                           for n in joints)
        lines.append(f"| {label} | {d['span_s']:.3f} | {cells} |")
    if "modes_at_start" in summary:
        lines += ["", f"## Constrained modes at t = 0 ({summary['modes_at_start']['realisation']} constraints, "
                  "flexible)", "", "| # | f [Hz] | growth [1/s] | springs | bodies |", "|---|---|---|---|---|"]
        lines += [f"| {m['mode']} | {m['frequency_hz']:.3f} | {m['growth_rate_per_s']:.3g} | {m['character']} | "
                  f"{m['bodies']} |" for m in summary["modes_at_start"]["modes"]]
    for realisation, entry in summary["spectra"].items():
        lines += ["", f"## Dominant spectral peaks, {realisation} constraints (flexible model; bin "
                  f"{entry['resolution_hz']:.3f} Hz, tolerance bin + 1 %)", "",
                  "| signal | peak [Hz] | explained by | modal band [Hz] | distance [Hz] | character |",
                  "|---|---|---|---|---|---|"]
        for p in entry["peaks"]:
            by = {"mode": f"mode {p['mode']}", "none": "NOTHING"}.get(p["explained_by"], p.get("combination"))
            band = p["band_hz"]
            lines.append(f"| {p['signal']} | {p['peak_hz']:.2f} | {by} | {band[0]:.2f} - {band[1]:.2f} | "
                         f"{p['distance_hz']:.2f} | {p['character']} |")
        largest = entry["max_abs"]
        lines.append("")
        for link in summary["flexible_links"]:
            lines.append(f"{link}: max |w_y| = {largest[f'{link}_tip_vertical']:.3e} m, max |w_z| = "
                         f"{largest[f'{link}_tip_horizontal']:.3e} m, max |tip torsion| = "
                         f"{largest[f'{link}_tip_torsion']:.3e} rad.")
        lines.append(f"Max |RFE angle| = {entry['max_abs_rfe_angle_rad']:.3e} rad.")
    return "\n".join(lines) + "\n"


def _plot_deflection(runs: dict, spectra: dict, path: Path) -> None:
    """Tip deflections and RFE angles over time, one column per realisation with an analysed flexible run."""
    plt = pyplot
    columns = list(spectra)
    fig, axes = plt.subplots(5, max(len(columns), 1), figsize=(7 * max(len(columns), 1), 13), squeeze=False,
                             constrained_layout=True, sharex="col")
    for c, realisation in enumerate(columns):
        r = runs[realisation, "flexible"]
        tr, model = r.trajectory, r.motion.dynamics.model
        signals = spectra[realisation]["signals"]
        for ax, key, label in zip(axes[:2, c], ("tip_vertical", "tip_horizontal"),
                                  ("$w_y$ (luffing plane)", "$w_z$ (horizontal)"), strict=True):
            for link in model.flexible_links:
                ax.plot(tr.t, 1e3 * signals[f"{link.name}_{key}"], lw=0.5, label=link.name)
            ax.set_ylabel(f"tip deflection {label} [mm]", fontsize="small")
            ax.legend(fontsize="x-small")
        axes[0, c].set_title(f"{realisation} constraints, flexible model")
        for ax, suffix, label in zip(axes[2:, c], ("_bend_vertical", "_bend_lateral", "_twist"),
                                     (r"bending $\psi$ (luffing plane)", r"bending $\theta$ (horizontal)",
                                      r"torsion $\varphi$"), strict=True):
            for k in rfe_indices(model, suffix):
                ax.plot(tr.t, tr.q[:, k], lw=0.5, label=model.joint_names[k].removesuffix(suffix))
            ax.set_ylabel(f"RFE {label} [rad]")
            ax.legend(fontsize="x-small", ncol=5)
        axes[-1, c].set_xlabel("t [s]")
        for ax in axes[:, c]:
            ax.grid(True, alpha=0.3)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_spectra(spectra: dict, labels: dict[str, str], path: Path) -> None:
    """PSDs of the deflection signals (``labels``: name -> label) with the bands of the resolved modes (shaded:
    min-max over the run) and the peaks."""
    plt = pyplot
    columns = list(spectra)
    fig, axes = plt.subplots(len(labels), max(len(columns), 1), figsize=(8 * max(len(columns), 1), 3.4 * len(labels)),
                             squeeze=False, constrained_layout=True)
    for c, realisation in enumerate(columns):
        result = spectra[realisation]
        bands = result["bands"]
        for ax, (name, label) in zip(axes[:, c], labels.items(), strict=True):
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
    """Differences at the actuated joints (the paper's psi2, psi(3,0), psi4) over time (raw grey, 0.1 s moving
    mean black), one row per pair (flexible - rigid per realisation, servo - ideal per model)."""
    plt = pyplot
    rows = max(len(diffs), 1)
    joints = [name for name in next(iter(diffs.values()), {"t": None}) if name != "t"]
    fig, axes = plt.subplots(rows, max(len(joints), 1), figsize=(5 * max(len(joints), 1), 3.8 * rows), squeeze=False,
                             constrained_layout=True)
    for r, (pair, d) in enumerate(diffs.items()):
        for ax, name in zip(axes[r], joints, strict=True):
            ax.plot(d["t"], d[name], color="0.7", lw=0.5, label="raw")
            ax.plot(d["t"], moving_mean(d["t"], d[name]), color="k", lw=1.2, label=f"{MEAN_WINDOW:g} s mean")
            _label_time_axes(ax, f"{name}: {pair}", "[rad or m]", fontsize="medium")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_efforts(runs: dict, model, path: Path) -> None:
    """Generalized force of the constraint realisation on the dependent coordinates (the paper's luff and
    knuckle) over the completed runs: the servo torques tau, and for ideal constraints the rows of A^T lambda
    (the moments of the ideal force at E about those joints)."""
    plt = pyplot
    dependent = [model.joint_names[k] for k in model.dependent_joints]
    fig, axes = plt.subplots(1, len(dependent), figsize=(7 * len(dependent), 4.5), squeeze=False,
                             constrained_layout=True)
    completed = sorted(((v == "rigid", r, v), run_) for (r, v), run_ in runs.items() if not run_.error)
    for (rigid, realisation, variant), r in completed:  # flexible first, rigid dashed on top
        tr = r.trajectory
        for ax, name in zip(axes[0], dependent, strict=True):
            k = tr.joint_names.index(name)
            ax.plot(tr.t, tr.constraint_forces[:, k], lw=0.6 if not rigid else 1.2, ls="--" if rigid else "-",
                    label=f"{realisation}, {variant}")
    for ax, name in zip(axes[0], dependent, strict=True):
        _label_time_axes(ax, f"constraint realisation's generalized force on {name}", "[N m or N]")
    fig.savefig(path, dpi=110)
    plt.close(fig)

"""Files of closed-loop runs: time series (CSV, NPZ), a summary (JSON, Markdown) and a figure."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..figures import pyplot as plt
from .closed_loop import TrackingRun


def label(run: TrackingRun) -> str:
    """A run's name in files and legends: its controller and feedforward."""
    return f"{run.spec.controller}_ff-{run.spec.feedforward}"


def series(run: TrackingRun) -> dict[str, np.ndarray]:
    """The time series of a run by column name (SI units in the names)."""
    columns = {"t_s": run.t}
    errors, powers = run.joint_errors(), run.powers()
    reference = run.reference
    for k, name in enumerate(run.joints):
        j = run.plant.joint_names.index(name)
        columns[f"{name}_rad"] = run.plant.q[:, j]
        columns[f"{name}_reference_rad"] = reference.q[:, j]
        columns[f"{name}_error_rad"] = errors[:, k]
        columns[f"{name}_torque_nm"] = run.torques[:, k]
        columns[f"{name}_power_w"] = powers[:, k]
    for axis, name in enumerate("xyz"):
        columns[f"ee_{name}_m"] = run.plant.ee_position[:, axis]
        columns[f"ee_{name}_reference_m"] = reference.ee_position[:, axis]
    columns["ellipse_distance_m"], columns["height_error_m"] = run.path_error.T
    for axis, name in enumerate(("x", "y", "z")):
        columns[f"tip_deflection_{name}_m"] = run.tip_deflection[:, axis]
    return columns


def summary_markdown(runs: list[TrackingRun]) -> str:
    """The runs' metrics side by side, with the gains used."""
    names = [label(run) for run in runs]
    summaries = [run.summary() for run in runs]
    lines = [f"# Closed-loop tracking of the reference ({runs[0].spec.variant} crane, "
             f"{runs[0].spec.realisation} reference, {runs[0].spec.rate:g} Hz controller, "
             f"{runs[0].spec.duration:g} s, step {runs[0].spec.step:g} s)", "",
             "| metric | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for metric in summaries[0]:
        lines.append(f"| {metric} | " + " | ".join(f"{s[metric]:.4g}" for s in summaries) + " |")
    lines += ["", "Gains (kp [N m/rad], kd [N m s/rad, in the joint drive], ki [N m/(rad s)], limit [N m]):", ""]
    for name, run in zip(names, runs, strict=True):
        gains = ", ".join(f"{joint} {g.kp:.4g} / {g.kd:.4g} / {g.ki:.4g} / {g.limit:.4g}"
                          for joint, g in zip(run.joints, run.gains, strict=True))
        lines.append(f"- {name}: {gains}")
    return "\n".join(lines) + "\n"


def plot(runs: list[TrackingRun], path: Path) -> None:
    """E's distance to the ellipse and height error, the joint errors, the tip deflection and the torques
    over time, one line style per run."""
    fig, axes = plt.subplots(5, 1, figsize=(11, 15), sharex=True, constrained_layout=True)
    styles = ["-", "--", ":", "-."]
    for run, style in zip(runs, styles * len(runs), strict=False):
        name = label(run)
        t = run.t
        axes[0].plot(t, 1e3 * run.path_error[:, 0], style, color="C0", label=f"{name}: ellipse (XY)")
        axes[0].plot(t, 1e3 * run.path_error[:, 1], style, color="C1", label=f"{name}: height")
        for k, joint in enumerate(run.joints):
            axes[1].plot(t, 1e3 * run.joint_errors()[:, k], style, color=f"C{k}", label=f"{name}: {joint}")
            axes[4].plot(t, 1e-3 * run.torques[:, k], style, color=f"C{k}", label=f"{name}: {joint}")
        axes[2].plot(t, 1e3 * run.tip_deflection[:, 1], style, color="C0", label=f"{name}: luffing plane")
        axes[2].plot(t, 1e3 * run.tip_deflection[:, 2], style, color="C1", label=f"{name}: horizontal")
        axes[3].plot(t, 1e3 * np.linalg.norm(run.tip_deflection, axis=1), style, color="C2", label=name)
    titles = ["E's deviation from the programmed path [mm]", "joint errors q_ref - q [mrad]",
              "tip deflection of the first flexible link [mm]", "|tip deflection| [mm]", "actuator torques [kN m]"]
    for ax, title in zip(axes, titles, strict=True):
        ax.set_title(title)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, ncol=3)
    axes[-1].set_xlabel("t [s]")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_report(runs: list[TrackingRun], out: str | Path) -> list[Path]:
    """tracking_<label>.csv / .npz per run, summary.json, summary.md and tracking.png in ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    for run in runs:
        columns = series(run)
        csv = out / f"tracking_{label(run)}.csv"
        np.savetxt(csv, np.column_stack(list(columns.values())), delimiter=",", header=",".join(columns),
                   comments="")
        npz = out / f"tracking_{label(run)}.npz"
        np.savez(npz, **columns)
        files += [csv, npz]
    (out / "summary.json").write_text(json.dumps({label(run): run.summary() for run in runs}, indent=2))
    (out / "summary.md").write_text(summary_markdown(runs))
    plot(runs, out / "tracking.png")
    return [*files, out / "summary.json", out / "summary.md", out / "tracking.png"]

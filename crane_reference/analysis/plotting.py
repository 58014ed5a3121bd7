"""Figure 2 of the paper: joint coordinates of the rigid and flexible models and E's path."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from scipy.ndimage import maximum_filter1d, uniform_filter1d

from ..motion.trajectory import Trajectory

MEAN_WINDOW = 0.1  # s: smooths the undamped RFE ringing out of the difference curves
COORDINATES = (("column_slew", r"$\psi^{(2)}$ [rad]"), ("boom_luff", r"$\psi^{(3,0)}$ [rad]"),
               ("knuckle", r"$\psi^{(4)}$ [rad]"))


def figure2(trajectories: list[Trajectory], ellipse: tuple[float, float], path: str | Path) -> None:
    """Time courses of psi2, psi(3,0), psi4 for each model, E's XY path with the target ellipse and
    z_E(t), and the constraint residual; with both models, the flexible-minus-rigid differences on a
    second axis (raw in grey, their moving mean in black: the undamped boom rings at 80-200 Hz)."""
    fig, axes = plt.subplots(2, 3, figsize=(15, 8.5), constrained_layout=True)
    styles = {"rigid": dict(color="tab:blue", ls="--"), "flexible": dict(color="tab:red", ls="-")}
    by_variant = {tr.variant: tr for tr in trajectories}
    for ax, (name, label) in zip(axes[0], COORDINATES, strict=True):
        for tr in trajectories:
            ax.plot(tr.t, tr.coordinate(name), label=tr.variant, lw=1.2, **styles[tr.variant])
        ax.set_xlabel("t [s]")
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
        if {"rigid", "flexible"} <= by_variant.keys():
            rigid, flexible = by_variant["rigid"], by_variant["flexible"]
            difference = flexible.coordinate(name) - np.interp(flexible.t, rigid.t, rigid.coordinate(name))
            window = max(1, round(float(MEAN_WINDOW / np.median(np.diff(flexible.t)))))
            twin = ax.twinx()
            twin.plot(flexible.t, difference, color="0.75", lw=0.5)
            twin.plot(flexible.t, uniform_filter1d(difference, window), color="k", lw=1.2,
                      label=f"flexible - rigid ({MEAN_WINDOW:g} s mean)")
            twin.set_ylabel("flexible - rigid [rad]")
            twin.legend(loc="lower right", fontsize="small")
        ax.legend(loc="upper left")
    a, b = ellipse
    phi = np.linspace(0.0, 2.0 * np.pi, 400)
    ax = axes[1, 0]
    ax.plot(a * np.cos(phi), b * np.sin(phi), color="k", lw=0.8, label="target ellipse")
    for tr in trajectories:
        ax.plot(tr.ee_position[:, 0], tr.ee_position[:, 1], lw=1.0, label=f"E, {tr.variant}", **styles[tr.variant])
    ax.set_aspect("equal")
    ax.set_xlabel(r"$x_E^{(0)}$ [m]")
    ax.set_ylabel(r"$y_E^{(0)}$ [m]")
    ax.legend(loc="upper right", fontsize="small")
    ax.grid(True, alpha=0.3)
    ax = axes[1, 1]
    for tr in trajectories:
        ax.plot(tr.t, tr.ee_position[:, 2], lw=1.2, label=tr.variant, **styles[tr.variant])
    ax.set_xlabel("t [s]")
    ax.set_ylabel(r"$z_E^{(0)}$ [m]")
    ax.legend()
    ax.grid(True, alpha=0.3)
    ax = axes[1, 2]
    for tr in trajectories:
        window = max(1, round(float(MEAN_WINDOW / np.median(np.diff(tr.t)))))
        worst = maximum_filter1d(tr.residual_distance.max(axis=1), window)
        ax.semilogy(tr.t, np.maximum(worst, 1e-18), lw=1.0, label=tr.variant, **styles[tr.variant])
    ax.set_xlabel("t [s]")
    ax.set_ylabel(f"constraint residual, max over {MEAN_WINDOW:g} s [m]")
    ax.legend()
    ax.grid(True, alpha=0.3)
    fig.suptitle("Programmed motion of the crane: rigid and flexible boom (cf. Fig. 2 of the paper)")
    fig.savefig(path, dpi=120)
    plt.close(fig)

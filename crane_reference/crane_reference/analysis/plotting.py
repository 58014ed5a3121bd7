"""Figure 2 of the paper: the actuated joints' coordinates of the rigid and flexible models and E's path (for
any crane: its actuated joints, the paper's psi2, psi(3,0), psi4)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.ndimage import maximum_filter1d

from ..motion.trajectory import Trajectory
from .bands import CONTROLLER_BAND, controller_band
from .figures import pyplot as plt

MEAN_WINDOW = 0.1  # [s], window of the residual maximum
PAPER_LABELS = {"column_slew": r"$\psi^{(2)}$ [rad]", "boom_luff": r"$\psi^{(3,0)}$ [rad]",
                "knuckle": r"$\psi^{(4)}$ [rad]"}
"""The paper's symbols for its crane's joints; another joint is labelled by its name."""


def figure2(trajectories: list[Trajectory], joints: tuple[str, ...], ellipse: tuple[float, float],
            path: str | Path) -> None:
    """Time courses of ``joints`` (the actuated ones; the paper's psi2, psi(3,0), psi4) for each model; with both
    models, the flexible-minus-rigid differences in panels of their own, raw (the undamped boom rings at
    70-450 Hz) and in the controller band (below 10 Hz, zero phase); E's XY path with the target ellipse,
    z_E(t) and the constraint residual."""
    by_variant = {tr.variant: tr for tr in trajectories}
    both = {"rigid", "flexible"} <= by_variant.keys()
    rows = 4 if both else 2
    columns = max(len(joints), 3)
    fig, axes = plt.subplots(rows, columns, figsize=(5 * columns, 4.0 * rows), constrained_layout=True)
    # the two models differ by milliradians: the rigid one dashed and on top, so both stay visible
    styles = {"rigid": dict(color="tab:blue", ls=(0, (4, 3)), zorder=3), "flexible": dict(color="tab:red", ls="-")}
    for ax in axes[:-1, len(joints):].flat:
        ax.set_visible(False)
    for ax in axes[-1, 3:]:
        ax.set_visible(False)
    for column, name in enumerate(joints):
        label = PAPER_LABELS.get(name, f"{name} [rad or m]")
        ax = axes[0, column]
        for tr in trajectories:
            ax.plot(tr.t, tr.coordinate(name), label=tr.variant, lw=2.0 if tr.variant == "rigid" else 1.2,
                    **styles[tr.variant])
        ax.set_xlabel("t [s]")
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper left")
        if both:
            rigid, flexible = by_variant["rigid"], by_variant["flexible"]
            difference = flexible.coordinate(name) - np.interp(flexible.t, rigid.t, rigid.coordinate(name))
            step = float(np.median(np.diff(flexible.t)))
            for row, values, title in ((1, difference, "raw"),
                                       (2, controller_band(difference, step), f"below {CONTROLLER_BAND:g} Hz")):
                ax = axes[row, column]
                ax.plot(flexible.t, values, color="k", lw=0.6 if row == 1 else 1.2)
                ax.set_xlabel("t [s]")
                ax.set_ylabel(f"flexible - rigid {label}")
                ax.set_title(f"flexible - rigid, {title}", fontsize="medium")
                ax.grid(True, alpha=0.3)
    bottom = axes[-1]
    a, b = ellipse
    phi = np.linspace(0.0, 2.0 * np.pi, 400)
    ax = bottom[0]
    ax.plot(a * np.cos(phi), b * np.sin(phi), color="k", lw=0.8, label="target ellipse")
    for tr in trajectories:
        ax.plot(tr.ee_position[:, 0], tr.ee_position[:, 1], lw=1.0, label=f"E, {tr.variant}", **styles[tr.variant])
    ax.set_aspect("equal")
    ax.set_xlabel(r"$x_E^{(0)}$ [m]")
    ax.set_ylabel(r"$y_E^{(0)}$ [m]")
    ax.legend(loc="upper right", fontsize="small")
    ax.grid(True, alpha=0.3)
    ax = bottom[1]
    for tr in trajectories:
        ax.plot(tr.t, tr.ee_position[:, 2], lw=1.2, label=tr.variant, **styles[tr.variant])
    ax.set_xlabel("t [s]")
    ax.set_ylabel(r"$z_E^{(0)}$ [m]")
    ax.legend()
    ax.grid(True, alpha=0.3)
    ax = bottom[2]
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

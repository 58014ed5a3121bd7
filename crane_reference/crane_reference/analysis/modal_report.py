"""The report of ``crane-reference modes``: a table of the constrained modes at a time of the motion and a
drawing of their shapes (the modal analysis itself is :mod:`.modal`'s)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..dynamics.chain_dynamics import CraneDynamics
from ..dynamics.kinematics import forward_kinematics
from ..model.description import CraneDescription
from .figures import pyplot
from .modal import Modes, modes_at


def modes_table(modes: Modes, count: int) -> str:
    """Plain-text table: index, frequency, growth rate, the springs that deform (strain energy), the
    bodies that move (kinetic energy) and the dominant coordinates (:attr:`Modes.participation`)."""
    lines = [f"{'#':>3} {'f [Hz]':>9} {'growth [1/s]':>12}  {'springs (share of strain energy)':<50} "
             f"{'bodies (share of kinetic energy)':<34} dominant coordinates"]
    for k in range(min(count, modes.frequencies.size)):
        dominant = ", ".join(f"{name} {share:.0%}" for name, share in modes.dominant(k))
        lines.append(f"{k + 1:>3} {modes.frequencies[k]:>9.3f} {modes.growth_rates[k]:>12.3g}  "
                     f"{modes.character(k):<50} {modes.moving_bodies(k):<34} {dominant}")
    return "\n".join(lines)


def skeleton(dynamics: CraneDynamics, q: np.ndarray) -> np.ndarray:
    """Polyline (k, 3) through the origins of the joint frames that have an offset, from the base's
    origin to E, for stick drawings; an offset with both a vertical and a horizontal part is drawn along
    the previous frame's z axis first (column, then luff pivot).  k does not depend on q."""
    model = dynamics.model
    chain = dynamics.chain
    kinds, axes, origins = chain.kinds, chain.axes, chain.origins
    T, _ = forward_kinematics(np.ascontiguousarray(q, dtype=float), kinds, axes, origins)
    points = [T[0][:3, 3]]
    for k in range(1, model.dof):
        offset = origins[k][:3, 3]
        if offset[2] != 0.0 and np.any(offset[:2] != 0.0):
            points.append(T[k - 1][:3, :3] @ np.array([0.0, 0.0, offset[2]]) + T[k - 1][:3, 3])
        if np.any(offset != 0.0):
            points.append(T[k][:3, 3])
    e = model.end_effector_joint
    points.append(T[e][:3, :3] @ model.end_effector_point + T[e][:3, 3])
    return np.array(points)


def plot_mode_shapes(modes: Modes, dynamics: CraneDynamics, path: str | Path, count: int = 12,
                     amplitude: float = 0.25, per_row: int = 3) -> None:
    """For each of the first ``count`` modes, side by side: a 3-D stick drawing of the crane at q and at
    q + s phi (s such that the largest point displacement is ``amplitude`` m, exaggerated) and a bar chart
    of the mass-scaled mode shape over the coordinates (:meth:`Modes.mass_scaled_shape`)."""
    plt = pyplot
    count = min(count, modes.frequencies.size)
    rows = -(-count // per_row)
    q = modes.linearisation.q
    rest = skeleton(dynamics, q)
    centre, span = 0.5 * (rest.max(axis=0) + rest.min(axis=0)), float(np.ptp(rest, axis=0).max()) + 2 * amplitude
    names = modes.joint_names
    fig = plt.figure(figsize=(8.0 * per_row, 5.0 * rows), constrained_layout=True)
    grid = fig.add_gridspec(rows, 2 * per_row, width_ratios=[1.2, 1.0] * per_row)
    for k in range(count):
        row, col = divmod(k, per_row)
        phi = modes.shapes[:, k]
        unit = np.max(np.linalg.norm(skeleton(dynamics, q + 1e-6 * phi) - rest, axis=1)) / 1e-6
        moved = skeleton(dynamics, q + amplitude / max(float(unit), 1e-12) * phi)
        ax = fig.add_subplot(grid[row, 2 * col], projection="3d")
        ax.plot(*rest.T, color="0.6", lw=2, marker="o", ms=3, label="rest")
        ax.plot(*moved.T, color="tab:red", lw=2, marker="o", ms=3, label=f"mode, {amplitude:g} m max")
        for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre, strict=True):
            setter(c - 0.5 * span, c + 0.5 * span)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_zlabel("z [m]")
        growth = f", growth {modes.growth_rates[k]:.3g}/s" if modes.growth_rates[k] > 0 else ""
        ax.set_title(f"mode {k + 1}: {modes.frequencies[k]:.2f} Hz{growth}\n{modes.character(k)}\n"
                     f"{modes.moving_bodies(k)}", fontsize="small")
        ax.legend(fontsize="x-small", loc="upper left")
        bar = fig.add_subplot(grid[row, 2 * col + 1])
        bar.barh(np.arange(len(names)), modes.mass_scaled_shape(k), color="tab:red")
        bar.set_yticks(np.arange(len(names)))
        bar.set_yticklabels(names, fontsize=6)
        bar.invert_yaxis()
        bar.set_xlim(-1.05, 1.05)
        bar.set_xlabel(r"$\phi_j \sqrt{M_{jj}}$, normalised", fontsize="small")
        bar.grid(True, axis="x", alpha=0.3)
    fig.suptitle(f"Modes of the constrained {dynamics.model.variant} crane at t = {modes.linearisation.t:g} s")
    fig.savefig(path, dpi=100)
    plt.close(fig)


def modes_report(params: CraneDescription, variant: str, t: float, count: int, realisation: str,
                 out: str | Path) -> Path:
    """Print the table of the first ``count`` modes at time t and write their drawing; returns the PNG."""
    modes, motion = modes_at(params, variant, t, realisation)
    print(f"Constrained modes of the {variant} crane ({realisation} constraints) at t = {modes.linearisation.t:g} s "
          f"({len(motion.independent)} independent coordinates):")
    print(modes_table(modes, count))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"modes_{variant}_{realisation}_t{modes.linearisation.t:g}.png"
    plot_mode_shapes(modes, motion.dynamics, path, count=count)
    print(f"wrote {path}")
    return path

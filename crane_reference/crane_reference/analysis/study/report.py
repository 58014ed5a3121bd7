"""What a study shows: the table as Parquet, plots and ``summary.md``.

* Two varied parameters: a heat map of each metric over them, infeasible cases hatched and labelled, and
  cells beyond the spec's design limit of the metric outlined and labelled (``heatmaps_limits.png``: the
  metrics with a limit only).
  Otherwise: each metric against each varied parameter, infeasible cases marked with crosses.
* ``summary.md``: the cases, how many are feasible and why not, and for each design limit of the spec
  and each varied parameter the largest value up to which every feasible case stays within the limit.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from ..figures import pyplot as plt
from .case import metrics
from .spec import StudySpec


def write_report(spec: StudySpec, table: pd.DataFrame, out: str | Path) -> list[Path]:
    """results.parquet, the plots and summary.md in ``out``; returns the files written."""
    out = Path(out)
    written = [out / "results.parquet"]
    table.to_parquet(written[0], index=False)
    plotted = [m for m in metrics(spec) if m not in ("feasible", "reason", "wall_s")]
    metrics_shown = [m for m in plotted if m in table and table[m].notna().any()]
    if len(spec.varied) == 2:
        written.append(_heat_maps(table, spec.varied, metrics_shown, out / "heatmaps.png", spec.limits))
        limited = [m for m in metrics_shown if m in spec.limits]
        if limited:
            written.append(_heat_maps(table, spec.varied, limited, out / "heatmaps_limits.png", spec.limits))
    else:
        written.append(_curves(table, spec.varied, metrics_shown, out / "metrics.png"))
    written.append(out / "summary.md")
    written[-1].write_text(summary(spec, table))
    return written


def _heat_maps(table: pd.DataFrame, varied: list[str], metrics: list[str], path: Path,
               limits: dict[str, float]) -> Path:
    x_name, y_name = varied
    xs, ys = np.unique(table[x_name]), np.unique(table[y_name])
    columns = min(3, len(metrics))
    rows = math.ceil(len(metrics) / columns)
    fig, axes = plt.subplots(rows, columns, figsize=(5 * columns, 4 * rows), squeeze=False)
    for ax, metric in zip(axes.flat, metrics, strict=False):
        grid = np.full((ys.size, xs.size), np.nan)
        infeasible = np.zeros_like(grid, dtype=bool)
        for _, row in table.iterrows():
            i, j = np.searchsorted(ys, row[y_name]), np.searchsorted(xs, row[x_name])
            grid[i, j] = row[metric] if row["feasible"] else np.nan
            infeasible[i, j] = not row["feasible"]
        mesh = ax.pcolormesh(np.arange(xs.size + 1), np.arange(ys.size + 1), grid, cmap="viridis")
        for i, j in zip(*np.nonzero(infeasible), strict=True):
            ax.add_patch(plt.Rectangle((j, i), 1, 1, fill=False, hatch="xx", edgecolor="red"))
            ax.text(j + 0.5, i + 0.5, "infeasible", ha="center", va="center", color="red", fontsize=7)
        if metric in limits:
            for i, j in zip(*np.nonzero(grid > limits[metric]), strict=True):
                ax.add_patch(plt.Rectangle((j, i), 1, 1, fill=False, linewidth=2.5, edgecolor="orange"))
                ax.text(j + 0.5, i + 0.5, f"> {limits[metric]:g}", ha="center", va="center", color="orange",
                        fontsize=7)
        ax.set_xticks(np.arange(xs.size) + 0.5, [f"{x:g}" for x in xs])
        ax.set_yticks(np.arange(ys.size) + 0.5, [f"{y:g}" for y in ys])
        ax.set_xlabel(x_name)
        ax.set_ylabel(y_name)
        ax.set_title(metric)
        fig.colorbar(mesh, ax=ax)
    for ax in list(axes.flat)[len(metrics):]:
        ax.set_visible(False)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _curves(table: pd.DataFrame, varied: list[str], metrics: list[str], path: Path) -> Path:
    fig, axes = plt.subplots(len(metrics), len(varied), figsize=(5 * len(varied), 2.6 * len(metrics)),
                             squeeze=False)
    feasible = table["feasible"].astype(bool)
    for i, metric in enumerate(metrics):
        for j, name in enumerate(varied):
            ax = axes[i, j]
            ax.plot(table.loc[feasible, name], table.loc[feasible, metric], "o", markersize=4)
            if (~feasible).any():
                low = np.nanmin(table[metric]) if table[metric].notna().any() else 0.0
                ax.plot(table.loc[~feasible, name], np.full((~feasible).sum(), low), "rx", label="infeasible")
                ax.legend(fontsize=7)
            ax.set_xlabel(name)
            ax.set_ylabel(metric, fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def largest_within(table: pd.DataFrame, parameter: str, metric: str, limit: float,
                   descending: bool = False) -> float | None:
    """The largest value of ``parameter`` up to which every feasible case has ``metric`` <= ``limit``
    (None if a case at the smallest value already exceeds it); with ``descending`` the smallest value from
    which on every feasible case stays within (for a parameter such as a gain, where more is better)."""
    best = None
    feasible = table[table["feasible"].astype(bool)]
    values = np.unique(feasible[parameter])
    for value in values[::-1] if descending else values:
        if (feasible.loc[feasible[parameter] == value, metric] > limit).any():
            break
        best = float(value)
    return best


def summary(spec: StudySpec, table: pd.DataFrame) -> str:
    feasible = table["feasible"].astype(bool)
    lines = [f"# Study: {len(table)} cases, {int(feasible.sum())} feasible", "",
             f"Variant {spec.variant}, {spec.duration:g} s per case at h = {spec.step:g} s; varied: "
             f"{', '.join(spec.varied)}.", ""]
    if (~feasible).any():
        lines += ["## Infeasible cases", ""]
        lines += [f"- case {int(r['case'])} ({', '.join(f'{n} = {r[n]:g}' for n in spec.varied)}): {r['reason']}"
                  for _, r in table[~feasible].iterrows()]
        lines.append("")
    if spec.limits:
        lines += ["## Design limits", ""]
        for metric, limit in spec.limits.items():
            for name in spec.varied:
                up, down = (largest_within(table, name, metric, limit, descending) for descending in (False, True))
                said = [f"every feasible case with {name} <= {up:g} stays within it"] if up is not None else []
                if down is not None and down != np.min(table[name]):
                    said.append(f"every feasible case with {name} >= {down:g} stays within it")
                lines.append(f"- {metric} <= {limit:g}: " + ("; ".join(said) or
                                                            f"no range of {name} keeps every case within it"))
            if len(spec.varied) == 2:
                first, second = spec.varied
                lines += ["", f"  Range of {first} within {metric} <= {limit:g}, for each {second}:", "",
                          f"  | {second} | largest {first} up to which | smallest {first} from which |",
                          "  |---|---|---|"]
                for value in np.unique(table[second]):
                    part = table[table[second] == value]
                    up, down = (largest_within(part, first, metric, limit, descending) for descending in (False, True))
                    lines.append(f"  | {value:g} | {'none' if up is None else f'{up:g}'} | "
                                 f"{'none' if down is None else f'{down:g}'} |")
                lines.append("")
        lines.append("")
    lines += ["## Ranges of the metrics (feasible cases)", "", "| metric | min | max |", "|---|---|---|"]
    for metric in (m for m in metrics(spec) if m not in ("feasible", "reason", "wall_s")):
        if metric in table and table.loc[feasible, metric].notna().any():
            values = table.loc[feasible, metric]
            lines.append(f"| {metric} | {values.min():.4g} | {values.max():.4g} |")
    return "\n".join(lines) + "\n"

"""Shared output of the benchmark scripts."""

from __future__ import annotations


def print_table(title: str, rows: list[dict[str, object]]) -> None:
    """``title``, then one line per key of ``rows`` with one column per row (floats to 3 decimals)."""
    print(title)
    for key in rows[0]:
        cells = "".join(f"{row[key]:>12.3f}" if isinstance(row[key], float) else f"{row[key]!s:>12}" for row in rows)
        print(f"{key:<22}{cells}")

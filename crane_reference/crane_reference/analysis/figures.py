"""The one place the package chooses matplotlib's backend: Agg, files only (no display; safe in a node's
process, on CI and over SSH)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as pyplot

__all__ = ["pyplot"]

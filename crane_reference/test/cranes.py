"""The crane files the tests use: the packaged cranes in ``config/`` and the packaged crane in the layout of the
paper's crane family (``data/paper_layout_crane.yaml``)."""

from __future__ import annotations

from pathlib import Path

CONFIG = Path(__file__).resolve().parent.parent / "config"
PAPER_LAYOUT = Path(__file__).resolve().parent / "data" / "paper_layout_crane.yaml"
"""The packaged crane (config/crane.yaml) in the layout of the paper's crane family."""
EXAMPLES = ("crane.yaml", "loader_crane.yaml", "knuckle_boom_crane.yaml")
"""The packaged cranes (files in :data:`CONFIG`): the paper's and the examples."""

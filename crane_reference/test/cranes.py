"""The crane files the tests use: the packaged cranes in ``config/`` and the packaged crane in the layout of the
paper's crane family (``data/paper_layout_crane.yaml``)."""

from __future__ import annotations

from pathlib import Path

import pytest

from crane_reference.model.config import ConfigError, parse_config
from crane_reference.model.drive import TorqueSource

CONFIG = Path(__file__).resolve().parent.parent / "config"
PAPER_LAYOUT = Path(__file__).resolve().parent / "data" / "paper_layout_crane.yaml"
"""The packaged crane (config/crane.yaml) in the layout of the paper's crane family."""
NO_DRIVE = TorqueSource(0.0, 0.0, 0.0)
"""A drive that applies nothing."""
DRIVE_OFF = 2.0
"""[s] a time after the packaged crane's torque drive (4000 N m on [0, 1) s): it applies nothing then."""
EXAMPLES = ("crane.yaml", "loader_crane.yaml", "knuckle_boom_crane.yaml")
"""The packaged cranes (files in :data:`CONFIG`): the paper's and the examples."""


def expect_config_error(data: object, *fragments: str) -> str:
    """parse_config(data) raises ConfigError naming the source ``crane.yaml`` and containing every fragment; the
    message."""
    with pytest.raises(ConfigError) as info:
        parse_config(data, source="crane.yaml")
    message = str(info.value)
    assert message.startswith("crane.yaml: ")
    for fragment in fragments:
        assert fragment in message, f"{fragment!r} not in {message!r}"
    return message


def with_trolley(data: dict) -> dict:
    """The crane ``data`` (the loader crane's) with a 100 kg trolley free to roll along its last link, the jib
    (no spring, no drive): a crane without a static equilibrium."""
    data["links"].append({"name": "trolley", "joint": {"name": "roll", "type": "prismatic", "axis": [1.0, 0.0, 0.0],
                                                        "origin": {"xyz": [2.0, 0.0, 0.0]}},
                          "inertial": {"mass": 100.0, "center_of_mass": [0.0, 0.0, 0.0],
                                       "inertia": {"ixx": 1.0, "iyy": 1.0, "izz": 1.0}}})
    return data


def spinning_crane(path: Path, start: float = 0.0) -> Path:
    """The packaged crane with a column torque of 1e6 N m (the largest ``drive.torque`` allows) from ``start`` [s]
    written to ``path``: it spins the slew faster than the integrator's steps can follow."""
    text = (CONFIG / "crane.yaml").read_text()
    torque, begin = "  torque: 4000.0 ", "  start: 0.0                        # [s]"
    assert torque in text and begin in text
    path.write_text(text.replace(torque, "  torque: 1.0e6 ").replace(begin, begin.replace("0.0", f"{start:.1f}")))
    return path


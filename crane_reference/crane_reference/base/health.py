"""A node's health as diagnostics report it, and its start-up failures, without ROS.

The levels have the values of diagnostic_msgs/DiagnosticStatus (OK 0, WARN 1, ERROR 2, STALE 3).  Before a node
serves, its health is what it is doing while it starts, at ERROR if it cannot (:func:`startup_health`).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

CANNOT = "cannot"
"""How a start-up message that says why the node cannot start begins ("cannot configure: ...")."""


class Level(IntEnum):
    """Severity, with the values of diagnostic_msgs/DiagnosticStatus."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


@dataclass(frozen=True)
class Health:
    level: Level
    message: str


def startup_health(doing: str) -> Health:
    """Before serving: what the node is doing (OK), or why it cannot start (ERROR, ``doing`` begins with
    :data:`CANNOT`)."""
    return Health(Level.ERROR if doing.startswith(CANNOT) else Level.OK, doing)


class StartupError(RuntimeError):
    """The node cannot start (unusable configuration or target)."""

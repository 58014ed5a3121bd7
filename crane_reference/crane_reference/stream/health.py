"""The reference's health as diagnostics report it: a level and a message, decided without ROS.

The levels have the values of diagnostic_msgs/DiagnosticStatus (OK 0, WARN 1, ERROR 2, STALE 3).  Before the
server publishes, the health is what the node is doing while it starts, at ERROR if it cannot
(:func:`startup_health`); once it publishes, :func:`serving_health` ranks what can be wrong, the worst first:
the solver stopped, the stream failed (or the server faulted), the clock went back, the clock leapt forward,
samples were held because the solver was late; else OK with the stream's state.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

from .reference_stream import ERROR
from .server import ServerStatus

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
    """Before publishing: what the node is doing (OK), or why it cannot start (ERROR, ``doing`` begins with
    :data:`CANNOT`)."""
    return Health(Level.ERROR if doing.startswith(CANNOT) else Level.OK, doing)


def serving_health(status: ServerStatus, newly_held: int) -> Health:
    """While publishing: the worst of what :mod:`this module <.health>` lists, from the server's ``status`` and
    the samples held late since the last report (``newly_held``)."""
    state = status.stream.state
    if not status.computing:
        return Health(Level.ERROR, f"solver stopped: {status.fault}; holding the last sample (deactivate, cleanup, "
                                   "configure and activate start a new solver)")
    if state == ERROR:
        return Health(Level.ERROR, f"{state}: {status.stream.last_error}; the reference runs to its last valid step "
                                   "and holds it there (deactivate, then ~/restart, or mend the cause and cleanup "
                                   "and configure; then activate)")
    if status.fault:
        return Health(Level.ERROR, f"{state}: {status.fault}")
    if status.clock_behind:
        return Health(Level.WARN, f"{state}: ROS time went back: waiting until it reaches the last stamp again "
                                  f"({status.clock_behind:.3f} s ahead)")
    if status.clock_note:
        return Health(Level.WARN, f"{state}: {status.clock_note}")
    if newly_held > 0:
        return Health(Level.WARN, f"{state}: {newly_held} samples held (solver late)")
    return Health(Level.OK, state)

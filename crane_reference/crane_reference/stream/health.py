"""The reference's health as diagnostics report it while the server publishes (:mod:`crane_reference.base.health`
before): :func:`serving_health` ranks what can be wrong, the worst first:
the solver stopped, the stream failed (or the server faulted), the clock went back, the clock leapt forward,
samples were held because the solver was late; else OK with the stream's state.
"""

from __future__ import annotations

from ..base.health import Health, Level
from .reference_stream import ERROR
from .served import ServerStatus


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

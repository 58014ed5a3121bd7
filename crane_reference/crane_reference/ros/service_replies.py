"""What the reference node's services and logs answer, in words, from the ROS-free server's results:
~/restart, ~/pause and the sample a command takes effect at.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..motion.simulation import SOLVER_FAILURES
from ..stream.reference_stream import ERROR, PAUSED, RUNNING
from ..stream.served import CommandRefusedError
from ..stream.server import ReferenceServer


@dataclass(frozen=True)
class Reply:
    """The answer to a request of the node's services: whether it was done, and what was done or why not."""

    success: bool
    message: str


def sample_named(server: ReferenceServer, k: int) -> str:
    """Sample k as a reply names it: by its stamp while publishing, else by its number (its stamp is given when
    publishing begins)."""
    if server.publishing:
        return f"the sample stamped {server.stamp_of(k):.6f} s"
    return f"sample {k} of the stream (stamped once published)"


def restart_reply(server: ReferenceServer, accepted_ns: int) -> Reply:
    """:meth:`~crane_reference.stream.server.ReferenceServer.restart` as ~/restart answers: how far the position
    jumps, or why the stream is unchanged."""
    try:
        restart = server.restart(accepted_ns)
    except (*SOLVER_FAILURES, CommandRefusedError) as error:
        return Reply(False, f"restart failed, stream unchanged: {error}")
    return Reply(True, f"restarted from the static equilibrium at sample {restart.k}, published once active: "
                       f"position jump up to {restart.jump:.6g} {restart.unit} on {restart.joint}")


def pause_reply(server: ReferenceServer, hold: bool, accepted_ns: int) -> Reply:
    """~/pause: ``hold`` brings the reference to rest along the speed ramp and holds it there, else it resumes;
    done already if the stream is so; refused once computing ahead stopped or in ERROR (with the remedy)."""
    stream = server.stream
    if not server.computing:
        return Reply(False, "the solver stopped; deactivate, cleanup, configure and activate start a new one")
    if stream.state == ERROR:
        return Reply(False, f"the stream is in ERROR ({stream.last_error}); deactivate, call ~/restart and activate")
    if stream.state == (PAUSED if hold else RUNNING):
        return Reply(True, f"already {stream.state.lower()}")
    k = server.command("pause" if hold else "resume", accepted_ns=accepted_ns)
    verb = "coming to rest" if hold else "resuming"
    return Reply(True, f"{verb} from {sample_named(server, k)} over {server.stream.ramp_time:g} s")

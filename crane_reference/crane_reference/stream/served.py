"""What the reference server (:mod:`.server`) takes and hands out, as data: the preview it makes, the samples due
to publish, a command's point, a re-target's milestones, a restart's jump and the status snapshot.  The words a
ROS service answers with are the ROS adapter's (:mod:`crane_reference.ros.service_replies`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from .frames import Frames
from .sample import ReferenceRows, ReferenceSample
from .solver_messages import StreamStatus

Encoder = Callable[[ReferenceRows], Any]
"""What a publisher makes of a batch's samples at once (its messages, a row a sample), kept as the frames'
``wire``: called in the thread that receives the batch from the solver, outside the server's lock, so the
publisher's own thread only stamps and sends."""


class CommandRefusedError(RuntimeError):
    """A command that the server's state does not allow (the message says why)."""


@dataclass(frozen=True)
class Preview:
    """A preview of ``points`` samples after the frame's own over ``horizon`` seconds, every ``decimation`` frames."""

    horizon: float
    points: int
    decimation: int


class Outgoing(NamedTuple):
    """Sample k to publish, stamped ``stamp_ns``: row ``row`` of ``frames`` (made by the solver, or the last one
    published, held)."""

    k: int
    stamp_ns: int
    frames: Frames
    row: int


class Due(NamedTuple):
    """What :meth:`~.server.ReferenceServer.due` hands the publisher: the samples to publish now, oldest first, the
    stamp [ns] of the next one (None while not publishing) and the clock reading they are due by [ns]."""

    outgoing: list[Outgoing]
    next_stamp_ns: int | None
    now_ns: int


class Published(NamedTuple):
    """The last sample published (None before the first) and its stamp [ns]."""

    sample: ReferenceSample | None
    stamp_ns: int


@dataclass(frozen=True)
class Restart:
    """A restart at sample k: the largest position change, the joint it is on and its unit (rad, or m for a
    prismatic joint)."""

    k: int
    jump: float
    joint: str
    unit: str


class CommandPoint(NamedTuple):
    """Where a command takes effect: sample k, at stream time tau [s], and the solver's answer to it."""

    k: int
    tau: float
    answer: Any


class Milestone:
    """The first sample published at or after motion time ``t`` [s]: its stamp [ns] once published, else None."""

    def __init__(self, t: float) -> None:
        self.t = t
        self.stamp_ns: int | None = None


class RetargetBlend(NamedTuple):
    """A re-target's blend (:meth:`~.server.ReferenceServer.retarget`): its command point k, the motion time [s] it
    begins at, and the milestones of its start and its end (the first sample on the new path)."""

    k: int
    start: float
    first: Milestone
    end: Milestone


@dataclass(frozen=True)
class ServerStatus:
    """A snapshot for diagnostics: the stream's status, whether publishing, the last sample sent, the
    counters, the fault, frames ready, each command's acceptance time and the stamp it takes effect at
    [s] (:meth:`~.command_log.CommandLog.entries`), how far the clock is behind the last stamp [s] (it went
    back), a note on a forward jump of the clock since the last snapshot, the achieved publish rate [Hz], the
    solver's real-time factor since the last snapshot and whether the server still computes ahead."""

    stream: StreamStatus
    publishing: bool
    last: ReferenceSample | None
    counters: dict[str, int]
    fault: str
    frames_ready: int
    commands: dict[str, str] = field(default_factory=dict)
    clock_behind: float = 0.0
    clock_note: str = ""
    achieved_rate: float = 0.0
    real_time_factor: float = math.inf
    computing: bool = True

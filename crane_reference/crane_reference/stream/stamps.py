"""The stamps of a published stream: when publishing started, the last stamp sent and what the clock did.

Sample k is stamped ``start + k / rate`` (:func:`~.schedule.stamp_at`), never before the last stamp sent.  A clock
that jumps forward beyond the schedule's catch-up limit makes the stamps leap with it (no sample skipped,
:meth:`~.schedule.FrameSchedule.anchored`); one that goes back makes nothing due until it reaches the next stamp
again, or, beyond the catch-up limit, restarts the stamps from it once (:meth:`Stamps.went_back`).  No threads or
locks of its own: the reference server's lock is held around every call.
"""

from __future__ import annotations

from collections.abc import Callable

from ..model.units import NANOSECONDS
from .frames import Frames
from .schedule import FrameSchedule, stamp_at


class Stamps:
    """The publishing clock of a stream at ``rate`` Hz; ``clock`` [ns] tells how much time passed since the last
    reading of the publisher's clock (:meth:`now_ns`)."""

    def __init__(self, rate: int, clock: Callable[[], int]):
        self.rate = rate
        self._clock = clock
        self.start_ns: int | None = None
        """The stamp [ns] of sample 0 while publishing, else None."""
        self.last_ns = 0
        """The last stamp sent [ns] (0 before the first)."""
        self.behind_ns = 0
        """How far the publisher's clock was behind the last stamp at its last reading [ns] (0 within a period)."""
        self.note = ""
        """What the clock did since the last status (a leap forward, a reset back), or ''."""
        self._seen = (0, 0)  # the last reading of the publisher's clock [ns] and ``clock`` then [ns]

    @property
    def publishing(self) -> bool:
        return self.start_ns is not None

    def stamp_ns(self, k: int) -> int:
        """Stamp [ns] of sample k (relative to the start while not publishing)."""
        return stamp_at(self.start_ns or 0, k, self.rate)

    def stamp_of(self, k: int) -> float:
        """Stamp [s] of sample k (relative to the start while not publishing)."""
        return self.stamp_ns(k) / NANOSECONDS

    def now_ns(self) -> int:
        """The publisher's clock now, from its last reading, as if it ran at the rate of ``clock``."""
        seen_ns, seen_at = self._seen
        return seen_ns + self._clock() - seen_at

    def begin(self, now_ns: int, next_k: int) -> None:
        """Publish from sample ``next_k`` on, stamped ``now_ns`` (or one period after the last stamp sent, if
        later: stamps only increase)."""
        start = max(now_ns, self.last_ns + NANOSECONDS // self.rate)
        self.start_ns = start - next_k * NANOSECONDS // self.rate

    def end(self) -> None:
        self.start_ns = None

    def due(self, now_ns: int, schedule: FrameSchedule) -> list[tuple[int, int, Frames, int]]:
        """Every sample of ``schedule`` due by the publisher's clock reading ``now_ns`` [ns] (while publishing), as
        (k, stamp [ns], frames, row), oldest first."""
        start = schedule.anchored(now_ns, self.start_ns)
        if start != self.start_ns:
            self.note = (f"ROS time jumped {(start - self.start_ns) / NANOSECONDS:.3f} s ahead of the schedule: the "
                         "stamps leap with it, no sample skipped")
            self.start_ns = start
        self._seen = (now_ns, self._clock())
        behind = self.last_ns - now_ns
        self.behind_ns = behind if behind > NANOSECONDS // self.rate else 0
        out = []
        for k, frames, row in schedule.due(now_ns, start):
            sent = schedule.outgoing(k, frames, row)
            if sent is not None:
                self.last_ns = stamp_at(start, k, self.rate)
                out.append((k, self.last_ns, *sent))
        return out

    def went_back(self, now_ns: int, schedule: FrameSchedule) -> None:
        """The clock jumped back to ``now_ns``: beyond the catch-up limit behind the next stamp, publishing goes on
        on the new timeline, the next sample stamped ``now_ns`` (:meth:`~.schedule.FrameSchedule.restamped`:
        stamps go back once, counted, announced); within it, publishing waits until the clock reaches the next
        stamp again."""
        if self.start_ns is None:
            return
        behind = stamp_at(self.start_ns, schedule.next_k, self.rate) - now_ns
        if behind <= schedule.max_catch_up * NANOSECONDS:
            return
        self.start_ns = schedule.restamped(now_ns)
        self.last_ns = now_ns - NANOSECONDS // self.rate
        self.behind_ns = 0  # on the new timeline the clock is at the next stamp (a reading may have seen it behind)
        self._seen = (now_ns, self._clock())  # :meth:`now_ns` goes on from the new time
        self.note = (f"ROS time went back {behind / NANOSECONDS:.3f} s: the stamps restart from it (once), no sample "
                     "skipped")

    def take_note(self) -> str:
        """:attr:`note`, cleared."""
        note, self.note = self.note, ""
        return note

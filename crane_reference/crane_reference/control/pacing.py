"""Real-time pacing of the plant node's control periods on a monotonic clock.

Period k is due at start + k T.  A period runs when it is due; found more than a period past its due time, the
periods due before the latest due time passed are missed: they are counted, not run, and the latest runs at
once.  The schedule stays on its grid, so every period due is either run or counted missed (the plant's time
then falls behind the wall clock by the missed periods).
"""

from __future__ import annotations

import math


class Pacing:
    """Periods of ``period`` [s] from ``start`` [s, the caller's monotonic clock], the first due one period
    after it."""

    def __init__(self, period: float, start: float):
        if not (math.isfinite(period) and period > 0.0):
            raise ValueError(f"period = {period!r} s: must be a finite number > 0")
        self.period = period
        self.due = start + period
        """[s] when the next period is due."""
        self.missed = 0
        """Periods missed so far."""

    def wait(self, now: float) -> float:
        """[s] until the next period is due at ``now`` (<= 0: run it).  More than a period past its due time, the
        periods due before the latest due time passed are counted :attr:`missed` and that one is next."""
        lateness = now - self.due
        if lateness > self.period:
            skipped = int(lateness // self.period)
            self.missed += skipped
            self.due += skipped * self.period
        return self.due - now

    def ran(self) -> None:
        """The due period ran: the next is due one period later."""
        self.due += self.period

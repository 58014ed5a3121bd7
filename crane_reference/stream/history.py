"""The computed motion kept for sampling and for rewinding (a re-target or a command in the past)."""

from __future__ import annotations

import bisect
from dataclasses import dataclass

import numpy as np

from ..motion.programmed_motion import ProgrammedMotion
from ..motion.simulation import StepperSnapshot
from .sample import ReferenceSample

TIME_SLACK = 1e-12  # [s], rounding slack when locating a motion time among the computed ones


@dataclass(frozen=True)
class Entry:
    """One computed instant: its reference sample, the programmed motion in force, the work accounts [J]
    (:class:`~crane_reference.motion.simulation.MotionStepper`) and, at the end of a compiled run, the
    stepper's snapshot to continue from unchanged (None inside a run)."""

    sample: ReferenceSample
    motion: ProgrammedMotion
    work: np.ndarray
    snapshot: StepperSnapshot | None


class History:
    """Computed instants in increasing motion time, the first one always restartable."""

    def __init__(self, start: StepperSnapshot, sample: ReferenceSample):
        self.entries: list[Entry] = [Entry(sample, start.motion, start.work, start)]
        self.times: list[float] = [sample.t]

    @property
    def last(self) -> Entry:
        return self.entries[-1]

    def extend(self, samples: list[ReferenceSample], work: np.ndarray, motion: ProgrammedMotion,
               end: StepperSnapshot) -> None:
        """Append a compiled run: its samples with their work accounts (N, 3) (the last one restartable
        from ``end``)."""
        self.entries += [Entry(sample, motion, w, None) for sample, w in zip(samples[:-1], work, strict=False)]
        self.entries.append(Entry(samples[-1], end.motion, end.work, end))
        self.times += [sample.t for sample in samples]

    def bracket(self, t: float) -> tuple[int, bool]:
        """Index k of the last instant at or before motion time t, and whether t is (within rounding)
        that instant itself or beyond the last one; a t within rounding before an instant is that instant."""
        times = self.times
        k = min(max(bisect.bisect_right(times, t) - 1, 0), len(times) - 1)
        if k + 1 < len(times) and t >= times[k + 1] - TIME_SLACK:
            return k + 1, True
        return k, k + 1 == len(times) or t <= times[k] + TIME_SLACK

    def first_at_or_after(self, t: float) -> int:
        """Index of the first instant at or after motion time t (the last one if none)."""
        return min(bisect.bisect_left(self.times, t - TIME_SLACK), len(self.times) - 1)

    def set_snapshot(self, k: int, snapshot: StepperSnapshot) -> None:
        """Make instant k (its sample unchanged) restartable from ``snapshot``."""
        self.entries[k] = Entry(self.entries[k].sample, snapshot.motion, snapshot.work, snapshot)

    def truncate(self, k: int) -> list[Entry]:
        """Forget everything after instant k; returns the entries forgotten (freeing them takes a while: the
        caller chooses when)."""
        forgotten = self.entries[k + 1:]
        del self.entries[k + 1:]
        del self.times[k + 1:]
        return forgotten

    def release(self, t: float) -> None:
        """Forget instants before motion time t, keeping a restartable one at or before it."""
        k = bisect.bisect_left(self.times, t) - 1
        while k > 0 and self.entries[k].snapshot is None:
            k -= 1
        if k > 0:
            del self.entries[:k]
            del self.times[:k]

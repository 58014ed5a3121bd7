"""The computed motion kept for sampling and for rewinding (a re-target or a command in the past).

The steps are kept as rows of arrays, in the order computed.  What only a reader needs (the generalized
effort, the feedforward and the constraint distance, by inverse dynamics at the step; the quaternion of E's frame) is
computed for the rows that are read, when they are first read: the stream's runs evaluate only their last
step (:class:`~crane_reference.motion.simulation.MotionStepper` with ``every_row`` False), and a node
publishing at 100 Hz reads one step in twenty.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..motion.programmed_motion import ProgrammedMotion
from ..motion.simulation import StepperSnapshot
from ..motion.trajectory import MotionRows, generalized_effort
from .sample import ReferenceRows, quaternions

TIME_SLACK = 1e-12  # [s], rounding slack when locating a motion time among the computed ones
STEP_FIELDS = ("t", "q", "qd", "qdd", "ee_position", "ee_rotation", "effort", "feedforward", "residual_distance")
"""The arrays kept per step (the rows of :meth:`~crane_reference.motion.simulation.MotionStepper.advance_until`,
with the effort, the feedforward and the largest constraint distance, NaN until a read evaluates them)."""


class Instant(NamedTuple):
    """A computed step to continue from under new constraints: motion time t [s], q, qd and the programmed
    motion in force there."""

    t: float
    q: np.ndarray
    qd: np.ndarray
    motion: ProgrammedMotion


class History:
    """Computed steps in increasing motion time (index 0 the oldest kept, always restartable)."""

    def __init__(self, start: StepperSnapshot, drive_joint: int, capacity: int = 4096):
        s = start.sample
        n = s.q.size
        shapes = {"t": (), "q": (n,), "qd": (n,), "qdd": (n,), "ee_position": (3,), "ee_rotation": (3, 3),
                  "effort": (n,), "feedforward": (n,), "residual_distance": ()}
        self._rows = {name: np.full((capacity, *shapes[name]), np.nan) for name in STEP_FIELDS}
        self._motion = np.zeros(capacity, dtype=np.int64)  # index into self._motions of each row's motion
        self._motions: list[ProgrammedMotion] = []
        self._snapshots: dict[int, StepperSnapshot] = {}  # by storage row
        self._begin = self._end = 0
        self.drive_joint = drive_joint
        self.extend(MotionRows.stacked([s]), start)

    def __len__(self) -> int:
        return self._end - self._begin

    @property
    def times(self) -> np.ndarray:
        """Motion times of the steps [s] (a view: valid until the history changes)."""
        return self._rows["t"][self._begin:self._end]

    @property
    def end_time(self) -> float:
        return float(self._rows["t"][self._end - 1])

    @property
    def last_snapshot(self) -> StepperSnapshot:
        return self._snapshots[self._end - 1]

    def extend(self, rows: MotionRows, end: StepperSnapshot) -> None:
        """Append a compiled run, its rows stacked (``MotionStepper.advance_until``; their effort and constraint
        distance are left for :meth:`read`, one formula for every row); the last one restartable from ``end``."""
        count = rows.t.size
        if self._end + count > self._motion.size:
            self._compact(count)
        new = slice(self._end, self._end + count)
        for name in ("t", "q", "qd", "qdd", "ee_position", "ee_rotation"):
            self._rows[name][new] = getattr(rows, name)
        for name in ("effort", "feedforward", "residual_distance"):
            self._rows[name][new] = np.nan  # NaN: not evaluated yet
        if not self._motions or self._motions[-1] is not end.motion:
            self._motions.append(end.motion)
        self._motion[new] = len(self._motions) - 1
        self._end += count
        self._snapshots[self._end - 1] = end

    def _compact(self, count: int) -> None:
        """Move the kept rows to the front of the storage, which grows to twice what they and ``count`` more
        need if that is more than it holds (so at least half of it is free after a compaction, and copying
        the kept rows costs a fraction of a row per row appended)."""
        kept = self._end - self._begin
        needed = 2 * (kept + count)
        capacity = needed if needed > self._motion.size else self._motion.size
        for name, old in self._rows.items():
            grown = np.full((capacity, *old.shape[1:]), np.nan)
            grown[:kept] = old[self._begin:self._end]
            self._rows[name] = grown
        used, index = np.unique(self._motion[self._begin:self._end], return_inverse=True)
        self._motions = [self._motions[i] for i in used]  # the motions of forgotten steps forgotten too
        motion = np.zeros(capacity, dtype=np.int64)
        motion[:kept] = index
        self._motion = motion
        self._snapshots = {row - self._begin: s for row, s in self._snapshots.items()}
        self._begin, self._end = 0, kept

    def locate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For each motion time of ``t``: the index k of the last step at or before it, and whether it is (within
        rounding) that step itself or beyond the last one; a time within rounding before a step is that step."""
        times = self.times
        k = np.clip(np.searchsorted(times, t, side="right") - 1, 0, times.size - 1)
        later = np.minimum(k + 1, times.size - 1)
        onto_next = (k + 1 < times.size) & (t >= times[later] - TIME_SLACK)
        k = np.where(onto_next, k + 1, k)
        exact = onto_next | (k + 1 == times.size) | (t <= times[k] + TIME_SLACK)
        return k, exact

    def first_at_or_after(self, t: float) -> int:
        """Index of the first step at or after motion time t (the last one if none)."""
        return min(int(np.searchsorted(self.times, t - TIME_SLACK, side="left")), len(self) - 1)

    def instant(self, k: int) -> Instant:
        row = self._begin + k
        return Instant(float(self._rows["t"][row]), self._rows["q"][row].copy(), self._rows["qd"][row].copy(),
                       self._motions[self._motion[row]])

    def read(self, k: np.ndarray) -> ReferenceRows:
        """The reference samples of steps ``k`` (indices), evaluated first where no read has yet."""
        rows = self._begin + np.asarray(k, dtype=np.int64)
        distance = self._rows["residual_distance"]
        missing = np.unique(rows[np.isnan(distance[rows])])
        for index in np.unique(self._motion[missing]):
            some = missing[self._motion[missing] == index]
            r = self._rows
            forces, torques, distances = self._motions[index].evaluated_rows(r["t"][some], r["q"][some],
                                                                             r["qd"][some], r["qdd"][some])
            r["effort"][some] = generalized_effort(forces, torques, self.drive_joint)
            r["feedforward"][some] = forces
            distance[some] = np.max(distances, axis=-1)
        r = self._rows
        return ReferenceRows(r["t"][rows], r["q"][rows], r["qd"][rows], r["qdd"][rows], r["effort"][rows],
                       r["feedforward"][rows], r["ee_position"][rows], quaternions(r["ee_rotation"][rows]),
                       distance[rows], np.zeros(rows.size, dtype=bool))

    def set_snapshot(self, k: int, snapshot: StepperSnapshot) -> None:
        """Make step k (its sample unchanged) restartable from ``snapshot``, under its motion from then on."""
        row = self._begin + k
        self._snapshots[row] = snapshot
        if self._motions[self._motion[row]] is not snapshot.motion:
            self._motions.append(snapshot.motion)
            self._motion[row] = len(self._motions) - 1

    def truncate(self, k: int) -> list[StepperSnapshot]:
        """Forget everything after step k; returns the snapshots forgotten (freeing them takes a while: the
        caller chooses when)."""
        row = self._begin + k
        forgotten = [self._snapshots.pop(r) for r in [r for r in self._snapshots if r > row]]
        self._end = row + 1
        return forgotten

    def release(self, t: float) -> None:
        """Forget steps before motion time t, keeping a restartable one at or before it."""
        k = int(np.searchsorted(self.times, t, side="left")) - 1
        restartable = [row - self._begin for row in self._snapshots if row - self._begin <= k]
        keep = max(restartable, default=0)
        if keep > 0:
            for row in [r for r in self._snapshots if r < self._begin + keep]:
                del self._snapshots[row]
            self._begin += keep

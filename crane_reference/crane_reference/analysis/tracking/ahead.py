"""Programmed motions integrated in a thread ahead of the closed loop that reads them.

The compiled kernels release the GIL, so on a machine with a second core the references of a closed-loop run
(the task's, and the rigid feedforward's own) are computed while the loop runs instead of before it.  The
motion is the one :func:`~crane_reference.motion.simulation.simulate` gives, run for run: only when it is
computed changes.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator, Sequence

import numpy as np

from ...base.threads import start_named
from ...motion.programmed_motion import ProgrammedMotion
from ...motion.simulation import joined
from ...motion.trajectory import MotionRows, Trajectory


class ComputedAhead:
    """The runs of each of ``motions`` (:func:`~crane_reference.motion.simulation.simulated_runs`), computed in a
    thread in turn, one run of each at a time; :meth:`through` waits for them, :meth:`close` stops the thread
    after the run in progress."""

    def __init__(self, motions: Sequence[ProgrammedMotion], runs: Sequence[Iterator[MotionRows]]):
        self._motions = tuple(motions)
        self._parts: list[list[Trajectory]] = [[] for _ in motions]
        self._computed = [-np.inf] * len(motions)  # motion time [s] each is computed through
        self._finished = False
        self._failure: BaseException | None = None
        self._changed = threading.Condition()
        self._closed = False
        self._thread = start_named(lambda runs=list(runs): self._compute(runs), "references")

    def _compute(self, runs: list[Iterator[MotionRows]]) -> None:
        try:
            active = list(range(len(runs)))
            while active and not self._closed:
                for i in list(active):
                    part = next(runs[i], None)
                    run = None if part is None else joined(self._motions[i], [part])
                    with self._changed:
                        if run is None:
                            active.remove(i)
                        else:
                            self._parts[i].append(run)
                            self._computed[i] = float(run.t[-1])
                        self._changed.notify_all()
        except BaseException as failure:  # handed to the reader, which raises it
            with self._changed:
                self._failure = failure
        finally:
            with self._changed:
                self._finished = True
                self._changed.notify_all()

    def through(self, t: float) -> tuple[list[Trajectory], bool]:
        """Each motion once all are computed through motion time t [s] (or are complete), as far as all are
        computed (one may be a run ahead of another), and whether all are complete; raises what stopped the
        computing."""
        with self._changed:
            self._changed.wait_for(lambda: self._finished or min(self._computed) >= t)
            if self._failure is not None:
                raise self._failure
            parts, finished = [list(p) for p in self._parts], self._finished
            common = np.inf if finished else min(self._computed)
        return [Trajectory.concatenated(_through(p, common)) for p in parts], finished

    def close(self) -> None:
        """Stop computing after the run in progress and wait for the thread (the reader is done, or failed)."""
        self._closed = True
        self._thread.join()


def _through(parts: list[Trajectory], t: float) -> list[Trajectory]:
    """The samples of the consecutive runs ``parts`` at motion times <= t [s]."""
    kept = [part for part in parts if part.t[0] <= t]
    if kept[-1].t[-1] > t:
        kept[-1] = kept[-1].subsampled(count=int(np.searchsorted(kept[-1].t, t, side="right")))
    return kept

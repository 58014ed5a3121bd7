"""What the two sides of the solver's pipe exchange: the frames of the reference, stacked (:class:`Frames`), what
the schedule asks for (:class:`Plan`, :class:`FrameRequest`) and what the solver makes (:class:`FrameBatch`).
The parent's side is :mod:`.schedule`, the solver's :mod:`.frame_maker`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .sample import ReferenceRows, ReferenceSample


@dataclass(frozen=True, eq=False)
class Frames:
    """Frames k .. k + N - 1 of the reference, stacked: their stream publish times ``tau`` (N,) [s], their samples
    (:class:`~.sample.ReferenceRows`, a row each) and the previews of some of them (row -> the preview's samples) over
    ``horizon`` seconds.  The solver makes them, the pipe carries them and the publisher reads them in this form:
    a few arrays a batch, no object a sample.  ``wire``: what the publisher made of the samples at once when the
    batch came (its messages, a row a sample: :data:`~.served.Encoder`), or None."""

    k: int
    tau: np.ndarray
    samples: ReferenceRows
    previews: dict[int, ReferenceRows] = field(default_factory=dict)
    horizon: float = 0.0
    wire: Any = None

    def __len__(self) -> int:
        return self.tau.size

    @property
    def end(self) -> int:
        """The frame after the last."""
        return self.k + self.tau.size

    @classmethod
    def held(cls, k: int, taus: np.ndarray, sample: ReferenceSample) -> Frames:
        """Frames k, ... at ``taus``, each ``sample`` held."""
        return cls(k, np.asarray(taus, dtype=float), ReferenceRows.repeated(sample.hold(), len(taus)))

    def head(self, count: int) -> Frames:
        """The first ``count`` frames (the wire's rows beyond them are never read)."""
        return Frames(self.k, self.tau[:count], self.samples.take(slice(0, count)),
                      {i: p for i, p in self.previews.items() if i < count}, self.horizon, self.wire)

    def renumbered(self, k: int) -> Frames:
        """The same frames as frames k, ..."""
        return replace(self, k=k)


@dataclass(frozen=True)
class Plan:
    """What the worker makes next: frames from k at stream time tau, for buffer ``generation``, at most
    ``room`` of them, the next preview due at ``next_preview_k``."""

    k: int
    tau: float
    generation: int
    next_preview_k: int
    room: int


@dataclass(frozen=True)
class FrameRequest:
    """What the solver makes for a :class:`Plan` (built by :meth:`FrameSchedule.request`, carried to the
    solver, which may be another process): up to ``count`` frames at ``rate`` Hz, a ``horizon``-second
    preview of ``points`` points every ``decimation`` frames, after computing ahead for at most
    ``compute_budget`` s of wall time (None: unbounded); frames before ``urgent_until`` are made as soon as
    their own motion is computed; ``last_valid`` is the last finite sample made."""

    plan: Plan
    count: int
    rate: int
    horizon: float
    points: int
    decimation: int
    compute_budget: float | None
    urgent_until: int
    last_valid: ReferenceSample


@dataclass(frozen=True)
class FrameBatch:
    """What the solver made for a :class:`FrameRequest`: the frames, the next frame due a preview, whether
    the motion is still short of the preview horizon (``busy``), the wall time spent computing and the
    motion computed in it [s], frames replaced because they were not finite and the fault that says why."""

    frames: Frames
    next_preview_k: int
    busy: bool
    compute_wall: float = 0.0
    compute_motion: float = 0.0
    non_finite: int = 0
    fault: str = ""

"""Which reference sample goes out when: the publishing schedule of a node, as plain logic.

Sample k of a stream published at ``rate`` Hz is stamped ``start + k / rate``
(:func:`stamp_at`) and shows the stream at publish time tau_k.
:class:`FrameSchedule` keeps the buffer of frames [next to publish ... made], made ahead of publishing
by a worker and taken by a publisher; it has no threads or locks of its own (the reference server holds them)
and no ROS types, so every rule here is tested without rclpy.  Frames stay stacked (:class:`Frames`, a few
arrays a batch) from the solver to the publisher, which writes a row's numbers into the serialized messages:
no object is made per sample on the way.

* making frames (:meth:`FrameSchedule.plan`, :meth:`FrameSchedule.request`, :func:`make_frames` on the
  solver's side, :meth:`FrameSchedule.accept`): up to the look-ahead, after one slice of computing ahead,
  with a preview every ``decimation`` frames; a frame that is not finite is replaced by the last valid
  sample held;
* commands (:meth:`FrameSchedule.command_point`, :meth:`FrameSchedule.after_command`): a command takes
  effect at the last frame stamped within ``lead`` seconds of its acceptance, but not before the one after
  the next to publish (nor after the next one to make); frames from there on are dropped and made again;
* publishing (:meth:`FrameSchedule.due`, :meth:`FrameSchedule.outgoing`): every sample due by now,
  skipping those more than ``max_catch_up`` seconds late; a sample whose frame is not ready is the last
  one published, held (zero velocity).
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..model.units import NANOSECONDS
from .reference_stream import ReferenceStream
from .sample import ReferenceSample, Samples

TIME_TOLERANCE = 1e-9  # [s], rounding slack when comparing stream times
COMPUTE_MARGIN = 0.05  # [s] of motion computed beyond the preview horizon
URGENT_PART = 4  # frames within lookahead / URGENT_PART of publishing are made before their preview horizon
FRAME_CHUNK = 100  # frames that are not urgent are made this many at a time (a waiting request ends them)


def stamp_at(start_ns: int, k: int, rate: int) -> int:
    """Stamp [ns] of sample k of a stream at ``rate`` Hz that starts at ``start_ns`` (exact when the rate
    divides 10^9 ns, otherwise rounded down to the nanosecond without accumulating an error)."""
    return start_ns + k * NANOSECONDS // rate


@dataclass(frozen=True, eq=False)
class Frames:
    """Frames k .. k + N - 1 of the reference, stacked: their stream publish times ``tau`` (N,) [s], their samples
    (:class:`~.sample.Samples`, a row each) and the previews of some of them (row -> the preview's samples) over
    ``horizon`` seconds.  The solver makes them, the pipe carries them and the publisher reads them in this form:
    a few arrays a batch, no object a sample.  ``wire``: what the publisher made of the samples at once when the
    batch came (its messages, a row a sample: :attr:`~.server.ReferenceServer.encode`), or None."""

    k: int
    tau: np.ndarray
    samples: Samples
    previews: dict[int, Samples] = field(default_factory=dict)
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
        return cls(k, np.asarray(taus, dtype=float), Samples.repeated(sample.hold(), len(taus)))

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


def make_frames(stream: ReferenceStream, request: FrameRequest, stop: np.ndarray | None = None) -> FrameBatch:
    """The frames of ``request`` as far as the motion is computed, after computing ahead far enough for
    them and for their previews (or until the ``stop`` flag is set: a request is waiting for the solver; then only
    urgent frames are made, the motion computed so far is kept and the batch is busy; frames that are not urgent
    are made FRAME_CHUNK at a time, and the flag set meanwhile drops them too).  A frame due a
    preview waits until its horizon is computed, so previews keep their cadence; an urgent frame (just after
    a command) is made as soon as its own motion is computed, without the preview due to it if its horizon
    is not computed yet (the next one is due a decimation later: the cadence stays).  A frame that is not
    finite is replaced by the last valid sample held (:func:`checked`)."""
    plan, count, horizon = request.plan, request.count, request.horizon
    dt = 1.0 / request.rate
    tau, next_preview_k = plan.tau, plan.next_preview_k
    ahead = tau + count * dt + horizon + COMPUTE_MARGIN
    frames_until = tau + (count - 1) * dt + 2 * TIME_TOLERANCE
    before = stream.computed_until
    target = frames_until if plan.k < request.urgent_until else ahead  # urgent: the frames' own motion only
    wall = motion = 0.0
    if before < target:
        start = time.perf_counter()
        stream.compute(target, request.compute_budget, stop)
        if math.isfinite(stream.computed_until):
            wall, motion = time.perf_counter() - start, stream.computed_until - before
    times = tau + dt * np.arange(count)  # in ERROR: the motion up to its last valid step, held beyond

    def waited() -> FrameBatch | None:
        """No frames (busy) if a request waits: it comes first (a command may drop these frames); urgent frames
        are made still."""
        if plan.k >= request.urgent_until and stop is not None and stop[0]:
            return FrameBatch(Frames(plan.k, times[:0], stream.samples(times[:0])), plan.next_preview_k, True, wall,
                              motion)
        return None

    if batch := waited():
        return batch
    computed_until = stream.computed_until
    made = int(np.count_nonzero(times <= computed_until - TIME_TOLERANCE))
    previewed = []  # the rows with a preview
    decimation = max(1, request.decimation)
    row = max(0, next_preview_k - plan.k)
    while row < made:  # the frames due a preview, in turn
        if computed_until >= float(times[row]) + horizon:
            previewed.append(row)
        elif plan.k + row >= request.urgent_until:
            made = row  # this frame's preview is not computed yet: make it on a later call
            break
        next_preview_k = plan.k + row + decimation  # (urgent, not computed: it goes without)
        row += decimation
    parts, points = [], request.points
    previews: dict[int, Samples] = {}
    for first in range(0, made, FRAME_CHUNK):  # a chunk's frames and their previews read at once
        if batch := waited():
            return batch
        end = min(made, first + FRAME_CHUNK)
        rows = [row for row in previewed if first <= row < end]
        read = stream.samples(np.concatenate((times[first:end],
                                              stream.preview_times(times[rows], horizon, points).ravel())))
        parts.append(read.take(slice(0, end - first)))
        for i, row in enumerate(rows):
            start = end - first + i * points
            previews[row] = read.take(slice(start, start + points))
    samples = Samples.concatenated(parts) if parts else stream.samples(times[:0])
    frames, non_finite, fault = checked(Frames(plan.k, times[:made], samples, previews, horizon), request.last_valid)
    return FrameBatch(frames, next_preview_k, computed_until < ahead, wall, motion, non_finite, fault)


def checked(frames: Frames, last_valid: ReferenceSample) -> tuple[Frames, int, str]:
    """``frames`` with each frame that is not finite replaced by the last valid sample before it (or
    ``last_valid``) held, and previews that are not finite dropped; how many were replaced and the fault that
    says why ("" if none): NaN is never published."""
    samples = frames.samples
    previews = {row: p for row, p in frames.previews.items() if np.all(p.finite())}
    bad = np.flatnonzero(~samples.finite())
    if not bad.size:
        return (frames if len(previews) == len(frames.previews) else replace(frames, previews=previews)), 0, ""
    samples = Samples(*(field.copy() for field in samples))
    for row in bad.tolist():
        held = (samples.row(row - 1) if row else last_valid).hold()
        for name, values in zip(Samples._fields, samples, strict=True):
            values[row] = getattr(held, name)
        previews.pop(row, None)
    tau = float(frames.tau[bad[-1]])
    return (replace(frames, samples=samples, previews=previews), int(bad.size),
            f"non-finite sample at stream time {tau:.3f} s: holding the last valid one")


@dataclass
class Counters:
    """Samples published, held because no frame was ready (solver late) and held because a frame was not
    finite; times the stamps leapt forward (:meth:`FrameSchedule.anchored`: the clock jumped, or publishing
    fell more than the catch-up limit behind) and went back with the clock (:meth:`FrameSchedule.restamped`)."""

    published: int = 0
    held_late: int = 0
    stamp_leaps: int = 0
    held_non_finite: int = 0
    clock_resets: int = 0

    def as_dict(self) -> dict[str, int]:
        return {"published": self.published, "held_late": self.held_late, "stamp_leaps": self.stamp_leaps,
                "held_non_finite": self.held_non_finite, "clock_resets": self.clock_resets}


@dataclass
class FrameSchedule:
    """The frame buffer and sample accounting of a stream published at ``rate`` Hz (see the module)."""

    rate: int
    lookahead: int
    lead: float
    max_catch_up: float
    last_valid: ReferenceSample
    frames: deque[Frames] = field(default_factory=deque)
    next_k: int = 0
    made_k: int = 0
    made_tau: float = 0.0
    generation: int = 0
    next_preview_k: int = 0
    counters: Counters = field(default_factory=Counters)
    published: tuple[Frames, int] | None = None  # the last frames published from and the row
    fault: str = ""
    compute_wall: float = 0.0
    compute_motion: float = 0.0

    # -- making frames (worker) ------------------------------------------------------------------------

    def plan(self) -> Plan:
        """Where the worker goes on: after the last frame made (or the next one to publish, if publishing
        overtook it: the stream time goes on from made_tau, so nothing jumps)."""
        return Plan(max(self.made_k, self.next_k), self.made_tau, self.generation, self.next_preview_k, self.room)

    @property
    def room(self) -> int:
        """Frames the buffer lacks to the look-ahead."""
        return self.lookahead - (max(self.made_k, self.next_k) - self.next_k)

    @property
    def urgent_until(self) -> int:
        """The first frame beyond 1 / URGENT_PART of the look-ahead from publishing."""
        return self.next_k + self.lookahead // URGENT_PART

    def is_urgent(self, plan: Plan) -> bool:
        """Whether the frames of ``plan`` are within 1 / URGENT_PART of the look-ahead from publishing."""
        return plan.k < self.urgent_until

    def request(self, plan: Plan, count: int, horizon: float, points: int, decimation: int,
                compute_budget: float | None) -> FrameRequest:
        """What the solver makes next for ``plan`` (see :func:`make_frames`): up to ``count`` frames, with a
        ``horizon``-second preview of ``points`` points every ``decimation`` frames, after computing ahead for
        at most ``compute_budget`` s of wall time (None: unbounded); with a budget, frames within 1 /
        URGENT_PART of the look-ahead from publishing are urgent."""
        urgent_until = self.urgent_until if compute_budget is not None else plan.k
        return FrameRequest(plan, count, self.rate, horizon, points, decimation, compute_budget, urgent_until,
                            self.last_valid)

    def accept(self, batch: FrameBatch, plan: Plan) -> bool:
        """Count the solver's work and faults of ``batch``; append its frames, made for ``plan``, unless a
        command replaced the buffer meanwhile (False)."""
        self.compute_wall += batch.compute_wall
        self.compute_motion += batch.compute_motion
        self.counters.held_non_finite += batch.non_finite
        if batch.fault:
            self.fault = batch.fault
        if plan.generation != self.generation:
            return False
        frames = batch.frames
        if len(frames):
            shift = max(0, self.next_k - frames.k)  # publishing held meanwhile: continue after it
            if shift:
                frames = frames.renumbered(self.next_k)
            self.frames.append(frames)
            self.made_k, self.made_tau = frames.end, float(frames.tau[-1]) + 1.0 / self.rate
            self.next_preview_k = batch.next_preview_k + shift
            self.last_valid = frames.samples.row(len(frames) - 1)
        return True

    # -- commands -------------------------------------------------------------------------------------

    def command_point(self, accepted_ns: int | None = None, start_ns: int = 0) -> tuple[int, float]:
        """The frame a command accepted at the clock reading ``accepted_ns`` takes effect at, and its stream
        time.  While publishing (stamps from ``start_ns``, :func:`stamp_at`): the last frame stamped at most
        ``lead`` after the acceptance, so the effect comes within ``lead``, but at least the one after the
        next to publish (the next may be going out); nothing being published (``accepted_ns`` None): the next
        frame itself.  Never beyond the next frame to make."""
        free = max(self.made_k, self.next_k)  # the next frame the worker makes
        if accepted_ns is None:
            k = min(self.next_k, free)
        else:
            within_lead = (accepted_ns + round(self.lead * NANOSECONDS) - start_ns) * self.rate // NANOSECONDS
            k = min(max(self.next_k + 1, within_lead), free)
        tau = self.made_tau if k == free else next(float(f.tau[k - f.k]) for f in self.frames if f.k <= k < f.end)
        return k, tau

    def after_command(self, k: int, tau: float) -> None:
        """Drop the frames from k on: the worker makes them again from stream time tau."""
        self.frames = deque(f if f.end <= k else f.head(k - f.k) for f in self.frames if f.k < k)
        if self.frames:  # the last valid sample before k, not of the frames dropped
            self.last_valid = self.frames[-1].samples.row(len(self.frames[-1]) - 1)
        elif self.published is not None:
            self.last_valid = self.last
        self.made_k, self.made_tau = k, tau
        self.generation += 1
        self.next_preview_k = k

    # -- publishing -----------------------------------------------------------------------------------

    def anchored(self, now_ns: int, start_ns: int) -> int:
        """The start [ns] (sample k stamped start + k / rate) for the clock reading ``now_ns``: the same, unless
        the next sample is more than the catch-up limit late (the clock jumped forward, or publishing stalled),
        then the one that stamps the next sample ``now_ns``: the stamps leap forward with the clock and no
        sample is skipped, so the motion goes on without a jump.  A clock that went back keeps the start
        (nothing is due until the clock reaches the next stamp again) unless it went back beyond the catch-up
        limit, which the clock's owner reports (:meth:`restamped`)."""
        if now_ns - stamp_at(start_ns, self.next_k, self.rate) > self.max_catch_up * NANOSECONDS:
            self.counters.stamp_leaps += 1
            return now_ns - self.next_k * NANOSECONDS // self.rate
        return start_ns

    def restamped(self, now_ns: int) -> int:
        """The start [ns] that stamps the next sample ``now_ns`` after the clock jumped back beyond the catch-up
        limit (a replayed bag looped, a simulator reset): the stamps go back once, with the clock, and the motion
        goes on sample by sample (counted as a clock reset)."""
        self.counters.clock_resets += 1
        return now_ns - self.next_k * NANOSECONDS // self.rate

    def due(self, now_ns: int, start_ns: int) -> list[tuple[int, Frames | None, int]]:
        """Every sample due by ``now_ns`` with the frames it is a row of and the row (None, -1: not ready), the
        oldest first (at most the catch-up limit of them with ``start_ns`` from :meth:`anchored`)."""
        due = (now_ns - start_ns) * self.rate // NANOSECONDS
        batch: list[tuple[int, Frames | None, int]] = []
        frames = self.frames
        while self.next_k <= due:
            k = self.next_k
            while frames and frames[0].end <= k:
                frames.popleft()
            if frames and frames[0].k <= k:
                batch.append((k, frames[0], k - frames[0].k))
            else:
                batch.append((k, None, -1))
            self.next_k = k + 1
        return batch

    def outgoing(self, k: int, frames: Frames | None, row: int) -> tuple[Frames, int] | None:
        """The frames and row to publish as sample k: ``frames``' row, or the last sample published, held, if
        the frame was not ready (None before anything was published).  Counts it as published."""
        if frames is None:
            if self.published is None:
                return None
            frames, row = Frames.held(k, [math.nan], self.last), 0
            self.counters.held_late += 1
        self.published = frames, row
        self.counters.published += 1
        return self.published

    @property
    def last(self) -> ReferenceSample | None:
        """The last sample published (None before the first)."""
        if self.published is None:
            return None
        frames, row = self.published
        return frames.samples.row(row)

    @property
    def ready(self) -> int:
        """Frames made from the next one to publish on."""
        return sum(f.end - max(f.k, self.next_k) for f in self.frames if f.end > self.next_k)

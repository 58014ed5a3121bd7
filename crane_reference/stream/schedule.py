"""Which reference sample goes out when: the publishing schedule of a node, as plain logic.

Sample k of a stream published at ``rate`` Hz is stamped ``start + k / rate``
(:func:`stamp_at`) and shows the stream at publish time tau_k.
:class:`FrameSchedule` keeps the buffer of frames [next to publish ... made], made ahead of publishing
by a worker and taken by a publisher; it has no threads or locks of its own (the reference server holds them)
and no ROS types, so every rule here is tested without rclpy:

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
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from ..model.units import NANOSECONDS
from .reference_stream import ERROR, ReferenceStream
from .sample import ReferenceSample, Samples

TIME_TOLERANCE = 1e-9  # [s], rounding slack when comparing stream times
COMPUTE_MARGIN = 0.05  # [s] of motion computed beyond the preview horizon
URGENT_PART = 4  # frames within lookahead / URGENT_PART of publishing are made before their preview horizon


def stamp_at(start_ns: int, k: int, rate: int) -> int:
    """Stamp [ns] of sample k of a stream at ``rate`` Hz that starts at ``start_ns`` (exact when the rate
    divides 10^9 ns, otherwise rounded down to the nanosecond without accumulating an error)."""
    return start_ns + k * NANOSECONDS // rate


@dataclass(frozen=True)
class Frame:
    """Sample k of the reference, at stream publish time ``tau``, with its preview (or None) over
    ``horizon`` seconds."""

    k: int
    tau: float
    sample: ReferenceSample
    preview: list[ReferenceSample] | None = None
    horizon: float = 0.0


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

    frames: list[Frame]
    next_preview_k: int
    busy: bool
    compute_wall: float = 0.0
    compute_motion: float = 0.0
    non_finite: int = 0
    fault: str = ""

    def __reduce__(self):
        """Pickled with the frames' fields stacked (:class:`~.sample.Samples`): the batch crosses from the
        solver's process to the node's many times a second."""
        frames = self.frames
        previews = [(i, Samples.stack(f.preview)) for i, f in enumerate(frames) if f.preview is not None]
        packed = (np.array([f.k for f in frames], dtype=np.int64), np.array([f.tau for f in frames]),
                  np.array([f.horizon for f in frames]), Samples.stack([f.sample for f in frames]), previews)
        return _unpacked_batch, (packed, self.next_preview_k, self.busy, self.compute_wall, self.compute_motion,
                                 self.non_finite, self.fault)


def _unpacked_batch(packed, *rest) -> FrameBatch:
    """The :class:`FrameBatch` that :meth:`FrameBatch.__reduce__` packed."""
    ks, taus, horizons, samples, previews = packed
    preview_of = {i: stacked.rows() for i, stacked in previews}
    frames = [Frame(k, tau, sample, preview_of.get(i), horizon) for i, (k, tau, horizon, sample) in
              enumerate(zip(ks.tolist(), taus.tolist(), horizons.tolist(), samples.rows(), strict=True))]
    return FrameBatch(frames, *rest)


def make_frames(stream: ReferenceStream, request: FrameRequest,
                interrupted: Callable[[], bool] | None = None) -> FrameBatch:
    """The frames of ``request`` as far as the motion is computed, after computing ahead far enough for
    them and for their previews (or until ``interrupted()``: a command is waiting for the solver).  A
    frame due a preview waits until its horizon is computed, so previews keep their cadence; an urgent
    frame (just after a command) is made as soon as its own motion is computed, without the preview due to
    it if its horizon is not computed yet (the next one is due a decimation later: the cadence stays).  A
    frame that is not finite is replaced by the last valid sample held (:func:`checked`)."""
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
        stream.compute(target, request.compute_budget, interrupted)
        if math.isfinite(stream.computed_until):
            wall, motion = time.perf_counter() - start, stream.computed_until - before
    last = request.last_valid  # the last sample of the frames made so far (finite)
    if stream.state == ERROR:  # hold the last sample made, not the stream's (computed further ahead)
        return FrameBatch([Frame(plan.k + i, tau + i * dt, last.hold()) for i in range(count)], next_preview_k,
                          False, wall, motion)
    computed_until = stream.computed_until
    times = [tau + i * dt for i in range(count)]
    times = [t for t in times if t <= computed_until - TIME_TOLERANCE]
    frames: list[Frame] = []
    non_finite, fault = 0, ""
    samples = stream.samples(times)
    finite = samples.finite()
    for i, (t, sample) in enumerate(zip(times, samples.rows(), strict=True)):
        k, preview, preview_finite = plan.k + i, None, True
        if k >= next_preview_k:
            if computed_until >= t + horizon:
                stacked = stream.preview(t, horizon, request.points)
                preview, preview_finite = stacked.rows(), bool(np.all(stacked.finite()))
                next_preview_k = k + request.decimation
            elif k >= request.urgent_until:
                break  # this frame's preview is not computed yet: make it on a later call
            else:
                next_preview_k = k + request.decimation  # urgent: it goes without, the cadence stays
        frame = Frame(k, t, sample, preview, horizon)
        if not (finite[i] and preview_finite):
            frame, why = checked(frame, last)
            if why:
                non_finite, fault = non_finite + 1, why
        frames.append(frame)
        last = frame.sample
    return FrameBatch(frames, next_preview_k, computed_until < ahead, wall, motion, non_finite, fault)


def checked(frame: Frame, last_valid: ReferenceSample) -> tuple[Frame, str]:
    """``frame`` if finite (a non-finite preview dropped), else ``last_valid`` held, with the fault that says
    why ("" if none): NaN is never published."""
    if frame.sample.is_finite():
        if frame.preview is None or all(sample.is_finite() for sample in frame.preview):
            return frame, ""
        return replace(frame, preview=None), ""
    return (Frame(frame.k, frame.tau, last_valid.hold()),
            f"non-finite sample at stream time {frame.tau:.3f} s: holding the last valid one")


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
    frames: deque[Frame] = field(default_factory=deque)
    next_k: int = 0
    made_k: int = 0
    made_tau: float = 0.0
    generation: int = 0
    next_preview_k: int = 0
    counters: Counters = field(default_factory=Counters)
    last: ReferenceSample | None = None
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
        if frames and frames[0].k < self.next_k:  # publishing held meanwhile: continue after it
            frames = [replace(f, k=f.k + self.next_k - frames[0].k) for f in frames]
        if frames:
            self.frames.extend(frames)
            self.made_k, self.made_tau = frames[-1].k + 1, frames[-1].tau + 1.0 / self.rate
            self.next_preview_k = batch.next_preview_k
            self.last_valid = frames[-1].sample
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
        tau = self.made_tau if k == free else next(f.tau for f in self.frames if f.k == k)
        return k, tau

    def after_command(self, k: int, tau: float) -> None:
        """Drop the frames from k on: the worker makes them again from stream time tau."""
        self.frames = deque(f for f in self.frames if f.k < k)
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

    def due(self, now_ns: int, start_ns: int) -> list[tuple[int, Frame | None]]:
        """Every sample due by ``now_ns`` with its frame (None: not ready), the oldest first (at most the
        catch-up limit of them with ``start_ns`` from :meth:`anchored`)."""
        due = (now_ns - start_ns) * self.rate // NANOSECONDS
        batch: list[tuple[int, Frame | None]] = []
        while self.next_k <= due:
            while self.frames and self.frames[0].k < self.next_k:
                self.frames.popleft()
            ready = self.frames and self.frames[0].k == self.next_k
            batch.append((self.next_k, self.frames.popleft() if ready else None))
            self.next_k += 1
        return batch

    def outgoing(self, k: int, frame: Frame | None) -> Frame | None:
        """The frame to publish as sample k: ``frame``, or the last sample published, held, if the frame
        was not ready (None before anything was published).  Counts it as published."""
        if frame is None:
            if self.last is None:
                return None
            frame = Frame(k, math.nan, self.last.hold())
            self.counters.held_late += 1
        self.last = frame.sample
        self.counters.published += 1
        return frame


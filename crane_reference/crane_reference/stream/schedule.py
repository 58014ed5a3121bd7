"""Which reference sample goes out when: the publishing schedule of a node, as plain logic.

Sample k of a stream published at ``rate`` Hz is stamped ``start + k / rate``
(:func:`stamp_at`) and shows the stream at publish time tau_k.
:class:`FrameSchedule` keeps the buffer of frames [next to publish ... made], made ahead of publishing
by a worker and taken by a publisher; it has no threads or locks of its own (the reference server holds them)
and no ROS types, so every rule here is tested without rclpy.  Frames stay stacked (:class:`Frames`, a few
arrays a batch) from the solver to the publisher, which writes a row's numbers into the serialized messages:
no object is made per sample on the way.

* making frames (:meth:`FrameSchedule.plan`, :meth:`FrameSchedule.request`, :func:`~.frame_maker.make_frames`
  on the solver's side, :meth:`FrameSchedule.accept`): up to the look-ahead, after one slice of computing ahead,
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
from collections import deque
from dataclasses import dataclass, field

from ..model.units import NANOSECONDS
from .frames import FrameBatch, FrameRequest, Frames, Plan
from .sample import ReferenceSample

URGENT_PART = 4  # frames within lookahead / URGENT_PART of publishing are made before their preview horizon


def stamp_at(start_ns: int, k: int, rate: int) -> int:
    """Stamp [ns] of sample k of a stream at ``rate`` Hz that starts at ``start_ns`` (exact when the rate
    divides 10^9 ns, otherwise rounded down to the nanosecond without accumulating an error)."""
    return start_ns + k * NANOSECONDS // rate


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
        """What the solver makes next for ``plan`` (see :func:`~.frame_maker.make_frames`): up to ``count``
        frames, with a ``horizon``-second preview of ``points`` points every ``decimation`` frames, after computing
        ahead for at most ``compute_budget`` s of wall time (None: unbounded); with a budget, frames within 1 /
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

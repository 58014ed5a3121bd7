"""The reference server: a stream computed ahead, published on a schedule and commanded, without ROS.

A :class:`ReferenceServer` owns the publishing schedule (:class:`~.schedule.FrameSchedule`) and its stamps
(:class:`~.stamps.Stamps`), the frame worker that keeps :data:`~.ahead.LOOKAHEAD` seconds of frames ready
(:class:`~.ahead.FrameWorker`: a thread, or, without it, a caller that makes each of its requests,
:meth:`ReferenceServer.compute_ahead`, on a clock of its own: a simulation), the stream's solver (:mod:`.solver`:
in a process of its own, or in the caller's thread) and the log of its commands (:class:`~.command_log.CommandLog`).
A publisher (the ROS node, a test, a tool) only asks it what is due; a ROS node adds the clock, the messages,
parameters and services, and words their replies (:mod:`crane_reference.ros.service_replies`).

Publishing
    :meth:`ReferenceServer.begin` at a clock reading starts the stamps (sample k stamped
    ``start + k / rate``, :func:`~.schedule.stamp_at`, never before the last stamp sent), then
    :meth:`ReferenceServer.due` gives every sample due by the publisher's clock (read under the server's lock),
    stamped, and when the next one is.  A frame not ready (the solver late) is the
    last sample held; a clock that jumps forward makes the stamps leap with it (no sample skipped, the
    motion goes on), one that goes back makes nothing due until it reaches the next stamp again
    (:meth:`~.schedule.FrameSchedule.anchored`), or, beyond the catch-up limit, restarts the stamps from it once
    when the clock's owner reports the jump (:meth:`ReferenceServer.clock_went_back`); :meth:`ReferenceServer.status`
    reports each.

Commands
    :meth:`ReferenceServer.command` applies a stream command (``pause``, ``resume``,
    ``speed_scaling``; :meth:`ReferenceServer.retarget` a re-target, whose milestones are stamped when the first
    samples at or after the blend's start and end are published) at the last frame stamped within ``lead``
    seconds of its acceptance
    (at least the one after the next to publish: the effect comes at most ``lead`` after the acceptance when
    ``lead`` spans two periods), or at the next frame to make while nothing is published; the frames from
    there on are dropped at once and made again after it (the first batch in the command's own request to
    the solver), so no frame of the motion before the command is published past that point.  The status
    gives, per command, when it was accepted, the stamp it takes effect at and its margin
    (:mod:`.command_log`).
    Speed changes and pauses are C2 ramps of the stream's time warp, re-targets C2 blends.
    :meth:`ReferenceServer.restart` (back to the static-equilibrium start: a position jump) is refused
    while publishing.  A command that raises leaves the stream as it was (its frames are made again, the
    same).  Once the solver has ended or failed (:attr:`ReferenceServer.computing` false) the last sample is
    held and every request is refused (:class:`~.served.CommandRefusedError`) before it touches the frames made.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import Any

from ..model.parameters import Task
from ..model.units import NANOSECONDS
from .ahead import LOOKAHEAD, RELEASE_KEEP, URGENT_SLICE, FrameWorker
from .command_log import CommandLog
from .history import TIME_SLACK
from .reference_stream import RUNNING
from .schedule import FrameSchedule
from .served import (
    CommandPoint,
    CommandRefusedError,
    Due,
    Encoder,
    Milestone,
    Outgoing,
    Preview,
    Published,
    Restart,
    RetargetBlend,
    ServerStatus,
)
from .solver import SolverClient
from .solver_messages import StreamStatus
from .stamps import Stamps
from .stream_solver import STREAM_COMMANDS

MAX_CATCH_UP = 1.0  # [s]: if publishing falls further behind than this, the stamps leap (re-anchored)
REST_MARGIN = 1.0  # [s] :meth:`ReferenceServer.come_to_rest` waits beyond the ramp and the lead
COMMANDS = tuple(name for name in STREAM_COMMANDS if name not in ("restart", "retarget"))  # those of ``command``


class ReferenceServer:
    """See the module documentation."""

    def __init__(self, solver: SolverClient, rate: int, lead: float, preview: Preview,
                 clock: Callable[[], int] = time.monotonic_ns, worker: bool = True, encode: Encoder | None = None):
        """Serve the stream of ``solver`` at ``rate`` Hz with commands ``lead`` seconds ahead and ``preview``;
        ``clock`` [ns] times the solver's answers and the clock readings of :meth:`due`; ``encode`` makes the
        publisher's wire of each batch of frames as it comes (:data:`~.served.Encoder`).  Starts computing ahead in
        a worker thread, or, without ``worker``, leaves each request to the caller (:meth:`compute_ahead`)."""
        self.solver = solver
        self.info = solver.info
        self.rate = rate
        self.schedule = FrameSchedule(rate, max(2, math.ceil(LOOKAHEAD * rate)), lead, MAX_CATCH_UP,
                                      self.info.start)
        self._lock = threading.Condition()  # the schedule, the stamps and the log (never held while solving)
        self._stamps = Stamps(rate, clock)
        self._log = CommandLog()
        self._milestones: list[Milestone] = []  # not yet published
        self._rates_reference = (0, 0.0, 0.0, 0)
        self._worker = FrameWorker(solver, self.schedule, self._lock, self._stamps, self._log, preview, clock, encode,
                                   thread=worker)

    @property
    def stream(self) -> StreamStatus:
        """The stream's status after the last request."""
        return self.solver.status

    @property
    def commands(self) -> dict[str, str]:
        """The log of the commands (:mod:`.command_log`)."""
        with self._lock:
            return self._log.entries()

    @property
    def preview(self) -> Preview:
        """The preview the frames carry (a new one applies from the next request of frames)."""
        return self._worker.preview

    @preview.setter
    def preview(self, preview: Preview) -> None:
        with self._lock:
            self._worker.preview = preview

    @property
    def publishing(self) -> bool:
        return self._stamps.publishing

    @property
    def computing(self) -> bool:
        """Whether the server computes ahead (False once its solver ended or failed: the last sample is held,
        and commands are refused; a new server with a new solver is needed).  Without a worker thread: until
        closed (the caller meets the solver's end in :meth:`compute_ahead`)."""
        return self._worker.computing

    def check_computing(self) -> None:
        """Raise :class:`~.served.CommandRefusedError` (saying why) once the solver has stopped."""
        self._worker.check_computing()

    def compute_ahead(self, wait: bool = False) -> bool:
        """One request of the frame worker (:meth:`~.ahead.FrameWorker.compute_ahead`), for a server without a
        worker thread."""
        return self._worker.compute_ahead(wait)

    def close(self) -> None:
        """Stop computing ahead (the request in progress cut short) and end the solver."""
        self._worker.close()

    # -- publishing -----------------------------------------------------------------------------------

    def ready(self) -> bool:
        """Whether the look-ahead of frames from the next one to publish is made."""
        with self._lock:
            return self.schedule.made_k >= self.schedule.next_k + self.schedule.lookahead

    def begin(self, now_ns: int) -> None:
        """Publish from the next sample on, stamped ``now_ns`` (or one period after the last stamp sent, if
        later: stamps only increase)."""
        with self._lock:
            self._stamps.begin(now_ns, self.schedule.next_k)
            self._log.stamp_pending(self._stamps)
            self._rates_reference = (self.schedule.counters.published, self.schedule.compute_wall,
                                     self.schedule.compute_motion, now_ns)

    def end(self) -> None:
        """Stop publishing (commands then need no lead)."""
        with self._lock:
            self._stamps.end()

    def due(self, read_clock: Callable[[], int]) -> Due:
        """Every sample due by the publisher's clock (``read_clock()`` [ns], read under the server's lock, so that
        no reading taken before a jump back is used after :meth:`clock_went_back` restarted the stamps: it would
        look like a leap forward), normally one, stamped, oldest first, and the stamp of the next one."""
        with self._lock:
            now_ns = read_clock()
            if not self._stamps.publishing:
                return Due([], None, now_ns)
            out = [Outgoing(*sent) for sent in self._stamps.due(now_ns, self.schedule)]
            if self._worker.wants_frames():
                self._lock.notify()
            if self._milestones:
                self._pass_milestones(out)
            return Due(out, self._stamps.stamp_ns(self.schedule.next_k), now_ns)

    def _pass_milestones(self, out: list[Outgoing]) -> None:
        """Stamp the milestones that ``out`` reaches (the server's lock held)."""
        for milestone in self._milestones:
            milestone.stamp_ns = next((o.stamp_ns for o in out
                                       if o.frames.samples.t[o.row] >= milestone.t - TIME_SLACK), None)
        self._milestones = [milestone for milestone in self._milestones if milestone.stamp_ns is None]

    def clock_went_back(self, now_ns: int) -> None:
        """The clock jumped back (reported by its owner: rclpy's jump callback) to ``now_ns``
        (:meth:`~.stamps.Stamps.went_back`)."""
        with self._lock:
            self._stamps.went_back(now_ns, self.schedule)

    def last_sample(self) -> Published:
        """The last sample published and its stamp [ns]."""
        with self._lock:
            return Published(self.schedule.last, self._stamps.last_ns)

    def stamp_of(self, k: int) -> float:
        """Stamp [s] of sample k (relative to the start while not publishing)."""
        return self._stamps.stamp_of(k)

    # -- commands -------------------------------------------------------------------------------------

    def _at_command_point(self, name: str, accepted_ns: int, *args: Any,
                          milestones: Callable[[Any], list[Milestone]] | None = None) -> CommandPoint:
        """Send the solver the stream command ``name`` with ``args`` at the stream time tau of the command point
        (frame k: the last one stamped within ``lead`` of the acceptance
        ``accepted_ns``, at least the one after the next to publish; the next frame to make while not
        publishing); the frames from k on are dropped at once, and the first batch of them is made again in
        the same request.  Records the command's acceptance and effect, and watches the ``milestones`` of the
        solver's answer from before any frame made after the command can be published."""
        worker, stamps = self._worker, self._stamps
        worker.check_computing()
        with self._lock:
            k, tau = self.schedule.command_point(accepted_ns if stamps.publishing else None, stamps.start_ns or 0)
            self.schedule.after_command(k, tau)
            self._log.expect(name, k, stamps)
            worker.commands_pending += 1
            plan = self.schedule.plan()
            frames = worker.frame_request(plan, worker.urgent_batch, URGENT_SLICE)
        batch = None
        try:
            answer, batch = worker.request(self.solver.command, name, tau, args, frames, RELEASE_KEEP + LOOKAHEAD)
            batch = worker.encoded(batch)
        finally:
            with self._lock:
                if batch is not None:
                    watched = milestones(answer) if milestones is not None else []  # may drop earlier ones
                    self._milestones += watched
                    worker.accept(batch, plan)
                worker.commands_pending -= 1
                self._lock.notify_all()  # the worker goes on after these frames, not at the next publish
        with self._lock:
            self._log.record(name, k, tau, accepted_ns, stamps)
        return CommandPoint(k, tau, answer)

    def command(self, name: str, *args: Any, accepted_ns: int) -> int:
        """Apply the stream command ``name`` (``pause``, ``resume``, ``speed_scaling`` (rate); a re-target is
        :meth:`retarget`) at the command point of its acceptance
        at the clock reading ``accepted_ns`` [ns] (:meth:`~.schedule.FrameSchedule.command_point`).  Returns
        the sample it takes effect at.  Raises what the stream raises (the stream unchanged), or
        :class:`~.served.CommandRefusedError` once the solver has stopped."""
        if name not in COMMANDS:
            raise ValueError(f"command {name!r}: not one of {', '.join(COMMANDS)}")
        return self._at_command_point(name, accepted_ns, *args).k

    def retarget(self, targets: Task, blend_time: float, accepted_ns: int) -> RetargetBlend:
        """Re-target to ``targets`` (checked with :meth:`check_targets`) over ``blend_time`` s of motion time from
        the command point of ``accepted_ns`` (as :meth:`command`); its blend, whose milestones are stamped as the
        samples at or after its start and end are published."""
        first, end = Milestone(math.inf), Milestone(math.inf)

        def watch(start: float) -> list[Milestone]:  # the server's lock held
            first.t, end.t = start, start + blend_time
            # the path an earlier blend's milestones at or after this start marked is never published
            self._milestones = [milestone for milestone in self._milestones if milestone.t < start]
            return [first, end]

        point = self._at_command_point("retarget", accepted_ns, targets, blend_time, milestones=watch)
        return RetargetBlend(point.k, point.answer, first, end)

    def check_targets(self, targets: Task) -> None:
        """Raise :class:`~.targets.UnreachableTargetError` unless ``targets`` can be streamed from here."""
        self._worker.request(self.solver.check_targets, targets)

    def set_lead(self, seconds: float) -> None:
        with self._lock:
            self.schedule.lead = seconds

    def reach(self, radius: float, heights: tuple[float, ...]) -> tuple[float, float]:
        """The crane's reach [m] at heights above E's static one (:meth:`~.stream_solver.StreamSolver.reach`)."""
        return self._worker.request(self.solver.reach, radius, heights)

    def restart(self, accepted_ns: int = 0) -> Restart:
        """Back to the static-equilibrium start of the current targets, also out of ERROR; only while not
        publishing (:class:`~.served.CommandRefusedError`: it is a position jump).  Solver failures propagate with
        the stream unchanged."""
        if self.publishing:
            raise CommandRefusedError("a restart makes the reference jump to the start: stop publishing first")
        point = self._at_command_point("restart", accepted_ns)
        jump = abs(point.answer.start - point.answer.before)
        largest = int(jump.argmax())
        restart = Restart(point.k, float(jump[largest]), self.info.joint_names[largest], self.info.joint_units[largest])
        with self._lock:
            self.schedule.fault = ""
            self._log.restarted(restart)
        return restart

    def come_to_rest(self, accepted_ns: int, stop: threading.Event | None = None) -> bool:
        """Pause a moving stream (a speed ramp to rest) and wait, while publishing, until its first sample at
        rest is published (at most the ramp, the lead and REST_MARGIN; sooner if ``stop`` is set).  Nothing to
        do once computing ahead has stopped (the solver ended, failed or hung: the last sample is held already).
        Whether the reference is brought to rest (False: it stopped at the held sample)."""
        stream = self.stream
        if not self.computing:
            return False
        if stream.state != RUNNING or stream.target_speed <= 0.0:
            return True
        try:
            point = self._at_command_point("pause", accepted_ns)
        except CommandRefusedError:  # the solver stopped while the pause waited for it
            return False
        stream = self.stream
        rest_k = point.k + math.ceil((stream.settled_at - point.tau) * self.rate - 1e-9) + 1
        deadline = time.monotonic() + stream.ramp_time + self.schedule.lead + REST_MARGIN
        stop = stop or threading.Event()
        while self.publishing and self.schedule.next_k <= rest_k and time.monotonic() < deadline:
            if stop.wait(1.0 / self.rate):
                break
        return True

    # -- status ---------------------------------------------------------------------------------------

    def status(self, now_ns: int) -> ServerStatus:
        """The server's status at the clock reading ``now_ns``; rates since the previous call."""
        schedule = self.schedule
        with self._lock:
            published, wall, motion = schedule.counters.published, schedule.compute_wall, schedule.compute_motion
            last_published, last_wall, last_motion, last_now = self._rates_reference
            self._rates_reference = (published, wall, motion, now_ns)
            return ServerStatus(
                stream=self.stream, publishing=self.publishing, last=schedule.last,
                counters=schedule.counters.as_dict(), fault=schedule.fault, frames_ready=schedule.ready,
                commands=self._log.entries(), clock_behind=self._stamps.behind_ns / NANOSECONDS,
                clock_note=self._stamps.take_note(),
                achieved_rate=((published - last_published) * NANOSECONDS / (now_ns - last_now) if now_ns > last_now
                               else 0.0),
                real_time_factor=(motion - last_motion) / (wall - last_wall) if wall > last_wall else math.inf,
                computing=self.computing)

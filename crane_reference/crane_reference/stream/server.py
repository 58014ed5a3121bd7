"""The reference server: a stream computed ahead, published on a schedule and commanded, without ROS.

A :class:`ReferenceServer` owns the publishing schedule (:class:`~.schedule.FrameSchedule`), a worker
thread that keeps :data:`LOOKAHEAD` seconds of frames ready (or, without it, a caller that makes each of its
requests, :meth:`ReferenceServer.compute_ahead`, on a clock of its own: a simulation), and the stream's solver
(:mod:`.solver`: in a process of its own, or in the caller's thread).  A publisher (the ROS node, a test, a
tool) only asks it what is due; a ROS node adds the clock, the messages, parameters and services.

Publishing
    :meth:`ReferenceServer.begin` at a clock reading starts the stamps (sample k stamped
    ``start + k / rate``, :func:`~.schedule.stamp_at`, never before the last stamp sent), then
    :meth:`ReferenceServer.due` gives every sample due by a clock reading, stamped, and when the next one
    is.  A frame not ready (the solver late) is the
    last sample held; a clock that jumps forward makes the stamps leap with it (no sample skipped, the
    motion goes on), one that goes back makes nothing due until it reaches the next stamp again
    (:meth:`~.schedule.FrameSchedule.anchored`); :meth:`ReferenceServer.status` reports both.

Computing ahead
    The worker asks the solver for frames in batches of :data:`REFILL` seconds of stream, once that much room
    is free (half the look-ahead if less), each after at most :data:`COMPUTE_SLICE` s of computing while
    publishing (unbounded before; any other request cuts it short at the next step, the solver's stop flag, and
    goes first: the worker asks nothing more while one waits).
    Frames close to publishing (within a quarter of the look-ahead, as after a command) are urgent: made as
    soon as their own motion is computed.  A request asks for as many of them as are ready ahead of publishing
    (at least :data:`URGENT_REFILL` seconds) and computes for at most half the time those last (at least
    :data:`URGENT_SLICE` s, at most :data:`COMPUTE_SLICE`; a command's own request: :data:`URGENT_BATCH` seconds
    of them).  So each request comes back before the frames ready run out, whether its motion needs computing or
    is computed already, and the next ones are larger: the buffer grows geometrically, and a solver slowed by a
    busy machine spends less of its time on the requests' own costs.  A request also asks for twice as many
    frames as were published while the last urgent one was out, and computes for as long as that took where
    the frames ready last less: answers that come late do not keep publishing behind.
    One urgent request goes past the urgent ones, so that the next is a full one.  The worker forgets
    motion older than :data:`RELEASE_KEEP` s before the frames it asks for.  Few large requests: the solver
    computes in long runs, seldom (a compiled run after an idle gap starts with cold caches), and answers few
    round trips.  The publisher never waits for the solver: the schedule's lock is held only to move frames.

Commands
    :meth:`ReferenceServer.command` applies a stream command (``pause``, ``resume``,
    ``speed_scaling``; :meth:`ReferenceServer.retarget` a re-target, whose milestones are stamped when the first
    samples at or after the blend's start and end are published) at the last frame stamped within ``lead``
    seconds of its acceptance
    (at least the one after the next to publish: the effect comes at most ``lead`` after the acceptance when
    ``lead`` spans two periods), or at the next frame to make while nothing is published; the frames from
    there on are dropped at once and made again after it (the first batch in the command's own request to
    the solver), so no frame of the motion before the command is published past that point.  The status
    gives, per command, when it was accepted, the stamp it takes effect at and its margin: how long before
    that stamp its first frame was ready (negative: samples were held; a longer ``lead`` helps).
    Speed changes and pauses are C2 ramps of the stream's time warp, re-targets C2 blends.
    :meth:`ReferenceServer.restart` (back to the static-equilibrium start: a position jump) is refused
    while publishing.  A command that raises leaves the stream as it was (its frames are made again, the
    same).  Once the solver has ended or failed (:attr:`ReferenceServer.computing` false) the last sample is
    held and every request is refused (:class:`CommandRefusedError`) before it touches the frames made.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

from ..base.threads import start_named
from ..model.parameters import Task
from ..model.units import NANOSECONDS
from ..motion.simulation import SOLVER_FAILURES
from .frames import FrameBatch, FrameRequest, Frames, Plan
from .history import TIME_SLACK
from .reference_stream import ERROR, PAUSED, RUNNING
from .sample import ReferenceRows, ReferenceSample
from .schedule import FrameSchedule, stamp_at
from .solver import STREAM_COMMANDS, SolverClient, SolverStoppedError, StreamStatus

LOOKAHEAD = 2.0  # [s] of frames kept ready ahead of publishing
COMPUTE_SLICE = 0.25  # [s] of wall time the solver computes per request while publishing (a command cuts it short)
URGENT_SLICE = 0.005  # [s] of wall time at least per request for frames close to publishing (after a command)
REFILL = 1.0  # [s] of frames made per request, and the room the worker waits for to ask again
URGENT_BATCH = 0.005  # [s] of stream (at least one frame) made in a command's own request
URGENT_REFILL = 0.05  # [s] of stream (at least one frame) asked for at least per request close to publishing
RELEASE_KEEP = 1.0  # [s] of computed motion kept before the next frame to make (for commands)
MAX_CATCH_UP = 1.0  # [s]: if publishing falls further behind than this, the stamps leap (re-anchored)
REST_MARGIN = 1.0  # [s] :meth:`ReferenceServer.come_to_rest` waits beyond the ramp and the lead
COMMANDS = tuple(name for name in STREAM_COMMANDS if name not in ("restart", "retarget"))  # those of ``command``


class CommandRefusedError(RuntimeError):
    """A command that the server's state does not allow (the message says why)."""


@dataclass(frozen=True)
class Preview:
    """A preview of ``points`` samples after the frame's own over ``horizon`` seconds, every ``decimation`` frames."""

    horizon: float
    points: int
    decimation: int


class Outgoing(NamedTuple):
    """Sample k to publish, stamped ``stamp_ns``: row ``row`` of ``frames`` (made by the solver, or the last one
    published, held)."""

    k: int
    stamp_ns: int
    frames: Frames
    row: int


class Due(NamedTuple):
    """What :meth:`ReferenceServer.due` hands the publisher: the samples to publish now, oldest first, and the
    stamp [ns] of the next one (None while not publishing)."""

    outgoing: list[Outgoing]
    next_stamp_ns: int | None


@dataclass(frozen=True)
class Restart:
    """A restart at sample k: the largest position change, the joint it is on and its unit (rad, or m for a
    prismatic joint)."""

    k: int
    jump: float
    joint: str
    unit: str


class Published(NamedTuple):
    """The last sample published (None before the first) and its stamp [ns]."""

    sample: ReferenceSample | None
    stamp_ns: int


class CommandPoint(NamedTuple):
    """Where a command takes effect: sample k, at stream time tau [s], and the solver's answer to it."""

    k: int
    tau: float
    answer: Any


class Milestone:
    """The first sample published at or after motion time ``t`` [s]: its stamp [ns] once published, else None."""

    def __init__(self, t: float) -> None:
        self.t = t
        self.stamp_ns: int | None = None


class RetargetBlend(NamedTuple):
    """A re-target's blend (:meth:`ReferenceServer.retarget`): its command point k, the motion time [s] it begins
    at, and the milestones of its start and its end (the first sample on the new path)."""

    k: int
    start: float
    first: Milestone
    end: Milestone


@dataclass(frozen=True)
class Reply:
    """The answer to a request of the node's services: whether it was done, and what was done or why not."""

    success: bool
    message: str


@dataclass(frozen=True)
class ServerStatus:
    """A snapshot for diagnostics: the stream's status, whether publishing, the last sample sent, the
    counters, the fault, frames ready, each command's acceptance time and the stamp it takes effect at
    [s], the last restart, how far the clock is behind the last stamp [s] (it went back), a note on a
    forward jump of the clock since the last snapshot, the achieved publish rate [Hz], the solver's
    real-time factor since the last snapshot and whether the server still computes ahead."""

    stream: StreamStatus
    publishing: bool
    last: ReferenceSample | None
    counters: dict[str, int]
    fault: str
    frames_ready: int
    commands: dict[str, str] = field(default_factory=dict)
    clock_behind: float = 0.0
    clock_note: str = ""
    achieved_rate: float = 0.0
    real_time_factor: float = math.inf
    computing: bool = True


class ReferenceServer:
    """See the module documentation."""

    def __init__(self, solver: SolverClient, rate: int, lead: float, preview: Preview,
                 clock: Callable[[], int] = time.monotonic_ns, worker: bool = True):
        """Serve the stream of ``solver`` at ``rate`` Hz with commands ``lead`` seconds ahead and ``preview``;
        ``clock`` [ns] times the solver's answers and the clock readings of :meth:`due`.  Starts computing ahead
        in a worker thread, or, without ``worker``, leaves each request to the caller (:meth:`compute_ahead`: a
        simulation on its own clock)."""
        self.solver = solver
        self._clock = clock
        self.info = solver.info
        self.rate = rate
        self.preview = preview
        self.schedule = FrameSchedule(rate, max(2, math.ceil(LOOKAHEAD * rate)), lead, MAX_CATCH_UP,
                                      self.info.start)
        self._urgent_batch = max(1, round(URGENT_BATCH * rate))
        self._urgent_refill = max(1, round(URGENT_REFILL * rate))
        self._refill = min(max(1, round(REFILL * rate)), max(1, self.schedule.lookahead // 2))
        self._clock_seen = (0, 0)  # the last clock reading [ns] of due() and the monotonic time [ns] of it
        self._lock = threading.Condition()  # the schedule and the counters here (never held while solving)
        self._solver_lock = threading.Lock()  # one request at a time, and commands against frame requests
        self._halt = threading.Event()
        self._commands_pending = 0
        self._requests_waiting = 0  # requests other than the worker's waiting for the solver (they come first)
        self._urgent_took = 0.0  # [s] from asking to receiving, of the last request if urgent (else 0)
        self._start_ns: int | None = None
        self._last_stamp = 0
        self._clock_behind = 0
        self._clock_note = ""
        self._commands: dict[str, str] = {}
        self._awaiting: dict[str, int] = {}  # command -> its first frame, until made
        self._unstamped: dict[str, int] = {}  # command made while not publishing -> its frame, stamped at begin
        self._milestones: list[Milestone] = []  # not yet published
        self._rates_reference = (0, 0.0, 0.0, 0)
        self.encode: Callable[[ReferenceRows], Any] | None = None
        """What the publisher makes of a batch's samples at once (its messages, a row a sample), set by it: made
        in the thread that receives the batch, outside the lock, and kept as the frames' ``wire``."""
        self._worker = start_named(self._work, "ref_frames") if worker else None

    @property
    def stream(self) -> StreamStatus:
        """The stream's status after the last request."""
        return self.solver.status

    @property
    def commands(self) -> dict[str, str]:
        """Each command's acceptance time, the stamp it takes effect at [s] and the stream time of that sample
        (``{name}_accepted_s``, ``{name}_stamp_s``, ``{name}_stream_time_s``, the last exact: it locates the
        command in a recording or an offline run), and the last restart's jump (``restart_jump_rad``,
        ``restart_jump_joint``)."""
        with self._lock:
            return dict(self._commands)

    @property
    def publishing(self) -> bool:
        return self._start_ns is not None

    def close(self) -> None:
        """Stop computing ahead (the request in progress cut short) and end the solver."""
        self._halt.set()
        self.solver.interrupt()
        with self._lock:
            self._lock.notify_all()
        if self._worker is not None and self._worker is not threading.current_thread():
            self._worker.join()
        self.solver.close()

    # -- computing ahead (worker thread) --------------------------------------------------------------

    def _work(self) -> None:
        """Keep LOOKAHEAD of frames ready ahead of publishing and the motion computed beyond them."""
        try:
            while not self._halt.is_set():
                self.compute_ahead(wait=True)
        except SolverStoppedError as error:
            if not self._halt.is_set():
                with self._lock:
                    self.schedule.fault = str(error)
        except Exception as error:  # publishing goes on (holding) and reports it
            with self._lock:
                self.schedule.fault = f"solver thread stopped: {type(error).__name__}: {error}"

    def compute_ahead(self, wait: bool = False) -> bool:
        """One request of frames for the schedule's plan (the worker's step): urgent ones close to publishing,
        else a batch once there is room for one.  Whether it made frames or was cut short (False: nothing to do
        until publishing frees room or a command comes; with ``wait``, waits for that or LOOKAHEAD, and for the
        requests of commands to go first)."""
        schedule = self.schedule
        with self._lock:
            while wait and (self._commands_pending or self._requests_waiting) and not self._halt.is_set():
                self._lock.wait(timeout=LOOKAHEAD)  # frames after a command once it is applied
            plan = schedule.plan()
            # in batches, but up to the whole look-ahead before publishing starts
            refill = plan.room >= self._refill or not self.publishing
            urgent = self.publishing and schedule.is_urgent(plan)
            if urgent:
                request = self._frame_request(plan, *self._urgent_request(plan.k - schedule.next_k))
            else:
                request = self._frame_request(plan, self._refill * refill, COMPUTE_SLICE)
        with self._solver_lock:
            if plan.generation != schedule.generation:  # a command came in meanwhile: plan again
                return True
            asked = self._clock()
            batch = self.solver.frames(request, RELEASE_KEEP + LOOKAHEAD)
        batch = self._encoded(batch)  # a command need not wait for it
        with self._lock:
            self._urgent_took = (self._clock() - asked) / NANOSECONDS if urgent else 0.0
            idle = self._accept(batch, plan) and not len(batch.frames) and not batch.busy
            if idle and wait:
                self._lock.wait(timeout=LOOKAHEAD)
            return not idle

    def _urgent_request(self, ready: int) -> tuple[int, float]:
        """How many urgent frames the worker asks for, ``ready`` frames being ready ahead of publishing, and for
        how long [s] the solver may compute for them: as many as are ready, at least URGENT_REFILL seconds of
        them and twice as many as the last urgent request took to come back; for half the time the ready ones
        last (at least URGENT_SLICE, at most COMPUTE_SLICE), or, if they last less than that request took (samples
        will be held whatever the request), as long as it took.  So a request brings more frames than are
        published meanwhile even where its fixed costs (the round trip to the solver, a busy machine's
        scheduling) outweigh its computing."""
        took = self._urgent_took
        outlasted = took if ready < took * self.rate else 0.0  # the frames ready run out before an answer
        return (max(self._urgent_refill, ready, math.ceil(2.0 * took * self.rate)),
                min(COMPUTE_SLICE, max(URGENT_SLICE, 0.5 * ready / self.rate, outlasted)))

    def _encoded(self, batch: FrameBatch) -> FrameBatch:
        """``batch`` with its frames' wire made (:attr:`encode`), if there are frames and an encoder."""
        encode = self.encode
        if encode is None or not len(batch.frames):
            return batch
        return replace(batch, frames=replace(batch.frames, wire=encode(batch.frames.samples)))

    def _frame_request(self, plan: Plan, count: int, budget: float) -> FrameRequest:
        """The solver's next request for ``plan`` (the server's lock held): up to ``count`` frames, after at most
        ``budget`` seconds of computing while publishing (unbounded before)."""
        preview = self.preview
        return self.schedule.request(plan, min(plan.room, count), preview.horizon,
                                     preview.points, preview.decimation,
                                     budget if self.publishing else None)

    def _accept(self, batch: FrameBatch, plan: Plan) -> bool:
        """Take the frames of ``batch`` made for ``plan`` (the server's lock held; False if a command replaced
        them meanwhile); a command whose first frame is now made gets its margin: how long before that
        frame is due it was ready, at least (negative: samples were held)."""
        accepted = self.schedule.accept(batch, plan)
        for name, k in list(self._awaiting.items()):
            if self._start_ns is None:
                del self._awaiting[name]
            elif self.schedule.made_k > k:
                seen_ns, seen_at = self._clock_seen  # the clock now, assuming it runs at the wall clock's rate
                now_ns = seen_ns + self._clock() - seen_at
                margin = (stamp_at(self._start_ns, k, self.rate) - now_ns) / NANOSECONDS
                self._commands[f"{name}_margin_s"] = f"{margin:.6f}"
                del self._awaiting[name]
        return accepted

    # -- publishing -----------------------------------------------------------------------------------

    def ready(self) -> bool:
        """Whether the look-ahead of frames from the next one to publish is made."""
        with self._lock:
            return self.schedule.made_k >= self.schedule.next_k + self.schedule.lookahead

    def begin(self, now_ns: int) -> None:
        """Publish from the next sample on, stamped ``now_ns`` (or one period after the last stamp sent, if
        later: stamps only increase)."""
        with self._lock:
            start = max(now_ns, self._last_stamp + NANOSECONDS // self.rate)
            self._start_ns = start - self.schedule.next_k * NANOSECONDS // self.rate
            for name, k in self._unstamped.items():  # their stamps are known from now on
                self._commands[f"{name}_stamp_s"] = f"{self.stamp_of(k):.6f}"
            self._unstamped.clear()
            self._rates_reference = (self.schedule.counters.published, self.schedule.compute_wall,
                                     self.schedule.compute_motion, now_ns)

    def end(self) -> None:
        """Stop publishing (commands then need no lead)."""
        with self._lock:
            self._start_ns = None

    def due(self, now_ns: int) -> Due:
        """Every sample due by the clock reading ``now_ns`` [ns] (normally one), stamped, oldest first, and the
        stamp of the next one."""
        schedule = self.schedule
        with self._lock:
            if self._start_ns is None:
                return Due([], None)
            start = schedule.anchored(now_ns, self._start_ns)
            if start != self._start_ns:
                self._clock_note = (f"ROS time jumped {(start - self._start_ns) / NANOSECONDS:.3f} s ahead of the "
                                    "schedule: the stamps leap with it, no sample skipped")
                self._start_ns = start
            self._clock_seen = (now_ns, self._clock())
            behind = self._last_stamp - now_ns
            self._clock_behind = behind if behind > NANOSECONDS // self.rate else 0
            batch = schedule.due(now_ns, start)
            if schedule.room >= self._refill:
                self._lock.notify()
            out = []
            for k, frames, row in batch:
                sent = schedule.outgoing(k, frames, row)
                if sent is not None:
                    self._last_stamp = stamp_at(start, k, self.rate)
                    out.append(Outgoing(k, self._last_stamp, *sent))
            if self._milestones:
                self._pass_milestones(out)
            return Due(out, stamp_at(start, schedule.next_k, self.rate))

    def _pass_milestones(self, out: list[Outgoing]) -> None:
        """Stamp the milestones that ``out`` reaches (the server's lock held)."""
        for milestone in self._milestones:
            milestone.stamp_ns = next((o.stamp_ns for o in out
                                       if o.frames.samples.t[o.row] >= milestone.t - TIME_SLACK), None)
        self._milestones = [milestone for milestone in self._milestones if milestone.stamp_ns is None]

    def clock_went_back(self, now_ns: int) -> None:
        """The clock jumped back (reported by its owner: rclpy's jump callback) to ``now_ns``: beyond the
        catch-up limit behind the next stamp, publishing goes on on the new timeline, the next sample stamped
        ``now_ns`` (:meth:`~.schedule.FrameSchedule.restamped`: stamps go back once, counted, announced); within
        it, publishing waits until the clock reaches the next stamp again."""
        with self._lock:
            if self._start_ns is None:
                return
            behind = stamp_at(self._start_ns, self.schedule.next_k, self.rate) - now_ns
            if behind <= self.schedule.max_catch_up * NANOSECONDS:
                return
            self._start_ns = self.schedule.restamped(now_ns)
            self._last_stamp = now_ns - NANOSECONDS // self.rate
            self._clock_note = (f"ROS time went back {behind / NANOSECONDS:.3f} s: the stamps restart from it "
                                "(once), no sample skipped")

    def last_sample(self) -> Published:
        """The last sample published and its stamp [ns]."""
        with self._lock:
            return Published(self.schedule.last, self._last_stamp)

    def stamp_of(self, k: int) -> float:
        """Stamp [s] of sample k (relative to the start while not publishing)."""
        return stamp_at(self._start_ns or 0, k, self.rate) / NANOSECONDS

    def sample_named(self, k: int) -> str:
        """Sample k as a reply names it: by its stamp while publishing, else by its number (its stamp is given
        when publishing begins)."""
        if self.publishing:
            return f"the sample stamped {self.stamp_of(k):.6f} s"
        return f"sample {k} of the stream (stamped once published)"

    # -- commands -------------------------------------------------------------------------------------

    def _at_command_point(self, name: str, accepted_ns: int, *args: Any,
                          milestones: Callable[[Any], list[Milestone]] | None = None) -> CommandPoint:
        """Send the solver the stream command ``name`` with ``args`` at the stream time tau of the command point
        (frame k: the last one stamped within ``lead`` of the acceptance
        ``accepted_ns``, at least the one after the next to publish; the next frame to make while not
        publishing); the frames from k on are dropped at once, and the first batch of them is made again in
        the same request.  Records the command's acceptance and effect, and watches the ``milestones`` of the
        solver's answer from before any frame made after the command can be published."""
        self.check_computing()
        with self._lock:
            k, tau = self.schedule.command_point(accepted_ns if self.publishing else None, self._start_ns or 0)
            self.schedule.after_command(k, tau)
            self._commands.pop(f"{name}_margin_s", None)
            if self.publishing:
                self._awaiting[name] = k
            self._commands_pending += 1
            plan = self.schedule.plan()
            frames = self._frame_request(plan, self._urgent_batch, URGENT_SLICE)
        batch = None
        try:
            answer, batch = self._request(self.solver.command, name, tau, args, frames, RELEASE_KEEP + LOOKAHEAD)
            batch = self._encoded(batch)
        finally:
            with self._lock:
                if batch is not None:
                    watched = milestones(answer) if milestones is not None else []  # may drop earlier ones
                    self._milestones += watched
                    self._accept(batch, plan)
                self._commands_pending -= 1
                self._lock.notify_all()  # the worker goes on after these frames, not at the next publish
        with self._lock:
            if self.publishing:
                self._commands[f"{name}_stamp_s"] = f"{self.stamp_of(k):.6f}"
            else:  # stamped when publishing begins (:meth:`begin`)
                self._commands.pop(f"{name}_stamp_s", None)
                self._unstamped[name] = k
            self._commands[f"{name}_accepted_s"] = f"{accepted_ns / NANOSECONDS:.6f}"
            self._commands[f"{name}_stream_time_s"] = repr(tau)
        return CommandPoint(k, tau, answer)

    @property
    def computing(self) -> bool:
        """Whether the server computes ahead (False once its solver ended or failed: the last sample is held,
        and commands are refused; a new server with a new solver is needed).  Without a worker thread: until
        closed (the caller meets the solver's end in :meth:`compute_ahead`)."""
        return self._worker.is_alive() if self._worker is not None else not self._halt.is_set()

    def check_computing(self) -> None:
        """Raise :class:`CommandRefusedError` (saying why) once the solver has stopped."""
        if not self.computing:
            raise CommandRefusedError(f"the solver stopped ({self.schedule.fault or 'closed'}): start a new one")

    def _request(self, request: Callable[..., Any], *args: Any) -> Any:
        """The answer to ``request(*args)`` (a method of the solver client), one request at a time;
        :class:`CommandRefusedError` if the solver has stopped."""
        self.check_computing()
        with self._lock:
            self._requests_waiting += 1  # the worker asks nothing more meanwhile
        try:
            self.solver.interrupt()  # the worker's request in progress stops at its next step
            with self._solver_lock:
                return request(*args)
        except SolverStoppedError as error:
            raise CommandRefusedError(f"the solver stopped ({error}): start a new one") from error
        finally:
            with self._lock:
                self._requests_waiting -= 1
                self._lock.notify_all()

    def command(self, name: str, *args: Any, accepted_ns: int) -> int:
        """Apply the stream command ``name`` (``pause``, ``resume``, ``speed_scaling`` (rate); a re-target is
        :meth:`retarget`) at the command point of its acceptance
        at the clock reading ``accepted_ns`` [ns] (:meth:`~.schedule.FrameSchedule.command_point`).  Returns
        the sample it takes effect at.  Raises what the stream raises (the stream unchanged), or
        :class:`CommandRefusedError` once the solver has stopped."""
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
        self._request(self.solver.check_targets, targets)

    def set_blend_time(self, seconds: float) -> None:
        self._request(self.solver.set_blend_time, seconds)

    def set_lead(self, seconds: float) -> None:
        with self._lock:
            self.schedule.lead = seconds

    def reach(self, radius: float, heights: tuple[float, ...]) -> tuple[float, float]:
        """The crane's reach [m] at heights above E's static one (:meth:`~.solver.StreamSolver.reach`)."""
        return self._request(self.solver.reach, radius, heights)

    def restart(self, accepted_ns: int = 0) -> Restart:
        """Back to the static-equilibrium start of the current targets, also out of ERROR; only while not
        publishing (:class:`CommandRefusedError`: it is a position jump).  Solver failures propagate with the
        stream unchanged."""
        if self.publishing:
            raise CommandRefusedError("a restart makes the reference jump to the start: stop publishing first")
        point = self._at_command_point("restart", accepted_ns)
        jump = abs(point.answer.start - point.answer.before)
        largest = int(jump.argmax())
        restart = Restart(point.k, float(jump[largest]), self.info.joint_names[largest], self.info.joint_units[largest])
        with self._lock:
            self.schedule.fault = ""
            self._commands.update(restart_jump_rad=f"{restart.jump:.6g}", restart_jump_joint=restart.joint)
        return restart

    def restart_reply(self, accepted_ns: int) -> Reply:
        """:meth:`restart` as ~/restart answers: how far the position jumps, or why the stream is unchanged."""
        try:
            restart = self.restart(accepted_ns)
        except (*SOLVER_FAILURES, CommandRefusedError) as error:
            return Reply(False, f"restart failed, stream unchanged: {error}")
        return Reply(True, f"restarted from the static equilibrium at sample {restart.k}, published once active: "
                           f"position jump up to {restart.jump:.6g} {restart.unit} on {restart.joint}")

    def pause(self, hold: bool, accepted_ns: int) -> Reply:
        """~/pause: ``hold`` brings the reference to rest along the speed ramp and holds it there, else it resumes;
        done already if the stream is so; refused once computing ahead stopped or in ERROR (with the remedy)."""
        stream = self.stream
        if not self.computing:
            return Reply(False, "the solver stopped; deactivate, cleanup, configure and activate start a new one")
        if stream.state == ERROR:
            return Reply(False, f"the stream is in ERROR ({stream.last_error}); deactivate, call ~/restart and "
                                "activate")
        if stream.state == (PAUSED if hold else RUNNING):
            return Reply(True, f"already {stream.state.lower()}")
        k = self.command("pause" if hold else "resume", accepted_ns=accepted_ns)
        verb = "coming to rest" if hold else "resuming"
        return Reply(True, f"{verb} from {self.sample_named(k)} over {self.stream.ramp_time:g} s")

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
            note, self._clock_note = self._clock_note, ""
            return ServerStatus(
                stream=self.stream, publishing=self.publishing, last=schedule.last,
                counters=schedule.counters.as_dict(), fault=schedule.fault, frames_ready=schedule.ready,
                commands=dict(self._commands), clock_behind=self._clock_behind / NANOSECONDS, clock_note=note,
                achieved_rate=((published - last_published) * NANOSECONDS / (now_ns - last_now) if now_ns > last_now
                               else 0.0),
                real_time_factor=(motion - last_motion) / (wall - last_wall) if wall > last_wall else math.inf,
                computing=self.computing)

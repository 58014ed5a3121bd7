"""Computing ahead: the frame worker of the reference server, which keeps the schedule's look-ahead of frames made.

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

Without a thread of its own, each request is the caller's (:meth:`FrameWorker.compute_ahead`: a simulation on a
clock of its own).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from ..base.threads import start_named
from ..model.units import NANOSECONDS
from .command_log import CommandLog
from .frames import FrameBatch, FrameRequest, Plan
from .schedule import FrameSchedule
from .served import CommandRefusedError, Encoder, Preview
from .solver import SolverClient
from .solver_messages import SolverStoppedError
from .stamps import Stamps

LOOKAHEAD = 2.0  # [s] of frames kept ready ahead of publishing
COMPUTE_SLICE = 0.25  # [s] of wall time the solver computes per request while publishing (a command cuts it short)
URGENT_SLICE = 0.005  # [s] of wall time at least per request for frames close to publishing (after a command)
REFILL = 1.0  # [s] of frames made per request, and the room the worker waits for to ask again
URGENT_BATCH = 0.005  # [s] of stream (at least one frame) made in a command's own request
URGENT_REFILL = 0.05  # [s] of stream (at least one frame) asked for at least per request close to publishing
RELEASE_KEEP = 1.0  # [s] of computed motion kept before the next frame to make (for commands)


class FrameWorker:
    """Makes the frames of ``schedule`` with ``solver`` (see the module documentation).  Shares ``lock`` with the
    server (the schedule, ``stamps`` and ``log`` are read and changed only under it); ``clock`` [ns] times the
    solver's answers; ``encode`` makes the publisher's wire of each batch."""

    def __init__(self, solver: SolverClient, schedule: FrameSchedule, lock: threading.Condition, stamps: Stamps,
                 log: CommandLog, preview: Preview, clock: Callable[[], int], encode: Encoder | None, thread: bool):
        self.solver, self.schedule, self.preview = solver, schedule, preview
        self._lock, self._stamps, self._log, self._clock, self._encode = lock, stamps, log, clock, encode
        rate = schedule.rate
        self.urgent_batch = max(1, round(URGENT_BATCH * rate))
        self._urgent_refill = max(1, round(URGENT_REFILL * rate))
        self._refill = min(max(1, round(REFILL * rate)), max(1, schedule.lookahead // 2))
        self._solver_lock = threading.Lock()  # one request at a time, and commands against frame requests
        self._halt = threading.Event()
        self.commands_pending = 0
        """Commands between their command point and their first frames (the worker waits for them)."""
        self._requests_waiting = 0  # requests other than the worker's waiting for the solver (they come first)
        self._urgent_took = 0.0  # [s] from asking to receiving, of the last request if urgent (else 0)
        self._thread = start_named(self._work, "ref_frames") if thread else None

    def wants_frames(self) -> bool:
        """Whether publishing has freed room for a batch (the lock held; the caller then notifies the worker)."""
        return self.schedule.room >= self._refill

    @property
    def computing(self) -> bool:
        """Whether frames are still made (False once the solver ended or failed; without a thread of its own:
        until closed)."""
        return self._thread.is_alive() if self._thread is not None else not self._halt.is_set()

    def check_computing(self) -> None:
        """Raise :class:`~.served.CommandRefusedError` (saying why) once the solver has stopped."""
        if not self.computing:
            raise CommandRefusedError(f"the solver stopped ({self.schedule.fault or 'closed'}): start a new one")

    def close(self) -> None:
        """Stop computing ahead (the request in progress cut short) and end the solver."""
        self._halt.set()
        self.solver.interrupt()
        with self._lock:
            self._lock.notify_all()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join()
        self.solver.close()

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
            while wait and (self.commands_pending or self._requests_waiting) and not self._halt.is_set():
                self._lock.wait(timeout=LOOKAHEAD)  # frames after a command once it is applied
            plan, publishing = schedule.plan(), self._stamps.publishing
            # in batches, but up to the whole look-ahead before publishing starts
            refill = plan.room >= self._refill or not publishing
            urgent = publishing and schedule.is_urgent(plan)
            if urgent:
                request = self.frame_request(plan, *self._urgent_request(plan.k - schedule.next_k))
            else:
                request = self.frame_request(plan, self._refill * refill, COMPUTE_SLICE)
        with self._solver_lock:
            if plan.generation != schedule.generation:  # a command came in meanwhile: plan again
                return True
            asked = self._clock()
            batch = self.solver.frames(request, RELEASE_KEEP + LOOKAHEAD)
        batch = self.encoded(batch)  # a command need not wait for it
        with self._lock:
            self._urgent_took = (self._clock() - asked) / NANOSECONDS if urgent else 0.0
            idle = self.accept(batch, plan) and not len(batch.frames) and not batch.busy
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
        took, rate = self._urgent_took, self.schedule.rate
        outlasted = took if ready < took * rate else 0.0  # the frames ready run out before an answer
        return (max(self._urgent_refill, ready, math.ceil(2.0 * took * rate)),
                min(COMPUTE_SLICE, max(URGENT_SLICE, 0.5 * ready / rate, outlasted)))

    def encoded(self, batch: FrameBatch) -> FrameBatch:
        """``batch`` with its frames' wire made by the publisher's encoder, if there are frames and an encoder."""
        if self._encode is None or not len(batch.frames):
            return batch
        return replace(batch, frames=replace(batch.frames, wire=self._encode(batch.frames.samples)))

    def frame_request(self, plan: Plan, count: int, budget: float) -> FrameRequest:
        """The solver's next request for ``plan`` (the lock held): up to ``count`` frames, after at most
        ``budget`` seconds of computing while publishing (unbounded before)."""
        preview = self.preview
        return self.schedule.request(plan, min(plan.room, count), preview.horizon, preview.points,
                                     preview.decimation, budget if self._stamps.publishing else None)

    def accept(self, batch: FrameBatch, plan: Plan) -> bool:
        """Take the frames of ``batch`` made for ``plan`` (the lock held; False if a command replaced them
        meanwhile); the commands whose first frames are now made get their margins."""
        accepted = self.schedule.accept(batch, plan)
        self._log.frames_made(self.schedule.made_k, self._stamps)
        return accepted

    def request(self, request: Callable[..., Any], *args: Any) -> Any:
        """The answer to ``request(*args)`` (a method of the solver client), before the worker's next request
        (its request in progress cut short); :class:`~.served.CommandRefusedError` if the solver has stopped."""
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

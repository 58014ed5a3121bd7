"""The caller's side of the stream's solver, in the caller's thread or in a process of its own.

:class:`~.stream_solver.StreamSolver` owns a :class:`~.reference_stream.ReferenceStream` and answers the requests
of a reference server (:mod:`.server`): frames to make (:func:`~.frame_maker.make_frames`), commands applied at a
stream time, target checks, the crane's reach.  Two clients carry the requests to it, with the methods of
:class:`SolverClient` (each returns the result and keeps the stream's
:class:`~.solver_messages.StreamStatus` of the reply; a request names the solver's method itself, which pickles
by reference, never a string):

* :class:`LocalSolver` calls it in the caller's thread (tests, tools);
* :class:`SolverProcess` runs it in a child process (``python -m crane_reference.stream.stream_solver``: a fresh
  interpreter that imports no ROS and not the caller's main module), so the integrator's Python parts never
  wait for, or delay, a publisher's thread behind Python's GIL.  Requests and replies are pickled over two
  pipes; an exception raised by the solver is raised again in the caller.

Both clients have :meth:`interrupt`: a caller with a command waiting for the solver cuts the request in
progress short, so the command waits for one integrator step of computing ahead or one chunk of frames, not a
whole slice (:func:`~.frame_maker.make_frames` returns the urgent frames made so far, and no others).  It sets
the solver's stop flag (:func:`~crane_reference.motion.integration.stop_flag`), which the compiled runs read at
every step; the process's flag is a byte of memory shared with the caller.  The flag is cleared before any
request but a frame request (so a command's own frames are made whole), and after a frame request (an
interrupt that came while the request was on its way ended it; the reference server asks no more frames
while another request waits, so that one comes next).

The child runs in a session of its own and ignores SIGINT (a Ctrl-C is the caller's to handle), and exits when
its request pipe closes, also if the caller dies.  It runs at a lower scheduling priority
(:data:`~.stream_solver.SOLVER_NICENESS`): it computes seconds of frames ahead and can wait, the caller's publisher
cannot.

A hung solver.  The child beats a counter in the shared memory every :data:`HEARTBEAT_PERIOD` from a thread of
its own, beside the kernels (which run without Python's lock).  A live solver always answers: each Newton
iteration, projection and compiled run of it is bounded.  So a caller waiting for a reply that sees no beat for
:data:`HUNG_AFTER` holds the process hung (stopped by a signal or a debugger, swapped out, stuck holding
Python's lock), kills and reaps it and raises :class:`SolverHungError` (a :class:`SolverStoppedError`: the
server holds the last sample and reports it).  The bound is not applied while the process starts (compiling
the kernels can hold Python's lock for seconds), and :meth:`SolverProcess.close` kills a process that gives no
beat for :data:`HUNG_AFTER` instead of waiting out its timeout.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from ..model.parameters import Task
from . import stream_solver
from .frames import FrameBatch, FrameRequest
from .solver_messages import (
    HEARTBEAT_PERIOD,
    HUNG_AFTER,
    SHARED_BYTES,
    SolverHungError,
    SolverStoppedError,
    StreamInfo,
    StreamSpec,
    StreamStatus,
    shared_memory,
)
from .stream_solver import STREAM_COMMANDS, StreamSolver

POLL_PERIOD = 0.1  # [s] between checks of the caller's stop flag while it waits for the solver process


class SolverClient:
    """The requests a reference server makes of a :class:`StreamSolver`; a client carries each to it
    (:meth:`_call`) and keeps :attr:`status`, the stream's after the last reply."""

    info: StreamInfo
    status: StreamStatus

    def _call(self, method: Callable[..., Any], *args: Any) -> Any:
        """``method(solver, *args)`` for the solver's own ``method``."""
        raise NotImplementedError

    def frames(self, request: FrameRequest, keep: float) -> FrameBatch:
        """:meth:`StreamSolver.frames`."""
        return self._call(StreamSolver.frames, request, keep)

    def command(self, name: str, tau: float, args: tuple, request: FrameRequest, keep: float
                ) -> tuple[Any, FrameBatch]:
        """:meth:`StreamSolver.command` of the command ``name`` (a key of :data:`STREAM_COMMANDS`)."""
        return self._call(StreamSolver.command, STREAM_COMMANDS[name], tau, args, request, keep)

    def check_targets(self, targets: Task) -> None:
        """:meth:`StreamSolver.check_targets`."""
        self._call(StreamSolver.check_targets, targets)

    def reach(self, radius: float, heights: tuple[float, ...]) -> tuple[float, float]:
        """:meth:`StreamSolver.reach`."""
        return self._call(StreamSolver.reach, radius, heights)

    def refresh_status(self) -> StreamStatus:
        """The stream's status now (:attr:`status` updated)."""
        return self._call(StreamSolver.status)

    def interrupt(self) -> None:
        """Cut the request in progress short (see the module)."""
        raise NotImplementedError

    def close(self) -> None:
        """Release the solver."""
        raise NotImplementedError


class LocalSolver(SolverClient):
    """A :class:`StreamSolver` called in the caller's thread."""

    def __init__(self, spec: StreamSpec):
        self.solver = StreamSolver(spec)
        self.info = self.solver.info()
        self.status = self.solver.status()

    def interrupt(self) -> None:
        """Cut the call in progress short (see the module)."""
        self.solver.stop[0] = 1

    def _call(self, method: Callable[..., Any], *args: Any) -> Any:
        """``method(solver, *args)`` (:meth:`StreamSolver.call`); :attr:`status` is the stream's after it (also
        if it raised)."""
        try:
            return self.solver.call(method, *args)
        finally:
            self.status = self.solver.status()
            self.solver.after_reply()

    def close(self) -> None:
        pass


class SolverProcess(SolverClient):
    """A :class:`StreamSolver` in a child process (see the module)."""

    def __init__(self, spec: StreamSpec, stopped: Callable[[], bool] = lambda: False):
        """Start the process and wait until its stream is built (kernels made ready first: a minute or two
        with an empty cache).  Raises what building the stream raised, or :class:`SolverStoppedError` if
        ``stopped()`` turns true meanwhile (checked every POLL_PERIOD) or the process dies."""
        package_root = str(Path(__file__).resolve().parents[2])
        path = os.pathsep.join(p for p in (package_root, os.environ.get("PYTHONPATH", "")) if p)
        with tempfile.TemporaryFile() as shared:  # the stop flag and the beats, mapped by both processes
            shared.truncate(SHARED_BYTES)
            self._stop, self._beats = shared_memory(shared.fileno())
            request_read, request_write = os.pipe()
            reply_read, reply_write = os.pipe()
            self._process = subprocess.Popen(
                [sys.executable, "-m", stream_solver.__name__, str(request_read), str(reply_write),
                 str(shared.fileno())],
                pass_fds=(request_read, reply_write, shared.fileno()), env={**os.environ, "PYTHONPATH": path},
                start_new_session=True)
        for fd in (request_read, reply_write):
            os.close(fd)
        self._requests = Connection(request_write, readable=False)
        self._replies = Connection(reply_read, writable=False)
        self._stopped = stopped
        self._lock = threading.Lock()
        self._last_beat = (int(self._beats[0]), time.monotonic())  # the count and when it was seen to change
        self._hung = ""  # why the process was killed as hung
        try:
            self._requests.send(spec)
            self.info = self._reply(hung_after=math.inf)  # compiling may hold the process's Python lock
        except BaseException:
            self.close()
            raise

    @property
    def pid(self) -> int:
        return self._process.pid

    @property
    def exit_code(self) -> int | None:
        """The process's exit status once it ended and was reaped (negative: the signal that ended it), else None."""
        return self._process.poll()

    def silent_for(self) -> float:
        """[s] since the process's beat counter was last seen to change (0 if it changed now)."""
        count, seen = self._last_beat
        now, latest = time.monotonic(), int(self._beats[0])
        if latest != count:
            self._last_beat = (latest, now)
            return 0.0
        return now - seen

    def _reply(self, hung_after: float | None = None) -> Any:
        """The reply to the request sent; a process silent for ``hung_after`` [s] (default :data:`HUNG_AFTER`)
        meanwhile is killed (:class:`SolverHungError`)."""
        hung_after = HUNG_AFTER if hung_after is None else hung_after
        self.silent_for()  # the silence counts from the request on
        try:
            while not self._replies.poll(POLL_PERIOD):
                if self._stopped():
                    raise SolverStoppedError("stopped while waiting for the solver process")
                if self._process.poll() is not None:
                    raise SolverStoppedError(f"the solver process ended (exit code {self._process.returncode})")
                silent = self.silent_for()
                if silent > hung_after:
                    self._hung = (f"the solver process gave no sign of life for {silent:.1f} s while a reply was due "
                                  f"(stopped, swapped out or stuck): killed (pid {self.pid})")
                    self._kill()
                    raise SolverHungError(self._hung)
            ok, result, status = self._replies.recv()
        except (EOFError, OSError, ValueError) as error:  # closed meanwhile (ValueError: a closed handle)
            raise SolverStoppedError(f"the solver process ended: {error}") from error
        if status is not None:
            self.status = status
        if not ok:
            raise result
        return result

    def interrupt(self) -> None:
        """Cut the request in progress short (see the module)."""
        self._stop[0] = 1

    def _call(self, method: Callable[..., Any], *args: Any) -> Any:
        """``method(solver, *args)`` in the process; :attr:`status` is the stream's after it."""
        with self._lock:
            if self._hung:
                raise SolverHungError(self._hung)
            try:
                self._requests.send((method, args))
            except (OSError, ValueError) as error:
                raise SolverStoppedError(f"the solver process ended: {error}") from error
            return self._reply()

    def _kill(self) -> None:
        """Kill the process and reap it."""
        self._process.kill()
        self._process.wait()

    def close(self, timeout: float = 1.0) -> None:
        """End the process: ask it, then wait up to ``timeout`` s for it to end, then kill it; a process that gives no
        beat for :data:`HUNG_AFTER` s meanwhile (stopped, or hung) is killed then instead of waited for."""
        if self._process.poll() is None and self._lock.acquire(timeout=timeout):
            try:
                self._requests.send(None)
            except (OSError, ValueError):
                pass
            finally:
                self._lock.release()
        self._requests.close()
        deadline = time.monotonic() + timeout
        self.silent_for()  # the silence counts from now on at the latest
        while self._process.poll() is None:
            if time.monotonic() >= deadline or self.silent_for() > HUNG_AFTER:
                self._kill()
                break
            time.sleep(0.2 * HEARTBEAT_PERIOD)
        self._replies.close()

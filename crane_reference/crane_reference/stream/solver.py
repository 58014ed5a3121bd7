"""The stream's solver side, in the caller's thread or in a process of its own.

:class:`StreamSolver` owns a :class:`~.reference_stream.ReferenceStream` and answers the requests of a
reference server (:mod:`.server`): frames to make (:func:`~.frame_maker.make_frames`), commands applied at a
stream time, target checks, the crane's reach.  Two clients carry the requests to it, with the methods of
:class:`SolverClient` (each returns the result and keeps the stream's :class:`StreamStatus` of the reply;
a request names the solver's method itself, which pickles by reference, never a string):

* :class:`LocalSolver` calls it in the caller's thread (tests, tools);
* :class:`SolverProcess` runs it in a child process (``python -m crane_reference.stream.solver``: a fresh
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
(:data:`SOLVER_NICENESS`): it computes seconds of frames ahead and can wait, the caller's publisher cannot.

A hung solver.  The child beats a counter in the shared memory every :data:`HEARTBEAT_PERIOD` from a thread of
its own, beside the kernels (which run without Python's lock).  A live solver always answers: each Newton
iteration, projection and compiled run of it is bounded.  So a caller waiting for a reply that sees no beat for
:data:`HUNG_AFTER` holds the process hung (stopped by a signal or a debugger, swapped out, stuck holding
Python's lock), kills and reaps it and raises :class:`SolverHungError` (a :class:`SolverStoppedError`: the
server holds the last sample and reports it).  The bound is not applied while the process starts (compiling
the kernels can hold Python's lock for seconds), and :meth:`SolverProcess.close` kills a process without beats
at once instead of waiting for it to end.
"""

from __future__ import annotations

import gc
import math
import mmap
import os
import pickle
import signal
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from ..model.chain import PRISMATIC
from ..model.description import CraneDescription
from ..model.drive import column_drive
from ..model.parameters import Task
from ..model.urdf import model_to_urdf
from ..motion.integration import stop_flag
from .frame_maker import make_frames
from .frames import FrameBatch, FrameRequest
from .reference_stream import ReferenceStream
from .sample import ReferenceSample
from .targets import reach
from .warmup import warm_up

POLL_PERIOD = 0.1  # [s] between checks of the caller's stop flag while it waits for the solver process
SOLVER_NICENESS = 5  # added to the solver process's nice value: the caller's threads win a contended core
HEARTBEAT_PERIOD = 0.05
"""[s] between the solver process's beats."""
HUNG_AFTER = 1.0
"""[s] without a beat after which a solver process that owes a reply is held hung (twenty beats missed)."""
SHARED_BYTES = 16
"""The memory the caller and the solver process share: the stop flag (byte 0) and the beat counter (bytes 8-15)."""


class SolverStoppedError(RuntimeError):
    """The caller stopped waiting for the solver (shutting down), or the solver process is gone."""


class SolverHungError(SolverStoppedError):
    """The solver process gave no sign of life for :data:`HUNG_AFTER` while a reply was due: it was killed."""


@dataclass(frozen=True)
class StreamSpec:
    """Everything that makes a :class:`~.reference_stream.ReferenceStream` (picklable): the crane's
    configuration, model variant, integrator step [s], blend time [s], targets, the column drive's torque
    [N m] and duration [s] (None: the configuration's), speed scaling and its ramp time [s]; ``warm_up``:
    make every kernel ready first (and say how)."""

    config: CraneDescription
    model: str
    step: float
    blend_time: float
    targets: Task
    drive_torque: float | None = None
    drive_duration: float | None = None
    speed_scaling: float = 1.0
    ramp_time: float = 1.0
    warm_up: bool = True


@dataclass(frozen=True)
class StreamInfo:
    """What a server needs to know of the stream once: joint names and their units ("rad", or "m" for a
    prismatic joint), the URDF of the model, the sample at the start, E's static height [m], the singular-value
    margin of target checks, and how the kernels were made ready ("" without warm-up)."""

    joint_names: tuple[str, ...]
    joint_units: tuple[str, ...]
    urdf: str
    start: ReferenceSample
    z_static: float
    singular_value_margin: float
    kernels: str


@dataclass(frozen=True)
class StreamStatus:
    """The stream's state after a request: RUNNING / PAUSED / ERROR, targets, the speed scaling it is at or
    moving to, the last error, the ramp time [s], the publish time [s] it settles at, the blend time [s]."""

    state: str
    targets: Task
    target_speed: float
    last_error: str
    ramp_time: float
    settled_at: float
    blend_time: float


class Return(NamedTuple):
    """A return to the start: q [SI units] at the stream time it happens, before, and q at the start."""

    before: np.ndarray
    start: np.ndarray


class StreamSolver:
    """The stream and the requests it answers (see the module)."""

    def __init__(self, spec: StreamSpec, stop: np.ndarray | None = None):
        """Build the stream of ``spec`` (after making the kernels ready if ``spec.warm_up``) and check its
        targets (:class:`~.targets.UnreachableTargetError` or a solver failure if there is no start); the
        ``stop`` flag (:func:`~crane_reference.motion.integration.stop_flag`, a new one if None), once set,
        says that a command waits: computing ahead stops at the next step."""
        self.stop = stop_flag() if stop is None else stop
        self.kernels = warm_up((spec.model,)).describe() if spec.warm_up else ""
        config = spec.config
        self.stream = ReferenceStream(config, spec.model, spec.step, spec.blend_time, spec.targets,
                                      column_drive(config, spec.drive_torque, spec.drive_duration),
                                      speed_scaling=spec.speed_scaling, ramp_time=spec.ramp_time)
        self.stream.check_targets(spec.targets)

    def info(self) -> StreamInfo:
        stream = self.stream
        units = tuple("m" if joint.kind == PRISMATIC else "rad" for joint in stream.model.joints)
        return StreamInfo(tuple(stream.joint_names), units, model_to_urdf(stream.model), stream.sample(0.0),
                          stream.scenario.z_static, stream.singular_value_margin, self.kernels)

    def status(self) -> StreamStatus:
        stream = self.stream
        return StreamStatus(stream.state, stream.targets, stream.target_speed, stream.last_error, stream.ramp_time,
                            stream.settled_at(), stream.blend_time)

    def frames(self, request: FrameRequest, keep: float) -> FrameBatch:
        """The frames of ``request`` (:func:`~.frame_maker.make_frames`); then the motion older than ``keep``
        seconds before the request's first frame is forgotten."""
        batch = make_frames(self.stream, request, self.stop)
        self.stream.release(request.plan.tau, keep)
        return batch

    def command(self, method: Callable[..., Any], tau: float, args: tuple, request: FrameRequest, keep: float
                ) -> tuple[Any, FrameBatch]:
        """The stream command ``method(self, tau, *args)`` (one of :data:`STREAM_COMMANDS`), then the frames of
        ``request`` (:meth:`frames`): one request, so a command's first frames are ready without a second trip."""
        return method(self, tau, *args), self.frames(request, keep)

    def call(self, method: Callable[..., Any], *args: Any) -> Any:
        """``method(self, *args)`` with the stop flag cleared as the module says: before any call but one of
        :meth:`frames` (an interrupt set it for the call that waited), and after a call of :meth:`frames`."""
        frames = method is StreamSolver.frames
        if not frames:
            self.stop[0] = 0
        try:
            return method(self, *args)
        finally:
            if frames:
                self.stop[0] = 0

    def after_reply(self) -> None:
        """Tidy up after a reply is sent (:meth:`~.reference_stream.ReferenceStream.free_forgotten`)."""
        self.stream.free_forgotten()

    def check_targets(self, targets: Task) -> None:
        self.stream.check_targets(targets)

    def reach(self, radius: float, heights: tuple[float, ...]) -> tuple[float, float]:
        """The crane's reach at E's heights ``heights`` [m above its static height] from ``radius``
        (:func:`~.targets.reach`)."""
        stream = self.stream
        return reach(stream.scenario, radius, tuple(stream.scenario.z_static + z for z in heights),
                     stream.singular_value_margin)

    def set_blend_time(self, seconds: float) -> None:
        self.stream.set_blend_time(seconds)

    def pause(self, tau: float) -> None:
        self.stream.pause(tau)

    def resume(self, tau: float) -> None:
        self.stream.resume(tau)

    def set_speed_scaling(self, tau: float, rate: float) -> None:
        self.stream.set_speed_scaling(tau, rate)

    def retarget(self, tau: float, targets: Task, blend_time: float) -> float:
        """Re-target at tau to targets already checked (:meth:`check_targets`) over ``blend_time`` [s]; the motion
        time [s] the blend begins at."""
        return self.stream.retarget(tau, targets, checked=True, blend_time=blend_time)

    def restart(self, tau: float) -> Return:
        """Back to the static-equilibrium start at tau, the shortest way on whole-turn coordinates
        (:meth:`~.reference_stream.ReferenceStream.restart`)."""
        stream = self.stream
        stream.compute(tau)
        before = stream.sample(tau).q
        stream.restart(tau, near=before)
        return Return(before, stream.sample(tau).q)


STREAM_COMMANDS: dict[str, Callable[..., Any]] = {
    "pause": StreamSolver.pause, "resume": StreamSolver.resume, "speed_scaling": StreamSolver.set_speed_scaling,
    "retarget": StreamSolver.retarget, "restart": StreamSolver.restart}
"""The commands a server sends at a stream time (:meth:`StreamSolver.command`), by the name it records them under."""


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

    def set_blend_time(self, seconds: float) -> None:
        """:meth:`StreamSolver.set_blend_time`."""
        self._call(StreamSolver.set_blend_time, seconds)

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


def shared_memory(fd: int) -> tuple[np.ndarray, np.ndarray]:
    """The stop flag (:func:`~crane_reference.motion.integration.stop_flag`) and the beat counter over the
    :data:`SHARED_BYTES` of the file ``fd``, mapped shared: what one process writes there, another that maps the
    same file reads."""
    memory = mmap.mmap(fd, SHARED_BYTES)
    return np.frombuffer(memory, dtype=np.uint8, count=1), np.frombuffer(memory, dtype=np.uint64, count=1, offset=8)


def beat(counter: np.ndarray) -> None:
    """The solver process's heartbeat: count every :data:`HEARTBEAT_PERIOD` for as long as the process lives."""
    while True:
        counter[0] += 1
        time.sleep(HEARTBEAT_PERIOD)


def _serve(requests: Connection, replies: Connection, stop: np.ndarray) -> None:
    """The solver process: read the :class:`StreamSpec`, build the solver with the ``stop`` flag shared with
    the caller, then answer (method, args) requests (:meth:`StreamSolver.call`) until the pipe closes or None
    comes.  Replies are (ok, result or exception, status)."""
    try:
        spec = requests.recv()
        solver = StreamSolver(spec, stop)
    except (EOFError, OSError):
        return
    except Exception as error:  # reported to the caller, which raises it
        replies.send((False, _portable(error), None))
        return
    replies.send((True, solver.info(), solver.status()))
    gc.freeze()  # the start-up's objects out of the collector's full passes (each would stall the replies)
    while True:
        try:
            request = requests.recv()
        except (EOFError, OSError):
            return
        if request is None:
            return
        method, args = request
        try:
            reply = (True, solver.call(method, *args))
        except Exception as error:  # reported to the caller, which raises it
            reply = (False, _portable(error))
        replies.send((*reply, solver.status()))
        del reply
        solver.after_reply()


def _portable(error: Exception) -> Exception:
    """``error`` if it pickles, else a RuntimeError with its type, message and traceback."""
    try:
        pickle.loads(pickle.dumps(error))
        return error
    except Exception:  # any pickling failure
        return RuntimeError(f"{type(error).__name__}: {error}\n{traceback.format_exc()}")


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
                [sys.executable, "-m", __name__, str(request_read), str(reply_write), str(shared.fileno())],
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
        """End the process: ask it, then wait up to ``timeout`` s, then kill it; a process that has not beaten for
        two periods and more (stopped, or hung) is killed at once."""
        if self.silent_for() > 2.0 * HEARTBEAT_PERIOD + POLL_PERIOD:
            self._kill()
        if self._process.poll() is None and self._lock.acquire(timeout=timeout):
            try:
                self._requests.send(None)
            except (OSError, ValueError):
                pass
            finally:
                self._lock.release()
        self._requests.close()
        try:
            self._process.wait(timeout)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()
        self._replies.close()


if __name__ == "__main__":
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the caller decides when the solver ends (see the module)
    os.nice(SOLVER_NICENESS)
    from crane_reference.base.threads import name_this_thread
    from crane_reference.stream import solver  # the classes under their importable names (pickled replies)

    name_this_thread("ref_solver")
    stop_flag, beats = solver.shared_memory(int(sys.argv[3]))
    threading.Thread(target=solver.beat, args=(beats,), name="ref_heartbeat", daemon=True).start()

    solver._serve(Connection(int(sys.argv[1]), writable=False), Connection(int(sys.argv[2]), readable=False), stop_flag)

"""The solver's side of the pipe: :class:`StreamSolver` owns a :class:`~.reference_stream.ReferenceStream` and
answers a reference server's requests (frames to make, commands at a stream time, target checks, the crane's
reach), in the caller's thread (:class:`~.solver.LocalSolver`) or as the main of a process of its own
(``python -m crane_reference.stream.stream_solver``, started by :class:`~.solver.SolverProcess`: :func:`serve`
answers the pickled requests, a thread beats the heartbeat).  :mod:`.solver` has the caller's side and the
protocol.
"""

from __future__ import annotations

import gc
import os
import pickle
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from ..model.chain import PRISMATIC
from ..model.drive import column_drive
from ..model.parameters import Task
from ..model.urdf import model_to_urdf
from ..motion.integration import stop_flag
from .frame_maker import make_frames
from .frames import FrameBatch, FrameRequest
from .reference_stream import ReferenceStream
from .solver_messages import HEARTBEAT_PERIOD, Return, StreamInfo, StreamSpec, StreamStatus, shared_memory
from .targets import reach
from .warmup import warm_up

SOLVER_NICENESS = 5  # added to the solver process's nice value: the caller's threads win a contended core


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
                            stream.settled_at())

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


def beat(counter: np.ndarray) -> None:
    """The solver process's heartbeat: count every :data:`HEARTBEAT_PERIOD` for as long as the process lives."""
    while True:
        counter[0] += 1
        time.sleep(HEARTBEAT_PERIOD)


def serve(requests: Connection, replies: Connection, stop: np.ndarray) -> None:
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


if __name__ == "__main__":
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the caller decides when the solver ends (see the module)
    os.nice(SOLVER_NICENESS)
    from crane_reference.base.threads import name_this_thread
    from crane_reference.stream import stream_solver  # the classes under their importable names (pickled replies)

    name_this_thread("ref_solver")
    stop, beats = shared_memory(int(sys.argv[3]))
    threading.Thread(target=stream_solver.beat, args=(beats,), name="ref_heartbeat", daemon=True).start()
    stream_solver.serve(Connection(int(sys.argv[1]), writable=False), Connection(int(sys.argv[2]), readable=False),
                        stop)

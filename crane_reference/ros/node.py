"""ROS 2 node publishing the crane's programmed motion as a reference: ``ros2 run crane_reference node``.

The node is thin: the motion comes from :class:`~crane_reference.reference_stream.ReferenceStream`, the
messages from :mod:`crane_reference.messages`, the parameters from :mod:`crane_reference.node_parameters`.

Clocks and stamps
    Sample k is stamped ``start + k / publish_rate`` (integer nanoseconds, :func:`~crane_reference.messages.stamp_at`),
    where ``start`` is the node clock's time when publishing begins; it is never the time a message
    happens to be sent.  The publisher thread is a timer on the node clock: it sleeps until the next
    sample's stamp and publishes every sample due (normally one), so no sample is skipped or
    duplicated even when it wakes late.  ``use_sim_time`` is honoured: the samples follow /clock.  With
    ``use_sim_time`` true and no /clock published, ROS time stays at zero, so publishing does not start
    and ROS-time timers never fire: nothing is published (no joint_states, pose, preview, markers or
    diagnostics) until /clock runs; the services and parameters keep working.
    A thread rather than an rclpy timer publishes because rclpy's executor costs about 0.3 ms per timer
    callback and runs the (slow) parameter validation on the same thread.

Computing ahead
    A worker thread advances the solver (``ReferenceStream.compute`` in slices of at most
    :data:`COMPUTE_SLICE` s of wall time) and samples it into a buffer of frames, :data:`LOOKAHEAD` s
    ahead of publishing.  The publisher only takes frames from that buffer and never waits on the
    solver's lock (both threads still share Python's GIL, which is what limits the timing at high rates).
    The stream's own clock (its "publish time" tau) advances by 1 / publish_rate per frame.
    Should the solver ever fall behind (real-time factor below 1), the publisher sends the last sample
    held (zero velocity) and the motion continues from there once frames are ready again (no position
    jump); diagnostics count these samples (held_late).  If the solver fails or the crane nears a
    singularity the stream goes to ERROR: the node holds the last sample it made (zero velocity) and
    diagnostics and the log report ERROR until ``~/restart``.  A sample that is not finite is never
    published: the last valid one is held instead.

Commands
    A re-target (``ellipse.*``, ``z.*`` parameters), ``~/pause`` and ``~/restart`` take effect at the
    frame :data:`COMMAND_LEAD` s after the next one to be published (the frames computed beyond it are
    dropped and computed again), so a change reaches the published samples about COMMAND_LEAD after it
    is accepted.  Parameter values are validated in the on-set callback (table of
    :mod:`~crane_reference.node_parameters`, then ``ReferenceStream.check_targets`` for the targets) and
    applied in the post-set callback, so ``set_parameters_atomically`` of ellipse.a and ellipse.b is one
    re-target, and a rejected change leaves the stream untouched.

Topics: ``joint_states`` (sensor_msgs/JointState), ``~/end_effector_pose`` (geometry_msgs/PoseStamped),
``~/reference_preview`` (trajectory_msgs/JointTrajectory, at ``preview.rate``), ``/diagnostics``
(diagnostic_msgs/DiagnosticArray, 1 Hz), ``~/markers`` (visualization_msgs/MarkerArray, 10 Hz: target
ellipse and E's trail), ``robot_description`` (std_msgs/String, transient local).
Services: ``~/restart`` (std_srvs/Trigger), ``~/pause`` (std_srvs/SetBool).
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rcl_interfaces.msg import SetParametersResult
from rclpy.executors import ExternalShutdownException
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import SetBool, Trigger
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import MarkerArray

from ..interface import messages
from ..model.config import ConfigError, load_config
from ..model.drive import column_drive
from ..model.parameters import CraneParameters, Task
from ..model.urdf import model_to_urdf
from ..motion.simulation import SOLVER_FAILURES
from ..stream.reference_stream import ERROR, PAUSED, ReferenceStream
from ..stream.sample import ReferenceSample
from ..stream.targets import UnreachableTargetError
from .message_types import rclpy_types
from .parameters import PARAMETERS, SPECS, TARGET_PARAMETERS, ParameterError, check, coerce_parameters, declare

NODE_NAME = messages.NODE_NAME
LOOKAHEAD = 1.0  # [s] of frames kept ready ahead of publishing
COMMAND_LEAD = 0.25  # [s] from the next sample to publish to the one a command takes effect at
COMPUTE_SLICE = 0.005  # [s] of wall time the worker holds the stream per compute call
FRAME_BATCH = 20  # frames sampled per hold of the stream lock
COMPUTE_MARGIN = 0.05  # [s] of motion computed beyond the preview horizon
RELEASE_KEEP = 1.0  # [s] of computed motion kept before the next frame to compute (for commands)
MAX_CATCH_UP = 1.0  # [s]: if publishing falls further behind than this, older samples are skipped
MARKER_RATE = 10.0  # [Hz]
TRAIL_RATE = 50.0  # [Hz] of points added to E's trail
TRAIL_POINTS = 500
TIME_TOLERANCE = 1e-9  # [s], rounding slack when comparing stream times
NANOSECONDS = messages.NANOSECONDS
RCLError = rclpy_implementation.RCLError


class StartupError(RuntimeError):
    """The node cannot start (unusable configuration or target)."""


@dataclass(frozen=True)
class Frame:
    """Sample k of the reference, at stream publish time ``tau``, with its preview (or None) over
    ``horizon`` seconds."""

    k: int
    tau: float
    sample: ReferenceSample
    preview: list[ReferenceSample] | None = None
    horizon: float = 0.0


class CraneReferenceNode(Node):
    """Publishes the reference of the crane's programmed motion; see the module documentation."""

    def __init__(self, node_name: str = NODE_NAME, **kwargs) -> None:
        """Declare and read the parameters, build the stream and start publishing.

        ``kwargs`` go to :class:`rclpy.node.Node` (``context``, ``parameter_overrides``, ``cli_args``...).
        Raises :class:`StartupError`, :class:`~crane_reference.config.ConfigError` or
        :class:`~crane_reference.node_parameters.ParameterError` if it cannot start.
        """
        super().__init__(node_name, **kwargs)
        config_file = declare(self, SPECS["config_file"])
        config = load_config(config_file or None)
        self._values = {spec.name: declare(self, spec, config) for spec in PARAMETERS if spec.name != "config_file"}
        self._rate = int(self._values["publish_rate"])
        self._lookahead = max(2, math.ceil(LOOKAHEAD * self._rate))
        self._stream = self._make_stream(config)
        self._last_valid = self._stream.sample(0.0)
        self._types = rclpy_types()
        self._joint_names = list(self._stream.joint_names)

        # Buffer of frames [next to publish ... _gen_k - 1], guarded by _lock (never held while solving).
        self._lock = threading.Condition()
        self._stream_lock = threading.Lock()
        self._frames: deque[Frame] = deque()
        self._next_k = 0
        self._gen_k = 0
        self._gen_tau = 0.0
        self._generation = 0
        self._next_preview_k = 0
        self._start_ns: int | None = None
        self._last: ReferenceSample | None = None
        self._last_stamp = 0
        self._achieved_rate = 0.0
        self._late_reported = 0
        self._fault = ""
        self._counters = {"published": 0, "held_late": 0, "skipped": 0, "held_non_finite": 0}
        self._compute = {"wall": 0.0, "motion": 0.0}
        self._effective: dict[str, float] = {}
        self._trail: deque[np.ndarray] = deque(maxlen=TRAIL_POINTS)
        self._diagnostics_reference = (0, 0.0, 0.0, self.get_clock().now().nanoseconds)

        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        depth = messages.PUBLISHER_DEPTH
        self._joint_pub = self.create_publisher(JointState, messages.JOINT_STATES_TOPIC, depth)
        self._pose_pub = self.create_publisher(PoseStamped, messages.END_EFFECTOR_POSE_TOPIC, depth)
        self._preview_pub = self.create_publisher(JointTrajectory, "~/reference_preview", depth)
        self._marker_pub = self.create_publisher(MarkerArray, "~/markers", depth)
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, messages.DIAGNOSTICS_TOPIC, depth)
        self._description_pub = self.create_publisher(String, "robot_description", latched)
        self._description_pub.publish(messages.robot_description(self._types, model_to_urdf(self._stream.model)))

        self.add_pre_set_parameters_callback(coerce_parameters)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.create_service(Trigger, "~/restart", self._on_restart)
        self.create_service(SetBool, "~/pause", self._on_pause)

        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._work, name="crane_reference_solver", daemon=True),
                         threading.Thread(target=self._publish_loop, name="crane_reference_publisher", daemon=True)]
        for thread in self._threads:
            thread.start()
        self.create_timer(messages.DIAGNOSTICS_PERIOD, self._publish_diagnostics)
        self.create_timer(1.0 / MARKER_RATE, self._publish_markers)
        self._status_timer = self.create_timer(self._values["status_period"], self._log_status)
        self.get_logger().info(
            f"publishing the {self._values['model']} crane's reference at {self._rate} Hz "
            f"({len(self._joint_names)} joints, config {config_file or 'packaged default'}, "
            f"{'running' if self._values['autostart'] else 'paused until ~/pause data: false'})")

    # -- set-up ---------------------------------------------------------------------------------------

    def _targets(self, overrides: dict[str, float] | None = None) -> Task:
        """Targets of the current parameter values, with ``overrides`` (parameter name -> value)."""
        values = {**self._values, **(overrides or {})}
        return Task(**{field: float(values[name]) for name, field in TARGET_PARAMETERS.items()})

    def _make_stream(self, config: CraneParameters) -> ReferenceStream:
        v = self._values
        targets = self._targets()
        try:
            stream = ReferenceStream(config, v["model"], v["integrator.step"], v["blend_time"], targets,
                                     column_drive(config, v["drive.torque"], v["drive.duration"]))
            stream.check_targets(targets)
        except UnreachableTargetError as error:
            raise StartupError(f"ellipse.* / z.* = {targets}: {error}") from error
        except SOLVER_FAILURES as error:
            raise StartupError(f"no consistent start for the targets {targets}: {error}") from error
        if not v["autostart"]:
            stream.pause(0.0)
        return stream

    # -- computing ahead (worker thread) --------------------------------------------------------------

    def _work(self) -> None:
        """Keep LOOKAHEAD of frames ready ahead of publishing and the motion computed beyond them."""
        try:
            while not self._stop.is_set():
                with self._lock:
                    k = max(self._gen_k, self._next_k)  # the stream time goes on from gen_tau: no jump
                    tau, generation, next_preview_k = self._gen_tau, self._generation, self._next_preview_k
                    room = self._lookahead - (k - self._next_k)
                frames, next_preview_k, busy = self._make_frames(k, tau, min(room, FRAME_BATCH), next_preview_k)
                with self._lock:
                    if generation != self._generation:
                        continue
                    if frames and frames[0].k < self._next_k:  # publishing held meanwhile: continue after it
                        frames = [replace(f, k=f.k + self._next_k - frames[0].k) for f in frames]
                    if frames:
                        self._frames.extend(frames)
                        self._gen_k, self._gen_tau = frames[-1].k + 1, frames[-1].tau + 1.0 / self._rate
                        self._next_preview_k = next_preview_k
                        self._last_valid = frames[-1].sample
                    elif not busy:
                        self._lock.wait(timeout=LOOKAHEAD)
        except Exception as error:  # publishing goes on (holding) and reports it
            self._fault = f"solver thread stopped: {type(error).__name__}: {error}"
            self.get_logger().error(self._fault)

    def _make_frames(self, k: int, tau: float, count: int, next_preview_k: int) -> tuple[list[Frame], int, bool]:
        """Up to ``count`` frames from sample k at stream time tau on, as far as the motion is computed,
        after one slice of computing ahead; returns them, the next sample due a preview, and whether the
        motion is still short of the preview horizon."""
        dt = 1.0 / self._rate
        horizon, points = self._values["preview.horizon"], self._values["preview.points"]
        ahead = tau + count * dt + horizon + COMPUTE_MARGIN
        frames = []
        with self._stream_lock:
            stream = self._stream
            before = stream.computed_until
            if before < ahead:
                start = time.perf_counter()
                stream.compute(ahead, COMPUTE_SLICE if self._start_ns is not None else None)  # all before starting
                if math.isfinite(stream.computed_until):
                    self._compute["wall"] += time.perf_counter() - start
                    self._compute["motion"] += stream.computed_until - before
            last = self._last_valid  # the last sample of the frames made so far (finite)
            for i in range(count):
                t = tau + i * dt
                if stream.state == ERROR:  # hold the last sample made, not the stream's (computed further ahead)
                    frames.append(Frame(k + i, t, last.hold()))
                    continue
                if t > stream.computed_until - TIME_TOLERANCE:
                    break
                preview = None
                if k + i >= next_preview_k and stream.computed_until >= t + horizon:
                    preview = stream.preview(t, horizon, points)
                    next_preview_k = k + i + self._preview_decimation()
                frames.append(self._checked(Frame(k + i, t, stream.sample(t), preview, horizon), last))
                last = frames[-1].sample
            stream.release(tau, RELEASE_KEEP + LOOKAHEAD)
            busy = stream.computed_until < ahead
        return frames, next_preview_k, busy

    def _preview_decimation(self) -> int:
        """Samples between two previews."""
        return max(1, round(self._rate / self._values["preview.rate"]))

    def _checked(self, frame: Frame, last_valid: ReferenceSample) -> Frame:
        """``frame`` if finite, else ``last_valid`` held (never publish NaN); a non-finite preview is dropped."""
        finite = frame.preview is None or all(sample.is_finite() for sample in frame.preview)
        preview = frame.preview if finite else None
        if frame.sample.is_finite():
            return replace(frame, preview=preview)
        self._fault = f"non-finite sample at stream time {frame.tau:.3f} s: holding the last valid one"
        self.get_logger().error(self._fault, throttle_duration_sec=1.0)
        self._counters["held_non_finite"] += 1
        return Frame(frame.k, frame.tau, last_valid.hold())

    # -- commands (executor threads) ------------------------------------------------------------------

    def _command(self, action: Callable[[float], None]) -> int:
        """Apply ``action(tau)`` to the stream at the frame COMMAND_LEAD after the next one to publish
        (or at the next frame to compute, if earlier); drop the frames from there on.  Returns the index
        of that frame; exceptions of ``action`` propagate with the stream and the buffer untouched."""
        with self._stream_lock:
            with self._lock:
                free = max(self._gen_k, self._next_k)  # the next frame the worker computes
                k = min(self._next_k + math.ceil(COMMAND_LEAD * self._rate), free)
                tau = self._gen_tau if k == free else next(f.tau for f in self._frames if f.k == k)
            action(tau)
            with self._lock:
                self._frames = deque(f for f in self._frames if f.k < k)
                self._gen_k, self._gen_tau = k, tau
                self._generation += 1
                self._next_preview_k = k
        return k

    def _stamp_s(self, k: int) -> float:
        """Stamp [s] of sample k (relative to the start if publishing has not begun)."""
        return messages.stamp_at(self._start_ns or 0, k, self._rate) / NANOSECONDS

    def _on_restart(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """~/restart: back to the static-equilibrium start of the current targets."""
        try:
            k = self._command(self._stream.restart)
        except SOLVER_FAILURES as error:
            response.success, response.message = False, f"restart failed, stream unchanged: {error}"
        else:
            response.success = True
            response.message = f"restarted from the static equilibrium at the sample stamped {self._stamp_s(k):.6f} s"
            self._effective["restart"] = self._stamp_s(k)
            self._fault = ""
        self.get_logger().info(response.message)
        return response

    def _on_pause(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        """~/pause: data true holds the reference (zero velocity), data false resumes it."""
        state = self._stream.state
        wanted = PAUSED if request.data else "RUNNING"
        if state == ERROR:
            response.success = False
            response.message = f"the stream is in ERROR ({self._stream.last_error}); call ~/restart"
        elif state == wanted:
            response.success, response.message = True, f"already {state.lower()}"
        else:
            k = self._command(self._stream.pause if request.data else self._stream.resume)
            verb = "paused" if request.data else "resumed"
            response.success, response.message = True, f"{verb} at the sample stamped {self._stamp_s(k):.6f} s"
            self._effective["pause" if request.data else "resume"] = self._stamp_s(k)
        self.get_logger().info(f"~/pause {request.data}: {response.message}")
        return response

    def _validate_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        """On-set callback: the table's checks, then the reachability of changed targets."""
        reason = check(parameters)
        changed = {p.name: p.value for p in parameters if p.name in TARGET_PARAMETERS}
        if reason is None and changed:
            targets = self._targets(changed)
            try:
                with self._stream_lock:
                    self._stream.check_targets(targets)
            except UnreachableTargetError as error:
                names = ", ".join(f"{name} = {value!r}" for name, value in changed.items())
                reason = f"{names}: target not reachable: {error}"
        return SetParametersResult(successful=reason is None, reason=reason or "")

    def _apply_parameters(self, parameters: list[Parameter]) -> None:
        """Post-set callback: apply accepted values (one re-target for all target parameters)."""
        names = [p.name for p in parameters if p.name in self._values]
        self._values.update({p.name: p.value for p in parameters if p.name in self._values})
        if "blend_time" in names:
            with self._stream_lock:
                self._stream.set_blend_time(self._values["blend_time"])
        if "status_period" in names:
            self._status_timer.timer_period_ns = round(self._values["status_period"] * NANOSECONDS)
            self._status_timer.reset()
        if any(name in TARGET_PARAMETERS for name in names):
            targets = self._targets()
            # the targets passed check_targets in the on-set callback
            k = self._command(lambda tau: self._stream.retarget(tau, targets, checked=True))
            self._effective["retarget"] = self._stamp_s(k)
            self.get_logger().info(f"re-targeting to {targets} from the sample stamped {self._stamp_s(k):.6f} s "
                                   f"over {self._values['blend_time']:g} s")

    # -- publishing (publisher thread and timers) ------------------------------------------------------

    def _publish_loop(self) -> None:
        """Publisher thread: a timer on the node clock that wakes at each sample's stamp to publish it.

        It starts once LOOKAHEAD of frames is ready and the clock runs (ROS time is 0 until the first
        /clock with use_sim_time).  It sleeps in wall time for the time left on the node clock and checks
        that clock again, so it follows ROS time and stops at once when the node is destroyed.  If the
        clock goes back (use_sim_time toggled, a bag replayed from its start) the stamps are re-based.
        """
        clock = self.get_clock()
        try:
            while not self._stop.is_set() and (self._gen_k < self._lookahead or clock.now().nanoseconds == 0):
                self._stop.wait(1.0 / self._rate)
            self._start_ns = clock.now().nanoseconds
            self._diagnostics_reference = (0, 0.0, 0.0, self._start_ns)
            while not self._stop.is_set():
                now = clock.now().nanoseconds
                if now < messages.stamp_at(self._start_ns, self._next_k - 1, self._rate):
                    self._start_ns = now - self._next_k * NANOSECONDS // self._rate
                self._publish(now)
                left = messages.stamp_at(self._start_ns, self._next_k, self._rate) - clock.now().nanoseconds
                if left > 0:
                    self._stop.wait(left / NANOSECONDS)
        except RCLError:
            if self.context.ok():
                raise  # not a shutdown: let the thread report it

    def _publish(self, now: int) -> None:
        """Publish every sample due by ``now`` [ns] (normally one), each stamped start + k / rate."""
        with self._lock:
            due = (now - self._start_ns) * self._rate // NANOSECONDS
            oldest = due - math.ceil(MAX_CATCH_UP * self._rate) + 1
            if self._next_k < oldest:
                self._counters["skipped"] += oldest - self._next_k
                self._next_k = oldest
            batch = []
            while self._next_k <= due:
                while self._frames and self._frames[0].k < self._next_k:
                    self._frames.popleft()
                if self._frames and self._frames[0].k == self._next_k:
                    batch.append((self._next_k, self._frames.popleft()))
                else:
                    batch.append((self._next_k, None))
                self._next_k += 1
            self._lock.notify()
        for k, frame in batch:
            self._send(k, frame)

    def _send(self, k: int, frame: Frame | None) -> None:
        """Publish sample k: the frame's, or the last one held if the solver is late."""
        if frame is None:
            if self._last is None:
                return
            frame = Frame(k, math.nan, self._last.hold())
            self._counters["held_late"] += 1
        sample = frame.sample
        types, frame_id = self._types, self._values["frame_id"]
        stamp = messages.stamp_at(self._start_ns, k, self._rate)
        self._joint_pub.publish(messages.joint_state(types, stamp, self._joint_names, sample))
        self._pose_pub.publish(messages.end_effector_pose(types, stamp, frame_id, sample))
        if frame.preview is not None:
            horizon_ns, count = round(frame.horizon * NANOSECONDS), len(frame.preview)
            offsets = [(i + 1) * horizon_ns // count for i in range(count)]
            self._preview_pub.publish(messages.reference_preview(types, stamp, frame_id, self._joint_names, offsets,
                                                                 frame.preview))
        if k % max(1, round(self._rate / TRAIL_RATE)) == 0:
            self._trail.append(sample.ee_position)
        self._last, self._last_stamp = sample, stamp
        self._counters["published"] += 1

    def _publish_markers(self) -> None:
        """~/markers (timer): the target ellipse at the final height and E's trail, stamped like the last sample."""
        if self._last is None:
            return
        targets = self._stream.targets
        z = self._stream.scenario.z_static + targets.z_increment
        self._marker_pub.publish(messages.markers(self._types, self._last_stamp, self._values["frame_id"],
                                                  (targets.ellipse_a, targets.ellipse_b, z), np.array(self._trail)))

    def _rates(self) -> tuple[float, float]:
        """Achieved publish rate [Hz] and solver real-time factor since the last call."""
        published, wall, motion, now = (self._counters["published"], self._compute["wall"], self._compute["motion"],
                                        self.get_clock().now().nanoseconds)
        last_published, last_wall, last_motion, last_now = self._diagnostics_reference
        self._diagnostics_reference = (published, wall, motion, now)
        rate = (published - last_published) * NANOSECONDS / (now - last_now) if now > last_now else 0.0
        factor = (motion - last_motion) / (wall - last_wall) if wall > last_wall else math.inf
        return rate, factor

    def _publish_diagnostics(self) -> None:
        """/diagnostics: state, constraint residual, real-time factor, achieved rate, counters."""
        if self._start_ns is None:
            return
        rate, factor = self._rates()
        self._achieved_rate = rate
        late, self._late_reported = (self._counters["held_late"] + self._counters["skipped"] - self._late_reported,
                                     self._counters["held_late"] + self._counters["skipped"])
        stream = self._stream
        sample = self._last
        level = messages.OK
        message = stream.state
        if stream.state == ERROR or self._fault:
            level, message = messages.ERROR, f"{stream.state}: {stream.last_error or self._fault}"
        elif late > 0:
            level, message = messages.WARN, f"{stream.state}: {late} samples held or skipped (solver or publisher late)"
        values = messages.diagnostic_values(
            stream.state, sample, factor, self._rate, rate, self._counters, stream.targets,
            stream.last_error or self._fault,
            {"frames_ready": len(self._frames),
             **{f"{name}_stamp_s": f"{stamp:.6f}" for name, stamp in self._effective.items()}})
        stamp = self.get_clock().now().nanoseconds
        self._diagnostics_pub.publish(messages.diagnostics(
            self._types, stamp, f"{self.get_name()}: reference", self.get_fully_qualified_name(), level, message,
            values))
        if level == messages.ERROR:
            self.get_logger().error(message, throttle_duration_sec=10.0)

    def _log_status(self) -> None:
        """One-line status: stream time, E, residual, achieved rate, state."""
        sample = self._last
        if sample is None:
            return
        x, y, z = sample.ee_position
        self.get_logger().info(
            f"t={sample.t:.3f} s E=({x:.3f}, {y:.3f}, {z:.3f}) m residual={sample.residual_distance:.1e} m "
            f"rate={self._achieved_rate:.1f} Hz state={self._stream.state}")

    def destroy_node(self) -> None:
        """Stop the solver and publisher threads, then destroy the node."""
        self._stop.set()
        with self._lock:
            self._lock.notify_all()
        for thread in self._threads:
            thread.join()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """Run the node until SIGINT / shutdown; exit code 0, or 1 if it cannot start.

    ``args`` are the command line arguments for ``rclpy.init`` (``None``: ``sys.argv``), e.g.
    ``['--ros-args', '-p', 'ellipse.a:=3.5']``.
    """
    rclpy.init(args=args)
    node = None
    try:
        node = CraneReferenceNode()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (StartupError, ConfigError, ParameterError) as error:
        rclpy.logging.get_logger(NODE_NAME).fatal(f"cannot start: {error}")
        return 1
    except RCLError:
        if rclpy.ok():
            raise  # a real failure; otherwise SIGINT / SIGTERM shut the context down while starting
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""ROS 2 node publishing the crane's programmed motion as a reference: ``ros2 run crane_reference node``.

A managed (lifecycle) node.  Constructing it declares the parameters and starts /diagnostics (every
second of wall time, in every state: what it is doing while it starts, why it cannot, or the stream's
figures); ``configure`` makes the solver kernels ready, builds the stream and starts computing ahead;
``activate`` publishes; ``deactivate`` ramps a moving reference to rest, publishes it to the first
sample at rest and stops; ``cleanup`` / ``shutdown`` release the solver.  ``autostart`` (default) runs
configure and activate at construction.

The node wires threads, locks and rclpy to the publishing schedule
(:class:`~crane_reference.stream.schedule.FrameSchedule`), the motion
(:class:`~crane_reference.stream.reference_stream.ReferenceStream`), the messages
(:mod:`crane_reference.interface.messages`) and the parameter table (:mod:`crane_reference.ros.parameters`).

Clocks and stamps
    Sample k is stamped ``start + k / publish_rate`` (integer nanoseconds,
    :func:`~crane_reference.interface.messages.stamp_at`), where ``start`` is the node clock's time when
    publishing begins; it is never the time a message happens to be sent.  The publisher thread is a timer on
    the node clock: it sleeps until the next sample's stamp and publishes every sample due (normally one), so no
    sample is skipped or duplicated even when it wakes late.  ``use_sim_time`` is honoured: the samples follow
    /clock.  With ``use_sim_time`` true and no /clock published, ROS time stays at zero, so publishing does not
    start and ROS-time timers never fire: nothing is published (no joint_states, pose, preview or markers;
    /diagnostics says why) until /clock runs; the services and parameters keep working. A thread rather than an rclpy
    timer publishes because rclpy's executor adds its overhead to every timer callback and runs the (slow)
    parameter validation on the same thread.

Computing ahead
    A worker thread advances the solver (``ReferenceStream.compute`` in slices of at most
    :data:`COMPUTE_SLICE` s of wall time) and samples it into a buffer of frames, :data:`LOOKAHEAD` s
    ahead of publishing, refilled in batches of :data:`FRAME_BATCH` frames (a quarter of the look-ahead if
    that is fewer), so the per-call costs of sampling are shared.  The publisher only takes frames from that
    buffer and never waits on the solver's lock (both threads still share Python's GIL, which is what
    limits the timing at high rates).  The stream's own clock (its "publish time" tau) advances by
    1 / publish_rate per frame.
    Should the solver ever fall behind (real-time factor below 1), the publisher sends the last sample
    held (zero velocity) and the motion continues from there once frames are ready again (no position
    jump); diagnostics count these samples (held_late).  If the solver fails or the crane nears a
    singularity the stream goes to ERROR: the node holds the last sample it made (zero velocity) and
    diagnostics and the log report ERROR until deactivate, ``~/restart`` and activate.  A sample that is
    not finite is never published: the last valid one is held instead.

Commands
    A re-target (``ellipse.*``, ``z.*`` parameters), a speed change (``speed_scaling``) and ``~/pause``
    take effect at the frame ``command_lead`` seconds after the next one to be published (the
    frames from there on are dropped at once and made again after the command), so a change reaches the
    published samples within command_lead plus one period after it is accepted; diagnostics give both
    instants (``{command}_accepted_s``, ``{command}_stamp_s``).  If the worker cannot make the frame at the
    command point in time (a lead too short for a loaded machine: it shares the interpreter with the
    publisher and the executor), the publisher holds the last sample and counts it (held_late); it never
    publishes the motion from before the command past that point.
    Speed changes and pauses are C2 ramps of the stream's time warp.  ``~/restart`` (back to the
    static-equilibrium start: a position jump) is done while inactive only, at the next frame, and
    published from the next activation; while nothing is published a command needs no lead.
    Parameter values are validated in the on-set callback (table of
    :mod:`~crane_reference.ros.parameters`, then ``ReferenceStream.check_targets`` for the targets) and
    applied in the post-set callback, so ``set_parameters_atomically`` of ellipse.a and ellipse.b is one
    re-target, and a rejected change leaves the stream untouched.

Topics (all in the node's namespace but /diagnostics): ``~/joint_states`` (sensor_msgs/JointState),
``~/end_effector_pose`` (geometry_msgs/PoseStamped), ``~/reference_preview`` (trajectory_msgs/JointTrajectory
of ``preview.joints``, at ``preview.rate``), ``/diagnostics`` (diagnostic_msgs/DiagnosticArray, 1 Hz),
``~/markers`` (visualization_msgs/MarkerArray, 10 Hz: target ellipse and E's trail), ``~/robot_description``
(std_msgs/String, transient local); subscribed: ``~/speed_scaling`` (std_msgs/Float64).
Services: ``~/restart`` (std_srvs/Trigger), ``~/pause`` (std_srvs/SetBool).
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rcl_interfaces.msg import FloatingPointRange, SetParametersResult
from rclpy.exceptions import ParameterNotDeclaredException
from rclpy.executors import ExternalShutdownException
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, String
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
from ..stream.schedule import Frame, FrameSchedule
from ..stream.targets import UnreachableTargetError, reach
from ..stream.warmup import warm_up
from .message_types import rclpy_types
from .parameters import PARAMETERS, SPECS, TARGET_PARAMETERS, ParameterError, check, coerce_parameters, declare

NODE_NAME = messages.NODE_NAME
LOOKAHEAD = 1.0  # [s] of frames kept ready ahead of publishing
COMPUTE_SLICE = 0.005  # [s] of wall time the worker holds the stream per compute call
FRAME_BATCH = 20  # frames sampled per hold of the stream lock, and the room the worker waits for to refill
RELEASE_KEEP = 1.0  # [s] of computed motion kept before the next frame to compute (for commands)
MAX_CATCH_UP = 1.0  # [s]: if publishing falls further behind than this, the stamps leap (re-anchored)
MAX_WAIT = 0.1  # [s] of wall time the publisher sleeps at most before reading the clock again
MARKER_RATE = 10.0  # [Hz]
DEACTIVATE_MARGIN = 1.0  # [s] a deactivation waits beyond the ramp and the command lead for the rest sample
TRAIL_RATE = 50.0  # [Hz] of points added to E's trail
TRAIL_POINTS = 500
NANOSECONDS = messages.NANOSECONDS
RCLError = rclpy_implementation.RCLError


class StartupError(RuntimeError):
    """The node cannot start (unusable configuration or target)."""


class CraneReferenceNode(LifecycleNode):
    """Publishes the reference of the crane's programmed motion; see the module documentation."""

    def __init__(self, node_name: str = NODE_NAME, **kwargs) -> None:
        """Declare and read the parameters, publish diagnostics, and with ``autostart`` configure and
        activate.

        ``kwargs`` go to :class:`rclpy.node.Node` (``context``, ``parameter_overrides``, ``cli_args``...).
        Raises :class:`StartupError`, :class:`~crane_reference.model.config.ConfigError` or
        :class:`~crane_reference.ros.parameters.ParameterError` if a parameter is unusable, or with
        ``autostart`` if it cannot be configured.
        """
        super().__init__(node_name, **kwargs)
        self._types = rclpy_types()
        self._stream: ReferenceStream | None = None
        self._start_ns: int | None = None
        self._stop = threading.Event()  # the node is being destroyed
        self._halt = threading.Event()  # the solver thread stops (cleanup)
        self._quiet = threading.Event()  # the publisher thread stops (deactivate)
        self._starting = "unconfigured"  # the diagnostics' message while not publishing
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, messages.DIAGNOSTICS_TOPIC,
                                                      messages.PUBLISHER_DEPTH)
        self._threads: dict[str, threading.Thread] = {}
        self._start_thread("diagnostics", self._diagnostics_loop)
        try:
            config_file = declare(self, SPECS["config_file"])
            self._values = {spec.name: declare(self, spec, load_config(config_file or None))
                            for spec in PARAMETERS if spec.name != "config_file"}
            self._check_overrides()
        except Exception as error:
            self._fail_start(error)
            raise
        except BaseException:  # KeyboardInterrupt while starting
            self._stop.set()
            raise
        self._rate = int(self._values["publish_rate"])
        self._lock = threading.Condition()  # the schedule's buffer and counters (never held while solving)
        self._stream_lock = threading.Lock()  # the stream
        self.add_pre_set_parameters_callback(coerce_parameters)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.create_service(Trigger, "~/restart", self._on_restart)
        self.create_service(SetBool, "~/pause", self._on_pause)
        self.create_subscription(Float64, messages.SPEED_SCALING_TOPIC, self._on_speed_scaling,
                                 messages.PUBLISHER_DEPTH)
        self._status_timer = self.create_timer(self._values["status_period"], self._log_status)
        if self._values["autostart"]:
            if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                self._stop.set()
                raise StartupError(self._starting.removeprefix("cannot configure: "))
            self.trigger_activate()

    def _start_thread(self, name: str, target: Callable[[], None]) -> None:
        self._threads[name] = threading.Thread(target=target, name=f"crane_reference_{name}", daemon=True)
        self._threads[name].start()

    def _join_thread(self, name: str) -> None:
        thread = self._threads.pop(name, None)
        if thread is not None and thread is not threading.current_thread():
            thread.join()

    def _fail_start(self, error: Exception) -> None:
        """Report in /diagnostics (ERROR) and stop the diagnostics thread: the node cannot start."""
        self._starting = f"cannot start: {error}"
        with suppress(RCLError):  # the context may be shutting down already
            self._publish_diagnostics()
        self._stop.set()

    # -- lifecycle --------------------------------------------------------------------------------------

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Load the crane and the task, make every solver kernel ready, compute the start and the first
        second of motion, create the publishers; the solver thread computes ahead from here on."""
        try:
            config_file = self._values["config_file"] = self.get_parameter("config_file").value
            config = load_config(config_file or None)
            self._starting = "configuring: making the solver kernels ready (compiled on a first start, else loaded)"
            self.get_logger().info("making the solver kernels ready (with an empty kernel cache this compiles for "
                                   "a minute or two; `crane-reference compile` after installing does it ahead)")
            self.get_logger().info(f"solver {warm_up((self._values['model'],)).describe()}")
            self._starting = "configuring: computing the start"
            stream = self._make_stream(config)
            self._joint_names = list(stream.joint_names)
            self._preview_indices = self._joint_indices(self._values["preview.joints"])
        except (StartupError, ConfigError, ParameterError) as error:
            self._starting = f"cannot configure: {error}"
            self.get_logger().error(self._starting)
            return TransitionCallbackReturn.FAILURE
        self._stream = stream
        self._offer_reach(stream)
        self._schedule = FrameSchedule(self._rate, max(2, math.ceil(LOOKAHEAD * self._rate)),
                                       self._values["command_lead"], MAX_CATCH_UP, stream.sample(0.0))
        self._refill = min(FRAME_BATCH, max(1, self._schedule.lookahead // 4))  # frames made per batch at least
        self._last_restart: dict[str, str] = {}
        self._last_stamp = 0
        self._clock_note = ""  # a re-anchoring after a jump of the clock, reported once
        self._behind_clock = 0  # [ns] the clock is behind the last stamp (it went back)
        self._achieved_rate = 0.0
        self._late_reported = 0
        self._effective: dict[str, float] = {}  # command -> stamp [s] of the sample it takes effect at
        self._accepted: dict[str, float] = {}  # command -> node-clock time [s] it was accepted at
        self._commands_pending = 0  # commands whose frames are dropped and whose action is not applied yet
        self._trail: deque[np.ndarray] = deque(maxlen=TRAIL_POINTS)
        self._diagnostics_reference = (0, 0.0, 0.0, self.get_clock().now().nanoseconds)
        depth = messages.PUBLISHER_DEPTH
        self._publishers_managed = [
            self.create_lifecycle_publisher(JointState, messages.JOINT_STATES_TOPIC, depth),
            self.create_lifecycle_publisher(PoseStamped, messages.END_EFFECTOR_POSE_TOPIC, depth),
            self.create_lifecycle_publisher(JointTrajectory, messages.REFERENCE_PREVIEW_TOPIC, depth),
            self.create_lifecycle_publisher(MarkerArray, messages.MARKERS_TOPIC, depth)]
        self._joint_pub, self._pose_pub, self._preview_pub, self._marker_pub = self._publishers_managed
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self._description_pub = self.create_publisher(String, messages.ROBOT_DESCRIPTION_TOPIC, latched)
        self._description_pub.publish(messages.robot_description(self._types, model_to_urdf(stream.model)))
        self._marker_timer = self.create_timer(1.0 / MARKER_RATE, self._publish_markers)
        self._resume_on_activate = False
        self._halt.clear()
        self._start_thread("solver", self._work)
        self._starting = "inactive: configured, computing ahead; activate to publish"
        self.get_logger().info(f"configured: the {self._values['model']} crane ({len(self._joint_names)} joints, "
                               f"config {config_file or 'packaged default'})")
        return TransitionCallbackReturn.SUCCESS

    def _offer_reach(self, stream: ReferenceStream) -> None:
        """Narrow the ranges of ellipse.a and ellipse.b (what rqt_reconfigure's sliders and rclpy's range check
        use) to the crane's reach at its start and target heights (:func:`~crane_reference.stream.targets.reach`);
        every change is still checked around the whole ellipse."""
        heights = (stream.scenario.z_static, stream.scenario.z_static + self._values["z.increment"])
        low, high = reach(stream.scenario, self._values["ellipse.b"], heights, stream.singular_value_margin)
        for name in ("ellipse.a", "ellipse.b"):
            spec = SPECS[name]
            descriptor = spec.descriptor()
            descriptor.floating_point_range = [FloatingPointRange(from_value=low, to_value=high, step=0.0)]
            descriptor.additional_constraints = (
                f"must be a number in [{low:g}, {high:g}] m: E's reach from the column's axis at the start and "
                "target heights (computed at configure); the whole ellipse is checked when it is set")
            self.set_descriptor(name, descriptor)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Publish from the next sample on (stamps continue from the clock's present time); a reference
        stopped by a deactivation resumes along a speed ramp."""
        self._starting = "activating: waiting for the first second of motion"
        if self._stream.state == PAUSED and self._resume_on_activate:
            self._command("resume", self._stream.resume)
        self._resume_on_activate = False
        self._quiet.clear()
        self._start_thread("publisher", self._publish_loop)
        self.get_logger().info(f"publishing the {self._values['model']} crane's reference at {self._rate} Hz")
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Bring a moving reference to rest along a speed ramp, publish it to the first sample at rest, then
        stop publishing (the reference is held there)."""
        stream = self._stream
        if stream.state == "RUNNING" and stream.rate > 0.0:
            with self._command_point() as (k, tau, accepted), self._stream_lock:
                stream.pause(tau)
            self._announce("pause", k, accepted)
            rest_k = k + math.ceil((stream.settled_at() - tau) * self._rate - 1e-9) + 1
            deadline = time.monotonic() + stream.ramp_time + self._schedule.lead + DEACTIVATE_MARGIN
            while self._schedule.next_k <= rest_k and time.monotonic() < deadline and not self._stop.is_set():
                time.sleep(1.0 / self._rate)
            self._resume_on_activate = True
        self._stop_publishing()
        self._starting = "inactive: publishing stopped; activate to publish again"
        self.get_logger().info("deactivated: the reference is at rest and no longer published")
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop the solver thread and release the stream and the publishers."""
        self._release()
        self._starting = "unconfigured"
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop_publishing()
        self._release()
        self._starting = "finalized"
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop_publishing()
        self._release()
        self._starting = "unconfigured after an error in a transition"
        return TransitionCallbackReturn.SUCCESS

    def _stop_publishing(self) -> None:
        self._quiet.set()
        self._join_thread("publisher")
        self._start_ns = None

    def _release(self) -> None:
        if self._stream is None:
            return
        self._halt.set()
        with self._lock:
            self._lock.notify_all()
        self._join_thread("solver")
        for publisher in self._publishers_managed:
            self.destroy_lifecycle_publisher(publisher)
        self.destroy_publisher(self._description_pub)
        self.destroy_timer(self._marker_timer)
        self._stream = None

    # -- set-up ---------------------------------------------------------------------------------------

    def _check_undeclared_parameters(self, parameter_list: list[Parameter]) -> None:
        """Reject parameters this node does not have, naming them and the node's parameters (rclpy's own
        message lists none of them)."""
        unknown = [p.name for p in parameter_list if not self.has_parameter(p.name)]
        if unknown:
            raise ParameterNotDeclaredException(
                f"{', '.join(unknown)}: not a parameter of {self.get_fully_qualified_name()}; its parameters are "
                f"{', '.join(sorted(self._parameters))}")
        super()._check_undeclared_parameters(parameter_list)

    def _check_overrides(self) -> None:
        """Refuse to start with a parameter override (``-p``, a params file) for a name the node lacks."""
        unknown = sorted(name for name in self._parameter_overrides
                         if not self.has_parameter(name) and not name.startswith("qos_overrides."))
        if unknown:
            raise StartupError(f"unknown parameter(s) {', '.join(unknown)}; the node's parameters are "
                               f"{', '.join(sorted(self._parameters))}")

    def _joint_indices(self, names: list[str]) -> list[int]:
        """Coordinates of the joints ``names`` (StartupError / ParameterError naming the unknown ones)."""
        unknown = [name for name in names if name not in self._joint_names]
        if unknown:
            raise ParameterError(f"preview.joints = {names!r}: {', '.join(unknown)} not joints of the "
                                 f"{self._values['model']} model; its joints are {', '.join(self._joint_names)}")
        return [self._joint_names.index(name) for name in names]

    def _targets(self, overrides: dict[str, float] | None = None) -> Task:
        """Targets of the current parameter values, with ``overrides`` (parameter name -> value)."""
        values = {**self._values, **(overrides or {})}
        return Task(**{field: float(values[name]) for name, field in TARGET_PARAMETERS.items()})

    def _make_stream(self, config: CraneParameters) -> ReferenceStream:
        v = self._values
        targets = self._targets()
        try:
            stream = ReferenceStream(config, v["model"], v["integrator.step"], v["blend_time"], targets,
                                     column_drive(config, v["drive.torque"], v["drive.duration"]),
                                     speed_scaling=v["speed_scaling"], ramp_time=v["speed_scaling.ramp_time"])
            stream.check_targets(targets)
        except UnreachableTargetError as error:
            raise StartupError(f"ellipse.* / z.* = {targets}: {error}") from error
        except SOLVER_FAILURES as error:
            raise StartupError(f"no consistent start for the targets {targets}: {error}") from error
        return stream

    # -- computing ahead (worker thread) --------------------------------------------------------------

    def _work(self) -> None:
        """Keep LOOKAHEAD of frames ready ahead of publishing and the motion computed beyond them."""
        schedule = self._schedule
        try:
            while not self._halt.is_set():
                with self._lock:
                    while self._commands_pending and not self._halt.is_set():  # frames after a command once
                        self._lock.wait(timeout=LOOKAHEAD)  # it is applied
                    plan = schedule.plan()
                    fault = schedule.fault
                    # in batches, but up to the whole look-ahead before publishing starts
                    refill = plan.room >= self._refill or self._start_ns is None
                    count = min(plan.room, FRAME_BATCH) if refill else 0
                with self._stream_lock:
                    if plan.generation != schedule.generation:  # a command came in meanwhile: plan again
                        continue
                    frames, next_preview_k, busy = schedule.make_frames(
                        self._stream, plan, count, self._values["preview.horizon"],
                        self._values["preview.points"] - 1, self._preview_decimation(),
                        COMPUTE_SLICE if self._start_ns is not None else None)  # all before starting
                    self._stream.release(plan.tau, RELEASE_KEEP + LOOKAHEAD)
                if schedule.fault != fault:
                    self.get_logger().error(schedule.fault, throttle_duration_sec=1.0)
                with self._lock:
                    if schedule.accept(frames, plan, next_preview_k) and not frames and not busy:
                        self._lock.wait(timeout=LOOKAHEAD)
        except Exception as error:  # publishing goes on (holding) and reports it
            schedule.fault = f"solver thread stopped: {type(error).__name__}: {error}"
            self.get_logger().error(schedule.fault)

    def _preview_decimation(self) -> int:
        """Samples between two previews."""
        return max(1, round(self._rate / self._values["preview.rate"]))

    # -- commands (executor threads) ------------------------------------------------------------------

    @contextmanager
    def _command_point(self) -> Iterator[tuple[int, float, int]]:
        """The schedule's command point, frame k at stream time tau (command_lead after the next sample to
        publish, decided on acceptance), and the acceptance time [ns].  The frames from k on are dropped at
        once and the worker makes none until the block ends, so no frame of the motion before the command
        is published from that point."""
        accepted = self.get_clock().now().nanoseconds
        with self._lock:
            k, tau = self._schedule.command_point(lead=self._start_ns is not None)  # no lead while not publishing
            self._schedule.after_command(k, tau)
            self._commands_pending += 1
        try:
            yield k, tau, accepted
        finally:
            with self._lock:
                self._commands_pending -= 1
                self._lock.notify_all()  # the worker makes the frames from k now, not at the next publish

    def _announce(self, name: str, k: int, accepted: int) -> None:
        """Record that command ``name`` accepted at ``accepted`` [ns] takes effect at sample k (diagnostics
        ``{name}_stamp_s``, ``{name}_accepted_s``)."""
        self._effective[name] = self._stamp_s(k)
        self._accepted[name] = accepted / NANOSECONDS

    def _command(self, name: str, action: Callable[[float], None]) -> int:
        """Apply ``action(tau)`` to the stream at the command point (:meth:`_command_point`) and announce it.
        Returns the index of that frame.  Exceptions of ``action`` propagate with the stream untouched (the
        dropped frames are made again, the same)."""
        with self._command_point() as (k, tau, accepted), self._stream_lock:
            action(tau)
        self._announce(name, k, accepted)
        return k

    def _stamp_s(self, k: int) -> float:
        """Stamp [s] of sample k (relative to the start if publishing has not begun)."""
        return messages.stamp_at(self._start_ns or 0, k, self._rate) / NANOSECONDS

    def _lifecycle_state(self) -> str:
        """The primary lifecycle state, from what the transitions set up: a stream after configure, a
        publisher thread after activate."""
        if self._stream is None:
            return "unconfigured"
        return "active" if "publisher" in self._threads else "inactive"

    def _on_restart(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """~/restart (while inactive): back to the static-equilibrium start of the current targets, also out of
        ERROR.  The position jumps to the start, so it is refused while active: consumers see the stream
        stop (deactivate), and it goes on from the start when activated again; the response and the
        diagnostics (restart_*) say by how much it jumps."""
        state = self._lifecycle_state()
        if state != "inactive":
            response.success = False
            response.message = (f"refused while {state}: a restart makes the reference jump to the start, so it is "
                                "done while inactive (deactivate, restart, activate)" if state == "active" else
                                f"refused while {state}: configure the node first")
            return response
        try:
            with self._command_point() as (k, tau, accepted), self._stream_lock:
                stream = self._stream
                stream.compute(tau)
                before = stream.sample(tau).q
                stream.restart(tau)
                after = stream.start_configuration()
                self._schedule.fault = ""
                self._resume_on_activate = False
        except SOLVER_FAILURES as error:
            response.success, response.message = False, f"restart failed, stream unchanged: {error}"
        else:
            self._trail.clear()
            jump = np.abs(after - before)
            joint = self._joint_names[int(np.argmax(jump))]
            self._announce("restart", k, accepted)
            self._last_restart = {"restart_jump_rad": f"{jump.max():.6g}", "restart_jump_joint": joint}
            response.success = True
            response.message = (f"restarted from the static equilibrium at sample {k}, published once active: "
                                f"position jump up to {jump.max():.6g} (SI units) on {joint}")
        self.get_logger().info(response.message)
        return response

    def _on_pause(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        """~/pause: data true holds the reference (zero velocity), data false resumes it."""
        if self._stream is None:
            response.success, response.message = False, f"refused while {self._lifecycle_state()}: configure first"
            return response
        state = self._stream.state
        wanted = PAUSED if request.data else "RUNNING"
        if state == ERROR:
            response.success = False
            response.message = (f"the stream is in ERROR ({self._stream.last_error}); deactivate, call ~/restart "
                                "and activate")
        elif state == wanted:
            response.success, response.message = True, f"already {state.lower()}"
        else:
            k = self._command("pause" if request.data else "resume",
                              self._stream.pause if request.data else self._stream.resume)
            verb = "coming to rest" if request.data else "resuming"
            response.success = True
            response.message = (f"{verb} from the sample stamped {self._stamp_s(k):.6f} s over "
                                f"{self._stream.ramp_time:g} s")
        self.get_logger().info(f"~/pause {request.data}: {response.message}")
        return response

    def _on_speed_scaling(self, msg: Float64) -> None:
        """~/speed_scaling (std_msgs/Float64): sets the speed_scaling parameter (same checks and ramp)."""
        result = self.set_parameters([Parameter("speed_scaling", Parameter.Type.DOUBLE, float(msg.data))])[0]
        if not result.successful:
            self.get_logger().error(f"~/speed_scaling rejected: {result.reason}", throttle_duration_sec=1.0)

    def _validate_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        """On-set callback: the table's checks, then the reachability of changed targets."""
        reason = check(parameters)
        joints = next((p.value for p in parameters if p.name == "preview.joints"), None)
        if reason is None and joints is not None and self._stream is not None:  # else checked at configure
            try:
                self._joint_indices(list(joints))
            except ParameterError as error:
                reason = str(error)
        changed = {p.name: p.value for p in parameters if p.name in TARGET_PARAMETERS}
        if reason is None and changed and self._stream is not None:  # else checked at configure
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
        if "status_period" in names:
            self._status_timer.timer_period_ns = round(self._values["status_period"] * NANOSECONDS)
            self._status_timer.reset()
        if self._stream is None:  # the values are read at configure
            return
        if "blend_time" in names:
            with self._stream_lock:
                self._stream.set_blend_time(self._values["blend_time"])
        if "command_lead" in names:
            with self._lock:
                self._schedule.lead = self._values["command_lead"]
        if "preview.joints" in names:
            self._preview_indices = self._joint_indices(list(self._values["preview.joints"]))
        if "speed_scaling" in names:
            rate = self._values["speed_scaling"]
            k = self._command("speed_scaling", lambda tau: self._stream.set_speed_scaling(tau, rate))
            self.get_logger().info(f"speed scaling {rate:g} from the sample stamped {self._stamp_s(k):.6f} s")
        if any(name in TARGET_PARAMETERS for name in names) and self._targets() != self._stream.targets:
            targets = self._targets()
            # the targets passed check_targets in the on-set callback
            k = self._command("retarget", lambda tau: self._stream.retarget(tau, targets, checked=True))
            self.get_logger().info(f"re-targeting to {targets} from the sample stamped {self._stamp_s(k):.6f} s "
                                   f"over {self._values['blend_time']:g} s")

    # -- publishing (publisher thread and timers) ------------------------------------------------------

    def _publish_loop(self) -> None:
        """Publisher thread: a timer on the node clock that wakes at each sample's stamp to publish it.

        It starts once LOOKAHEAD of frames is ready and the clock runs (ROS time is 0 until the first
        /clock with use_sim_time).  It sleeps in wall time for the time left on the node clock and checks
        that clock again (at least every MAX_WAIT), so it follows ROS time and stops at once when the node is
        destroyed.  Jumps of the clock (/clock jumping, use_sim_time switched, a bag replayed from its start)
        never make stamps go back or skip motion (:meth:`FrameSchedule.anchored`): forward, the stamps leap
        with the clock; back, publishing waits until the clock reaches the next stamp again.  Diagnostics
        WARN about both.
        """
        clock = self.get_clock()
        try:
            ready = self._schedule.next_k + self._schedule.lookahead  # the look-ahead of frames from the next one
            while not self._quiet.is_set() and (self._schedule.made_k < ready or clock.now().nanoseconds == 0):
                if self._schedule.made_k >= ready:
                    self._starting = "activating: waiting for /clock (use_sim_time is true and ROS time is 0)"
                self._quiet.wait(1.0 / self._rate)
            now = clock.now().nanoseconds
            start = max(now, self._last_stamp + NANOSECONDS // self._rate)  # stamps go on increasing
            self._start_ns = start - self._schedule.next_k * NANOSECONDS // self._rate
            self._diagnostics_reference = (self._schedule.counters.published, self._schedule.compute_wall,
                                           self._schedule.compute_motion, now)
            while not self._quiet.is_set():
                now = clock.now().nanoseconds
                start = self._schedule.anchored(now, self._start_ns)
                if start != self._start_ns:
                    self._clock_note = (f"ROS time jumped {(start - self._start_ns) / NANOSECONDS:.3f} s ahead of the "
                                        "schedule: the stamps leap with it, no sample skipped")
                    self._start_ns = start
                behind = self._last_stamp - now
                self._behind_clock = behind if behind > NANOSECONDS // self._rate else 0
                self._publish(now)
                left = messages.stamp_at(self._start_ns, self._schedule.next_k, self._rate) - clock.now().nanoseconds
                if left > 0:
                    self._quiet.wait(min(left / NANOSECONDS, MAX_WAIT))
        except RCLError:
            if self.context.ok():
                raise  # not a shutdown: let the thread report it

    def _publish(self, now: int) -> None:
        """Publish every sample due by ``now`` [ns] (normally one), each stamped start + k / rate."""
        with self._lock:
            batch = self._schedule.due(now, self._start_ns)
            if self._schedule.room >= self._refill:
                self._lock.notify()
        for k, frame in batch:
            self._send(k, frame)

    def _send(self, k: int, frame: Frame | None) -> None:
        """Publish sample k: the frame's, or the last one held if the solver is late."""
        frame = self._schedule.outgoing(k, frame)
        if frame is None:
            return
        sample = frame.sample
        types, frame_id = self._types, self._values["frame_id"]
        stamp = messages.stamp_at(self._start_ns, k, self._rate)
        self._joint_pub.publish(messages.joint_state(types, stamp, self._joint_names, sample))
        self._pose_pub.publish(messages.end_effector_pose(types, stamp, frame_id, sample))
        if frame.preview is not None:
            horizon_ns, count = round(frame.horizon * NANOSECONDS), len(frame.preview)
            offsets = [i * horizon_ns // count for i in range(count + 1)]
            names = [self._joint_names[i] for i in self._preview_indices]
            self._preview_pub.publish(messages.reference_preview(
                types, stamp, frame_id, names, self._preview_indices, offsets, [sample, *frame.preview],
                self._values["preview.effort"]))
        if k % max(1, round(self._rate / TRAIL_RATE)) == 0:
            self._trail.append(sample.ee_position)
        self._last_stamp = stamp

    def _publish_markers(self) -> None:
        """~/markers (timer): the target ellipse at the final height and E's trail, stamped like the last sample."""
        if self._schedule.last is None:
            return
        targets = self._stream.targets
        z = self._stream.scenario.z_static + targets.z_increment
        self._marker_pub.publish(messages.markers(self._types, self._last_stamp, self._values["frame_id"],
                                                  (targets.ellipse_a, targets.ellipse_b, z), np.array(self._trail)))

    def _rates(self) -> tuple[float, float]:
        """Achieved publish rate [Hz] and solver real-time factor since the last call."""
        schedule = self._schedule
        published, wall, motion, now = (schedule.counters.published, schedule.compute_wall, schedule.compute_motion,
                                        self.get_clock().now().nanoseconds)
        last_published, last_wall, last_motion, last_now = self._diagnostics_reference
        self._diagnostics_reference = (published, wall, motion, now)
        rate = (published - last_published) * NANOSECONDS / (now - last_now) if now > last_now else 0.0
        factor = (motion - last_motion) / (wall - last_wall) if wall > last_wall else math.inf
        return rate, factor

    def _diagnostics_loop(self) -> None:
        """Diagnostics thread: /diagnostics every DIAGNOSTICS_PERIOD of wall time from the node's creation on
        (while it starts, and whether or not the ROS clock runs)."""
        try:
            while not self._stop.wait(messages.DIAGNOSTICS_PERIOD):
                self._publish_diagnostics()
        except RCLError:
            if self.context.ok():
                raise  # not a shutdown: let the thread report it

    def _publish_diagnostics(self) -> None:
        """/diagnostics: before publishing starts, what the node is doing (or why it cannot start); then
        state, constraint residual, real-time factor, achieved rate, counters."""
        if self._start_ns is None:
            level = messages.ERROR if self._starting.startswith("cannot") else messages.OK
            self._diagnostics_pub.publish(messages.diagnostics(
                self._types, self.get_clock().now().nanoseconds, f"{self.get_name()}: reference",
                self.get_fully_qualified_name(), level, self._starting, {}))
            return
        rate, factor = self._rates()
        self._achieved_rate = rate
        counters, fault = self._schedule.counters, self._schedule.fault
        late, self._late_reported = counters.held_late - self._late_reported, counters.held_late
        stream = self._stream
        sample = self._schedule.last
        level = messages.OK
        message = stream.state
        if stream.state == ERROR or fault:
            level, message = messages.ERROR, f"{stream.state}: {stream.last_error or fault}"
        elif self._behind_clock:
            level, message = messages.WARN, (f"{stream.state}: ROS time went back: waiting until it reaches the last "
                                             f"stamp again ({self._behind_clock / NANOSECONDS:.3f} s ahead)")
        elif self._clock_note:
            level, message = messages.WARN, f"{stream.state}: {self._clock_note}"
            self._clock_note = ""
        elif late > 0:
            level, message = messages.WARN, f"{stream.state}: {late} samples held (solver late)"
        values = messages.diagnostic_values(
            stream.state, sample, factor, self._rate, rate, counters.as_dict(), stream.targets, stream.rate,
            stream.last_error or fault,
            {"frames_ready": len(self._schedule.frames),
             **{f"{name}_stamp_s": f"{stamp:.6f}" for name, stamp in self._effective.items()},
             **{f"{name}_accepted_s": f"{stamp:.6f}" for name, stamp in self._accepted.items()}, **self._last_restart})
        stamp = self.get_clock().now().nanoseconds
        self._diagnostics_pub.publish(messages.diagnostics(
            self._types, stamp, f"{self.get_name()}: reference", self.get_fully_qualified_name(), level, message,
            values))
        if level == messages.ERROR:
            self.get_logger().error(message, throttle_duration_sec=10.0)

    def _log_status(self) -> None:
        """One-line status: stream time, E, residual, achieved rate, state."""
        sample = self._schedule.last if self._stream is not None else None
        if sample is None:
            return
        x, y, z = sample.ee_position
        self.get_logger().info(
            f"t={sample.t:.3f} s E=({x:.3f}, {y:.3f}, {z:.3f}) m residual={sample.residual_distance:.1e} m "
            f"rate={self._achieved_rate:.1f} Hz state={self._stream.state}")

    def destroy_node(self) -> None:
        """Stop the solver and publisher threads, then destroy the node."""
        self._stop.set()
        self._stop_publishing()
        self._halt.set()
        if hasattr(self, "_lock"):
            with self._lock:
                self._lock.notify_all()
        for name in list(self._threads):
            self._join_thread(name)
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

"""What the node publishes and when: the samples at their stamps (a thread), ~/markers (a thread, while active)
and /diagnostics (a thread, every second of wall time from the node's creation on).

Sample k is stamped ``start + k / publish_rate`` (integer nanoseconds) by the
:class:`~crane_reference.stream.server.ReferenceServer`; the publisher thread sleeps until the next stamp on
the node clock and publishes every sample due (normally one), so no sample is skipped or duplicated when it
wakes late.  A thread rather than an rclpy timer publishes because rclpy's executor adds its overhead to every
timer callback and runs the (slow) parameter validation on the same thread.  ~/joint_states and
~/end_effector_pose are serialized once, as prototypes; the numbers of each batch of frames are written into
copies of them at once as the batch comes (:class:`~.sample_encoder.SampleEncoder`, in the server's frame
worker), so the publisher thread only stamps each message and publishes its bytes
(:mod:`crane_reference.interface.serialized`).
It reads the node clock through rclpy only while ROS time is active (use_sim_time): otherwise that clock is the
system clock, read with one system call.
The reference topics take ``qos_overrides.<topic>.publisher.<policy>`` parameters (rclpy's QoS overriding),
e.g. ``-p qos_overrides./crane_reference/joint_states.publisher.depth:=50``.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rclpy.clock import ClockChange, JumpThreshold, ROSClock, TimeJump
from rclpy.lifecycle import LifecycleNode
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, QoSPolicyKind, QoSProfile
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import MarkerArray

from ..base.health import Level, startup_health
from ..base.threads import real_time_switching, start_named
from ..interface import messages
from ..interface.serialized import SerializedPreview
from ..model.units import NANOSECONDS
from ..stream.health import serving_health
from ..stream.served import Outgoing
from ..stream.server import ReferenceServer
from .sample_encoder import SampleEncoder

OVERRIDABLE = QoSOverridingOptions([QoSPolicyKind.HISTORY, QoSPolicyKind.DEPTH, QoSPolicyKind.RELIABILITY,
                                    QoSPolicyKind.DURABILITY])
"""The QoS policies a reference topic's ``qos_overrides`` parameters may set (rclpy's defaults and durability:
a transient-local preview reaches a controller that starts late)."""
MAX_WAIT = 0.1  # [s] of wall time the publisher sleeps at most before reading the clock again
SLEEP_LIMIT = 20_000_000  # [ns]: the publisher sleeps shorter waits plainly (an Event's wait costs more per
# wake-up; stopping then waits for the sleep to end, at most this long)
MARKER_RATE = 10.0  # [Hz]
TRAIL_RATE = 50.0  # [Hz] of points added to E's trail
TRAIL_POINTS = 500


publish = Publisher.publish
"""How the publisher thread publishes a sample's bytes on a lifecycle publisher: rclpy's Publisher.publish, without
the lifecycle wrapper's check that the publisher is enabled (microseconds a message): the thread runs only while
the node is active (started by activate, joined by deactivate), when every lifecycle publisher is enabled."""


def run_until_shutdown(node: LifecycleNode, loop: Callable[[], None]) -> Callable[[], None]:
    """``loop`` for a thread of ``node``: an error once its context is shut down (SIGINT, SIGTERM while it
    publishes) ends it quietly; any other propagates (the thread reports it)."""
    def run() -> None:
        try:
            loop()
        except Exception:
            if node.context.ok():
                raise
    return run


class NodeTime:
    """A reader of ``clock`` (a node's) [ns]: rclpy's reading while ROS time is active; otherwise the system time
    that rclpy would read (rcl's system clock, CLOCK_REALTIME), without converting it to an rclpy Time.  Whether
    ROS time is active (use_sim_time) is kept from rclpy's jump callback on a change of clock, registered while
    the reader is open (a context manager): asking rclpy at every reading costs microseconds."""

    def __init__(self, clock: ROSClock):
        self._clock = clock
        self._handle = clock.create_jump_callback(
            JumpThreshold(min_forward=None, min_backward=None, on_clock_change=True), post_callback=self._changed)
        self.ros_time_active = clock.ros_time_is_active  # after registering: no change is missed

    def _changed(self, jump: TimeJump) -> None:
        if jump.clock_change in (ClockChange.ROS_TIME_ACTIVATED, ClockChange.ROS_TIME_DEACTIVATED):
            self.ros_time_active = jump.clock_change == ClockChange.ROS_TIME_ACTIVATED

    def __call__(self) -> int:
        return self._clock.now().nanoseconds if self.ros_time_active else time.time_ns()

    def __enter__(self) -> NodeTime:
        return self

    def __exit__(self, *_: object) -> None:
        self._handle.unregister()


@dataclass(frozen=True)
class PublishSettings:
    """What the parameters choose of the messages: the frame of poses, previews and markers (prefixed), the
    preview's joints (coordinate indices) and whether previews carry efforts."""

    frame_id: str
    preview_indices: tuple[int, ...]
    preview_effort: bool


class SamplePublisher:
    """The reference's lifecycle publishers (made at configure), its publisher thread (while active) and
    the ~/markers timer; ``settings`` may be replaced at any time (parameter changes).  ``encode`` is the
    encoder the server was given."""

    def __init__(self, node: LifecycleNode, types: messages.MessageTypes, server: ReferenceServer,
                 settings: PublishSettings, encode: SampleEncoder):
        self.node, self.types, self.server, self.encode = node, types, server, encode
        self.settings = settings
        self.joint_names = list(server.info.joint_names)
        self.trail: deque[Any] = deque(maxlen=TRAIL_POINTS)  # E's positions as Point messages
        self._trail_stride = max(1, round(server.rate / TRAIL_RATE))  # samples between two trail points
        self._ellipse: tuple[tuple[float, ...], list[Any]] = ((), [])  # (a, b, z) and its Point messages
        self._preview_writer: tuple[tuple, SerializedPreview] | None = None  # for (settings, horizon, points)
        depth, overridable = messages.PUBLISHER_DEPTH, OVERRIDABLE
        self._managed = [node.create_lifecycle_publisher(message_type, topic, depth, qos_overriding_options=overridable)
                         for message_type, topic in ((JointState, messages.JOINT_STATES_TOPIC),
                                                     (PoseStamped, messages.END_EFFECTOR_POSE_TOPIC),
                                                     (JointTrajectory, messages.REFERENCE_PREVIEW_TOPIC),
                                                     (MarkerArray, messages.MARKERS_TOPIC))]
        self._joints, self._poses, self._previews, self._markers = self._managed
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self._description = node.create_publisher(String, messages.ROBOT_DESCRIPTION_TOPIC, latched)
        self._description.publish(messages.robot_description(types, server.info.urdf))
        self._quiet = threading.Event()
        self._thread: threading.Thread | None = None
        self._marker_thread: threading.Thread | None = None
        self.waiting_for_clock = False

    @property
    def settings(self) -> PublishSettings:
        return self._settings

    @settings.setter
    def settings(self, settings: PublishSettings) -> None:
        self.encode.frame_id = settings.frame_id  # first: a sample re-encoded for the new frame gets it
        self._settings = settings

    @property
    def active(self) -> bool:
        return self._thread is not None

    def start(self) -> None:
        """Start the publisher thread and the markers' (activate)."""
        self._quiet.clear()
        self._thread = start_named(run_until_shutdown(self.node, self._loop), "ref_publisher")
        self._marker_thread = start_named(run_until_shutdown(self.node, self._markers_loop), "ref_markers")

    def stop(self) -> None:
        """Stop the publisher thread and the markers' (deactivate, shutdown); the server ends publishing."""
        self._quiet.set()
        threads, self._thread, self._marker_thread = (self._thread, self._marker_thread), None, None
        for thread in threads:
            if thread is not None and thread is not threading.current_thread():
                thread.join()
        self.server.end()

    def destroy(self) -> None:
        """Destroy the publishers (cleanup)."""
        for publisher in self._managed:
            self.node.destroy_lifecycle_publisher(publisher)
        self.node.destroy_publisher(self._description)

    def _markers_loop(self) -> None:
        """:meth:`publish_markers` at MARKER_RATE while active (a thread of its own: a timer would wake the
        executor, which costs more than the check)."""
        while not self._quiet.wait(1.0 / MARKER_RATE):
            self.publish_markers()

    def _loop(self) -> None:
        """Wake at each sample's stamp on the node clock to publish it.

        It starts once the server's look-ahead of frames is ready and the clock runs (ROS time is 0 until the
        first /clock with use_sim_time).  It sleeps in wall time for the time left on the node clock and checks
        that clock again (at least every MAX_WAIT), so it follows ROS time and stops within SLEEP_LIMIT.  The
        node clock is read once a wake-up (:class:`NodeTime`); the time the publishing took is added from the
        monotonic clock.  A wait of up to SLEEP_LIMIT is a plain sleep.  While it publishes, Python's thread switch
        interval is short (:func:`~crane_reference.base.threads.real_time_switching`), so that a wake-up gets the
        GIL from the node's other threads within it.
        """
        with NodeTime(self.node.get_clock()) as clock:
            server, rate = self.server, self.server.rate
            while not self._quiet.is_set() and (not server.ready() or clock() == 0):
                self.waiting_for_clock = server.ready()
                self._quiet.wait(1.0 / rate)
            self.waiting_for_clock = False
            if self._quiet.is_set():  # stopped before publishing began: nothing to begin
                return
            server.begin(clock())
            quiet, send = self._quiet, self.send
            read_at = 0  # the monotonic time [ns] of the last reading of the clock

            def read_clock() -> int:
                nonlocal read_at
                read_at = time.monotonic_ns()
                return clock()

            with real_time_switching():
                while not quiet.is_set():
                    due = server.due(read_clock)
                    for outgoing in due.outgoing:
                        send(outgoing)
                    left = due.next_stamp_ns - due.now_ns - (time.monotonic_ns() - read_at)
                    if left > SLEEP_LIMIT:  # long (a slow rate, a stalled or reset clock): stopping wakes it
                        quiet.wait(min(left / NANOSECONDS, MAX_WAIT))
                    elif left > 0:  # within a period at 50 Hz or faster: one system call (an Event's wait takes locks)
                        time.sleep(left / NANOSECONDS)

    def send(self, outgoing: Outgoing) -> None:
        """Publish one sample, a row of the stacked frames: joint states and E's pose (the frames' rows of
        :attr:`encode`, stamped; a held sample's, or one made before a change of frame, encoded here alone), the
        preview if the row has one (serialized once, then filled in place and published as bytes); E's trail."""
        frames, row, stamp, settings = outgoing.frames, outgoing.row, outgoing.stamp_ns, self.settings
        samples, wire, wire_row = frames.samples, frames.wire, row
        if wire is None or wire.frame_id != settings.frame_id:
            wire, wire_row = self.encode(samples.take(slice(row, row + 1))), 0
        publish(self._joints, wire.joint_states.stamped(wire_row, stamp))
        publish(self._poses, wire.poses.stamped(wire_row, stamp))
        preview = frames.previews.get(row)
        if preview is not None:
            key = (settings, frames.horizon, preview.t.size)
            if self._preview_writer is None or self._preview_writer[0] != key:
                indices = list(settings.preview_indices)
                self._preview_writer = key, SerializedPreview(serialize_message(messages.reference_preview(
                    self.types, stamp, settings.frame_id, [self.joint_names[i] for i in indices], indices,
                    messages.preview_offsets(frames.horizon, preview.t.size), [samples.row(row), *preview.rows()],
                    settings.preview_effort)), indices)
            publish(self._previews, self._preview_writer[1].fill_row(stamp, samples, row, preview))
        if outgoing.k % self._trail_stride == 0:
            self.trail.append(messages.point(self.types, samples.ee_position[row]))

    def publish_markers(self) -> None:
        """~/markers: the target ellipse at the final height and E's trail, stamped like the last sample;
        built and published only while something subscribes (RViz; the trail is kept meanwhile)."""
        sample, stamp = self.server.last_sample()
        if sample is None or self._markers.get_subscription_count() == 0:  # nobody looks: nothing to build
            return
        targets = self.server.stream.targets
        ellipse = (targets.ellipse_a, targets.ellipse_b, self.server.info.z_static + targets.z_increment)
        if ellipse != self._ellipse[0]:
            self._ellipse = ellipse, messages.points(self.types, messages.ellipse_points(*ellipse))
        self._markers.publish(messages.markers(self.types, stamp, self.settings.frame_id, self._ellipse[1],
                                               list(self.trail)))


class DiagnosticsPublisher:
    """/diagnostics every DIAGNOSTICS_PERIOD of wall time from the node's creation on, in every state: before
    publishing, what ``activity()`` says the node does (or why it cannot start); then the server's status
    (:mod:`crane_reference.stream.health`).  ``server()`` is the node's server (None unconfigured)."""

    def __init__(self, node: LifecycleNode, types: messages.MessageTypes, activity: Callable[[], str],
                 server: Callable[[], ReferenceServer | None], stopped: threading.Event):
        self.node, self.types, self._activity, self._server, self._stopped = node, types, activity, server, stopped
        self._publisher = node.create_publisher(DiagnosticArray, messages.DIAGNOSTICS_TOPIC, messages.PUBLISHER_DEPTH)
        self._held_reported = 0
        self.achieved_rate = 0.0
        self._thread = start_named(run_until_shutdown(node, self._loop), "ref_diagnostics")

    def log_status(self) -> None:
        """One-line status in the node's log (a timer): stream time, E, residual, achieved rate, state."""
        server = self._server()
        sample = server.last_sample().sample if server is not None else None
        if sample is None:
            return
        x, y, z = sample.ee_position
        self.node.get_logger().info(
            f"t={sample.t:.3f} s E=({x:.3f}, {y:.3f}, {z:.3f}) m residual={sample.residual_distance:.1e} m "
            f"rate={self.achieved_rate:.1f} Hz state={server.stream.state}")

    def join(self) -> None:
        if self._thread is not threading.current_thread():
            self._thread.join()

    def _loop(self) -> None:
        while not self._stopped.wait(messages.DIAGNOSTICS_PERIOD):
            self.publish()

    def publish(self) -> None:
        """One /diagnostics message: unconfigured, what the node is doing (or why it cannot start); configured,
        also the server's values (state, constraint residual, real-time factor, achieved rate, counters, the last
        commands and restart), with what the node is doing as the message while it does not publish, unless the
        solver stopped or the stream failed (ERROR)."""
        node, server = self.node, self._server()
        now = node.get_clock().now().nanoseconds
        name, hardware_id = f"{node.get_name()}: reference", node.get_fully_qualified_name()
        if server is None:
            health = startup_health(self._activity())
            self._publisher.publish(messages.diagnostics(self.types, now, name, hardware_id, health.level,
                                                         health.message, {}))
            return
        status = server.status(now)
        stream, counters = status.stream, status.counters
        health = serving_health(status, counters["held_late"] - self._held_reported)
        if not server.publishing and health.level != Level.ERROR:
            health = startup_health(self._activity())
        self._held_reported = counters["held_late"]
        self.achieved_rate = status.achieved_rate
        values = messages.diagnostic_values(
            stream.state, status.last, status.real_time_factor, server.rate, status.achieved_rate, counters,
            stream.targets, stream.target_speed, stream.last_error or status.fault,
            {"frames_ready": status.frames_ready, "blend_time_s": f"{node.get_parameter('blend_time').value:g}",
             **status.commands})
        self._publisher.publish(messages.diagnostics(self.types, node.get_clock().now().nanoseconds, name,
                                                     hardware_id, health.level, health.message, values))
        if health.level == Level.ERROR:
            node.get_logger().error(health.message, throttle_duration_sec=10.0)

"""Live recording to rosbag2 without rosbag2: ``crane-reference record [-o DIR] [--storage mcap|sqlite3]
[--version 9|8] [--duration S] [--node NAME] [TOPIC ...]``.

Without TOPICs it records every topic the node ``--node`` (default ``/crane_reference``) publishes, as
the ROS graph shows them (``get_publisher_names_and_types_by_node``), so a renamed or namespaced node is
recorded with its actual topics; ``/rosout`` and ``/parameter_events`` are left out.

A :class:`Recorder` subscribes with rclpy to each topic once a publisher of it is discovered
(``get_topic_names_and_types`` / ``get_publishers_info_by_topic``, polled: at every turn of the loop, at most
:data:`SPIN_TIMEOUT` apart, until a topic is recorded, then every :data:`DISCOVERY_PERIOD`, so topics that
appear later are added then), with ``raw=True``: the serialized CDR bytes go to a
:class:`~crane_reference.interface.bag.BagWriter` unchanged, stamped with the receive time on the node
clock (rosbag2's semantics).  Each topic is registered with the publishers' type (its RIHS01 hash must
equal rosbags' Jazzy typestore's, i.e. the installed message packages') and their offered QoS profiles;
the subscription adapts to the offers as rosbag2 does (reliable if every publisher is, transient local
if every publisher is).

:func:`record_command` stops at SIGINT or SIGTERM (or after ``--duration``): it takes what is
already waiting in the subscriptions' queues, then closes the bag (indexes, metadata.yaml) in a
``finally``, so every message received before the signal is in the bag and the bag opens.  A status
line on stderr (topics, counts, size) refreshes about once a second; at exit the received counts are
printed on stdout.
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable
from datetime import datetime
from functools import partial
from pathlib import Path
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.expand_topic_name import expand_topic_name
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.topic_endpoint_info import TopicEndpointInfo
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

from ..interface.bag import BagError, BagWriter
from ..model.units import NANOSECONDS

RECORD_DEPTH = 1000  # history depth of the recording subscriptions
DISCOVERY_PERIOD = 0.2  # [s] between two looks at the ROS graph for topics not yet recorded, once one is
STATUS_PERIOD = 1.0  # [s] between two status lines
SPIN_TIMEOUT = 0.05  # [s], longest wait for a message before the loop looks at signals, discovery and status
DRAIN_TIME = 0.2  # [s], longest time spent taking the messages already queued when stopping
IGNORED_TOPICS = ("/rosout", "/parameter_events")  # published by every node


def rosbags_qos(profile: QoSProfile) -> Qos:
    """rosbags' Qos of an rclpy QoS profile (durations as rmw_time_t: infinite is sec 9223372036, nsec
    854775807, as rosbag2 writes it)."""

    def duration(value: Any) -> QosTime:
        nanoseconds = value.nanoseconds
        return QosTime(sec=nanoseconds // NANOSECONDS, nsec=nanoseconds % NANOSECONDS)

    return Qos(
        history=QosHistory[profile.history.name], depth=profile.depth,
        reliability=QosReliability[profile.reliability.name], durability=QosDurability[profile.durability.name],
        deadline=duration(profile.deadline), lifespan=duration(profile.lifespan),
        liveliness=QosLiveliness[profile.liveliness.name],
        liveliness_lease_duration=duration(profile.liveliness_lease_duration),
        avoid_ros_namespace_conventions=profile.avoid_ros_namespace_conventions)


def subscription_qos(offers: Iterable[QoSProfile]) -> QoSProfile:
    """The profile to record with that connects to every offer (rosbag2's ``adapt_request_to_offers``):
    reliable if all publishers are reliable, transient local if all are; keep last :data:`RECORD_DEPTH`."""
    offers = list(offers)
    reliable = all(p.reliability == ReliabilityPolicy.RELIABLE for p in offers)
    latched = all(p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in offers)
    return QoSProfile(depth=RECORD_DEPTH,
                      reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


def message_class(msgtype: str) -> type:
    """The rclpy class of ``pkg/msg/Name``, or of an action's message ``pkg/action/Name_Part`` (``Goal``,
    ``Result``, ``Feedback`` on the action, ``FeedbackMessage`` on its ``Impl``); raises ImportError or
    AttributeError if not installed."""
    package, kind, name = msgtype.split("/")
    module = importlib.import_module(f"{package}.{kind}")
    if kind != "action":
        return getattr(module, name)
    action, _, part = name.partition("_")
    definition = getattr(module, action)
    return getattr(definition, part) if hasattr(definition, part) else getattr(definition.Impl, part)


class Recorder:
    """Records ``topics`` from the ROS graph of ``node`` into ``bag``: call :meth:`discover` now and
    then, and spin the node.  ``received`` counts the messages per topic (each is written as it arrives)."""

    def __init__(self, node: Node, bag: BagWriter, topics: Iterable[str], source: str | None = None) -> None:
        self.node, self.bag = node, bag
        self.topics = list(dict.fromkeys(node.resolve_topic_name(topic) for topic in topics))
        self.source = split_node_name(source) if source else None
        self.received = dict.fromkeys(self.topics, 0)
        self.failed: dict[str, str] = {}
        self._subscriptions: dict[str, Any] = {}
        self._clock = node.get_clock()
        self.started_ns = self._clock.now().nanoseconds
        """When the recorder started [ns, the node clock: the bag's timestamps' clock]."""

    @property
    def waiting(self) -> list[str]:
        """Topics without a publisher so far."""
        return [t for t in self.topics if t not in self._subscriptions and t not in self.failed]

    @property
    def recording(self) -> bool:
        """Whether a topic is subscribed."""
        return bool(self._subscriptions)

    @property
    def total(self) -> int:
        return sum(self.received.values())

    def discover(self) -> list[str]:
        """Subscribe to the waiting topics that have publishers now; returns the topics added.  A topic
        that cannot be recorded (unknown type, type hash or type different from the installed
        definition) is logged once and left out (:attr:`failed`).  With a ``source`` node, its published
        topics join the topics to record as they appear."""
        if self.source is not None:
            self._add_source_topics()
        waiting = self.waiting
        if not waiting:
            return []
        present = dict(self.node.get_topic_names_and_types())
        added = []
        for topic in waiting:
            publishers = self.node.get_publishers_info_by_topic(topic) if topic in present else []
            if not publishers:
                continue
            reason = self._unrecordable(topic, publishers)
            if reason is not None:
                self.failed[topic] = reason
                self.node.get_logger().error(f"not recording {topic}: {reason}")
                continue
            msgtype = publishers[0].topic_type
            self.bag.add_topic(topic, msgtype, [rosbags_qos(p.qos_profile) for p in publishers])
            self._subscriptions[topic] = self.node.create_subscription(
                message_class(msgtype), topic, partial(self._receive, topic),
                subscription_qos(p.qos_profile for p in publishers), raw=True)
            added.append(topic)
        return added

    def _add_source_topics(self) -> None:
        """Add the topics that a node named ``source`` publishes, from each topic's publishers (every node of
        that name counts).  rclpy's by-node query answered with the node's lifecycle topic alone after the
        in-process node tests, while each topic's publishers named the node (CI, 2026-11-24)."""
        name, namespace = self.source
        for topic, _ in self.node.get_topic_names_and_types():
            if topic in self.received or topic in IGNORED_TOPICS:
                continue
            if any(p.node_name == name and p.node_namespace == namespace
                   for p in self.node.get_publishers_info_by_topic(topic)):
                self.topics.append(topic)
                self.received[topic] = 0

    def _unrecordable(self, topic: str, publishers: list[TopicEndpointInfo]) -> str | None:
        """Why ``topic`` cannot be recorded, or None."""
        types = sorted({p.topic_type for p in publishers})
        if len(types) > 1:
            return f"publishers of different types {', '.join(types)}"
        msgtype = types[0]
        if msgtype not in self.bag.typestore.types:
            return f"type {msgtype} is not in rosbags' Jazzy typestore nor this project's interfaces"
        try:
            message_class(msgtype)
        except (ImportError, AttributeError, ValueError) as error:
            return f"type {msgtype} is not installed: {error}"
        expected = self.bag.typestore.hash_rihs01(msgtype)
        offered = {str(p.topic_type_hash) for p in publishers if p.topic_type_hash.version == 1}
        if offered - {expected}:
            return f"publishers' type hash {', '.join(sorted(offered))} differs from the Jazzy definition's {expected}"
        return None

    def _receive(self, topic: str, data: bytes) -> None:
        self.bag.write(topic, data, self._clock.now().nanoseconds)
        self.received[topic] += 1

    def status(self, elapsed: float) -> str:
        """One status line: time, counts per topic, topics waiting, bag size."""
        topics = "  ".join(f"{t} {n}" for t, n in self.received.items() if t in self._subscriptions)
        waiting = f"  waiting for {', '.join(self.waiting)}" if self.waiting else ""
        return (f"recording {self.bag.path} {elapsed:6.1f} s  {topics or 'no topic yet'}{waiting}  "
                f"{self.bag.size() / 1e6:.2f} MB")


def split_node_name(name: str) -> tuple[str, str]:
    """(name, namespace) of a node name, absolute (/ns/name) or relative to the root namespace."""
    namespace, _, base = ("/" + name.strip("/")).rpartition("/")
    return base, namespace or "/"


def node_name() -> str:
    """Name of the recorder's node (with the process id, so that several recorders can run)."""
    return f"crane_reference_recorder_{os.getpid()}"


def record(bag: BagWriter, topics: Iterable[str], stop: threading.Event, *, duration: float | None = None,
           context: Context | None = None, status: Callable[[str], None] | None = None,
           source: str | None = None) -> Recorder:
    """Record ``topics`` (and those the node ``source`` publishes) into ``bag`` until ``stop`` is set or
    ``duration`` seconds have passed, then take the messages already queued (for at most
    :data:`DRAIN_TIME`); ``status`` gets a status line about every :data:`STATUS_PERIOD`.  ``context``
    must be initialized; the bag is left open."""
    node = Node(node_name(), context=context, start_parameter_services=False)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    recorder = Recorder(node, bag, topics, source)
    try:
        start = time.monotonic()
        next_discovery = next_status = start
        while not stop.is_set() and (duration is None or time.monotonic() - start < duration):
            now = time.monotonic()
            if now >= next_discovery:  # at every turn of the loop until a topic is recorded
                recorder.discover()
                next_discovery = now + (DISCOVERY_PERIOD if recorder.recording else 0.0)
            if status is not None and now >= next_status:
                status(recorder.status(now - start))
                next_status = now + STATUS_PERIOD
            executor.spin_once(timeout_sec=SPIN_TIMEOUT)
        deadline = time.monotonic() + DRAIN_TIME
        while time.monotonic() < deadline:
            before = recorder.total
            executor.spin_once(timeout_sec=0.0)
            if recorder.total == before:
                break
        if status is not None:
            status(recorder.status(time.monotonic() - start))
    finally:
        executor.shutdown()
        node.destroy_node()
    return recorder


class StatusLine:
    """Status lines on stderr: rewritten in place on a terminal, one per line otherwise."""

    def __init__(self) -> None:
        self.tty = sys.stderr.isatty()

    def __call__(self, line: str) -> None:
        sys.stderr.write(f"\r{line}\x1b[K" if self.tty else f"{line}\n")
        sys.stderr.flush()

    def close(self) -> None:
        if self.tty:
            sys.stderr.write("\n")


def record_command(args: argparse.Namespace) -> int:
    """``crane-reference record``: see the module documentation.  Exit code 0, or 2 for bad arguments."""
    output = Path(args.output or datetime.now().strftime("rosbag2_%Y_%m_%d-%H_%M_%S"))
    if args.duration is not None and not (0 < args.duration < float("inf")):
        print(f"crane-reference record: --duration {args.duration}: must be a finite number of seconds > 0",
              file=sys.stderr)
        return 2
    topics = args.topics
    for topic in topics:
        try:
            expand_topic_name(topic, node_name(), "/")
        except ValueError as error:
            print(f"crane-reference record: {error}", file=sys.stderr)
            return 2
    try:
        bag = BagWriter(output, args.storage, args.version)
    except BagError as error:
        print(f"crane-reference record: {error}", file=sys.stderr)
        return 2
    stop = threading.Event()
    handlers = {signum: signal.signal(signum, lambda *_: stop.set()) for signum in (signal.SIGINT, signal.SIGTERM)}
    status = StatusLine()
    started = time.monotonic()
    try:
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        recorder = record(bag, topics, stop, duration=args.duration, status=status,
                          source=None if topics else args.node)
    finally:
        bag.close()
        rclpy.try_shutdown()
        status.close()
        for signum, handler in handlers.items():
            signal.signal(signum, handler)
    print(f"recorded {recorder.total} messages over {bag.duration:.2f} s (the bag's duration; "
          f"{time.monotonic() - started:.1f} s of recording) to {bag.path} ({bag.storage}, version {bag.version}, "
          f"{bag.size() / 1e6:.2f} MB)")
    if bag.first_ns is not None:
        print(f"  the first message came {(bag.first_ns - recorder.started_ns) / NANOSECONDS:.3f} s after the "
              "recorder started")
    for topic, count in recorder.received.items():
        print(f"  {topic}: received {count}, written {bag.counts.get(topic, 0)}"
              f"{f' (not recorded: {recorder.failed[topic]})' if topic in recorder.failed else ''}")
    return 0

"""The node's topics in a bag without ROS (:class:`ReferenceBag`) and the offline export of the reference
(:func:`export_reference`).

:class:`ReferenceBag` writes the node's topics (joint states, end-effector pose, diagnostics) through a
:class:`~.bag.BagWriter` with the messages built by :mod:`crane_reference.interface.messages` from rosbags'
classes, so they are the node's messages.  (rclpy's ``serialize_message`` is no alternative: its buffers can
carry up to 8 bytes of junk after the message, which rosbags rejects on reading.)

:func:`export_reference` writes what the node publishes, computed offline: a
:class:`~crane_reference.stream.reference_stream.ReferenceStream` stepped and sampled at the publish rate,
written through a :class:`ReferenceBag`, so the messages are the node's for the same parameters.
Time is simulated time: sample k has header stamp and bag timestamp ``start_ns + k * 10**9 // rate``
(:func:`~crane_reference.stream.schedule.stamp_at`).  ``crane-reference simulate --bag DIR [--rate HZ]`` runs
it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence

from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability

from ..base.health import Level
from ..model.description import CraneDescription
from ..model.drive import column_drive
from ..model.units import NANOSECONDS
from ..motion.steps import ONLINE_STEP
from ..stream.reference_stream import ERROR, ReferenceStream
from ..stream.sample import ReferenceSample
from ..stream.schedule import stamp_at
from . import messages
from .bag import INFINITE, BagWriter

NODE_NAME = messages.NODE_NAME
JOINT_STATES = messages.JOINT_STATES_TOPIC.replace("~", f"/{NODE_NAME}", 1)
END_EFFECTOR_POSE = messages.END_EFFECTOR_POSE_TOPIC.replace("~", f"/{NODE_NAME}", 1)
DIAGNOSTICS = messages.DIAGNOSTICS_TOPIC
TOPIC_TYPES = {
    JOINT_STATES: "sensor_msgs/msg/JointState",
    END_EFFECTOR_POSE: "geometry_msgs/msg/PoseStamped",
    DIAGNOSTICS: "diagnostic_msgs/msg/DiagnosticArray",
}
DEFAULT_TOPICS = tuple(TOPIC_TYPES)
MAX_RATE = messages.MAX_PUBLISH_RATE
DIAGNOSTICS_PERIOD_NS = round(messages.DIAGNOSTICS_PERIOD * NANOSECONDS)
RELEASE_KEEP = 1.0  # [s] of computed motion kept behind the sample being exported
NODE_QOS = Qos(  # what the node's publishers offer: keep last, reliable, volatile, no deadline or lifespan
    history=QosHistory.KEEP_LAST, depth=messages.PUBLISHER_DEPTH, reliability=QosReliability.RELIABLE,
    durability=QosDurability.VOLATILE, deadline=INFINITE, lifespan=INFINITE,
    liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=INFINITE,
    avoid_ros_namespace_conventions=False)


# --- the node's topics -----------------------------------------------------------------------------


class ReferenceBag:
    """The node's topics in a bag, with the messages of :mod:`crane_reference.interface.messages` built from rosbags'
    classes: joint states and end-effector pose of each sample, and diagnostics.  The offline export
    writes through it, and so can the node (to record itself, stamped with the sample stamps).

    The topic names default to those of a node named :data:`NODE_NAME` in the root namespace; a node
    passes its publishers' ``topic_name``.
    """

    def __init__(self, bag: BagWriter, *, joint_states: str = JOINT_STATES,
                 end_effector_pose: str = END_EFFECTOR_POSE, diagnostics: str = DIAGNOSTICS) -> None:
        self.bag = bag
        self.types = messages.rosbags_types(bag.typestore)
        self.joint_states, self.end_effector_pose, self.diagnostics = joint_states, end_effector_pose, diagnostics
        for topic, default in ((joint_states, JOINT_STATES), (end_effector_pose, END_EFFECTOR_POSE),
                               (diagnostics, DIAGNOSTICS)):
            bag.add_topic(topic, TOPIC_TYPES[default], [NODE_QOS])

    def write_sample(self, stamp_ns: int, joint_names: Sequence[str], frame_id: str, sample: ReferenceSample) -> None:
        """joint_states and the end-effector pose of ``sample``, header stamp and bag timestamp ``stamp_ns``."""
        self.bag.write_message(self.joint_states, messages.joint_state(self.types, stamp_ns, joint_names, sample),
                               stamp_ns)
        self.bag.write_message(self.end_effector_pose,
                               messages.end_effector_pose(self.types, stamp_ns, frame_id, sample), stamp_ns)

    def write_diagnostics(self, stamp_ns: int, name: str, hardware_id: str, level: int, message: str,
                          values: Mapping[str, object]) -> None:
        """/diagnostics (arguments of :func:`crane_reference.interface.messages.diagnostics`)."""
        self.bag.write_message(self.diagnostics, messages.diagnostics(self.types, stamp_ns, name, hardware_id, level,
                                                                      message, values), stamp_ns)


# --- offline export of the reference ---------------------------------------------------------------


def node_stream(config: CraneDescription, variant: str = "flexible", step: float = ONLINE_STEP) -> ReferenceStream:
    """The stream the node builds for ``config`` with its parameters at their defaults (the column drive
    made as the node makes it, so that the motion is the same to the bit)."""
    return ReferenceStream(config, variant, step, drive=column_drive(config))


def export_reference(bag: BagWriter, stream: ReferenceStream, rate: int, duration: float, *,
                     frame_id: str = "world", node_name: str = NODE_NAME, start_ns: int = 0,
                     progress: Callable[[float], None] | None = None) -> int:
    """Write samples k = 0 .. floor(duration * rate) of ``stream`` (a fresh one: publish time 0 is its
    start) to ``bag`` on the node's topics (:class:`ReferenceBag`), as the node publishes them at ``rate``
    Hz from ``start_ns``: joint_states and end-effector pose at every sample, /diagnostics every second of
    simulated time.  ``progress`` is called with the simulated time.  Returns the number of samples."""
    if not (isinstance(rate, int) and 1 <= rate <= MAX_RATE):
        raise ValueError(f"rate = {rate!r}: must be an integer in [1, {MAX_RATE}] Hz")
    if not (math.isfinite(duration) and duration >= 0):
        raise ValueError(f"duration = {duration!r}: must be a finite number of seconds >= 0")
    reference = ReferenceBag(bag)
    count = math.floor(duration * rate + 1e-9) + 1
    next_diagnostics = DIAGNOSTICS_PERIOD_NS
    last_wall, last_motion = time.perf_counter(), 0.0
    for k in range(count):
        tau = k / rate
        stream.compute(tau)
        sample = stream.sample(tau)
        stamp = stamp_at(start_ns, k, rate)
        reference.write_sample(stamp, stream.joint_names, frame_id, sample)
        if stamp - start_ns >= next_diagnostics:
            next_diagnostics += DIAGNOSTICS_PERIOD_NS
            wall = time.perf_counter()
            factor = (sample.t - last_motion) / (wall - last_wall)
            last_wall, last_motion = wall, sample.t
            level, message = ((Level.ERROR, f"{ERROR}: {stream.last_error}") if stream.state == ERROR
                              else (Level.OK, stream.state))
            counters = {"published": k + 1, "held_late": 0, "stamp_leaps": 0, "held_non_finite": 0}
            values = messages.diagnostic_values(stream.state, sample, factor, rate, float(rate), counters,
                                                stream.targets, stream.target_speed, stream.last_error)
            reference.write_diagnostics(stamp, f"{node_name}: reference", f"/{node_name}", level, message, values)
        stream.release(tau, RELEASE_KEEP)
        if progress is not None:
            progress(tau)
    return count

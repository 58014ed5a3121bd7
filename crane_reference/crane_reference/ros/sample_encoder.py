"""The publisher's encoder: a batch of reference samples written at once into serialized ~/joint_states and
~/end_effector_pose messages, a row a sample, as the batch comes from the solver (the server's frame worker calls
it: :data:`~crane_reference.stream.served.Encoder`), so that the publisher thread only writes each stamp and sends
the bytes (:mod:`crane_reference.interface.serialized`).
"""

from __future__ import annotations

from typing import NamedTuple

from rclpy.serialization import serialize_message

from ..interface import messages
from ..interface.serialized import SerializedJointState, SerializedPose, SerializedRows
from ..stream.sample import ReferenceRows


class SampleMessages(NamedTuple):
    """A batch's ~/joint_states and ~/end_effector_pose (its frame ``frame_id``), serialized, a row a sample."""

    frame_id: str
    joint_states: SerializedRows
    poses: SerializedRows


class SampleEncoder:
    """The joint states and E's poses of stacked samples (a batch of frames), serialized at once in the frame
    ``frame_id`` (replaced on a parameter change), a row a sample; the prototypes are serialized once per frame.
    The server's frame worker calls it as each batch comes (:data:`~crane_reference.stream.served.Encoder`), the
    publisher for a sample held or made before a change of frame."""

    def __init__(self, types: messages.MessageTypes, joint_names: tuple[str, ...], frame_id: str):
        self.types, self.joint_names, self.frame_id = types, list(joint_names), frame_id
        self._writers: tuple[str, SerializedJointState, SerializedPose] | None = None  # prototypes, pose's frame

    def __call__(self, samples: ReferenceRows) -> SampleMessages:
        frame_id, writers = self.frame_id, self._writers
        if writers is None or writers[0] != frame_id:
            first = samples.row(0)
            writers = self._writers = (frame_id, SerializedJointState(serialize_message(
                messages.joint_state(self.types, 0, self.joint_names, first))), SerializedPose(serialize_message(
                    messages.end_effector_pose(self.types, 0, frame_id, first))))
        return SampleMessages(frame_id, writers[1].rows(samples), writers[2].rows(samples))

"""Serialized per-sample messages (crane_reference.interface.serialized) against the message libraries'
own serializers: rosbags' CDR (both byte orders) and rclpy's serialize_message, the bytes the node
publishes."""

from __future__ import annotations

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from crane_reference.interface import messages
from crane_reference.interface.serialized import (
    SerializedJointState,
    SerializedPose,
    SerializedPreview,
    SerializedVector3,
)
from crane_reference.ros.message_types import rclpy_types
from crane_reference.stream.sample import ReferenceRows, ReferenceSample

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
JOINT_STATE, POSE, VECTOR, TRAJECTORY = ("sensor_msgs/msg/JointState", "geometry_msgs/msg/PoseStamped",
                                         "geometry_msgs/msg/Vector3Stamped", "trajectory_msgs/msg/JointTrajectory")
# frame_ids and names of every length modulo 8, so that each field's alignment padding varies
FRAME_IDS = ["", "w", "ab", "abc", "world", "crane_1", "map/base", "crane/world"]
NAME_SETS = [["column_slew"], ["a", "bb", "ccc"], [f"joint_{'x' * i}" for i in range(9)]]
STAMPS = [0, 1, 999_999_999, 1_700_000_000_123_456_789]


def random_sample(rng: np.random.Generator, n: int) -> ReferenceSample:
    quaternion = rng.normal(size=4)
    return ReferenceSample(float(rng.uniform(0, 10)), rng.normal(size=n), rng.normal(size=n), rng.normal(size=n),
                           rng.normal(size=n) * 1e3, rng.normal(size=n) * 1e3, rng.normal(size=3),
                           quaternion / np.linalg.norm(quaternion), 1e-15, False)


def zero_sample(n: int) -> ReferenceSample:
    return ReferenceSample(0.0, np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(3),
                           np.array([0.0, 0.0, 0.0, 1.0]), 0.0, False)


@pytest.mark.parametrize("little_endian", [True, False])
@pytest.mark.parametrize("names", NAME_SETS)
def test_joint_states_filled_in_place_equal_rosbags_serialization(names, little_endian):
    """Every filled message is byte for byte what rosbags serializes for the same values, and reads back as
    them, whatever the padding before each array."""
    types, rng = messages.rosbags_types(TYPESTORE), np.random.default_rng(len(names))
    for frame_id in FRAME_IDS:
        prototype = messages.joint_state(types, 5, names, zero_sample(len(names)))
        prototype.header.frame_id = frame_id  # JointState's frame_id is empty in the node; any works here
        writer = SerializedJointState(bytes(TYPESTORE.serialize_cdr(prototype, JOINT_STATE,
                                                                     little_endian=little_endian)))
        assert writer.names == names
        for stamp in STAMPS:
            sample = random_sample(rng, len(names))
            data = writer.fill(stamp, sample)
            expected = messages.joint_state(types, stamp, names, sample)
            expected.header.frame_id = frame_id
            assert data == bytes(TYPESTORE.serialize_cdr(expected, JOINT_STATE, little_endian=little_endian))
            read = TYPESTORE.deserialize_cdr(data, JOINT_STATE)
            assert (read.header.stamp.sec, read.header.stamp.nanosec) == divmod(stamp, 10**9)
            assert read.name == names and read.header.frame_id == frame_id
            np.testing.assert_array_equal(read.position, sample.q)
            np.testing.assert_array_equal(read.velocity, sample.qd)
            np.testing.assert_array_equal(read.effort, sample.effort)


@pytest.mark.parametrize("little_endian", [True, False])
def test_poses_filled_in_place_equal_rosbags_serialization(little_endian):
    types, rng = messages.rosbags_types(TYPESTORE), np.random.default_rng(7)
    for frame_id in FRAME_IDS:
        prototype = messages.end_effector_pose(types, 0, frame_id, zero_sample(3))
        writer = SerializedPose(bytes(TYPESTORE.serialize_cdr(prototype, POSE, little_endian=little_endian)))
        assert writer.frame_id == frame_id
        for stamp in STAMPS:
            sample = random_sample(rng, 3)
            data = writer.fill(stamp, sample)
            assert data == bytes(TYPESTORE.serialize_cdr(messages.end_effector_pose(types, stamp, frame_id, sample),
                                                         POSE, little_endian=little_endian))
            read = TYPESTORE.deserialize_cdr(data, POSE)
            position, orientation = read.pose.position, read.pose.orientation
            np.testing.assert_array_equal([position.x, position.y, position.z], sample.ee_position)
            np.testing.assert_array_equal([orientation.x, orientation.y, orientation.z, orientation.w],
                                          sample.ee_quaternion)


@pytest.mark.parametrize("little_endian", [True, False])
@pytest.mark.parametrize("effort", [False, True])
def test_previews_filled_in_place_equal_rosbags_serialization(effort, little_endian):
    """A sample and its preview written into a prototype are byte for byte what rosbags serializes for the
    preview's message object (:func:`~crane_reference.interface.messages.reference_preview`), for joints picked
    out of the samples' coordinates in any order, with and without efforts, whatever the padding."""
    types, rng, n = messages.rosbags_types(TYPESTORE), np.random.default_rng(11), 9
    for frame_id, names in zip(FRAME_IDS, [*NAME_SETS, *NAME_SETS], strict=False):
        indices = list(rng.permutation(n)[:len(names)])
        for points in (2, 3, 11):
            offsets = messages.preview_offsets(0.7, points - 1)
            prototype = messages.reference_preview(types, 0, frame_id, names, indices, offsets,
                                                   [zero_sample(n)] * points, effort)
            writer = SerializedPreview(bytes(TYPESTORE.serialize_cdr(prototype, TRAJECTORY,
                                                                      little_endian=little_endian)), indices)
            assert (writer.frame_id, writer.joint_names, writer.effort, writer.points) == (frame_id, names, effort,
                                                                                           points)
            for stamp in STAMPS:
                samples = ReferenceRows.stack([random_sample(rng, n) for _ in range(3)])
                preview = ReferenceRows.stack([random_sample(rng, n) for _ in range(points - 1)])
                data = writer.fill_row(stamp, samples, 1, preview)
                expected = messages.reference_preview(types, stamp, frame_id, names, indices, offsets,
                                                      [samples.row(1), *preview.rows()], effort)
                assert data == bytes(TYPESTORE.serialize_cdr(expected, TRAJECTORY, little_endian=little_endian))
                read = TYPESTORE.deserialize_cdr(data, TRAJECTORY)
                np.testing.assert_array_equal([p.positions for p in read.points],
                                              np.vstack((samples.q[1], preview.q))[:, indices])
                if effort:  # the feedforward (what a controller adds), not the generalized effort
                    np.testing.assert_array_equal([p.effort for p in read.points],
                                                  np.vstack((samples.feedforward[1], preview.feedforward))[:, indices])


def test_the_node_s_messages_read_back_by_rclpy_as_the_message_objects():
    """With the prototype from rclpy (as the node makes it), rclpy reads a filled message back as the message
    object with the same values, and it has the length of rclpy's serialization of that object (rclpy's
    serializer leaves the alignment padding as it finds it, so the padding bytes are not compared)."""
    types, rng = rclpy_types(), np.random.default_rng(3)
    names = NAME_SETS[2]
    joints = SerializedJointState(serialize_message(messages.joint_state(types, 0, names, zero_sample(len(names)))))
    poses = SerializedPose(serialize_message(messages.end_effector_pose(types, 0, "world", zero_sample(3))))
    for stamp in STAMPS:
        sample = random_sample(rng, len(names))
        for writer, message, kind in ((joints, messages.joint_state(types, stamp, names, sample), JointState),
                                      (poses, messages.end_effector_pose(types, stamp, "world", sample), PoseStamped)):
            data = writer.fill(stamp, sample)
            assert deserialize_message(data, kind) == message
            assert len(data) == len(serialize_message(message))


def test_a_prototype_that_does_not_fit_is_refused():
    types = messages.rosbags_types(TYPESTORE)
    short = messages.joint_state(types, 0, ["a", "b"], zero_sample(2))
    short.effort = np.zeros(1)
    with pytest.raises(ValueError, match="1 effort entries for 2 names"):
        SerializedJointState(bytes(TYPESTORE.serialize_cdr(short, JOINT_STATE)))
    with pytest.raises(ValueError, match="not a plain-CDR serialized message"):
        SerializedPose(b"\x01\x00\x00\x00" + bytes(64))
    trajectory = messages.reference_preview(types, 0, "w", ["a", "b"], [0, 1], [0, 5], [zero_sample(2)] * 2)
    trajectory.points[1].velocities = np.zeros(1)
    with pytest.raises(ValueError, match="1 velocities for 2 joints"):
        SerializedPreview(bytes(TYPESTORE.serialize_cdr(trajectory, TRAJECTORY)), [0, 1])
    trajectory.points[1].velocities = np.zeros(2)
    with pytest.raises(ValueError, match="2 joints for 3 coordinates"):
        SerializedPreview(bytes(TYPESTORE.serialize_cdr(trajectory, TRAJECTORY)), [0, 1, 2])
    with pytest.raises(ValueError, match="a preview of 2 points for a prototype of 1"):
        SerializedPreview(bytes(TYPESTORE.serialize_cdr(trajectory, TRAJECTORY)), [0, 1]).fill_row(
            0, ReferenceRows.stack([zero_sample(2)]), 0, ReferenceRows.stack([zero_sample(2)] * 2))
    with pytest.raises(ValueError, match="ends inside its float64 fields"):
        SerializedPose(bytes(TYPESTORE.serialize_cdr(messages.end_effector_pose(types, 0, "w", zero_sample(3)),
                                                     POSE))[:-8])


@pytest.mark.parametrize("little_endian", [True, False])
def test_vectors_filled_in_place_equal_rosbags_serialization(little_endian):
    types, rng = messages.rosbags_types(TYPESTORE), np.random.default_rng(3)
    for frame_id in FRAME_IDS:
        prototype = messages.tip_deflection(types, 0, frame_id, np.zeros(3))
        writer = SerializedVector3(bytes(TYPESTORE.serialize_cdr(prototype, VECTOR, little_endian=little_endian)))
        assert writer.frame_id == frame_id
        for stamp in STAMPS:
            vector = rng.normal(size=3)
            data = writer.fill(stamp, vector)
            expected = TYPESTORE.serialize_cdr(messages.tip_deflection(types, stamp, frame_id, vector), VECTOR,
                                               little_endian=little_endian)
            assert data == bytes(expected)


@pytest.mark.parametrize("rate", [1000, 100])
def test_a_batch_of_frames_is_published_as_rclpy_and_rosbags_serialize_each_sample(params, rate):
    """The rows of a batch of frames made by the stream at the node's rates, written into the messages as the
    publisher writes them (the joint states and poses of the whole batch at once, :meth:`rows`, each stamped as it
    goes out; the previews a row at a time, :meth:`fill_row`), are rclpy's serialization of each sample's message
    objects, read back field by field, and rosbags' bytes in both byte orders."""
    from crane_reference.model.paper_layout import ACTUATED as ACTUATED_JOINTS
    from crane_reference.stream.frame_maker import make_frames
    from crane_reference.stream.reference_stream import ReferenceStream
    from crane_reference.stream.schedule import FrameSchedule

    stream = ReferenceStream(params, "rigid", step=1e-3)
    schedule = FrameSchedule(rate, rate, 0.1, 1.0, stream.sample(0.0))
    frames = make_frames(stream, schedule.request(schedule.plan(), 20, 0.2, 5, 10, None)).frames
    names, rclpy_message_types = list(stream.joint_names), rclpy_types()
    rosbags_message_types = messages.rosbags_types(TYPESTORE)
    start = frames.samples.row(0)
    joints = SerializedJointState(serialize_message(messages.joint_state(rclpy_message_types, 0, names, start)))
    poses = SerializedPose(serialize_message(messages.end_effector_pose(rclpy_message_types, 0, "world", start)))
    ordered = {little: (SerializedJointState(bytes(TYPESTORE.serialize_cdr(
                            messages.joint_state(rosbags_message_types, 0, names, start), JOINT_STATE,
                            little_endian=little))),
                        SerializedPose(bytes(TYPESTORE.serialize_cdr(
                            messages.end_effector_pose(rosbags_message_types, 0, "world", start), POSE,
                            little_endian=little))))
               for little in (True, False)}
    indices = [names.index(j) for j in ACTUATED_JOINTS]
    offsets = messages.preview_offsets(frames.horizon, 5)
    assert len(frames) == 20 and sorted(frames.previews) == [0, 10]
    for row, preview in frames.previews.items():
        stamp = 1_700_000_000_000_000_000 + (frames.k + row) * 10**9 // rate
        points = [frames.samples.row(row), *preview.rows()]
        writer = SerializedPreview(serialize_message(messages.reference_preview(
            rclpy_message_types, 0, "world", list(ACTUATED_JOINTS), indices, offsets, points)), indices)
        filled = writer.fill_row(stamp, frames.samples, row, preview)
        assert deserialize_message(filled, JointTrajectory) == messages.reference_preview(
            rclpy_message_types, stamp, "world", list(ACTUATED_JOINTS), indices, offsets, points)
        assert len(filled) == len(TYPESTORE.serialize_cdr(messages.reference_preview(  # no bytes past the message
            rosbags_message_types, stamp, "world", list(ACTUATED_JOINTS), indices, offsets, points), TRAJECTORY))
        for little in (True, False):
            writer = SerializedPreview(bytes(TYPESTORE.serialize_cdr(messages.reference_preview(
                rosbags_message_types, 0, "world", list(ACTUATED_JOINTS), indices, offsets, points), TRAJECTORY,
                little_endian=little)), indices)
            assert writer.fill_row(stamp, frames.samples, row, preview) == bytes(TYPESTORE.serialize_cdr(
                messages.reference_preview(rosbags_message_types, stamp, "world", list(ACTUATED_JOINTS), indices,
                                           offsets, points), TRAJECTORY, little_endian=little))
    # the batch's rows written at once, then stamped in any order, one of them twice (a later stamp wins)
    joint_rows, pose_rows = joints.rows(frames.samples), poses.rows(frames.samples)
    ordered_rows = {little: (joint_writer.rows(frames.samples), pose_writer.rows(frames.samples))
                    for little, (joint_writer, pose_writer) in ordered.items()}
    assert len(joint_rows) == len(pose_rows) == len(frames)
    joint_rows.stamped(3, 5)
    for row in [*range(len(frames) - 1, -1, -2), *range(0, len(frames), 2)]:
        stamp, sample = 1_700_000_000_000_000_000 + (frames.k + row) * 10**9 // rate, frames.samples.row(row)
        assert deserialize_message(joint_rows.stamped(row, stamp), JointState) == messages.joint_state(
            rclpy_message_types, stamp, names, sample)
        assert deserialize_message(pose_rows.stamped(row, stamp), PoseStamped) == \
            messages.end_effector_pose(rclpy_message_types, stamp, "world", sample)
        for little, (joint_writer, pose_writer) in ordered_rows.items():
            assert joint_writer.stamped(row, stamp) == bytes(TYPESTORE.serialize_cdr(
                messages.joint_state(rosbags_message_types, stamp, names, sample), JOINT_STATE, little_endian=little))
            assert pose_writer.stamped(row, stamp) == bytes(TYPESTORE.serialize_cdr(
                messages.end_effector_pose(rosbags_message_types, stamp, "world", sample), POSE, little_endian=little))

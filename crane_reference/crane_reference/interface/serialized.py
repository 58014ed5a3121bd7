"""The node's messages (JointState, E's PoseStamped, the preview's JointTrajectory) as serialized messages,
filled in place.

Publishing a message object costs a conversion to its C form and a serialization at every sample;
a publisher handed the serialized bytes (rclpy's ``Publisher.publish(bytes)``, which goes to
``rmw_publish_serialized_message``) publishes them as they are.  The bytes here are those of a prototype
serialized by a message library (rclpy's ``serialize_message`` in the node, rosbags' CDR serializer
offline) with each sample's numbers written over the prototype's at their offsets; the names and the
frame_id stay the prototype's.  A batch of stacked samples is written at once, a message a row of one buffer
(:class:`SerializedRows`), each stamped as it goes out.

Layout of a ROS 2 serialized message (plain CDR, XCDR version 1, as every ROS 2 middleware and rosbag2
use it): a 4-byte encapsulation header (second byte 1: little endian, 0: big endian), then the body, in
which each primitive is aligned to its own size counted from the body's start; a string is a uint32
length (the terminating NUL included) and its bytes; a sequence is a uint32 count and its elements.
std_msgs/Header is the stamp (int32 sec, uint32 nanosec) and the frame_id string; builtin_interfaces/Duration
is int32 sec, uint32 nanosec.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..model.units import NANOSECONDS

if TYPE_CHECKING:
    from ..stream.sample import ReferenceRows, ReferenceSample

ENCAPSULATION = 4
"""[bytes] before the body."""


def _aligned(offset: int, size: int) -> int:
    """``offset`` rounded up to a multiple of ``size`` (offsets count from the body's start)."""
    return offset + (-offset) % size


class _Layout:
    """Reads a serialized message's body field by field, with its byte order (from the encapsulation)."""

    def __init__(self, data: bytes):
        if len(data) < ENCAPSULATION + 8 or data[0] != 0 or data[1] not in (0, 1):
            raise ValueError(f"not a plain-CDR serialized message (encapsulation {data[:ENCAPSULATION].hex()})")
        self.data, self.order = data, "<" if data[1] == 1 else ">"
        self.offset = 8  # after the header's stamp

    def count(self) -> int:
        """A uint32 (string length or sequence count) at the next aligned offset; moves past it."""
        self.offset = _aligned(self.offset, 4)
        (value,) = struct.unpack_from(self.order + "I", self.data, ENCAPSULATION + self.offset)
        self.offset += 4
        return value

    def string(self) -> str:
        """The next string; moves past it."""
        length = self.count()
        start = ENCAPSULATION + self.offset
        self.offset += length
        return self.data[start:start + length - 1].decode()

    def duration(self) -> None:
        """Moves past a builtin_interfaces/Duration (two 4-byte integers)."""
        self.offset = _aligned(self.offset, 4) + 8

    def doubles(self, count: int) -> int:
        """The body offset of the next ``count`` float64 (aligned to 8); moves past them."""
        self.offset = _aligned(self.offset, 8)
        start = self.offset
        self.offset += 8 * count
        if ENCAPSULATION + self.offset > len(self.data):
            raise ValueError(f"serialized message of {len(self.data)} bytes ends inside its float64 fields")
        return start


class _SerializedMessage:
    """A prototype's bytes, up to the end of its last field as ``layout`` read them, and writable views of its stamp
    and float64 fields.  (rclpy's ``serialize_message`` may return bytes beyond that end: for a JointTrajectory
    whose points have empty efforts, the size its type support estimates, the excess not written.)"""

    def __init__(self, prototype: bytes, layout: _Layout):
        self._buffer = bytearray(prototype[:ENCAPSULATION + layout.offset])
        self._order = layout.order
        self._stamp = struct.Struct(layout.order + "iI")

    def _doubles(self, offset: int, count: int) -> np.ndarray:
        return np.frombuffer(self._buffer, dtype=np.dtype(self._order + "f8"), count=count,
                             offset=ENCAPSULATION + offset)

    def _stamped(self, stamp_ns: int) -> bytes:
        """The message with header.stamp = ``stamp_ns`` (a non-negative time [ns]), as bytes."""
        _write_stamp(self._stamp, self._buffer, 0, stamp_ns)
        return bytes(self._buffer)

    def _rows(self, count: int) -> SerializedRows:
        """``count`` copies of the prototype, a row each (:class:`SerializedRows`)."""
        return SerializedRows(bytes(self._buffer), self._order, self._stamp, count)


def _write_stamp(stamp: struct.Struct, buffer: bytearray, start: int, stamp_ns: int) -> None:
    """header.stamp = ``stamp_ns`` (a non-negative time [ns]: sec, nanosec) in the message at ``start`` of
    ``buffer``."""
    stamp.pack_into(buffer, start + ENCAPSULATION, stamp_ns // NANOSECONDS, stamp_ns % NANOSECONDS)


class SerializedRows:
    """``count`` copies of a serialized message, a row each, one after the other in one buffer: a field of every row
    is written at once (:meth:`columns`, numbers stacked from a batch of samples), and each row is stamped as it
    goes out (:meth:`stamped`)."""

    def __init__(self, prototype: bytes, order: str, stamp: struct.Struct, count: int):
        """``count`` copies of ``prototype`` (byte order ``order``, its stamp written by ``stamp``)."""
        self._size = len(prototype)
        self._data = bytearray(prototype * count)
        self._rows = memoryview(self._data)
        self._order, self._stamp, self._count = order, stamp, count

    def __len__(self) -> int:
        return self._count

    def columns(self, offset: int, width: int) -> np.ndarray:
        """A writable (count, width) view of the ``width`` float64 at body offset ``offset`` in every row."""
        return np.ndarray((self._count, width), np.dtype(self._order + "f8"), self._data, ENCAPSULATION + offset,
                          (self._size, 8))

    def stamped(self, row: int, stamp_ns: int) -> bytes:
        """Row ``row``'s message with header.stamp = ``stamp_ns`` (a non-negative time [ns]), as bytes."""
        start = row * self._size
        _write_stamp(self._stamp, self._data, start, stamp_ns)
        return bytes(self._rows[start:start + self._size])


class SerializedJointState(_SerializedMessage):
    """sensor_msgs/JointState: header, name[], position[], velocity[], effort[] (see
    :func:`~.messages.joint_state`); ``prototype`` serialized with one entry per name in each array."""

    def __init__(self, prototype: bytes):
        layout = _Layout(prototype)
        layout.string()  # header.frame_id
        self.names = [layout.string() for _ in range(layout.count())]
        arrays = []
        for field in ("position", "velocity", "effort"):
            count = layout.count()
            if count != len(self.names):
                raise ValueError(f"prototype JointState has {count} {field} entries for {len(self.names)} names")
            arrays.append(layout.doubles(count))
        super().__init__(prototype, layout)
        self._offsets = arrays
        self._position, self._velocity, self._effort = (self._doubles(offset, len(self.names)) for offset in arrays)

    def fill(self, stamp_ns: int, sample: ReferenceSample) -> bytes:
        """The serialized JointState of ``sample`` stamped ``stamp_ns``."""
        self._position[:] = sample.q
        self._velocity[:] = sample.qd
        self._effort[:] = sample.effort
        return self._stamped(stamp_ns)

    def rows(self, samples: ReferenceRows) -> SerializedRows:
        """The serialized JointStates of stacked ``samples``, a row each, their numbers written at once (stamped as
        each goes out: :meth:`SerializedRows.stamped`)."""
        rows = self._rows(len(samples.t))
        for offset, values in zip(self._offsets, (samples.q, samples.qd, samples.effort), strict=True):
            rows.columns(offset, len(self.names))[:] = values
        return rows


class SerializedPose(_SerializedMessage):
    """geometry_msgs/PoseStamped: header, then position (x, y, z) and orientation (x, y, z, w) (see
    :func:`~.messages.end_effector_pose`)."""

    def __init__(self, prototype: bytes):
        layout = _Layout(prototype)
        self.frame_id = layout.string()
        offset = layout.doubles(7)
        super().__init__(prototype, layout)
        self._offset = offset
        self._pose = self._doubles(offset, 7)

    def fill(self, stamp_ns: int, sample: ReferenceSample) -> bytes:
        """The serialized PoseStamped of E in ``sample`` stamped ``stamp_ns``."""
        self._pose[:3] = sample.ee_position
        self._pose[3:] = sample.ee_quaternion
        return self._stamped(stamp_ns)

    def rows(self, samples: ReferenceRows) -> SerializedRows:
        """The serialized PoseStamped of E in stacked ``samples``, a row each, their numbers written at once
        (stamped as each goes out: :meth:`SerializedRows.stamped`)."""
        rows = self._rows(len(samples.t))
        pose = rows.columns(self._offset, 7)
        pose[:, :3] = samples.ee_position
        pose[:, 3:] = samples.ee_quaternion
        return rows


class SerializedVector3(_SerializedMessage):
    """geometry_msgs/Vector3Stamped: header, then x, y, z (see :func:`~.messages.tip_deflection`)."""

    def __init__(self, prototype: bytes):
        layout = _Layout(prototype)
        self.frame_id = layout.string()
        offset = layout.doubles(3)
        super().__init__(prototype, layout)
        self._vector = self._doubles(offset, 3)

    def fill(self, stamp_ns: int, vector: np.ndarray) -> bytes:
        """The serialized Vector3Stamped of ``vector`` stamped ``stamp_ns``."""
        self._vector[:] = vector
        return self._stamped(stamp_ns)


class SerializedPreview(_SerializedMessage):
    """trajectory_msgs/JointTrajectory of a sample and its preview (see :func:`~.messages.reference_preview`):
    header, joint_names[], then per point positions[], velocities[], accelerations[], effort[] and
    time_from_start.  ``prototype`` is serialized with the joints, the points' count and their times from start
    of the messages to fill, which carry the coordinates ``indices`` of the samples (efforts if the prototype's
    points have them; the times from start stay the prototype's)."""

    def __init__(self, prototype: bytes, indices: Sequence[int]):
        layout = _Layout(prototype)
        self.frame_id = layout.string()
        self.joint_names = [layout.string() for _ in range(layout.count())]
        self._columns = np.asarray(indices, dtype=np.int64)
        joints = len(self.joint_names)
        if self._columns.size != joints:
            raise ValueError(f"prototype JointTrajectory has {joints} joints for {self._columns.size} coordinates")
        points = []
        for _ in range(layout.count()):
            offsets = []
            for field in ("positions", "velocities", "accelerations", "effort"):
                count = layout.count()
                if count != joints and not (field == "effort" and count == 0):
                    raise ValueError(f"prototype JointTrajectory has {count} {field} for {joints} joints")
                if count:
                    offsets.append(layout.doubles(count))
            layout.duration()
            points.append(offsets)
        if not points or len({len(offsets) for offsets in points}) != 1:
            raise ValueError("prototype JointTrajectory needs points, all with efforts or all without")
        super().__init__(prototype, layout)
        self.effort = len(points[0]) == 4
        self._points = [[self._doubles(offset, joints) for offset in offsets] for offsets in points]

    @property
    def points(self) -> int:
        return len(self._points)

    def fill_row(self, stamp_ns: int, samples: ReferenceRows, row: int, preview: ReferenceRows) -> bytes:
        """The serialized preview stamped ``stamp_ns`` of row ``row`` of stacked ``samples`` (its first point) and
        the samples of ``preview`` (the points after it, as many as the prototype has)."""
        if len(preview.t) != self.points - 1:
            raise ValueError(f"a preview of {len(preview.t)} points for a prototype of {self.points - 1}")
        columns = self._columns
        first = (samples.q[row], samples.qd[row], samples.qdd[row], samples.feedforward[row])
        later = (preview.q[:, columns], preview.qd[:, columns], preview.qdd[:, columns],
                 preview.feedforward[:, columns])
        for view, values in zip(self._points[0], first, strict=False):
            view[:] = values[columns]
        for views, i in zip(self._points[1:], range(self.points - 1), strict=True):
            for view, values in zip(views, later, strict=False):
                view[:] = values[i]
        return self._stamped(stamp_ns)

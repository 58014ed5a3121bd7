"""The rclpy implementation of :class:`~crane_reference.interface.messages.MessageTypes`."""

from __future__ import annotations

import array

import numpy as np
from builtin_interfaces.msg import Duration, Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, Pose, PoseStamped, Quaternion, Vector3, Vector3Stamped
from sensor_msgs.msg import CompressedImage, JointState
from std_msgs.msg import ColorRGBA, Header, String
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
from visualization_msgs.msg import Marker, MarkerArray, MeshFile

from ..interface.messages import MessageTypes


def rclpy_types() -> MessageTypes:
    """Constructors of the rclpy message classes (ROS 2 Python message packages)."""

    return MessageTypes(
        Time=Time, Duration=Duration, Header=Header, String=String, ColorRGBA=ColorRGBA, Point=Point,
        Quaternion=Quaternion, Vector3=Vector3, Vector3Stamped=Vector3Stamped, Pose=Pose, PoseStamped=PoseStamped,
        JointState=JointState, JointTrajectory=JointTrajectory, JointTrajectoryPoint=JointTrajectoryPoint,
        KeyValue=KeyValue,
        DiagnosticStatus=DiagnosticStatus, DiagnosticArray=DiagnosticArray, CompressedImage=CompressedImage,
        MeshFile=MeshFile, Marker=Marker, MarkerArray=MarkerArray,
        float64_array=lambda values: array.array("d", np.ascontiguousarray(values, dtype=np.float64).tobytes()),
        uint8_array=lambda data: array.array("B", data),
        byte=lambda value: bytes((value,)),
    )

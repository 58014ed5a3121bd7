"""Every ROS message crane_reference publishes, built from a
:class:`~crane_reference.stream.sample.ReferenceSample`.

The builders never import a message package themselves: they take a :class:`MessageTypes`, a small
namespace of message constructors and array converters, so that the same code makes

* rclpy messages for the live node (:func:`crane_reference.ros.message_types.rclpy_types`), and
* rosbags messages for writing rosbag2 files offline without ROS (:func:`rosbags_types`, from rosbags'
  Jazzy typestore).

Every field is passed by keyword (rosbags' message classes are dataclasses without defaults), float
arrays go through :attr:`MessageTypes.float64_array` (``array.array('d')`` for rclpy, a float64 numpy
array for rosbags), byte-typed fields through :attr:`MessageTypes.byte`.

Stamps are integer nanoseconds (``stamp_ns``); sample k of a stream published at ``rate`` Hz from
``start_ns`` is stamped ``start_ns + k * 10**9 // rate`` by the node, never with the time it is sent.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..model.units import NANOSECONDS

if TYPE_CHECKING:
    from ..control.plant_server import PlantState
    from ..model.parameters import Task
    from ..stream.sample import ReferenceSample

# The node's interface, shared by the node and the offline bag export (which must not import rclpy)
NODE_NAME = "crane_reference"
# Every reference topic lives in the node's namespace (~/...), never on a topic that measured state uses.
JOINT_STATES_TOPIC = "~/joint_states"
END_EFFECTOR_POSE_TOPIC = "~/end_effector_pose"
REFERENCE_PREVIEW_TOPIC = "~/reference_preview"
MARKERS_TOPIC = "~/markers"
ROBOT_DESCRIPTION_TOPIC = "~/robot_description"
SPEED_SCALING_TOPIC = "~/speed_scaling"  # input, std_msgs/Float64
DIAGNOSTICS_TOPIC = "/diagnostics"
# the plant's own (its joint states and E's pose on the names above, in its namespace)
COMMANDS_TOPIC = "~/commands"  # input, std_msgs/Float64MultiArray
TIP_DEFLECTION_TOPIC = "~/tip_deflection"
CLOCK_TOPIC = "/clock"  # lock-step
PUBLISHER_DEPTH = 10  # keep-last depth of every publisher (reliable, volatile)
DIAGNOSTICS_PERIOD = 1.0  # [s]
MAX_PUBLISH_RATE = 1000  # [Hz], upper bound of the publish_rate parameter
STORAGES = ("mcap", "sqlite3")  # rosbag2 storage plugins the recorder and the offline export write
ELLIPSE_SEGMENTS = 128
ELLIPSE_NAMESPACE = "target_ellipse"
TRAIL_NAMESPACE = "end_effector_trail"
LINE_WIDTH = 0.03  # [m], width of the marker lines
ELLIPSE_COLOR = (0.1, 0.6, 1.0, 1.0)  # r, g, b, a
TRAIL_COLOR = (1.0, 0.4, 0.1, 1.0)


@dataclass(frozen=True)
class MessageTypes:
    """Message constructors (called with every field by keyword) and the converters for array and
    byte fields of one message implementation."""

    Time: Callable[..., Any]
    Duration: Callable[..., Any]
    Header: Callable[..., Any]
    String: Callable[..., Any]
    ColorRGBA: Callable[..., Any]
    Point: Callable[..., Any]
    Quaternion: Callable[..., Any]
    Vector3: Callable[..., Any]
    Vector3Stamped: Callable[..., Any]
    Pose: Callable[..., Any]
    PoseStamped: Callable[..., Any]
    JointState: Callable[..., Any]
    JointTrajectory: Callable[..., Any]
    JointTrajectoryPoint: Callable[..., Any]
    KeyValue: Callable[..., Any]
    DiagnosticStatus: Callable[..., Any]
    DiagnosticArray: Callable[..., Any]
    CompressedImage: Callable[..., Any]
    MeshFile: Callable[..., Any]
    Marker: Callable[..., Any]
    MarkerArray: Callable[..., Any]
    float64_array: Callable[[np.ndarray], Any]
    uint8_array: Callable[[bytes], Any]
    byte: Callable[[int], Any]


def rosbags_types(typestore: Any = None) -> MessageTypes:
    """Constructors of rosbags' message dataclasses (default: its ROS 2 Jazzy typestore)."""
    if typestore is None:
        from rosbags.typesys import Stores, get_typestore

        typestore = get_typestore(Stores.ROS2_JAZZY)
    types = typestore.types
    return MessageTypes(
        Time=types["builtin_interfaces/msg/Time"],
        Duration=types["builtin_interfaces/msg/Duration"],
        Header=types["std_msgs/msg/Header"],
        String=types["std_msgs/msg/String"],
        ColorRGBA=types["std_msgs/msg/ColorRGBA"],
        Point=types["geometry_msgs/msg/Point"],
        Quaternion=types["geometry_msgs/msg/Quaternion"],
        Vector3=types["geometry_msgs/msg/Vector3"],
        Vector3Stamped=types["geometry_msgs/msg/Vector3Stamped"],
        Pose=types["geometry_msgs/msg/Pose"],
        PoseStamped=types["geometry_msgs/msg/PoseStamped"],
        JointState=types["sensor_msgs/msg/JointState"],
        JointTrajectory=types["trajectory_msgs/msg/JointTrajectory"],
        JointTrajectoryPoint=types["trajectory_msgs/msg/JointTrajectoryPoint"],
        KeyValue=types["diagnostic_msgs/msg/KeyValue"],
        DiagnosticStatus=types["diagnostic_msgs/msg/DiagnosticStatus"],
        DiagnosticArray=types["diagnostic_msgs/msg/DiagnosticArray"],
        CompressedImage=types["sensor_msgs/msg/CompressedImage"],
        MeshFile=types["visualization_msgs/msg/MeshFile"],
        Marker=types["visualization_msgs/msg/Marker"],
        MarkerArray=types["visualization_msgs/msg/MarkerArray"],
        float64_array=lambda values: np.array(values, dtype=np.float64),
        uint8_array=lambda data: np.frombuffer(bytes(data), dtype=np.uint8).copy(),
        byte=int,
    )


# --- basic types ----------------------------------------------------------------------------------


def time_msg(types: MessageTypes, stamp_ns: int) -> Any:
    """builtin_interfaces/Time of a non-negative time in nanoseconds."""
    return types.Time(sec=stamp_ns // NANOSECONDS, nanosec=stamp_ns % NANOSECONDS)


def duration_msg(types: MessageTypes, duration_ns: int) -> Any:
    """builtin_interfaces/Duration (nanosec in [0, 10^9), sec rounded towards minus infinity)."""
    return types.Duration(sec=duration_ns // NANOSECONDS, nanosec=duration_ns % NANOSECONDS)


def header(types: MessageTypes, stamp_ns: int, frame_id: str) -> Any:
    return types.Header(stamp=time_msg(types, stamp_ns), frame_id=frame_id)


def point(types: MessageTypes, xyz: Sequence[float]) -> Any:
    """geometry_msgs/Point (x, y, z) [m]."""
    return types.Point(x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]))


def points(types: MessageTypes, xyz: np.ndarray) -> list[Any]:
    """geometry_msgs/Point of each row of ``xyz`` (N, 3) [m]."""
    return [point(types, p) for p in np.asarray(xyz, dtype=float).reshape(-1, 3)]


def _color(types: MessageTypes, rgba: Sequence[float]) -> Any:
    return types.ColorRGBA(r=float(rgba[0]), g=float(rgba[1]), b=float(rgba[2]), a=float(rgba[3]))


def _pose(types: MessageTypes, position: Sequence[float], quaternion: Sequence[float]) -> Any:
    """geometry_msgs/Pose from a position and a quaternion (x, y, z, w)."""
    x, y, z, w = (float(v) for v in quaternion)
    return types.Pose(position=point(types, position), orientation=types.Quaternion(x=x, y=y, z=z, w=w))


# --- published messages ---------------------------------------------------------------------------


def joint_state(types: MessageTypes, stamp_ns: int, joint_names: Sequence[str], sample: ReferenceSample | PlantState,
                message: Any = None) -> Any:
    """sensor_msgs/JointState: positions, velocities and efforts (a reference's generalized efforts of
    constraints and drive, a plant's actuator torques), one entry per joint name (header.frame_id empty, as
    for every JointState).  ``message``: a
    JointState of these joint names made here before, filled again instead of a new one (a publisher
    serializes a message as it publishes it, so one object serves every sample)."""
    if message is None:
        empty = types.float64_array([])
        message = types.JointState(header=header(types, stamp_ns, ""), name=list(joint_names), position=empty,
                                   velocity=empty, effort=empty)
    message.header.stamp = time_msg(types, stamp_ns)
    message.position = types.float64_array(sample.q)
    message.velocity = types.float64_array(sample.qd)
    message.effort = types.float64_array(sample.effort)
    return message


def end_effector_pose(types: MessageTypes, stamp_ns: int, frame_id: str, sample: ReferenceSample | PlantState,
                      message: Any = None) -> Any:
    """geometry_msgs/PoseStamped of E (position, and orientation of the last link) in ``frame_id``;
    ``message``: one made here before for ``frame_id``, filled again (see :func:`joint_state`)."""
    if message is None:
        message = types.PoseStamped(header=header(types, stamp_ns, frame_id),
                                    pose=_pose(types, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)))
    message.header.stamp = time_msg(types, stamp_ns)
    position, orientation = message.pose.position, message.pose.orientation
    position.x, position.y, position.z = (float(v) for v in sample.ee_position)
    orientation.x, orientation.y, orientation.z, orientation.w = (float(v) for v in sample.ee_quaternion)
    return message


def tip_deflection(types: MessageTypes, stamp_ns: int, frame_id: str, deflection: Sequence[float],
                   message: Any = None) -> Any:
    """geometry_msgs/Vector3Stamped of the boom tip's deflection [m] in ``frame_id`` (the first boom element's
    link); ``message``: one made here before for ``frame_id``, filled again (see :func:`joint_state`)."""
    if message is None:
        message = types.Vector3Stamped(header=header(types, stamp_ns, frame_id),
                                       vector=types.Vector3(x=0.0, y=0.0, z=0.0))
    message.header.stamp = time_msg(types, stamp_ns)
    vector = message.vector
    vector.x, vector.y, vector.z = (float(v) for v in deflection)
    return message


def preview_offsets(horizon: float, count: int) -> list[int]:
    """time_from_start [ns] of a preview's sample and its ``count`` points after it, evenly spaced over
    ``horizon`` [s] (integer nanoseconds, strictly increasing for a horizon of at least ``count`` ns)."""
    horizon_ns = round(horizon * NANOSECONDS)
    return [i * horizon_ns // count for i in range(count + 1)]


def reference_preview(types: MessageTypes, stamp_ns: int, frame_id: str, joint_names: Sequence[str],
                      indices: Sequence[int], offsets_ns: Sequence[int], samples: Sequence[ReferenceSample],
                      effort: bool = False) -> Any:
    """trajectory_msgs/JointTrajectory of the joints ``joint_names`` (coordinates ``indices`` of the
    samples) whose first point is at ``stamp_ns`` (header.stamp, time_from_start 0): point i is
    ``samples[i]`` at time_from_start ``offsets_ns[i]`` (0 first, then strictly increasing); positions,
    velocities and accelerations, efforts only with ``effort``: the samples' feedforward, what a controller adds
    at those joints (the constraint forces, without the drive's torque, which the plant applies itself)."""
    if len(offsets_ns) != len(samples) or len(joint_names) != len(indices):
        raise ValueError(f"{len(offsets_ns)} offsets for {len(samples)} samples, {len(joint_names)} names for "
                         f"{len(indices)} coordinates")
    if (offsets_ns and offsets_ns[0] != 0) or any(b <= a for a, b in itertools.pairwise(offsets_ns)):
        raise ValueError(f"preview offsets must start at 0 and increase strictly, got {list(offsets_ns)}")
    columns = list(indices)
    points = [types.JointTrajectoryPoint(
        positions=types.float64_array(s.q[columns]),
        velocities=types.float64_array(s.qd[columns]),
        accelerations=types.float64_array(s.qdd[columns]),
        effort=types.float64_array(s.feedforward[columns] if effort else []),
        time_from_start=duration_msg(types, offset),
    ) for offset, s in zip(offsets_ns, samples, strict=True)]
    return types.JointTrajectory(header=header(types, stamp_ns, frame_id), joint_names=list(joint_names),
                                 points=points)


def diagnostics(types: MessageTypes, stamp_ns: int, name: str, hardware_id: str, level: int, message: str,
                values: Mapping[str, object]) -> Any:
    """diagnostic_msgs/DiagnosticArray with one status; ``values`` become key/value strings."""
    status = types.DiagnosticStatus(
        level=types.byte(level), name=name, message=message, hardware_id=hardware_id,
        values=[types.KeyValue(key=key, value=str(value)) for key, value in values.items()])
    return types.DiagnosticArray(header=header(types, stamp_ns, ""), status=[status])


def diagnostic_values(state: str, sample: ReferenceSample | None, real_time_factor: float, publish_rate: int,
                      achieved_rate: float, counters: Mapping[str, int], targets: Task, speed_scaling: float,
                      last_error: str, extra: Mapping[str, object] | None = None) -> dict[str, str]:
    """The key/value pairs of the node's reference status (the node and the offline bag export), every
    value a number (or the state and the error text): stream state, motion time [s] and largest
    constraint distance [m] of the last sample, solver real-time factor, publish and achieved rate
    [Hz], the sample counters, the targets and speed scaling, ``extra`` pairs and the last error."""
    values = {
        "state": state,
        "motion_time_s": f"{sample.t:.6f}" if sample else "nan",
        "constraint_residual_m": f"{sample.residual_distance:.3e}" if sample else "nan",
        "real_time_factor": f"{real_time_factor:.3f}",
        "publish_rate_hz": publish_rate,
        "achieved_rate_hz": f"{achieved_rate:.3f}",
        **counters,
        "target_ellipse_a_m": f"{targets.ellipse_a:g}",
        "target_ellipse_b_m": f"{targets.ellipse_b:g}",
        "target_z_increment_m": f"{targets.z_increment:g}",
        "target_rise_time_s": f"{targets.rise_time:g}",
        "speed_scaling": f"{speed_scaling:g}",
        **(extra or {}),
        "last_error": last_error,
    }
    return {key: str(value) for key, value in values.items()}


def _line_strip(types: MessageTypes, stamp_ns: int, frame_id: str, namespace: str,
                vertices: list[Any], rgba: Sequence[float]) -> Any:
    """A LINE_STRIP marker through the Point messages ``vertices`` in ``frame_id``; every Marker field given."""
    return types.Marker(
        header=header(types, stamp_ns, frame_id), ns=namespace, id=0, type=types.Marker.LINE_STRIP,
        action=types.Marker.ADD, pose=_pose(types, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)),
        scale=types.Vector3(x=LINE_WIDTH, y=0.0, z=0.0), color=_color(types, rgba),
        lifetime=duration_msg(types, 0), frame_locked=False, points=vertices, colors=[],
        texture_resource="", texture=types.CompressedImage(header=header(types, 0, ""), format="",
                                                           data=types.uint8_array(b"")),
        uv_coordinates=[], text="", mesh_resource="",
        mesh_file=types.MeshFile(filename="", data=types.uint8_array(b"")),
        mesh_use_embedded_materials=False,
    )


def ellipse_points(a: float, b: float, z: float, segments: int = ELLIPSE_SEGMENTS) -> np.ndarray:
    """Closed polyline (segments + 1, 3) of the ellipse (x/a)^2 + (y/b)^2 = 1 at height z."""
    phi = np.linspace(0.0, 2.0 * np.pi, segments + 1)
    return np.column_stack([a * np.cos(phi), b * np.sin(phi), np.full_like(phi, z)])


def markers(types: MessageTypes, stamp_ns: int, frame_id: str, ellipse: list[Any], trail: list[Any]) -> Any:
    """visualization_msgs/MarkerArray: the target ellipse and E's trail as LINE_STRIPs through their Point
    messages (:func:`points` of :func:`ellipse_points` and of E's positions: a publisher keeps them, so a
    point is made once, not at every publication)."""
    return types.MarkerArray(markers=[
        _line_strip(types, stamp_ns, frame_id, ELLIPSE_NAMESPACE, ellipse, ELLIPSE_COLOR),
        _line_strip(types, stamp_ns, frame_id, TRAIL_NAMESPACE, trail, TRAIL_COLOR),
    ])


def robot_description(types: MessageTypes, urdf: str) -> Any:
    """std_msgs/String with the URDF of the model the reference is computed for (RViz's RobotModel can
    read it from ~/robot_description; robot_state_publisher takes the same URDF as its parameter)."""
    return types.String(data=urdf)

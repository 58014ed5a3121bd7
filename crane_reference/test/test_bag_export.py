"""Offline export of the reference to rosbag2 (crane_reference.interface.reference_bag, written through
interface.bag), read back with rosbags and mcap."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.interfaces import QosDurability, QosReliability
from rosbags.rosbag2 import Reader

from crane_reference import cli
from crane_reference.base.health import Level
from crane_reference.interface import bag as bag_export
from crane_reference.interface import messages
from crane_reference.interface.bag import BagError, BagWriter
from crane_reference.interface.reference_bag import (
    DEFAULT_TOPICS,
    DIAGNOSTICS,
    END_EFFECTOR_POSE,
    JOINT_STATES,
    NODE_QOS,
    TOPIC_TYPES,
    ReferenceBag,
    export_reference,
    node_stream,
)
from crane_reference.model.config import load_config

RATE = 50
DURATION = 2.0  # [s]: samples 0 .. 100, diagnostics at 1 s and 2 s
SAMPLES = round(DURATION * RATE) + 1
PERIOD_NS = 10**9 // RATE


def installed_type_hash(msgtype: str) -> str:
    """RIHS01 hash of ``pkg/msg/Name`` from the installed message package's share/pkg/msg/Name.json (of an
    action's ``pkg/action/Name_Part``, from share/pkg/action/Name.json), as rosidl wrote it."""
    package, kind, name = msgtype.split("/")
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p] + [sys.prefix]
    for prefix in prefixes:
        path = Path(prefix, "share", package, kind, f"{name.partition('_')[0] if kind == 'action' else name}.json")
        if path.is_file():
            hashes = json.loads(path.read_text())["type_hashes"]
            return next(h["hash_string"] for h in hashes if h["type_name"] == msgtype)
    raise FileNotFoundError(f"no share/{package}/{kind}/{name}.json under {prefixes}")


def read_bag(path: Path) -> tuple[dict, dict[str, list[tuple[int, object, bytes]]]]:
    """Connections by topic and (timestamp, message, raw bytes) by topic, read with rosbags' AnyReader."""
    with AnyReader([path]) as reader:
        connections = {c.topic: c for c in reader.connections}
        by_topic: dict[str, list] = {topic: [] for topic in connections}
        for connection, timestamp, raw in reader.messages():
            by_topic[connection.topic].append((timestamp, reader.deserialize(raw, connection.msgtype), raw))
    return connections, by_topic


def metadata(path: Path) -> dict:
    """The bag's metadata.yaml (rosbag2_bagfile_information)."""
    return yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]


def stamp_ns(header) -> int:
    return header.stamp.sec * 10**9 + header.stamp.nanosec


@pytest.fixture(scope="module")
def offline(tmp_path_factory):
    """An MCAP (version 9) export of the default (flexible) reference, DURATION s at RATE Hz, read back,
    and the samples of an independent stream at the same publish times."""
    path = tmp_path_factory.mktemp("export") / "bag"
    config = load_config(None)
    with BagWriter(path) as bag:
        count = export_reference(bag, node_stream(config), RATE, DURATION)
    assert count == SAMPLES
    stream = node_stream(config)
    stream.compute(DURATION)
    samples = [stream.sample(k / RATE) for k in range(SAMPLES)]
    return path, *read_bag(path), samples, list(stream.joint_names)


@pytest.mark.slow
def test_topics_types_hashes_qos_and_counts(offline):
    path, connections, by_topic, _, _ = offline
    assert set(connections) == set(DEFAULT_TOPICS)
    for topic, connection in connections.items():
        assert connection.msgtype == TOPIC_TYPES[topic]
        assert connection.digest == installed_type_hash(connection.msgtype)
        assert connection.ext.serialization_format == "cdr"
        assert connection.ext.offered_qos_profiles == [NODE_QOS]
    assert len(by_topic[JOINT_STATES]) == len(by_topic[END_EFFECTOR_POSE]) == SAMPLES
    assert len(by_topic[DIAGNOSTICS]) == int(DURATION)
    info = metadata(path)
    assert info["version"] == 9 and info["storage_identifier"] == "mcap"
    assert info["message_count"] == 2 * SAMPLES + int(DURATION)
    with Reader(path) as reader:
        assert reader.message_count == 2 * SAMPLES + int(DURATION)


def test_stamps_and_values_equal_the_stream(offline):
    _, _, by_topic, samples, joint_names = offline
    for k, ((t_joint, joint, _), (t_pose, pose, _), sample) in enumerate(
            zip(by_topic[JOINT_STATES], by_topic[END_EFFECTOR_POSE], samples, strict=True)):
        assert t_joint == t_pose == stamp_ns(joint.header) == stamp_ns(pose.header) == k * PERIOD_NS
        assert joint.name == joint_names and joint.header.frame_id == ""
        np.testing.assert_array_equal(joint.position, sample.q)
        np.testing.assert_array_equal(joint.velocity, sample.qd)
        np.testing.assert_array_equal(joint.effort, sample.effort)
        assert pose.header.frame_id == "world"
        position, orientation = pose.pose.position, pose.pose.orientation
        np.testing.assert_array_equal([position.x, position.y, position.z], sample.ee_position)
        np.testing.assert_array_equal([orientation.x, orientation.y, orientation.z, orientation.w],
                                      sample.ee_quaternion)
    for second, (timestamp, diagnostics, _) in enumerate(by_topic[DIAGNOSTICS], start=1):
        assert timestamp == stamp_ns(diagnostics.header) == second * 10**9
        (status,) = diagnostics.status
        values = {kv.key: kv.value for kv in status.values}
        assert status.level == Level.OK and status.name == "crane_reference: reference"
        assert status.hardware_id == "/crane_reference"
        assert values["state"] == "RUNNING" and values["published"] == str(second * RATE + 1)
        assert float(values["motion_time_s"]) == pytest.approx(second, abs=1e-6)
        assert float(values["constraint_residual_m"]) == pytest.approx(samples[second * RATE].residual_distance,
                                                                       rel=1e-3)


@pytest.mark.ros
def test_content_equals_the_node_messages(offline):
    """The bag's messages, read with rclpy, equal the rclpy messages the node builds for the same samples
    (bytes may differ in CDR padding, which rclpy leaves uninitialized)."""
    from geometry_msgs.msg import PoseStamped
    from rclpy import serialization as rclpy_serialization
    from sensor_msgs.msg import JointState

    _, _, by_topic, samples, joint_names = offline
    from crane_reference.ros.message_types import rclpy_types

    types = rclpy_types()
    for k in (0, 1, SAMPLES // 2, SAMPLES - 1):
        stamp = k * PERIOD_NS
        node_joint_state = messages.joint_state(types, stamp, joint_names, samples[k])
        node_pose = messages.end_effector_pose(types, stamp, "world", samples[k])
        assert rclpy_serialization.deserialize_message(by_topic[JOINT_STATES][k][2], JointState) == node_joint_state
        assert rclpy_serialization.deserialize_message(by_topic[END_EFFECTOR_POSE][k][2], PoseStamped) == node_pose
        assert len(by_topic[JOINT_STATES][k][2]) == len(rclpy_serialization.serialize_message(node_joint_state))


def test_mcap_reads_independently(offline):
    """The mcap package (no rosbags) sees the ros2 profile, schemas, channels with QoS, and every message."""
    path, connections, by_topic, _, _ = offline
    typestore = bag_export.jazzy_typestore()
    (mcap_file,) = path.glob("*.mcap")
    with mcap_file.open("rb") as stream:
        reader = make_reader(stream)
        header = reader.get_header()
        summary = reader.get_summary()
        assert header.profile == "ros2"
        channels = {c.topic: c for c in summary.channels.values()}
        assert set(channels) == set(DEFAULT_TOPICS)
        for topic, channel in channels.items():
            schema = summary.schemas[channel.schema_id]
            assert schema.name == TOPIC_TYPES[topic] and schema.encoding == "ros2msg"
            assert schema.data.decode() == typestore.generate_msgdef(TOPIC_TYPES[topic], ros_version=2)[0]
            assert channel.message_encoding == "cdr"
            assert "reliability: reliable" in channel.metadata["offered_qos_profiles"]
            assert summary.statistics.channel_message_counts[channel.id] == len(by_topic[topic])
        seen = {topic: [] for topic in channels}
        for _, channel, message in reader.iter_messages(log_time_order=True):
            assert message.log_time == message.publish_time
            seen[channel.topic].append((message.log_time, message.data))
    for topic, messages_read in seen.items():
        assert messages_read == [(timestamp, raw) for timestamp, _, raw in by_topic[topic]]
        decoded = typestore.deserialize_cdr(messages_read[-1][1], TOPIC_TYPES[topic])
        assert stamp_ns(decoded.header) == messages_read[-1][0]
    assert connections[JOINT_STATES].msgcount == SAMPLES


def test_sqlite3_version_8(tmp_path):
    """A Humble-readable bag: version 8 metadata (QoS as a YAML string), SQLite 3 storage."""
    path = tmp_path / "humble"
    with BagWriter(path, "sqlite3", 8) as bag:
        export_reference(bag, node_stream(load_config(None), "rigid"), 20, 0.5)
    info = metadata(path)
    assert info["version"] == 8 and info["storage_identifier"] == "sqlite3"
    (topic_metadata,) = [t["topic_metadata"] for t in info["topics_with_message_count"]
                         if t["topic_metadata"]["name"] == JOINT_STATES]
    assert isinstance(topic_metadata["offered_qos_profiles"], str)
    connections, by_topic = read_bag(path)
    qos = connections[JOINT_STATES].ext.offered_qos_profiles
    assert qos[0].reliability == QosReliability.RELIABLE and qos[0].durability == QosDurability.VOLATILE
    assert [t for t, _, _ in by_topic[JOINT_STATES]] == [k * 10**9 // 20 for k in range(11)]
    assert DIAGNOSTICS not in by_topic or not by_topic[DIAGNOSTICS]


def test_reference_bag_with_a_node_s_topic_names(tmp_path):
    """What a node recording itself does: its publishers' topic names, sample stamps as bag timestamps."""
    stream = node_stream(load_config(None), "rigid")
    sample = stream.sample(0.0)
    names = {"joint_states": "/crane1/joint_states", "end_effector_pose": "/crane1/reference/end_effector_pose",
             "diagnostics": "/diagnostics"}
    with BagWriter(tmp_path / "self") as bag:
        reference = ReferenceBag(bag, **names)
        reference.write_sample(7, stream.joint_names, "map", sample)
        reference.write_diagnostics(9, "reference: reference", "/crane1/reference", Level.WARN, "late",
                                    {"held_late": 3})
    connections, by_topic = read_bag(tmp_path / "self")
    assert {t: c.msgtype for t, c in connections.items()} == {
        names["joint_states"]: TOPIC_TYPES[JOINT_STATES], names["end_effector_pose"]: TOPIC_TYPES[END_EFFECTOR_POSE],
        names["diagnostics"]: TOPIC_TYPES[DIAGNOSTICS]}
    ((t, joint, _),) = by_topic[names["joint_states"]]
    assert t == stamp_ns(joint.header) == 7 and list(joint.name) == list(stream.joint_names)
    ((t, pose, _),) = by_topic[names["end_effector_pose"]]
    assert t == 7 and pose.header.frame_id == "map"
    ((t, diagnostics, _),) = by_topic[names["diagnostics"]]
    (status,) = diagnostics.status
    assert t == 9 and status.level == Level.WARN and status.values[0].value == "3"


def test_bag_writer_errors(tmp_path):
    with pytest.raises(BagError, match="storage 'rosbag'"):
        BagWriter(tmp_path / "a", "rosbag")
    with pytest.raises(BagError, match="version 7"):
        BagWriter(tmp_path / "a", "mcap", 7)
    with pytest.raises(BagError, match="exists already"):
        BagWriter(tmp_path)
    bag = BagWriter(tmp_path / "b")
    with pytest.raises(BagError, match="not in the typestore"):
        bag.add_topic("/x", "crane_msgs/msg/Nothing")
    bag.add_topic("/s", "std_msgs/msg/String")
    with pytest.raises(BagError, match="in the bag already"):
        bag.add_topic("/s", "std_msgs/msg/String")
    with pytest.raises(BagError, match="not added"):
        bag.write("/t", b"", 0)
    bag.write_message("/s", bag.typestore.types["std_msgs/msg/String"](data="hi"), 5)
    bag.close()
    bag.close()
    with pytest.raises(BagError, match="closed"):
        bag.write("/s", b"", 0)
    _, by_topic = read_bag(tmp_path / "b")
    assert [(t, m.data) for t, m, _ in by_topic["/s"]] == [(5, "hi")]
    with pytest.raises(ValueError, match="rate"):
        export_reference(BagWriter(tmp_path / "c"), node_stream(load_config(None), "rigid"), 1001, 1.0)


def test_cli_simulate_bag(tmp_path, capsys):
    path = tmp_path / "cli"
    args = ["simulate", "--bag", str(path), "--model", "rigid", "--duration", "0.2", "--rate", "20",
            "--bag-storage", "sqlite3", "--bag-version", "8"]
    assert cli.main(args) == 0
    assert "5 samples at 20 Hz" in capsys.readouterr().out
    connections, by_topic = read_bag(path)
    assert len(by_topic[JOINT_STATES]) == 5 and connections[JOINT_STATES].digest == installed_type_hash(
        TOPIC_TYPES[JOINT_STATES])
    assert cli.main(args) == 2
    assert "exists already" in capsys.readouterr().err
    assert cli.main(["simulate", "--bag", str(tmp_path / "r"), "--rate", "0"]) == 2
    assert "--rate 0" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main(["simulate", "--bag", str(tmp_path / "s"), "--bag-storage", "rosbag"])

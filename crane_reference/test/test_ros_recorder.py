"""Live recording (crane_reference.ros.recorder): in-process, stopped by SIGINT/SIGTERM, and of the running node."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import rclpy
from crane_reference_interfaces.action import Retarget
from mcap.reader import make_reader
from rclpy.action import ActionClient
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from test_bag_export import installed_type_hash, metadata, read_bag, stamp_ns
from test_ros_node import held_samples
from waiting import wait_for

from crane_reference import cli
from crane_reference.interface.bag import BagWriter
from crane_reference.interface.reference_bag import (
    DIAGNOSTICS,
    END_EFFECTOR_POSE,
    JOINT_STATES,
    TOPIC_TYPES,
    export_reference,
    node_stream,
)
from crane_reference.model.config import load_config
from crane_reference.ros.recorder import (
    message_class,
    record,
    rosbags_qos,
    subscription_qos,
)

# An isolated ROS graph for this test process (and the subprocesses it starts).
ROOT = Path(__file__).resolve().parents[1]
INFINITE = QosTime(sec=9223372036, nsec=854775807)
FEEDBACK = "/crane_reference/retarget/_action/feedback"
LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)


@pytest.fixture
def context():
    """One initialized rclpy context per test."""
    context = Context()
    rclpy.init(context=context)
    yield context
    rclpy.try_shutdown(context=context)




def joint_state(k: int) -> JointState:
    """Test message k: its stamp is k ms and its position k, so that any loss or reordering shows."""
    message = JointState(name=["a", "b"], position=[float(k), -float(k)], velocity=[0.5, 0.25], effort=[])
    message.header.stamp.sec, message.header.stamp.nanosec = divmod(k * 10**6, 10**9)
    return message


class StatusReader:
    """Collects a recorder subprocess's stderr (its status lines) on a thread."""

    def __init__(self, process: subprocess.Popen) -> None:
        self.lines: list[str] = []
        self._thread = threading.Thread(target=lambda: self.lines.extend(iter(process.stderr.readline, "")),
                                        daemon=True)
        self._thread.start()

    def count(self, topic: str) -> int:
        """Messages of ``topic`` in the latest status line (0 before any)."""
        for line in reversed(self.lines):
            match = re.search(rf" {re.escape(topic)} (\d+)", line)
            if match:
                return int(match.group(1))
        return 0

    def text(self) -> str:
        return "".join(self.lines)


def python_command(*args: str) -> list[str]:
    return [sys.executable, "-m", *args]


def test_qos_conversions():
    qos = rosbags_qos(QoSProfile(depth=7, reliability=ReliabilityPolicy.BEST_EFFORT,
                                 durability=DurabilityPolicy.TRANSIENT_LOCAL, deadline=Duration(seconds=1.5)))
    assert qos == Qos(QosHistory.KEEP_LAST, 7, QosReliability.BEST_EFFORT, QosDurability.TRANSIENT_LOCAL,
                      QosTime(1, 500_000_000), QosTime(0, 0), QosLiveliness.SYSTEM_DEFAULT, QosTime(0, 0), False)
    reliable, best_effort = QoSProfile(depth=1), QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
    assert subscription_qos([reliable, LATCHED]).reliability == ReliabilityPolicy.RELIABLE
    assert subscription_qos([reliable, LATCHED]).durability == DurabilityPolicy.VOLATILE
    assert subscription_qos([LATCHED]).durability == DurabilityPolicy.TRANSIENT_LOCAL
    assert subscription_qos([reliable, best_effort]).reliability == ReliabilityPolicy.BEST_EFFORT
    assert message_class("std_msgs/msg/String") is String


@pytest.mark.parametrize(("storage", "version"), [("mcap", 9), ("sqlite3", 8)])
def test_record_in_process(context, tmp_path, storage, version):
    """Known messages published in this process are recorded with their types, hashes, offered QoS, values
    and receive-time stamps; a topic that appears during the recording (latched) is added then."""
    count = 200
    publisher_node = rclpy.create_node("recorder_test_publisher", context=context)
    joints = publisher_node.create_publisher(JointState, "/recorder_test/joints", 10)
    path = tmp_path / "bag"
    stop = threading.Event()
    result = {}
    with BagWriter(path, storage, version) as bag:
        thread = threading.Thread(target=lambda: result.update(recorder=record(
            bag, ["/recorder_test/joints", "recorder_test/latched"], stop, context=context)))
        thread.start()
        try:
            wait_for(lambda: joints.get_subscription_count() > 0, "the recorder's subscription", 20.0)
            sent = []
            for k in range(count):
                sent.append(publisher_node.get_clock().now().nanoseconds)
                joints.publish(joint_state(k))
                time.sleep(0.002)
            latched = publisher_node.create_publisher(String, "/recorder_test/latched", LATCHED)
            latched.publish(String(data="robot description"))  # before the recorder subscribes
            wait_for(lambda: latched.get_subscription_count() > 0, "the recorder's latched subscription", 20.0)
            wait_for(lambda: bag.counts.get("/recorder_test/latched") == 1, "the latched message", 5.0)
            wait_for(lambda: bag.counts["/recorder_test/joints"] == count, "every message", 5.0)
            stopped = publisher_node.get_clock().now().nanoseconds
        finally:
            stop.set()
            thread.join()
    recorder = result["recorder"]
    assert recorder.received == {"/recorder_test/joints": count, "/recorder_test/latched": 1}
    connections, by_topic = read_bag(path)
    assert {topic: c.msgtype for topic, c in connections.items()} == {
        "/recorder_test/joints": "sensor_msgs/msg/JointState", "/recorder_test/latched": "std_msgs/msg/String"}
    for connection in connections.values():
        assert connection.digest == installed_type_hash(connection.msgtype)
    (joints_qos,) = connections["/recorder_test/joints"].ext.offered_qos_profiles
    (latched_qos,) = connections["/recorder_test/latched"].ext.offered_qos_profiles
    assert (joints_qos.reliability, joints_qos.durability) == (QosReliability.RELIABLE, QosDurability.VOLATILE)
    assert (latched_qos.reliability, latched_qos.durability) == (QosReliability.RELIABLE,
                                                                 QosDurability.TRANSIENT_LOCAL)
    assert joints_qos.deadline == joints_qos.lifespan == INFINITE
    received = by_topic["/recorder_test/joints"]
    assert [list(m.position) for _, m, _ in received] == [[float(k), -float(k)] for k in range(count)]
    assert [stamp_ns(m.header) for _, m, _ in received] == [k * 10**6 for k in range(count)]
    assert all(list(m.name) == ["a", "b"] and list(m.velocity) == [0.5, 0.25] for _, m, _ in received)
    times = [t for t, _, _ in received]
    assert all(s <= t <= stopped for s, t in zip(sent, times, strict=True)), "receive time between send and stop"
    assert times == sorted(times)
    assert by_topic["/recorder_test/latched"][0][1].data == "robot description"
    assert metadata(path)["version"] == version
    if storage == "mcap":
        (mcap_file,) = path.glob("*.mcap")
        with mcap_file.open("rb") as stream:
            reader = make_reader(stream)
            decoded = [(c.topic, s.name, m.log_time, m.data) for s, c, m in reader.iter_messages(log_time_order=True)]
        assert [d for d in decoded if d[0] == "/recorder_test/joints"] == [
            ("/recorder_test/joints", "sensor_msgs/msg/JointState", t, raw) for t, _, raw in received]
    publisher_node.destroy_node()


def test_record_arguments(tmp_path, capsys):
    (tmp_path / "exists").mkdir()
    assert cli.main(["record", "-o", str(tmp_path / "exists")]) == 2
    assert "exists already" in capsys.readouterr().err
    assert cli.main(["record", "-o", str(tmp_path / "new"), "--duration", "-1"]) == 2
    assert "--duration -1" in capsys.readouterr().err
    assert cli.main(["record", "-o", str(tmp_path / "new"), "/joint_states", "bad topic"]) == 2
    assert "'bad topic' is invalid" in capsys.readouterr().err
    for bad in (["--storage", "rosbag"], ["--version", "7"]):
        with pytest.raises(SystemExit):
            cli.main(["record", "-o", str(tmp_path / "new"), *bad])
        assert "invalid choice" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()


@pytest.mark.parametrize(("signum", "storage"), [(signal.SIGINT, "mcap"), (signal.SIGTERM, "sqlite3")],
                         ids=["SIGINT-mcap", "SIGTERM-sqlite3"])
@pytest.mark.slow
def test_signal_leaves_a_complete_bag(context, tmp_path, signum, storage):
    """A recorder stopped by a signal while messages stream in writes every message it received: its
    count at exit equals the bag's, and the bag holds messages 0 .. n-1 of those published, none missing."""
    rate, topic = 500, "/signal_test/joints"
    node = rclpy.create_node("signal_test_publisher", context=context)
    publisher = node.create_publisher(JointState, topic, 10)
    path = tmp_path / "bag"
    process = subprocess.Popen(python_command("crane_reference.cli", "record", "-o", str(path), "--storage", storage,
                                              topic), cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)
    try:
        wait_for(lambda: publisher.get_subscription_count() > 0, "the recorder's subscription", 30.0)
        start, sent, signalled = time.monotonic(), 0, None
        while time.monotonic() - start < 1.5:
            publisher.publish(joint_state(sent))
            sent += 1
            if signalled is None and sent == rate:  # about 1 s into the run, messages still streaming
                process.send_signal(signum)
                signalled = sent
            time.sleep(max(0.0, sent / rate - (time.monotonic() - start)))
        out, err = process.communicate(timeout=20)
    finally:
        process.kill()
    assert process.returncode == 0, err
    received = int(re.search(rf"{topic}: received (\d+), written (\d+)", out).group(1))
    assert re.search(rf"recording {path}.*{topic} \d+", err), "status line"
    connections, by_topic = read_bag(path)
    positions = [m.position[0] for _, m, _ in by_topic[topic]]
    assert len(positions) == received == connections[topic].msgcount
    assert positions == [float(k) for k in range(received)], "a contiguous prefix of what was published"
    assert signalled - rate // 2 <= received <= sent, (signalled, received, sent)
    stamps = [t for t, _, _ in by_topic[topic]]  # the summary's duration is the bag's: its first to last stamp
    said = float(re.search(r"over ([0-9.]+) s \(the bag's duration", out).group(1))
    assert said == pytest.approx((stamps[-1] - stamps[0]) / 1e9, abs=0.005)
    assert metadata(path)["duration"]["nanoseconds"] == stamps[-1] - stamps[0]
    node.destroy_node()


@pytest.mark.slow
def test_live_node_matches_offline_export(context, tmp_path):
    """`crane-reference record` (default topics) of the running node agrees with `simulate --bag` for the
    same parameters: joint states and poses at the same stamps equal to 1e-9; same topics and types; a
    ~/retarget goal during the recording puts the action's feedback and status in the bag, with the package's
    own type and its hash (read by rosbags from the .action file)."""
    rate, model = 50, "rigid"
    log = tmp_path / "node.log"
    with log.open("w") as log_file:
        node = subprocess.Popen(python_command("crane_reference.ros.node", "--ros-args", "-p", f"publish_rate:={rate}",
                                               "-p", f"model:={model}"), cwd=ROOT, stdout=log_file, stderr=log_file)
    probe = rclpy.create_node("live_test_probe", context=context)
    heard: list[JointState] = []
    probe.create_subscription(JointState, JOINT_STATES, heard.append, 10)
    retarget = ActionClient(probe, Retarget, "/crane_reference/retarget")
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(probe)
    live = tmp_path / "live"
    try:
        try:
            wait_for(lambda: executor.spin_once(timeout_sec=0.1) or heard, "the node's first sample", 120.0)
        except TimeoutError as error:
            raise TimeoutError(f"{error}; node log:\n{log.read_text()}") from None
        publishing = time.monotonic()  # the node publishes from about now on
        recorder = subprocess.Popen(python_command("crane_reference.cli", "record", "-o", str(live)), cwd=ROOT,
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        status = StatusReader(recorder)
        try:
            try:
                wait_for(lambda: status.count(JOINT_STATES) >= 3 * rate, "3 s of joint states", 90.0, period=0.1)
                goal = retarget.send_goal_async(Retarget.Goal(ellipse_a=3.1, ellipse_b=2.0, z_increment=0.2,
                                                              z_rise_time=5.0, blend_time=0.3))
                wait_for(lambda: executor.spin_once(timeout_sec=0.05) or goal.done(), "the goal's answer", 30.0)
                result = goal.result().get_result_async()
                wait_for(lambda: executor.spin_once(timeout_sec=0.05) or result.done(), "the goal's result", 30.0)
                blend = result.result().result.blend_stamp  # the motion from here on is not the export's
                blend_ns = blend.sec * 10**9 + blend.nanosec
                wait_for(lambda: status.count(FEEDBACK) >= 1, "the goal's feedback recorded", 30.0, period=0.1)
            except TimeoutError as error:
                raise TimeoutError(f"{error}; recorder status:\n{status.text()}\nnode log:\n{log.read_text()}") \
                    from None
            recorder.send_signal(signal.SIGINT)
            recorder.wait(timeout=20)
        finally:
            recorder.kill()
        published_for = time.monotonic() - publishing
        assert recorder.returncode == 0, status.text()
    finally:
        node.send_signal(signal.SIGINT)
        try:
            node.wait(timeout=20)
        finally:
            node.kill()
        executor.shutdown()
        probe.destroy_node()
    assert node.returncode == 0, log.read_text()
    connections, by_topic = read_bag(live)
    recorded = {t: c.msgtype for t, c in connections.items()}
    assert TOPIC_TYPES.items() <= recorded.items()  # the exported topics, among every topic the node publishes
    assert {"/crane_reference/reference_preview", "/crane_reference/markers", "/crane_reference/robot_description",
            FEEDBACK, "/crane_reference/retarget/_action/status"} <= set(recorded)  # the action's topics too
    assert not {"/rosout", "/parameter_events"} & set(recorded)
    assert recorded[FEEDBACK] == "crane_reference_interfaces/action/Retarget_FeedbackMessage"
    assert all(c.digest == installed_type_hash(c.msgtype) for c in connections.values())
    joints, poses = by_topic[JOINT_STATES], by_topic[END_EFFECTOR_POSE]
    assert len(joints) >= 3 * rate and by_topic[DIAGNOSTICS] and by_topic[FEEDBACK]
    joints = [row for row in joints if stamp_ns(row[1].header) < blend_ns]  # before the goal's blend
    assert len(joints) >= 3 * rate
    assert all(t >= stamp_ns(m.header) for t, m, _ in joints), "received after its stamp"
    diagnostics = {kv.key: kv.value for kv in by_topic[DIAGNOSTICS][-1][1].status[0].values}

    # Sample index k of each live message: stamps are start + k * period, and a sample held while the solver was late
    # (as on a busy machine: the last one again, at rest) does not advance the stream; find k of one by its positions.
    stamps = np.array([stamp_ns(m.header) for _, m, _ in joints])
    period = 10**9 // rate
    assert np.all((stamps - stamps[0]) % period == 0)
    held = held_samples({"q": np.array([m.position for _, m, _ in joints]),
                         "qd": np.array([m.velocity for _, m, _ in joints])})
    assert held.mean() <= 0.2, "most samples must come from the stream"
    offset = np.cumsum(np.where(held, 0, np.r_[0, np.diff(stamps) // period]))
    offline = tmp_path / "offline"
    with BagWriter(offline) as bag:
        # longer than the node published: it starts before the probe hears it (discovery takes seconds on a
        # loaded machine), so its sample indices run past published_for
        export_reference(bag, node_stream(load_config(None), model), rate, published_for + 10.0)
    offline_connections, offline_topics = read_bag(offline)
    assert {t: (c.msgtype, c.digest) for t, c in offline_connections.items()} == {
        t: (c.msgtype, c.digest) for t, c in connections.items() if t in offline_connections}
    q_offline = np.array([m.position for _, m, _ in offline_topics[JOINT_STATES]])
    middle = int(np.flatnonzero(~held)[np.count_nonzero(~held) // 2])
    k_middle = int(np.argmin(np.abs(q_offline - joints[middle][1].position).max(axis=1)))
    ks = k_middle + offset - offset[middle]
    assert ks[0] >= 0 and ks[-1] < len(q_offline)
    live_poses = {stamp_ns(m.header): m for _, m, _ in poses if stamps[0] <= stamp_ns(m.header) <= stamps[-1]}
    assert set(live_poses) <= set(stamps.tolist()) and len(live_poses) >= len(joints) - rate // 2, \
        "poses at the joint states' stamps (subscriptions may match up to a few samples apart)"
    # The node advances its stream's publish time by summing 1 / rate, the export uses k / rate: the sample
    # times differ by ~1e-13 s, which moves positions and velocities by far less than 1e-9 but the efforts
    # (constraint forces of ~1e4 N m interpolated between integrator steps) by up to ~1e-8 N m.
    tolerances = {"position": 1e-9, "velocity": 1e-9, "effort": 1e-6}
    errors = dict.fromkeys([*tolerances, "pose"], 0.0)
    for k, stamp, (_, live_joint, _), skip in zip(ks, stamps, joints, held, strict=True):
        if skip:
            continue
        (_, joint, _), (_, pose, _) = offline_topics[JOINT_STATES][k], offline_topics[END_EFFECTOR_POSE][k]
        assert list(live_joint.name) == list(joint.name)
        for field in tolerances:
            errors[field] = max(errors[field], np.abs(getattr(live_joint, field) - getattr(joint, field)).max())
        live_pose = live_poses.get(int(stamp))
        if live_pose is not None:
            assert live_pose.header.frame_id == pose.header.frame_id == "world"
            for part, names in (("position", "xyz"), ("orientation", "xyzw")):
                errors["pose"] = max(errors["pose"], *(abs(getattr(getattr(live_pose.pose, part), n)
                                                           - getattr(getattr(pose.pose, part), n)) for n in names))
    assert all(errors[name] <= tolerance for name, tolerance in {**tolerances, "pose": 1e-9}.items()), errors
    offline_keys = {kv.key for kv in offline_topics[DIAGNOSTICS][0][1].status[0].values}
    assert offline_keys <= set(diagnostics)


@contextmanager
def recording(bag: BagWriter, context: Context, source: str) -> Iterator[dict]:
    """Record every topic of the node ``source`` into ``bag`` on a thread while the block runs; the dict
    yielded holds the recorder (``"recorder"``) after the block."""
    stop, result = threading.Event(), {}
    thread = threading.Thread(target=lambda: result.update(recorder=record(bag, [], stop, context=context,
                                                                           source=source)))
    thread.start()
    try:
        yield result
    finally:
        stop.set()
        thread.join()


def test_records_the_topics_of_a_renamed_node(context, tmp_path):
    """Without topics, record takes every topic the named node publishes (its actual, remapped names)."""
    publisher_node = rclpy.create_node("renamed", namespace="/site_a", context=context)
    other = rclpy.create_node("other", context=context)
    joints = publisher_node.create_publisher(JointState, "~/joint_states", 10)
    other.create_publisher(JointState, "/joint_states", 10)  # measured state of someone else: not recorded
    with BagWriter(tmp_path / "bag") as bag, recording(bag, context, "/site_a/renamed") as result:
        wait_for(lambda: joints.get_subscription_count() > 0, "the recorder's subscription", 20.0)
        for k in range(5):
            joints.publish(joint_state(k))
        wait_for(lambda: bag.counts.get("/site_a/renamed/joint_states") == 5, "the messages", 5.0)
    assert set(result["recorder"].topics) == {"/site_a/renamed/joint_states"}
    publisher_node.destroy_node()
    other.destroy_node()


def test_records_every_node_of_the_name(context, tmp_path):
    """Two nodes share the name, each in its own participant (a stale one left by an earlier test or process,
    and the running one): the topics of both are recorded, not only those of the one rclpy's by-node query
    answers for."""
    elsewhere = Context()
    rclpy.init(context=elsewhere)
    stale = rclpy.create_node("twin", context=elsewhere)
    running = rclpy.create_node("twin", context=context)
    events = stale.create_publisher(String, "~/transition_event", 10)
    joints = running.create_publisher(JointState, "~/joint_states", 10)
    with BagWriter(tmp_path / "bag") as bag, recording(bag, context, "/twin") as result:
        wait_for(lambda: joints.get_subscription_count() > 0, "the recorder's subscription", 20.0)
        for k in range(3):
            joints.publish(joint_state(k))
        wait_for(lambda: bag.counts.get("/twin/joint_states") == 3, "the messages", 5.0)
        wait_for(lambda: events.get_subscription_count() > 0, "the recorder's subscription to the twin", 20.0)
    assert set(result["recorder"].topics) == {"/twin/joint_states", "/twin/transition_event"}
    stale.destroy_node()
    running.destroy_node()
    rclpy.try_shutdown(context=elsewhere)

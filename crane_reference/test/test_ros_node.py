"""In-process tests of the crane_reference ROS 2 node (rclpy, one Context per test, an isolated domain id).

The node runs in its own executor thread; a probe node (its own executor thread) subscribes to every
topic and calls the services and the standard parameter services, as another process would.  The
published motion is compared with an independent :class:`ReferenceStream` and E with the kinematics
(:meth:`CraneDynamics.end_effector_poses`) of the published joint positions.
"""

from __future__ import annotations

import dataclasses
import math
import os
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rclpy
import yaml
from cranes import spinning_crane, with_trolley
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rclpy.exceptions import ParameterNotDeclaredException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rosgraph_msgs.msg import Clock
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, String
from std_srvs.srv import SetBool, Trigger
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import MarkerArray
from waiting import wait_for

from crane_reference.base.health import Level
from crane_reference.dynamics.chain_dynamics import CraneDynamics
from crane_reference.interface import messages
from crane_reference.model.chain import build_model
from crane_reference.model.config import load_config
from crane_reference.model.drive import make_drive
from crane_reference.model.parameters import Task
from crane_reference.model.urdf import model_to_urdf
from crane_reference.ros.message_types import rclpy_types
from crane_reference.ros.node import CraneReferenceNode
from crane_reference.ros.parameters import PARAMETERS, SPECS, NodeParameters, field_name
from crane_reference.ros.publishing import NodeTime
from crane_reference.stream.ahead import LOOKAHEAD
from crane_reference.stream.reference_stream import ERROR, ReferenceStream

NS = 10**9
NODE = "crane_reference"
TOPICS = {
    "joint_states": (JointState, f"/{NODE}/joint_states"),
    "pose": (PoseStamped, f"/{NODE}/end_effector_pose"),
    "preview": (JointTrajectory, f"/{NODE}/reference_preview"),
    "markers": (MarkerArray, f"/{NODE}/markers"),
    "diagnostics": (DiagnosticArray, "/diagnostics"),
}


def stamp_ns(msg: Any) -> int:
    return msg.header.stamp.sec * NS + msg.header.stamp.nanosec


class Harness:
    """The node under test and a probe node, each spun by its own executor thread."""

    def __init__(self) -> None:
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node: CraneReferenceNode | None = None
        self.probe = Node("probe", context=self.context)
        self.received: dict[str, list[tuple[float, Any]]] = {name: [] for name in TOPICS}
        for name, (msg_type, topic) in TOPICS.items():
            self.probe.create_subscription(msg_type, topic, lambda msg, name=name: self.received[name].append(
                (time.monotonic(), msg)), 10000)
        self.parameters = AsyncParameterClient(self.probe, NODE)
        self.restart = self.probe.create_client(Trigger, f"/{NODE}/restart")
        self.pause = self.probe.create_client(SetBool, f"/{NODE}/pause")
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.spin(self.probe)

    def spin(self, node: Node) -> None:
        """Spin ``node`` in an executor thread of its own until the harness closes."""
        executor = SingleThreadedExecutor(context=self.context)
        executor.add_node(node)

        def spin() -> None:
            try:
                while not self._stop.is_set():
                    executor.spin_once(timeout_sec=0.02)
            except ExternalShutdownException:
                pass

        thread = threading.Thread(target=spin, daemon=True)
        thread.start()
        self._threads.append(thread)

    def start(self, cli_args: list[str] | None = None, **parameters: Any) -> CraneReferenceNode:
        """Start the node with parameter overrides (``blend_time=1.0``; dots as ``__``: ``ellipse__a``)."""
        overrides = [Parameter(name.replace("__", "."), value=value) for name, value in parameters.items()]
        self.node = CraneReferenceNode(context=self.context, parameter_overrides=overrides, cli_args=cli_args)
        self.spin(self.node)
        self.wait_for(lambda: len(self.received["joint_states"]) >= 2, "the first joint_states")
        return self.node

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join()
        if self.node is not None:
            self.node.destroy_node()
        self.probe.destroy_node()
        self.context.try_shutdown()

    @staticmethod
    def wait_for(condition: Callable[[], bool], what: str, timeout: float = 30.0) -> None:
        wait_for(condition, what, timeout)

    def result(self, future: Any, timeout: float = 10.0) -> Any:
        self.wait_for(future.done, "a service response", timeout)
        return future.result()

    def set_parameters(self, *parameters: Parameter, atomically: bool = False) -> list[Any]:
        """Set parameters through the node's parameter services; the SetParametersResult list."""
        assert self.parameters.wait_for_services(timeout_sec=10.0)
        if atomically:
            return [self.result(self.parameters.set_parameters_atomically(list(parameters))).result]
        return self.result(self.parameters.set_parameters(list(parameters))).results

    def call(self, client: Any, request: Any) -> Any:
        assert client.wait_for_service(timeout_sec=10.0)
        return self.result(client.call_async(request))

    def samples(self, after_ns: int = 0) -> dict[str, np.ndarray]:
        """Received joint states with stamps > after_ns as arrays: stamp, receive time, q, qd, effort."""
        states = [(t, m) for t, m in list(self.received["joint_states"]) if stamp_ns(m) > after_ns]
        return {"stamp": np.array([stamp_ns(m) for _, m in states]), "received": np.array([t for t, _ in states]),
                "q": np.array([m.position for _, m in states]), "qd": np.array([m.velocity for _, m in states]),
                "effort": np.array([m.effort for _, m in states])}

    def start_on_sim_time(self, rate: int, clock_at: Callable[[int], int]) -> CraneReferenceNode:
        """Start the rigid crane's node with use_sim_time at ``rate`` Hz, and publish /clock every 5 ms at
        ``clock_at(ns of wall time since now)``."""
        self.node = CraneReferenceNode(context=self.context, parameter_overrides=[
            Parameter("use_sim_time", value=True), Parameter("publish_rate", value=rate),
            Parameter("model", value="rigid")])
        self.spin(self.node)
        clock = self.probe.create_publisher(Clock, "/clock", 10)
        wall_start = time.monotonic_ns()
        self.probe.create_timer(0.005, lambda: clock.publish(Clock(clock=messages.time_msg(
            rclpy_types(), clock_at(time.monotonic_ns() - wall_start)))))
        return self.node

    def wait_until_stamp(self, stamp: int, timeout: float = 15.0) -> None:
        self.wait_for(lambda: self.received["joint_states"] and stamp_ns(self.received["joint_states"][-1][1]) >= stamp,
                      f"the sample stamped {stamp}", timeout)

    def published_for(self, seconds: float) -> None:
        """Wait until ``seconds`` more of the reference are published (stamps, not the wall clock): from the
        last sample received, or from the first one to come."""
        self.wait_for(lambda: self.received["joint_states"], "a sample")
        self.wait_until_stamp(stamp_ns(self.received["joint_states"][-1][1]) + round(seconds * NS))


def diagnostics_values(ros: Harness, since: float = 0.0) -> list[dict[str, str]]:
    """The key/value pairs of every /diagnostics with values received after the monotonic time ``since``."""
    return [{kv.key: kv.value for kv in d.status[0].values} for t, d in list(ros.received["diagnostics"])
            if t > since and d.status[0].values]


def latest_values(ros: Harness, since: float = 0.0) -> dict[str, str]:
    """The values of the newest /diagnostics received after ``since`` (waiting for one)."""
    ros.wait_for(lambda: diagnostics_values(ros, since), "diagnostics values")
    return diagnostics_values(ros, since)[-1]


def command_report(ros: Harness, name: str, after: str | None = None) -> dict[str, str]:
    """The node's /diagnostics values once they report the command ``name`` (``{name}_accepted_s``,
    ``{name}_stamp_s``, ``{name}_stream_time_s``), accepted at another time than ``after`` (a previous
    report's ``{name}_accepted_s``)."""
    def report() -> dict[str, str] | None:
        return next((v for v in reversed(diagnostics_values(ros)) if v.get(f"{name}_accepted_s", after) != after),
                    None)

    ros.wait_for(lambda: report() is not None, f"the diagnostics of {name}")
    return report()


def held_samples(data: dict[str, np.ndarray]) -> np.ndarray:
    """Mask of the received samples held while the solver was late (as on a machine too busy for it): the
    last sample again with zero velocity; the stream goes on from it.  (A reference at rest looks the same:
    only for moving ones.)"""
    repeat = np.r_[False, np.all(data["q"][1:] == data["q"][:-1], axis=1)]
    return repeat & np.all(data["qd"] == 0.0, axis=1)


def stream_times(data: dict[str, np.ndarray], reference: ReferenceStream, rate: int) -> np.ndarray:
    """Stream time [s] of each received sample of a moving reference, NaN where held: the first one found
    among the first second's samples k / rate of ``reference`` (the same stream before any command), each
    later one as many periods on as its stamp is after the last received one's unless held (a sample lost on its
    way, as a loaded machine's transport may lose one, is counted by the stamps)."""
    reference.compute(1.0)
    distance = [np.max(np.abs(data["q"][0] - reference.sample(k / rate).q)) for k in range(rate)]
    first = int(np.argmin(distance))
    assert distance[first] < 1e-10, "the first sample received is one of the stream's first second"
    held = held_samples(data)
    assert held.mean() <= 0.2, "most samples must come from the stream"
    periods = np.r_[0, np.rint(np.diff(data["stamp"]) * rate / NS).astype(int)]
    return np.where(held, np.nan, (first + np.cumsum(np.where(held, 0, periods))) / rate)


def stamp_at(data: dict[str, np.ndarray], tau: np.ndarray, stream_time: float) -> int:
    """Stamp of the received sample at ``stream_time`` (``tau`` from :func:`stream_times`)."""
    (index,) = np.nonzero(np.abs(tau - stream_time) < 1e-9)
    assert len(index) == 1, f"one sample at stream time {stream_time}"
    return int(data["stamp"][index[0]])


def assert_continuous(q: np.ndarray, qd: np.ndarray, dt: float, steps: np.ndarray | None = None) -> None:
    """No jump of q (samples, coordinates) beyond what its rate qd and the sample period dt imply: every
    step (of those selected by the mask ``steps``) within 1.5 dt max|qd| of its coordinate (the flexible
    boom's fast modes make qd oscillate between samples, so the bound uses the largest rate of the run,
    not the two neighbouring ones)."""
    step = np.abs(np.diff(q, axis=0))
    if steps is not None:
        step = step[steps]
    bound = 1.5 * dt * np.max(np.abs(qd), axis=0) + 1e-9
    worst = np.unravel_index(np.argmax(step - bound), step.shape)
    assert np.all(step <= bound), f"jump {step[worst]:.3g} > {bound[worst[1]]:.3g} at sample, coordinate {worst}"


# --- publishing -----------------------------------------------------------------------------------


@pytest.mark.slow
def test_rate_sizes_and_stamps(ros: Harness) -> None:
    """Every sample, stamped a period apart, with every coordinate (the rate on the wall clock is
    benchmarks/bench_node.py's to measure)."""
    ros.start(publish_rate=200)
    ros.published_for(2.0)
    data = ros.samples()
    dof = len(load_and_model()[1].joint_names)
    assert data["q"].shape[1] == data["qd"].shape[1] == data["effort"].shape[1] == dof == 24
    names = {tuple(m.name) for _, m in ros.received["joint_states"]}
    assert names == {tuple(load_and_model()[1].joint_names)}
    assert set(np.diff(data["stamp"]).tolist()) == {NS // 200}
    pose_stamps = [stamp_ns(m) for _, m in ros.received["pose"]]
    assert set(np.diff(pose_stamps).tolist()) == {NS // 200}
    assert np.all(np.isfinite(data["q"])) and np.all(np.isfinite(data["qd"])) and np.all(np.isfinite(data["effort"]))


def load_and_model() -> tuple[Any, Any]:
    stream = ReferenceStream(load_config(), "flexible")
    return stream, stream.model


def test_pose_is_the_end_effector_of_the_published_positions(ros: Harness) -> None:
    ros.start(publish_rate=100)
    ros.published_for(1.0)
    config = load_config()
    _, model = load_and_model()
    dynamics = CraneDynamics(model, make_drive(config.drive, config.drive_start))
    positions = {stamp_ns(m): np.array(m.position) for _, m in list(ros.received["joint_states"])}
    poses = [m for _, m in list(ros.received["pose"]) if stamp_ns(m) in positions]
    assert len(poses) > 50
    for pose in poses:
        assert pose.header.frame_id == "world"
        p, R = dynamics.end_effector_poses(positions[stamp_ns(pose)])
        position = pose.pose.position
        np.testing.assert_allclose([position.x, position.y, position.z], p, atol=1e-9)
        np.testing.assert_allclose(dynamics.end_effector(positions[stamp_ns(pose)])[0], p, atol=1e-12)
        o = pose.pose.orientation
        relative = Rotation.from_quat([o.x, o.y, o.z, o.w]).inv() * Rotation.from_matrix(R)
        assert relative.magnitude() < 1e-9


def jtc_rejects(trajectory: JointTrajectory, joints: list[str], now_ns: int, *,
                allow_nonzero_velocity_at_trajectory_end: bool = False, allow_partial_joints_goal: bool = False,
                has_effort_command_interface: bool = False) -> str | None:
    """Why the Jazzy joint_trajectory_controller rejects an incoming trajectory (None: it accepts it):
    the checks of JointTrajectoryController::validate_trajectory_msg (ros2_controllers, branch jazzy,
    joint_trajectory_controller/src/joint_trajectory_controller.cpp), with its default
    allow_integration_in_goal_trajectories = false."""
    names, points = list(trajectory.joint_names), list(trajectory.points)
    if not allow_partial_joints_goal and len(names) != len(joints):
        return "joints on incoming trajectory don't match the controller joints"
    if not names:
        return "empty joint names"
    if not points:
        return "empty trajectory"
    if any(name not in joints for name in names):
        return "incoming joint doesn't match the controller's joints"
    if not allow_nonzero_velocity_at_trajectory_end and any(abs(v) > np.finfo(np.float32).eps
                                                            for v in points[-1].velocities):
        return "velocity of last trajectory point is not zero"
    start = stamp_ns(trajectory)
    duration = lambda p: p.time_from_start.sec * NS + p.time_from_start.nanosec  # noqa: E731
    if start != 0 and start + duration(points[-1]) < now_ns:
        return "trajectory with non-zero start time ends in the past"
    for i, point in enumerate(points):
        if i > 0 and duration(point) <= duration(points[i - 1]):
            return "time between points is not strictly increasing"
        if len(point.positions) != len(names):
            return "positions size mismatch"
        if point.velocities and len(point.velocities) != len(names):
            return "velocities size mismatch"
        if point.accelerations and len(point.accelerations) != len(names):
            return "accelerations size mismatch"
        if not has_effort_command_interface and point.effort:
            return "effort fields need the effort command interface"
    return None


def test_preview_markers_diagnostics_and_robot_description(ros: Harness) -> None:
    ros.start(publish_rate=100, preview__points=7, preview__horizon=0.6, preview__rate=20)
    ros.wait_for(lambda: len(ros.received["diagnostics"]) >= 1 and len(ros.received["preview"]) >= 10,
                 "diagnostics and previews")
    stamps = {stamp_ns(m): m for _, m in ros.received["joint_states"]}
    joints = ["column_slew", "boom_luff", "knuckle"]
    for _, preview in list(ros.received["preview"]):
        assert list(preview.joint_names) == joints and len(preview.points) == 7
        offsets = [p.time_from_start.sec * NS + p.time_from_start.nanosec for p in preview.points]
        assert offsets[0] == 0 and np.all(np.diff(offsets) > 0) and offsets[-1] == 600_000_000
        assert all(len(p.positions) == len(p.velocities) == len(p.accelerations) == 3 and not p.effort
                   for p in preview.points)
        # the first point is the sample published with the same stamp
        state = stamps.get(stamp_ns(preview))
        if state is not None:
            columns = [list(state.name).index(name) for name in joints]
            np.testing.assert_array_equal(preview.points[0].positions, np.array(state.position)[columns])
        # accepted by a joint_trajectory_controller of these joints that allows a moving end (as the README
        # says to configure it), rejected by one left at its default
        assert jtc_rejects(preview, joints, stamp_ns(preview), allow_nonzero_velocity_at_trajectory_end=True) is None
        assert jtc_rejects(preview, joints, stamp_ns(preview)) == "velocity of last trajectory point is not zero"
    # Every 5th sample (20 Hz at 100 Hz); one is left out only while the motion over its horizon is not
    # computed yet (the solver running late), then the next sample that has it carries it.
    spacing = np.diff(sorted(stamp_ns(m) for _, m in ros.received["preview"]))
    assert np.all(spacing >= NS // 20) and np.median(spacing) == NS // 20

    _, markers = ros.received["markers"][-1]
    ellipse, trail = markers.markers
    assert ellipse.type == trail.type == ellipse.LINE_STRIP and ellipse.header.frame_id == "world"
    xy = np.array([[p.x, p.y] for p in ellipse.points])
    np.testing.assert_allclose((xy[:, 0] / 3.0) ** 2 + (xy[:, 1] / 2.0) ** 2, 1.0, atol=1e-12)
    assert len(trail.points) > 1

    # a status made while publishing (one made before the first sample has no last sample to report)
    publishing_since = ros.received["joint_states"][0][0]

    def while_publishing() -> list:
        return [d for at, d in list(ros.received["diagnostics"]) if d.status[0].values and at > publishing_since]

    ros.wait_for(while_publishing, "diagnostics values while publishing")
    diagnostics = while_publishing()[-1]
    status = diagnostics.status[0]
    values = {kv.key: kv.value for kv in status.values}
    assert status.level == rclpy_types().byte(Level.OK), status.message
    assert values["state"] == "RUNNING" and float(values["constraint_residual_m"]) < 1e-9
    assert float(values["real_time_factor"]) > 0 and float(values["achieved_rate_hz"]) > 0
    numbers = {key: float(value) for key, value in values.items() if key not in ("state", "last_error")}
    assert numbers["target_ellipse_a_m"] == 3.0 and numbers["speed_scaling"] == 1.0

    latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    descriptions: list[String] = []
    ros.probe.create_subscription(String, f"/{NODE}/robot_description", descriptions.append, latched)
    ros.wait_for(lambda: descriptions, "the latched robot_description")
    assert descriptions[0].data.startswith("<?xml") and all(f'name="{n}"' in descriptions[0].data
                                                              for n in load_and_model()[1].joint_names)


def test_use_sim_time_waits_for_clock_and_follows_it(ros: Harness) -> None:
    node = CraneReferenceNode(context=ros.context, parameter_overrides=[
        Parameter("use_sim_time", value=True), Parameter("publish_rate", value=100)])
    ros.node = node
    ros.spin(node)
    # ROS time is 0 until /clock runs: no sample is published, but the diagnostics say why
    ros.wait_for(lambda: any("waiting for /clock" in d.status[0].message for _, d in list(ros.received["diagnostics"])),
                 "diagnostics while waiting for /clock")
    assert ros.received["joint_states"] == []
    assert all(d.status[0].level == b"\x00" for _, d in ros.received["diagnostics"])
    clock = ros.probe.create_publisher(Clock, "/clock", 10)
    sim_start = 1000 * NS
    wall_start = time.monotonic_ns()

    def tick() -> None:
        now = sim_start + time.monotonic_ns() - wall_start
        clock.publish(Clock(clock=messages.time_msg(rclpy_types(), now)))

    ros.probe.create_timer(0.005, tick)
    ros.wait_for(lambda: len(ros.received["joint_states"]) >= 20, "joint_states on simulated time")
    stamps = ros.samples()["stamp"]
    assert sim_start <= stamps[0] < sim_start + 5 * NS
    assert set(np.diff(stamps).tolist()) == {NS // 100}


def test_clock_jumps_restamp_without_skipping_motion(ros: Harness) -> None:
    """With use_sim_time, /clock goes back 0.5 s (within the catch-up limit: publishing waits, no stamp goes
    back), then 120 s back (a looped bag: the stamps restart from the new time once, counted as a
    clock reset and announced), then 180 s forward (the stamps leap once with the clock); through all of it the
    motion goes on sample by sample (no skipped sample, no position jump)."""
    rate = 100
    offset = [1000 * NS]
    ros.start_on_sim_time(rate, lambda wall: offset[0] + wall)
    ros.wait_for(lambda: len(ros.received["joint_states"]) >= 50, "joint_states on simulated time")
    offset[0] -= NS // 2
    count = len(ros.received["joint_states"])
    ros.wait_for(lambda: len(ros.received["joint_states"]) >= count + 30, "joint_states after the small jump")
    offset[0] -= 120 * NS
    ros.wait_for(lambda: any("the stamps restart" in m for m in diagnostic_messages(ros)), "a WARN: stamps restart")
    offset[0] += 180 * NS
    ros.wait_for(lambda: any("jumped" in m for m in diagnostic_messages(ros)), "a WARN: the stamps leapt")
    count = len(ros.received["joint_states"])
    ros.wait_for(lambda: len(ros.received["joint_states"]) >= count + 50, "joint_states after the jumps")
    data = ros.samples()
    steps = np.diff(data["stamp"])
    back, leaps = steps < 0, steps > NS // rate
    assert back.sum() == 1 and -121 * NS < steps[back][0] < -119 * NS  # once back, with the 120 s jump
    assert leaps.sum() == 1 and steps[leaps][0] > 50 * NS  # one leap, with the forward jump
    assert np.all(steps[~back & ~leaps] == NS // rate)
    assert_continuous(data["q"], data["qd"], 1.0 / rate)  # the motion went on sample by sample
    last = [d for _, d in list(ros.received["diagnostics"]) if d.status[0].values][-1]
    values = {kv.key: kv.value for kv in last.status[0].values}
    assert values["stamp_leaps"] == "1" and values["clock_resets"] == "1"


def test_a_clock_looping_every_5_s_gets_samples_in_every_loop(ros: Harness) -> None:
    """A bag replayed in a loop: /clock runs 5 s and starts again, four times; every loop gets the samples of
    its 5 s, and the motion goes on from loop to loop."""
    rate = 50
    loop, start = 5 * NS, 2000 * NS
    wall_start = time.monotonic_ns()
    ros.start_on_sim_time(rate, lambda wall: start + wall % loop)
    ros.wait_for(lambda: (time.monotonic_ns() - wall_start) > 4 * loop, "four loops of the clock", timeout=40.0)
    data = ros.samples()
    assert np.all((data["stamp"] >= start) & (data["stamp"] < start + loop))
    steps = np.diff(data["stamp"])
    assert (steps < 0).sum() >= 3  # each new loop starts the stamps again
    loops = np.split(data["stamp"], np.flatnonzero(steps < 0) + 1)
    assert all(len(stamps) >= 2 * rate for stamps in loops[1:-1])  # whole loops: most of their 5 s published
    assert_continuous(data["q"], data["qd"], 1.0 / rate)


# --- parameters -----------------------------------------------------------------------------------


def test_parameters_are_declared_from_one_table(ros: Harness) -> None:
    node = ros.start()
    for spec in PARAMETERS:
        descriptor = node.describe_parameter(spec.name)
        assert descriptor.type == spec.ros_type.value and descriptor.read_only == spec.read_only
        assert descriptor.description
        assert bool(descriptor.floating_point_range or descriptor.integer_range) == (spec.bounds is not None)


def test_typed_parameters_have_one_field_per_declared_parameter() -> None:
    """NodeParameters has the table's parameters in its order, each with the Python type of its ROS type, and
    a change of one parameter (as the post-set callback gets it) changes that field alone."""
    python_types = {Parameter.Type.BOOL: "bool", Parameter.Type.INTEGER: "int", Parameter.Type.DOUBLE: "float",
                    Parameter.Type.STRING: "str", Parameter.Type.STRING_ARRAY: "tuple[str, ...]"}
    fields = dataclasses.fields(NodeParameters)
    assert [f.name for f in fields] == [field_name(spec.name) for spec in PARAMETERS]
    assert [f.type for f in fields] == [python_types[spec.ros_type] for spec in PARAMETERS]
    defaults = NodeParameters.from_values({spec.name: spec.default for spec in PARAMETERS})
    changed = defaults.changed([Parameter("ellipse.a", Parameter.Type.INTEGER, 3),
                                Parameter("preview.joints", Parameter.Type.STRING_ARRAY, ["knuckle"])])
    assert changed.ellipse_a == 3.0 and isinstance(changed.ellipse_a, float)
    assert changed.preview_joints == ("knuckle",)
    restored = dataclasses.replace(changed, ellipse_a=defaults.ellipse_a, preview_joints=defaults.preview_joints)
    assert restored == defaults
    assert changed.targets() == Task(3.0, defaults.ellipse_b, defaults.z_increment, defaults.z_rise_time)


def test_an_unknown_parameter_is_refused_naming_the_nodes_parameters(ros: Harness) -> None:
    """Setting a parameter the node lacks is refused as rclpy refuses it (ParameterNotDeclaredException), with a
    message naming the unknown name and the node's parameters; the stream goes on."""
    node = ros.start(publish_rate=100)
    with pytest.raises(ParameterNotDeclaredException) as refused:
        node.set_parameters_atomically([Parameter("elipse.a", value=3.5), Parameter("ellipse.b", value=2.1)])
    message = str(refused.value)
    assert "elipse.a: not a parameter of /crane_reference; its parameters are" in message
    assert all(spec.name in message for spec in PARAMETERS)
    assert node.get_parameter("ellipse.b").value == 2.0  # nothing of the atomic request was set
    count = len(ros.received["joint_states"])
    ros.wait_for(lambda: len(ros.received["joint_states"]) > count + 10, "joint_states after the refusal")


def test_ellipse_ranges_are_the_cranes_reach(ros: Harness) -> None:
    """At configure the ranges of ellipse.a and ellipse.b narrow from the table's [0.1, 20] m to E's reach from
    the column's axis (:func:`reach`, tested against plane geometry): a value beyond it is refused naming the
    parameter and the range, one inside is taken."""
    node = ros.start(publish_rate=100)
    for name in ("ellipse.a", "ellipse.b"):
        descriptor = node.describe_parameter(name)
        (allowed,) = descriptor.floating_point_range
        assert 0.1 < allowed.from_value < 2.0 < 3.0 < allowed.to_value < 20.0
        assert f"[{allowed.from_value:g}, {allowed.to_value:g}] m" in descriptor.additional_constraints
    (refused,) = ros.set_parameters(Parameter("ellipse.a", value=10.0))
    assert not refused.successful and "ellipse.a" in refused.reason and "out of range" in refused.reason
    (taken,) = ros.set_parameters(Parameter("ellipse.a", value=3.2))
    assert taken.successful, taken.reason


def test_node_yaml_lists_the_table_defaults() -> None:
    data = yaml.safe_load((Path(__file__).resolve().parent.parent / "config" / "node.yaml").read_text())
    values = data["/**"]["ros__parameters"]  # any node name or namespace
    assert set(values) == {spec.name for spec in PARAMETERS if spec.from_config is None}
    for name, value in values.items():
        assert SPECS[name].check(SPECS[name].coerce(value)) is None and value == SPECS[name].default, name


def test_rejected_changes_leave_the_stream_untouched(ros: Harness) -> None:
    node = ros.start(publish_rate=100)
    ros.published_for(0.3)
    rejected = {
        "out of range": Parameter("ellipse.a", value=-1.0),
        "NaN": Parameter("ellipse.b", value=math.nan),
        "wrong type": Parameter("ellipse.a", value="abc"),
        "unreachable": Parameter("ellipse.a", value=15.0),
        "unreachable z": Parameter("z.increment", value=-5),
        "read-only": Parameter("model", value="rigid"),
        "bad frame": Parameter("frame_id", value=""),
        "unknown joint": Parameter("preview.joints", value=["column_slew", "jib"]),
        "speed above 1": Parameter("speed_scaling", value=1.5),
    }
    for case, parameter in rejected.items():
        before = node.get_parameter(parameter.name).value
        (result,) = ros.set_parameters(parameter)
        assert not result.successful, case
        assert parameter.name in result.reason or "type" in result.reason, (case, result.reason)
        assert node.get_parameter(parameter.name).value == before, case
    (result,) = ros.set_parameters(Parameter("ellipse.a", value=15.0))  # beyond the reach offered as its range
    assert "ellipse.a out of range" in result.reason
    (result,) = ros.set_parameters(Parameter("z.increment", value=-5.0))  # the project's reachability check
    assert "z.increment" in result.reason and "reach" in result.reason, result.reason
    (result,) = ros.set_parameters(Parameter("elipse.a", value=3.2))  # a typo: named, with the valid names
    assert not result.successful and "elipse.a" in result.reason and "ellipse.a" in result.reason, result.reason
    (result,) = ros.set_parameters(Parameter("ellipse.a", value=3))  # the current value: no re-target
    assert result.successful
    values = latest_values(ros, since=time.monotonic())  # no re-target: the first targets, none reported
    assert "retarget_stamp_s" not in values
    assert [values[f"target_{name}"] for name in ("ellipse_a_m", "ellipse_b_m", "z_increment_m", "rise_time_s")] == \
        ["3", "2", "0.2", "5"]
    # The motion goes on exactly as without the requests (same samples as an independent stream).
    end = ros.samples()["stamp"][-1] + NS // 2
    ros.wait_until_stamp(end)
    data = ros.samples()
    reference = ReferenceStream(load_config(), "flexible")
    tau = stream_times(data, reference, 100)
    moving = ~np.isnan(tau)
    reference.compute(tau[moving][-1])
    np.testing.assert_allclose(data["q"][moving], [reference.sample(t).q for t in tau[moving]], atol=1e-10)
    assert_continuous(data["q"], data["qd"], 0.01)


def test_integer_values_for_double_parameters(ros: Harness, tmp_path: Path) -> None:
    params_file = tmp_path / "params.yaml"
    params_file.write_text(f"{NODE}:\n  ros__parameters:\n    ellipse.b: 2\n    blend_time: 1\n")
    node = ros.start(cli_args=["--ros-args", "-p", "ellipse.a:=3", "--params-file", str(params_file)],
                     z__increment=0)
    assert latest_values(ros)["blend_time_s"] == "1"  # the node's blend time
    for name, value in {"ellipse.a": 3.0, "ellipse.b": 2.0, "blend_time": 1.0, "z.increment": 0.0}.items():
        parameter = node.get_parameter(name)
        assert parameter.type_ == Parameter.Type.DOUBLE and parameter.value == value, name
    results = ros.set_parameters(Parameter("blend_time", value=3), Parameter("ellipse.b", value=2))
    assert all(r.successful for r in results), results
    assert node.get_parameter("blend_time").type_ == Parameter.Type.DOUBLE
    assert node.get_parameter("blend_time").value == 3.0
    assert latest_values(ros, since=time.monotonic())["blend_time_s"] == "3"


@pytest.mark.slow
def test_atomic_ellipse_change_is_smooth_and_converges(ros: Harness) -> None:
    rate, blend = 100, 1.0
    node = ros.start(publish_rate=rate, blend_time=blend)
    ros.published_for(0.5)
    (result,) = ros.set_parameters(Parameter("ellipse.a", value=3.3), Parameter("ellipse.b", value=2.2),
                                   atomically=True)
    assert result.successful, result.reason
    report = command_report(ros, "retarget")
    tau_change, targets = float(report["retarget_stream_time_s"]), Task(3.3, 2.2, 0.2, 5.0)
    assert (report["target_ellipse_a_m"], report["target_ellipse_b_m"]) == ("3.3", "2.2")
    ros.wait_until_stamp(round(float(report["retarget_stamp_s"]) * NS) + round((blend + 0.3) * NS))
    data = ros.samples()
    ros.wait_for(lambda: stamp_ns(ros.received["pose"][-1][1]) >= data["stamp"][-1],
                 "the pose of the last joint states")  # published after them
    poses = {stamp_ns(m): m.pose.position for _, m in list(ros.received["pose"])}

    # The published motion is the stream's, re-targeted once at tau_change to both a and b (an independent
    # stream): a and b set atomically are one re-target.
    reference = ReferenceStream(load_config(), "flexible", blend_time=blend)
    reference.compute(tau_change)
    reference.retarget(tau_change, targets)
    tau = stream_times(data, reference, rate)
    change = stamp_at(data, tau, tau_change)
    index = np.nonzero(~np.isnan(tau))[0]
    reference.compute(tau[index[-1]])
    expected = [reference.sample(t) for t in tau[index]]
    np.testing.assert_allclose(data["q"][index], [s.q for s in expected], atol=1e-10)
    np.testing.assert_allclose(data["qd"][index], [s.qd for s in expected], atol=1e-8)

    # No jump in position or velocity beyond what the rate implies.
    dt = 1.0 / rate
    assert_continuous(data["q"], data["qd"], dt)
    consecutive = np.diff(index) == 1  # a sample held while the solver was late has zero velocity
    assert_continuous(data["qd"][index], np.array([s.qdd for s in expected]), dt, consecutive)

    # E on the old ellipse before the change, on the new one once the blend is over.
    def residual(stamps: np.ndarray, a: float, b: float) -> np.ndarray:
        p = np.array([[poses[s].x, poses[s].y] for s in stamps])
        return (p[:, 0] / a) ** 2 + (p[:, 1] / b) ** 2 - 1.0

    before = data["stamp"][data["stamp"] <= change]
    # by stream time: a sample held while the solver was late (loaded machine) delays the blend's end in stamps
    after = data["stamp"][tau >= tau_change + blend]
    assert len(before) > 10 and len(after) > 10
    assert np.max(np.abs(residual(before, 3.0, 2.0))) < 1e-9
    assert np.max(np.abs(residual(after, 3.3, 2.2))) < 1e-9
    assert node.get_parameter("ellipse.a").value == 3.3 and node.get_parameter("ellipse.b").value == 2.2


# --- services and failures ------------------------------------------------------------------------


@pytest.mark.slow
def test_pause_and_resume(ros: Harness) -> None:
    """~/pause ramps the speed to rest (no step in velocity) over the ramp time of the stream, holds, and
    resumes along a ramp."""
    rate, ramp = 100, 0.3
    ros.start(publish_rate=rate, speed_scaling__ramp_time=ramp, model="rigid")  # no 70 Hz boom vibration
    ros.published_for(1.2)  # past the drive's torque step at 1 s (a jump of the programmed acceleration)
    response = ros.call(ros.pause, SetBool.Request(data=True))
    assert response.success and "coming to rest" in response.message, response.message
    paused_at = round(float(command_report(ros, "pause")["pause_stamp_s"]) * NS)
    ros.wait_until_stamp(paused_at + NS)
    assert ros.call(ros.pause, SetBool.Request(data=True)).message == "already paused"
    assert ros.call(ros.pause, SetBool.Request(data=False)).success
    resumed_at = round(float(command_report(ros, "resume")["resume_stamp_s"]) * NS)
    ros.wait_until_stamp(resumed_at + NS // 2)
    data = ros.samples(after_ns=paused_at - NS // 2)
    # the ramp spans ramp * rate samples of the stream from the pause point: the sample at its end is stamped
    # paused_at + ramp, later by a period for each sample held meanwhile (a solver late on a busy machine);
    # the reported stamps are rounded to the microsecond
    held = held_samples(data)
    after = data["stamp"] > paused_at - 1000
    advanced = np.cumsum(after & ~held)
    end = int(np.argmax(advanced == round(ramp * rate) + 1))
    held_in_ramp = int(np.sum(held[after & (np.arange(advanced.size) < end)]))
    assert abs(data["stamp"][end] - (paused_at + round(ramp * NS) + held_in_ramp * (NS // rate))) < 1000
    at_rest = (np.arange(advanced.size) >= end) & (data["stamp"] < resumed_at)
    assert at_rest.sum() >= rate // 2
    assert np.all(data["qd"][at_rest] == 0.0) and np.all(data["q"][at_rest] == data["q"][at_rest][0])
    assert np.max(np.abs(data["qd"][data["stamp"] > resumed_at + round(ramp * NS)][-1])) > 0
    # no step in the column's velocity: per sample it changes by at most what the quintic ramp's peak
    # deceleration 15/8 |v| / ramp gives on top of normal running, a small fraction of |v|
    slew = list(ros.received["joint_states"][0][1].name).index("column_slew")
    dv = np.abs(np.diff(data["qd"][:, slew]))
    normal = data["stamp"][1:] < paused_at
    speed = np.max(np.abs(data["qd"][:, slew]))
    ramp_bound = 15.0 / 8.0 * speed / ramp / rate
    assert dv[~normal].max() <= 1.2 * ramp_bound + dv[normal].max()
    assert dv.max() < 0.15 * speed
    assert_continuous(data["q"], data["qd"], 1.0 / rate)



def change_state(ros: Harness, transition: int) -> bool:
    """A lifecycle transition requested through the node's ~/change_state service, as a manager does."""
    client = ros.probe.create_client(ChangeState, f"/{NODE}/change_state")
    return ros.call(client, ChangeState.Request(transition=Transition(id=transition))).success


def lifecycle_state(ros: Harness) -> str:
    client = ros.probe.create_client(GetState, f"/{NODE}/get_state")
    return ros.call(client, GetState.Request()).current_state.label


def diagnostic_messages(ros: Harness) -> list[str]:
    return [d.status[0].message for _, d in list(ros.received["diagnostics"])]


def test_lifecycle_deactivate_restart_activate_without_a_jump_while_active(ros: Harness) -> None:
    """~/restart while active is refused (it would make the reference jump).  Deactivating brings the moving
    reference to rest along the speed ramp, publishes it to the first sample at rest and stops; while
    inactive ~/restart goes back to the static equilibrium (announced); activating publishes from there, with
    stamps that go on increasing, the motion of a fresh stream, and E's trail cleared."""
    rate = 100
    ros.start(publish_rate=rate, speed_scaling__ramp_time=0.3, model="rigid")
    ros.published_for(1.0)
    response = ros.call(ros.restart, Trigger.Request())
    assert not response.success and "refused while active" in response.message
    assert change_state(ros, Transition.TRANSITION_DEACTIVATE)
    assert lifecycle_state(ros) == "inactive"
    count = len(ros.received["joint_states"])
    time.sleep(0.5)
    assert len(ros.received["joint_states"]) == count  # no longer published
    stopped = ros.samples()
    assert np.all(stopped["qd"][-1] == 0.0)  # the last sample published is at rest
    assert_continuous(stopped["q"][-rate:], stopped["qd"][-rate:], 1.0 / rate)  # reached along the ramp
    ros.wait_for(lambda: any(m.startswith("inactive") for m in diagnostic_messages(ros)), "inactive diagnostics")

    response = ros.call(ros.restart, Trigger.Request())
    assert response.success and "position jump up to" in response.message, response.message
    ros.wait_for(lambda: any("restart_jump_rad" in {kv.key for kv in d.status[0].values}  # while still inactive
                             for _, d in list(ros.received["diagnostics"])), "the restart in the diagnostics")
    assert change_state(ros, Transition.TRANSITION_ACTIVATE)
    ros.wait_for(lambda: len(ros.received["joint_states"]) >= len(stopped["stamp"]) + rate // 2, "samples once active")
    data = ros.samples(after_ns=stopped["stamp"][-1])
    assert data["stamp"][0] > stopped["stamp"][-1] and set(np.diff(data["stamp"]).tolist()) == {NS // rate}
    reference = ReferenceStream(load_config(), "rigid")
    reference.compute(len(data["stamp"]) / rate)
    np.testing.assert_allclose(data["q"], [reference.sample(i / rate).q for i in range(len(data["stamp"]))],
                               atol=1e-10)  # the fresh motion from the static equilibrium, from the first sample
    jump = np.max(np.abs(data["q"][0] - stopped["q"][-1]))
    assert float(response.message.split("position jump up to ")[1].split()[0]) == pytest.approx(jump, rel=1e-5)


def test_without_autostart_the_node_waits_for_a_manager(ros: Harness) -> None:
    """autostart false: the node stays unconfigured (diagnostics say so, nothing published) until configured
    (inactive, still silent) and activated (publishing the motion from its start)."""
    node = CraneReferenceNode(context=ros.context, parameter_overrides=[
        Parameter("autostart", value=False), Parameter("publish_rate", value=100)])
    ros.node = node
    ros.spin(node)
    ros.wait_for(lambda: "unconfigured" in diagnostic_messages(ros), "unconfigured diagnostics")
    assert lifecycle_state(ros) == "unconfigured"
    assert change_state(ros, Transition.TRANSITION_CONFIGURE)
    ros.wait_for(lambda: any(m.startswith("inactive") for m in diagnostic_messages(ros)), "inactive diagnostics")
    assert ros.received["joint_states"] == []
    assert change_state(ros, Transition.TRANSITION_ACTIVATE)
    ros.wait_for(lambda: len(ros.received["joint_states"]) >= 10, "joint_states once active")
    assert lifecycle_state(ros) == "active"
    data = ros.samples()
    reference = ReferenceStream(load_config(), "flexible")
    reference.compute(0.2)
    # the motion from its start: the first samples can be lost to discovery, so match the first received one
    first = int(np.argmin([np.max(np.abs(data["q"][0] - reference.sample(i / 100).q)) for i in range(10)]))
    np.testing.assert_allclose(data["q"][:10], [reference.sample((first + i) / 100).q for i in range(10)], atol=1e-10)


def solver_processes() -> list[int]:
    """PIDs of this process's children that run the solver (``python -m crane_reference.stream.stream_solver``)."""
    pids = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            parent = int(stat.read_text().rsplit(")", 1)[1].split()[1])
            command = (stat.parent / "cmdline").read_bytes()
        except (OSError, ValueError, IndexError):
            continue  # ended meanwhile
        if parent == os.getpid() and b"crane_reference.stream.stream_solver" in command:
            pids.append(int(stat.parent.name))
    return pids


def test_a_dead_solver_holds_reports_error_and_a_new_configure_recovers(ros: Harness) -> None:
    """The solver's process killed (as by the OOM killer): the frames made before are published, then the last
    sample held (zero velocity) with an ERROR diagnostic that says how to recover; commands are refused with
    that reason; deactivate, cleanup, configure and activate start a new solver, published from its start."""
    rate = 100
    node = ros.start(publish_rate=rate, model="rigid")
    ros.published_for(0.3)
    (pid,) = solver_processes()
    os.kill(pid, signal.SIGKILL)
    ros.wait_for(lambda: any("solver stopped" in m for m in diagnostic_messages(ros)), "the solver's end reported")
    status = next(d.status[0] for _, d in list(ros.received["diagnostics"]) if "solver stopped" in d.status[0].message)
    assert status.level == rclpy_types().byte(Level.ERROR) and "configure" in status.message, status.message
    ros.wait_until_stamp(ros.samples()["stamp"][-1] + round((LOOKAHEAD + 0.5) * NS))  # past the frames made before
    data = ros.samples()
    held = held_samples(data)
    first = int(np.argmax(held))  # the first held sample: the stream's motion before it, held from it on
    assert first > 0 and np.all(held[first:]) and not np.any(held[:first])
    np.testing.assert_array_equal(data["q"][first:], np.broadcast_to(data["q"][first - 1], data["q"][first:].shape))
    moving = {name: values[:first] for name, values in data.items()}
    reference = ReferenceStream(load_config(), "rigid")
    tau = stream_times(moving, reference, rate)
    reference.compute(tau[-1])
    np.testing.assert_allclose(moving["q"], [reference.sample(t).q for t in tau], atol=1e-10)

    response = ros.call(ros.pause, SetBool.Request(data=True))
    assert not response.success and "solver stopped" in response.message, response.message
    (result,) = ros.set_parameters(Parameter("ellipse.a", value=3.2))
    assert not result.successful and "ellipse.a" in result.reason and "solver stopped" in result.reason
    assert node.get_parameter("ellipse.a").value == 3.0
    assert change_state(ros, Transition.TRANSITION_DEACTIVATE)  # no ramp: nothing computes it
    stopped = ros.samples()["stamp"][-1]
    for transition in (Transition.TRANSITION_CLEANUP, Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE):
        assert change_state(ros, transition), transition
    ros.wait_for(lambda: len(ros.samples(after_ns=stopped)["stamp"]) >= rate // 2, "samples from the new solver")
    restarted = ros.samples(after_ns=stopped)
    tau = stream_times(restarted, ReferenceStream(load_config(), "rigid"), rate)  # the motion from its start
    assert tau[0] < 0.1 and set(np.diff(restarted["stamp"]).tolist()) == {NS // rate}
    assert latest_values(ros, since=time.monotonic())["state"] == "RUNNING"


def test_a_hung_solver_is_killed_reported_and_a_new_configure_recovers(ros: Harness) -> None:
    """The solver's process stopped (SIGSTOP: alive, but never answering): the node reports at ERROR that it gave no
    sign of life and was killed, and reaps it; deactivate answers (the reference stops at its held sample, no ramp
    to compute it), and cleanup, configure and activate start a new solver."""
    node = ros.start(publish_rate=100, model="rigid")
    (pid,) = solver_processes()
    os.kill(pid, signal.SIGSTOP)
    ros.wait_for(lambda: any("gave no sign of life" in m for m in diagnostic_messages(ros)), "the hang reported")
    status = next(d.status[0] for _, d in list(ros.received["diagnostics"])
                  if "gave no sign of life" in d.status[0].message)
    assert status.level == rclpy_types().byte(Level.ERROR) and "configure" in status.message, status.message
    ros.wait_for(lambda: not solver_processes(), "the hung process reaped")
    assert change_state(ros, Transition.TRANSITION_DEACTIVATE)
    stopped = ros.samples()["stamp"][-1]
    for transition in (Transition.TRANSITION_CLEANUP, Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE):
        assert change_state(ros, transition), transition
    ros.wait_for(lambda: len(ros.samples(after_ns=stopped)["stamp"]) >= 50, "samples from the new solver")
    assert node.get_parameter("model").value == "rigid"


def test_a_numerical_failure_holds_the_last_sample_reports_error_and_restart_recovers(
        ros: Harness, tmp_path: Path) -> None:
    """A crane file whose column torque (the largest drive.torque allows, 1e6 N m) spins the slew faster than
    the integrator's steps can follow: the node publishes the motion up to the failing step, then holds the
    start of that step (finite, zero velocity; what a ROS-free stream holds) with an ERROR that names the
    failure, its time and the remedies; deactivate, ~/restart and activate publish the motion from its start
    again (the slew a whole number of turns on: the restart goes the shortest way)."""
    crane = spinning_crane(tmp_path / "crane.yaml")
    rate = 100
    ros.start(config_file=str(crane), publish_rate=rate, model="rigid")
    ros.wait_for(lambda: any("IntegrationError" in m for m in diagnostic_messages(ros)), "the failure reported")
    status = next(d.status[0] for _, d in list(ros.received["diagnostics"])
                  if "IntegrationError" in d.status[0].message)
    assert status.level == rclpy_types().byte(Level.ERROR), status.message
    assert "did not converge" in status.message and "the step from t = " in status.message
    assert "~/restart" in status.message and "configure" in status.message
    failed_at = float(status.message.split("the step from t = ")[1].split()[0])  # [s] of motion
    ros.wait_until_stamp(ros.samples()["stamp"][0] + round((failed_at + 1.0) * NS))
    data = ros.samples()
    held = held_samples(data)
    first = int(np.argmax(held))
    assert first > 0 and np.all(held[first:]) and not np.any(held[:first]) and np.all(np.isfinite(data["q"]))
    reference = ReferenceStream(load_config(str(crane)), "rigid")
    tau = stream_times({name: values[:first] for name, values in data.items()}, reference, rate)
    # the motion up to the last sample before the failing step; from the next one on, that step's start held
    assert tau[-1] == (math.floor(failed_at * rate + 1e-9) + 1) / rate and np.all(data["qd"][first - 1] == 0.0)
    assert np.any(data["qd"][first - 2] != 0.0) and reference.state == ERROR
    np.testing.assert_array_equal(data["q"][first - 1], reference.sample(tau[-1]).q)
    np.testing.assert_array_equal(data["q"][first:], np.broadcast_to(data["q"][first - 1], data["q"][first:].shape))

    assert change_state(ros, Transition.TRANSITION_DEACTIVATE)  # answered at once: nothing to bring to rest
    stopped = ros.samples()["stamp"][-1]
    assert ros.call(ros.restart, Trigger.Request()).success
    assert change_state(ros, Transition.TRANSITION_ACTIVATE)
    ros.wait_for(lambda: len(ros.samples(after_ns=stopped)["stamp"]) >= rate // 4, "the motion from its start again")
    restarted = ros.samples(after_ns=stopped)
    reference = ReferenceStream(load_config(str(crane)), "rigid")
    reference.compute(0.1)
    turns = np.remainder(restarted["q"][0] - reference.sample(0.0).q + math.pi, 2 * math.pi) - math.pi
    assert min(np.max(np.abs(turns - (reference.sample(k / rate).q - reference.sample(0.0).q)))
               for k in range(10)) < 1e-9  # a whole number of turns from a sample of the first 0.1 s
    assert not np.any(held_samples(restarted)[1:])  # moving again (drive.torque is read-only: a new node mends it)


# --- message builders -----------------------------------------------------------------------------


def plain(msg: Any) -> Any:
    """Field values of an rclpy or a rosbags message as plain Python data (for comparison)."""
    if hasattr(msg, "get_fields_and_field_types"):
        return {name: plain(getattr(msg, name)) for name in msg.get_fields_and_field_types()}
    if dataclasses.is_dataclass(msg):
        return {f.name: plain(getattr(msg, f.name)) for f in dataclasses.fields(msg)
                if not (f.name.startswith("__") or f.name.isupper())}  # not __msgtype__ or constants
    if isinstance(msg, bytes):
        return list(msg) if len(msg) != 1 else msg[0]
    if isinstance(msg, (list, tuple, np.ndarray)) or type(msg).__name__ == "array":
        return [plain(v) for v in msg]
    return msg.item() if isinstance(msg, np.generic) else msg


def test_rclpy_and_rosbags_messages_agree() -> None:
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_JAZZY)
    stream, model = load_and_model()
    stream.compute(0.5)
    sample = stream.sample(0.25)
    preview = stream.preview(0.25, 0.2, 4)
    names = model.joint_names
    stamp = 1_700_000_000_123_456_789
    offsets = [0, 50_000_000, 100_000_000, 150_000_000, 200_000_000]
    indices = list(range(len(names)))
    builders = {
        "joint_state": lambda t: messages.joint_state(t, stamp, names, sample),
        "pose": lambda t: messages.end_effector_pose(t, stamp, "world", sample),
        "preview": lambda t: messages.reference_preview(t, stamp, "world", names, indices, offsets,
                                                        [sample, *preview.rows()], effort=True),
        "diagnostics": lambda t: messages.diagnostics(t, stamp, "crane", "node", Level.WARN, "late",
                                                      {"rate": 99.5, "state": "RUNNING"}),
        "markers": lambda t: messages.markers(t, stamp, "world",
                                              messages.points(t, messages.ellipse_points(3.0, 2.0, 2.3)),
                                              messages.points(t, np.array([[1.0, 2.0, 3.0]] * 3))),
        "robot_description": lambda t: messages.robot_description(t, "<robot/>"),
    }
    for name, build in builders.items():
        ours, theirs = build(rclpy_types()), build(messages.rosbags_types(typestore))
        assert plain(ours) == plain(theirs), name
        # On the wire too (float32 fields such as colours are rounded by both serializations alike):
        ours_read = typestore.deserialize_cdr(serialize_message(ours), theirs.__msgtype__)
        theirs_read = typestore.deserialize_cdr(typestore.serialize_cdr(theirs, theirs.__msgtype__), theirs.__msgtype__)
        assert plain(ours_read) == plain(theirs_read), name
    with pytest.raises(ValueError, match="increase strictly"):
        messages.reference_preview(messages.rosbags_types(typestore), stamp, "world", names, indices,
                                   [0, 2, 2, 3, 4], [sample, *preview.rows()])


def test_speed_scaling_topic_sets_the_parameter_and_slows_the_reference(ros: Harness) -> None:
    """~/speed_scaling (std_msgs/Float64) goes through the parameter's checks: 0.5 halves the speed after
    the ramp (checked against an independent stream sampled at the warped time), 1.5 is rejected."""
    node = ros.start(publish_rate=100, model="rigid", speed_scaling__ramp_time=0.2)
    publisher = ros.probe.create_publisher(Float64, f"/{NODE}/speed_scaling", 10)
    ros.wait_for(lambda: publisher.get_subscription_count() > 0, "the node's ~/speed_scaling subscription")
    publisher.publish(Float64(data=0.5))
    report = command_report(ros, "speed_scaling")
    assert node.get_parameter("speed_scaling").value == 0.5 and report["speed_scaling"] == "0.5"
    tau_change = float(report["speed_scaling_stream_time_s"])
    ros.wait_until_stamp(round(float(report["speed_scaling_stamp_s"]) * NS) + NS)
    publisher.publish(Float64(data=1.5))  # out of range: rejected, the speed stays
    time.sleep(0.3)
    assert node.get_parameter("speed_scaling").value == 0.5
    assert latest_values(ros, since=time.monotonic())["speed_scaling_accepted_s"] == report["speed_scaling_accepted_s"]
    data = ros.samples()
    reference = ReferenceStream(load_config(), "rigid")
    tau = stream_times(data, reference, 100)
    changed = stamp_at(data, tau, tau_change)
    index = np.nonzero(~np.isnan(tau) & (data["stamp"] > changed + 3 * NS // 10))[0]  # after the 0.2 s ramp
    reference.compute(tau_change + 0.1 + 0.5 * (tau[index[-1]] - tau_change))
    # motion time: up to the change at rate 1, then the ramp (mean rate 0.75 over 0.2 s), then 0.5
    t = tau_change + 0.2 * 0.75 + 0.5 * (tau[index] - tau_change - 0.2)
    expected = [reference.sample(ti) for ti in t]
    np.testing.assert_allclose(data["q"][index], [e.q for e in expected], atol=1e-9)
    np.testing.assert_allclose(data["qd"][index], [0.5 * e.qd for e in expected], atol=1e-9)


def test_command_lead_sets_when_a_command_takes_effect(ros: Harness) -> None:
    """A command takes effect at the last sample stamped within command_lead of its acceptance (at least the
    one after the next to publish): the stamp the node announces lies within (lead - 1 period, lead] of its
    acceptance (or 2 periods, if the publisher runs late), for the default and for a lead changed while
    running, and the stream is told the same instant."""
    rate = 100
    node = ros.start(publish_rate=rate, model="rigid")
    ros.published_for(0.5)
    reference, previous = ReferenceStream(load_config(), "rigid"), None
    for lead in (node.get_parameter("command_lead").value, 0.4):
        ros.published_for(0.5)  # the look-ahead made again after the last command (a command is never beyond it)
        (result,) = ros.set_parameters(Parameter("command_lead", value=lead))
        assert result.successful, result.reason
        value = 0.5 if lead != 0.4 else 1.0
        (result,) = ros.set_parameters(Parameter("speed_scaling", value=value))
        assert result.successful, result.reason
        report = command_report(ros, "speed_scaling", after=previous)
        previous = report["speed_scaling_accepted_s"]
        effective, accepted = float(report["speed_scaling_stamp_s"]), float(previous)
        assert lead - 1.0 / rate < effective - accepted <= max(lead, 2.0 / rate) + 1e-6, (lead, effective - accepted)
        ros.wait_until_stamp(round(effective * NS) + NS // 10)
        data = ros.samples()
        tau = stream_times(data, reference, rate)
        changed = stamp_at(data, tau, float(report["speed_scaling_stream_time_s"]))
        assert abs(changed - effective * NS) < 1e3  # [ns], float seconds
    (result,) = ros.set_parameters(Parameter("command_lead", value=0.0))
    assert not result.successful and "command_lead" in result.reason


def test_two_namespaced_cranes_publish_disjoint_topics_and_frames() -> None:
    """Two nodes in namespaces crane1 and crane2 with frame prefixes crane1/ and crane2/ (as the bring-up runs
    them beside their robot_state_publishers): their topics are disjoint but /diagnostics (shared, told apart by
    the status's hardware id), and every frame they name carries their own prefix."""
    context = rclpy.Context()
    rclpy.init(context=context)
    executor = SingleThreadedExecutor(context=context)
    nodes, poses = [], {"crane1": [], "crane2": []}
    try:
        for crane in poses:
            overrides = [Parameter("model", value="rigid"), Parameter("publish_rate", value=50),
                         Parameter("frame_prefix", value=f"{crane}/"), Parameter("solver_process", value=False),
                         Parameter("preview.rate", value=50.0)]
            nodes.append(CraneReferenceNode(context=context, namespace=crane, parameter_overrides=overrides))
            executor.add_node(nodes[-1])
        probe = Node("two_cranes_probe", context=context)
        executor.add_node(probe)
        previews = {crane: [] for crane in poses}
        for crane in poses:
            probe.create_subscription(PoseStamped, f"/{crane}/{NODE}/end_effector_pose", poses[crane].append, 100)
            probe.create_subscription(JointTrajectory, f"/{crane}/{NODE}/reference_preview", previews[crane].append,
                                      100)
        deadline = time.monotonic() + 30.0
        while not all(len(p) >= 5 for p in (*poses.values(), *previews.values())):
            assert time.monotonic() < deadline, "no poses and previews from both cranes"
            executor.spin_once(timeout_sec=0.05)
        for crane in poses:
            assert {m.header.frame_id for m in poses[crane]} == {f"{crane}/world"}
            assert {m.header.frame_id for m in previews[crane]} == {f"{crane}/world"}
        published = [{name for name, _ in probe.get_publisher_names_and_types_by_node(NODE, f"/{crane}")}
                     for crane in poses]
        shared = published[0] & published[1]
        assert shared <= {"/diagnostics", "/parameter_events", "/rosout"}, shared
        assert all(any(name.startswith(f"/{crane}/{NODE}/") for name in names)
                   for crane, names in zip(poses, published, strict=True))
        assert {node.get_fully_qualified_name() for node in nodes} == {f"/crane1/{NODE}", f"/crane2/{NODE}"}
    finally:
        for node in nodes:
            node.destroy_node()
        executor.shutdown()
        context.try_shutdown()


def test_qos_overrides_of_the_reference_topics(ros: Harness) -> None:
    """The reference publishers take rclpy's qos_overrides parameters: joint_states made best effort (and its
    depth 3) by overrides, the pose left reliable."""
    name = f"/{NODE}/joint_states"
    ros.node = CraneReferenceNode(context=ros.context, parameter_overrides=[
        Parameter("model", value="rigid"), Parameter("publish_rate", value=50),
        Parameter(f"qos_overrides.{name}.publisher.reliability", value="best_effort"),
        Parameter(f"qos_overrides.{name}.publisher.depth", value=3)])
    ros.spin(ros.node)
    ros.wait_for(lambda: ros.probe.get_publishers_info_by_topic(name)
                 and ros.probe.get_publishers_info_by_topic(f"/{NODE}/end_effector_pose"), "the publishers")
    (joints,) = ros.probe.get_publishers_info_by_topic(name)
    (pose,) = ros.probe.get_publishers_info_by_topic(f"/{NODE}/end_effector_pose")
    assert joints.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT  # (the graph does not carry depths)
    assert pose.qos_profile.reliability == ReliabilityPolicy.RELIABLE
    assert ros.node.get_parameter(f"qos_overrides.{name}.publisher.depth").value == 3


def test_the_publisher_reads_the_node_clock_as_rclpy_does(ros: Harness) -> None:
    """Without ROS time, the publisher's reading of the node clock (the system time) lies between two of rclpy's
    own readings; with ROS time active (use_sim_time set while it reads, a /clock received), it is rclpy's
    reading; with use_sim_time cleared again, the system time again."""
    clock = ros.probe.get_clock()

    def system_time(now: NodeTime) -> None:
        for _ in range(100):
            before, reading, after = clock.now().nanoseconds, now(), clock.now().nanoseconds
            assert before <= reading <= after

    with NodeTime(clock) as now:
        system_time(now)
        ros.probe.set_parameters([Parameter("use_sim_time", value=True)])
        publisher = ros.probe.create_publisher(Clock, "/clock", 10)
        tick = Clock(clock=messages.time_msg(rclpy_types(), 1234 * NS))
        ros.wait_for(lambda: publisher.publish(tick) or clock.now().nanoseconds == 1234 * NS, "ROS time from /clock")
        assert clock.ros_time_is_active and now() == 1234 * NS
        ros.probe.set_parameters([Parameter("use_sim_time", value=False)])
        assert not clock.ros_time_is_active
        system_time(now)


def test_a_crane_of_its_own_from_a_urdf_and_its_overlay(ros: Harness) -> None:
    """The example crane (b) (config/knuckle_boom_crane.yaml: a URDF and its overlay; a spring drive; a fixed
    base): the joint states name its coordinates, the preview its actuated joints, E stays on its ellipse (its
    pose from the published positions by the chain's kinematics, checked against Pinocchio in
    test_dynamics_pinocchio) and ~/robot_description is its chain."""
    ros.start(config_file="knuckle_boom_crane.yaml", publish_rate=100)
    ros.wait_for(lambda: len(ros.received["joint_states"]) >= 50 and len(ros.received["preview"]) >= 2,
                 "50 joint states and previews")
    config = load_config("knuckle_boom_crane.yaml")
    model = build_model(config, "flexible")
    dynamics = CraneDynamics(model, make_drive(config.drive, config.drive_start))
    for _, state in list(ros.received["joint_states"]):
        assert list(state.name) == model.joint_names
        x, y, _ = dynamics.end_effector(np.array(state.position))[0]
        assert (x / config.task.ellipse_a) ** 2 + (y / config.task.ellipse_b) ** 2 == pytest.approx(1.0, abs=1e-9)
    assert all(list(p.joint_names) == ["slew", "luff", "fold"] for _, p in list(ros.received["preview"]))
    latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    descriptions: list[String] = []
    ros.probe.create_subscription(String, f"/{NODE}/robot_description", descriptions.append, latched)
    ros.wait_for(lambda: descriptions, "the latched robot_description")
    assert descriptions[0].data == model_to_urdf(model)


def _trolley_crane(text: str) -> str:
    """The loader crane with a 100 kg trolley free to roll along its jib (test_failures: no static equilibrium)."""
    return yaml.safe_dump(with_trolley(yaml.safe_load(text)))


@pytest.mark.parametrize(("spoil", "reason"), [
    (lambda text: text.replace("joint: column_slew\n", "joint: wrist\n"),
     "drive.joint = 'wrist': must be a joint of the chain"),
    (_trolley_crane, "static equilibrium not found: largest unbalanced generalized force 926 N on roll"),
])
def test_a_bad_crane_file_leaves_the_node_unconfigured_until_it_is_mended(
        ros: Harness, tmp_path: Path, spoil: Callable[[str], str], reason: str) -> None:
    """A crane file that names a joint it lacks, or one without a static equilibrium to start from (without
    autostart): configure fails, the node stays unconfigured with the file, the reason and what is allowed at
    ERROR in /diagnostics; once the file is mended, configure succeeds."""
    crane = tmp_path / "crane.yaml"
    text = (Path(__file__).resolve().parent.parent / "config" / "loader_crane.yaml").read_text()
    crane.write_text(spoil(text))
    node = CraneReferenceNode(context=ros.context, parameter_overrides=[
        Parameter("autostart", value=False), Parameter("config_file", value=str(crane))])
    ros.node = node
    ros.spin(node)
    assert not change_state(ros, Transition.TRANSITION_CONFIGURE)
    assert lifecycle_state(ros) == "unconfigured"
    ros.wait_for(lambda: any(reason in m for m in diagnostic_messages(ros)), "the reason in /diagnostics")
    error = next(d.status[0] for _, d in list(ros.received["diagnostics"]) if reason in d.status[0].message)
    assert error.level == rclpy_types().byte(Level.ERROR) and str(crane) in error.message, error.message
    crane.write_text(text)
    assert change_state(ros, Transition.TRANSITION_CONFIGURE)
    assert lifecycle_state(ros) == "inactive"

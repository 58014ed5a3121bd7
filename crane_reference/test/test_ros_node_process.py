"""The node as a process (``python -m crane_reference.ros.node``): it publishes, SIGINT ends it with exit
code 0 and no traceback, and a start-up error exits 1 with the reason and no traceback."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from sensor_msgs.msg import JointState

NODE_YAML = Path(__file__).resolve().parent.parent / "config" / "node.yaml"


def start(*ros_args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "crane_reference.ros.node", "--ros-args", *ros_args], env=os.environ,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def listen_then_signal(process: subprocess.Popen, msg_type: type, topic: str, count: int, signal_number: int,
                       transitions: tuple[int, ...] = ()) -> tuple[list, str, str]:
    """The lifecycle ``transitions`` requested (as a manager does), then messages of ``topic`` from the node
    ``process`` until ``count`` arrived (60 s at most), then ``signal_number`` to it; the messages and its
    stdout and stderr once it ended."""
    context = rclpy.Context()
    rclpy.init(context=context)
    received: list = []
    try:
        node = Node("listener", context=context)
        node.create_subscription(msg_type, topic, received.append, 100)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        deadline = time.monotonic() + 60.0
        change_state = node.create_client(ChangeState, "/crane_reference/change_state")
        for transition in transitions:
            # a node of an earlier test may still be known to discovery: hear this one before asking it
            while not received and time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.1)
            assert change_state.wait_for_service(timeout_sec=60.0)
            for _ in range(6):  # a request sent before discovery matched this node's server is lost: ask again
                future = change_state.call_async(ChangeState.Request(transition=Transition(id=transition)))
                executor.spin_until_future_complete(future, timeout_sec=10.0)
                if future.done():
                    break
            assert future.done() and future.result().success, "no answer to the lifecycle transition"
        received.clear()
        while len(received) < count and time.monotonic() < deadline and process.poll() is None:
            executor.spin_once(timeout_sec=0.1)
        node.destroy_node()
    finally:
        context.try_shutdown()
        process.send_signal(signal_number)
        stdout, stderr = process.communicate(timeout=30)
    return received, stdout, stderr


@pytest.mark.slow
@pytest.mark.parametrize("signal_number", [signal.SIGINT, signal.SIGTERM])
def test_publishes_and_exits_cleanly_on_a_signal(signal_number: int) -> None:
    process = start("--params-file", str(NODE_YAML), "-p", "publish_rate:=50", "-p", "ellipse.a:=3")
    received, stdout, stderr = listen_then_signal(process, JointState, "/crane_reference/joint_states", 20,
                                                  signal_number)
    assert len(received) >= 20, stderr
    assert len(received[-1].name) == len(received[-1].position) == 24
    assert process.returncode == 0, stderr
    assert "Traceback" not in stderr and "Traceback" not in stdout, stderr
    assert "publishing the flexible crane's reference at 50 Hz" in stderr


def test_start_up_error_names_the_parameter() -> None:
    process = start("-p", "ellipse.a:=30")
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 1
    assert "cannot start: ellipse.a = 30.0: must be a number in [0.1, 20] m" in stderr
    assert "Traceback" not in stderr


def test_an_unknown_parameter_stops_the_start_naming_it() -> None:
    process = start("-p", "elipse.a:=3.0")
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 1
    assert "cannot start: unknown parameter(s) elipse.a; the node's parameters are" in stderr and "ellipse.a" in stderr
    assert "Traceback" not in stderr


@pytest.mark.slow
@pytest.mark.parametrize("signal_number", [signal.SIGINT, signal.SIGTERM])
@pytest.mark.parametrize(("transitions", "state"), [((), "unconfigured"),
                                                    ((Transition.TRANSITION_CONFIGURE,), "inactive")])
def test_a_waiting_node_reports_its_state_and_exits_cleanly_on_a_signal(signal_number: int, transitions: tuple,
                                                                         state: str) -> None:
    """autostart false: the node publishes /diagnostics while unconfigured (a lifecycle manager would
    configure it) and, once configured, while inactive; in both it ends with exit code 0 on SIGINT or
    SIGTERM."""
    process = start("-p", "autostart:=false")
    received, stdout, stderr = listen_then_signal(process, DiagnosticArray, "/diagnostics", 1, signal_number,
                                                  transitions)
    assert received and received[0].status[0].message.startswith(state), stderr
    assert process.returncode == 0, stderr
    assert "Traceback" not in stderr and "Traceback" not in stdout, stderr


@pytest.mark.slow
@pytest.mark.parametrize(("override", "reason", "mended"), [
    ("ellipse.a:=3.9", "ellipse.* / z.* = ", Parameter("ellipse.a", value=3.0)),  # in the table's range, out of reach
    ("config_file:=missing.yaml", "missing.yaml: cannot read", None),  # mended: the file is written
])
def test_a_failed_start_leaves_the_node_unconfigured_until_mended(tmp_path: Path, override: str, reason: str,
                                                                  mended: Parameter | None) -> None:
    """With autostart (the default), a target out of reach or a crane file that does not load: the node keeps
    running, unconfigured, with the reason and the remedy at ERROR in /diagnostics; once the parameter is set (or
    the file written), configure and activate publish; SIGINT then ends it with exit code 0."""
    process = subprocess.Popen([sys.executable, "-m", "crane_reference.ros.node", "--ros-args", "-p", override,
                                "-p", "publish_rate:=50"], env=os.environ, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    context = rclpy.Context()
    rclpy.init(context=context)
    statuses: list = []
    joints: list = []
    try:
        node = Node("prober", context=context)
        node.create_subscription(DiagnosticArray, "/diagnostics", lambda msg: statuses.extend(msg.status), 100)
        node.create_subscription(JointState, "/crane_reference/joint_states", joints.append, 100)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)

        def wait_for(condition, what: str, timeout: float = 60.0) -> None:
            deadline = time.monotonic() + timeout
            while not condition():
                assert time.monotonic() < deadline and process.poll() is None, f"no {what}"
                executor.spin_once(timeout_sec=0.05)

        def call(future) -> object:
            wait_for(future.done, "answer")
            return future.result()

        wait_for(lambda: any("cannot configure" in s.message for s in statuses), "ERROR in /diagnostics")
        status = next(s for s in statuses if "cannot configure" in s.message)
        assert status.level == b"\x02" and reason in status.message and "then configure" in status.message
        if mended is not None:
            parameters = AsyncParameterClient(node, "crane_reference")
            assert parameters.wait_for_services(timeout_sec=30.0)
            assert call(parameters.set_parameters([mended])).results[0].successful
        else:
            (tmp_path / "missing.yaml").write_text((Path(__file__).resolve().parent.parent / "config" /
                                                    "crane.yaml").read_text())
        change_state = node.create_client(ChangeState, "/crane_reference/change_state")
        assert change_state.wait_for_service(timeout_sec=30.0)
        for transition in (Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE):
            request = ChangeState.Request(transition=Transition(id=transition))
            assert call(change_state.call_async(request)).success, transition
        wait_for(lambda: len(joints) >= 10, "joint states")
        node.destroy_node()
    finally:
        context.try_shutdown()
        process.send_signal(signal.SIGINT)
        _, stderr = process.communicate(timeout=30)
    assert process.returncode == 0, stderr
    assert stderr.count("cannot configure") == 1 and "Traceback" not in stderr, stderr

"""The crane_plant node (crane_reference.ros.plant_node): in-process with a probe node (one Context per test), and
as a process for the signals.

* Lock-step over ROS equals the plant core driven directly with the same commands (another path: the
  messages, the executor, /clock), bit for bit, and /clock and the stamps advance one period per command.
* Bad commands (length, NaN, inf) are refused and counted in /diagnostics, never integrated: the run equals
  the core's with them refused, and the stream goes on.
* In real time, silence beyond ``command_timeout`` starts the hold command, reported at WARN; a process stopped
  for 0.5 s counts the periods it missed, reported at WARN.
* The lifecycle transitions through the standard services; SIGINT and SIGTERM end the process with 0.
* The closed loop over ROS (reference node, plant in lock-step, example controller) is ``crane-reference
  track``'s loop in one process, bit for bit.
"""

from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import threading
import time
from contextlib import suppress
from typing import Any

import numpy as np
import pytest
import rclpy
from cranes import CONFIG, spinning_crane
from diagnostic_msgs.msg import DiagnosticArray
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from waiting import wait_for

from crane_reference.analysis.tracking.closed_loop import TrackingSpec, run_tracking
from crane_reference.base.health import StartupError
from crane_reference.control.plant import held_start
from crane_reference.control.plant_server import CommandRefusedError, PlantServer, PlantSettings
from crane_reference.model.paper_layout import ACTUATED as ACTUATED_JOINTS
from crane_reference.motion.simulation import Scenario
from crane_reference.motion.steps import ONLINE_STEP
from crane_reference.ros.controller_node import CraneControllerNode
from crane_reference.ros.node import CraneReferenceNode
from crane_reference.ros.parameter_spec import ParameterError
from crane_reference.ros.plant_node import NODE_NAME, CranePlantNode

NS = 10**9
PERIOD = 1e-3


def _stamp(state: JointState) -> int:
    return state.header.stamp.sec * NS + state.header.stamp.nanosec


class Probe:
    """The plant node and a probe (joint_states, /clock, /diagnostics; publishes ~/commands), each spun by an
    executor thread of its own."""

    def __init__(self, **parameters: Any) -> None:
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.states: list[JointState] = []
        self.clock: list[Clock] = []
        self.diagnostics: list[DiagnosticArray] = []
        self.probe = Node("probe", context=self.context)
        self.probe.create_subscription(JointState, f"/{NODE_NAME}/joint_states", self.states.append, 10000)
        self.probe.create_subscription(Clock, "/clock", self.clock.append, 10000)
        self.probe.create_subscription(DiagnosticArray, "/diagnostics", self.diagnostics.append, 100)
        self.commands = self.probe.create_publisher(Float64MultiArray, f"/{NODE_NAME}/commands", 100)
        self.change_state = self.probe.create_client(ChangeState, f"/{NODE_NAME}/change_state")
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        overrides = [Parameter(name.replace("__", "."), value=value) for name, value in parameters.items()]
        self.node = CranePlantNode(context=self.context, parameter_overrides=overrides)
        for node in (self.probe, self.node):
            self._spin(node)

    def _spin(self, node: Node) -> None:
        executor = SingleThreadedExecutor(context=self.context)
        executor.add_node(node)

        def spin() -> None:
            with suppress(ExternalShutdownException):
                while not self._stop.is_set():
                    executor.spin_once(timeout_sec=0.02)

        thread = threading.Thread(target=spin, daemon=True)
        thread.start()
        self._threads.append(thread)

    def wait_for(self, condition, what: str, timeout: float = 30.0) -> None:
        wait_for(condition, what, timeout)

    def command(self, values) -> None:
        self.commands.publish(Float64MultiArray(data=[float(v) for v in values]))

    def periods(self) -> list[JointState]:
        """The states of successive periods: a lock-step plant repeats an unanswered state on its heartbeat (a
        slow answer, on a busy machine), with the same stamp; the repeats are left out (each checked a copy)."""
        periods: list[JointState] = []
        for state in list(self.states):
            if periods and _stamp(state) == _stamp(periods[-1]):
                assert state.position == periods[-1].position and state.velocity == periods[-1].velocity
            else:
                periods.append(state)
        return periods

    def lockstep(self, commands) -> None:
        """Each command after the state of the period before it arrived (as a controller answers each period's
        state once)."""
        self.wait_for(lambda: self.states and self.commands.get_subscription_count() > 0, "the plant")
        for k, values in enumerate(commands):
            self.wait_for(lambda k=k: len(self.periods()) >= k + 1, f"state {k}")
            self.command(values)
        self.wait_for(lambda: len(self.periods()) >= len(commands) + 1, "the last state")

    def latest_diagnostics(self) -> dict[str, str]:
        status = self.diagnostics[-1].status[0]
        return {"level": status.level[0] if isinstance(status.level, bytes) else status.level,
                "message": status.message, **{kv.key: kv.value for kv in status.values}}

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join()
        self.node.destroy_node()
        self.probe.destroy_node()
        self.context.try_shutdown()


@pytest.fixture
def probe_factory():
    probes = []

    def make(**parameters: Any) -> Probe:
        probes.append(Probe(**parameters))
        return probes[-1]

    yield make
    for probe in probes:
        probe.close()


@pytest.fixture(scope="module")
def start_efforts(params):
    return held_start(Scenario(params, "flexible")).torques


def _direct(params, commands) -> list[np.ndarray]:
    """The core driven directly: q of the joints after each command (refused ones leave the last in force)."""
    server = PlantServer(params, PlantSettings())
    out = []
    for values in commands:
        with suppress(CommandRefusedError):
            server.command(values, server.t)
        out.append(server.tick(server.t).q)
    return out


def test_lockstep_over_ros_is_the_core_driven_directly(params, probe_factory, start_efforts):
    commands = [start_efforts + np.array([3e3 * math.sin(0.1 * k), -2e3, 40.0]) for k in range(60)]
    probe = probe_factory(clock_mode="lockstep")
    probe.lockstep(commands)
    periods = probe.periods()
    assert [_stamp(s) for s in periods] == [round((1.0 + k * PERIOD) * NS) for k in range(61)]  # from clock_start
    assert [c.clock.sec * NS + c.clock.nanosec for c in probe.clock] == [_stamp(s) for s in probe.states]
    assert periods[0].name == ["column_slew", "boom_luff", "knuckle"]
    direct = _direct(params, commands)
    assert all(np.array_equal(np.array(s.position), q) for s, q in zip(periods[1:], direct, strict=True))
    assert np.abs(np.array(periods[-1].position) - periods[0].position).max() > 1e-4  # it moved


def test_an_unanswered_lockstep_state_is_repeated_with_its_stamp(params, probe_factory, start_efforts):
    """With no command, the lock-step plant repeats its state (same stamp, same values: checked by ``periods``)
    and /clock on its heartbeat, without advancing; the commands that come then step it as usual."""
    probe = probe_factory(clock_mode="lockstep")
    probe.wait_for(lambda: len(probe.states) >= 3, "two repetitions of the first state", timeout=10.0)
    assert len(probe.periods()) == 1
    assert {c.clock.sec * NS + c.clock.nanosec for c in probe.clock} == {_stamp(probe.states[0])}
    commands = [start_efforts] * 3
    probe.lockstep(commands)
    direct = _direct(params, commands)
    assert all(np.array_equal(np.array(s.position), q) for s, q in zip(probe.periods()[1:], direct, strict=True))


def test_bad_commands_are_refused_counted_and_never_integrated(params, probe_factory, start_efforts):
    good = [start_efforts + np.array([2e3, 0.0, 0.0])] * 20
    bad = {5: [1.0, 2.0], 9: [math.nan, 0.0, 0.0], 13: [0.0, -math.inf, 0.0]}
    commands = [bad.get(k, values) for k, values in enumerate(good)]
    probe = probe_factory(clock_mode="lockstep")
    probe.lockstep(commands)
    direct = _direct(params, commands)
    assert all(np.array_equal(np.array(s.position), q) for s, q in zip(probe.periods()[1:], direct, strict=True))
    assert all(np.isfinite(s.position).all() and np.isfinite(s.velocity).all() for s in probe.states)
    probe.wait_for(lambda: probe.diagnostics and probe.latest_diagnostics()["commands_refused"] == "3",
                   "the refusals in /diagnostics", timeout=5.0)
    report = probe.latest_diagnostics()
    assert report["commands_accepted"] == "17" and "not finite" in report["last_refusal"]


def test_silence_starts_the_hold_command_with_a_warning(probe_factory, start_efforts):
    probe = probe_factory(command_timeout=0.05, control_rate=100)  # the semantics, not the speed
    probe.wait_for(lambda: probe.states and probe.commands.get_subscription_count() > 0, "the plant")
    probe.command(start_efforts)
    probe.wait_for(lambda: probe.diagnostics and probe.latest_diagnostics()["timeouts"] == "1",
                   "a timeout in /diagnostics", timeout=10.0)
    report = probe.latest_diagnostics()
    assert report["level"] == 1 and "the hold command acts" in report["message"]
    count = len(probe.states)
    probe.wait_for(lambda: len(probe.states) > count + 20, "states while holding")  # the stream goes on
    assert probe.node.set_parameters([Parameter("command_timeout", value=60)])[0].successful  # an integer, too
    probe.command(start_efforts)  # ends the hold
    probe.wait_for(lambda: probe.latest_diagnostics()["level"] == 0, "OK after a command", timeout=5.0)
    assert probe.latest_diagnostics()["timeouts"] == "1"


def test_lifecycle_transitions(probe_factory):
    probe = probe_factory(autostart=False, clock_mode="lockstep")
    assert probe.change_state.wait_for_service(timeout_sec=10.0)

    def transition(transition_id: int) -> bool:
        future = probe.change_state.call_async(ChangeState.Request(transition=Transition(id=transition_id)))
        probe.wait_for(future.done, f"transition {transition_id}")
        return future.result().success

    assert not probe.states
    assert transition(Transition.TRANSITION_CONFIGURE) and not probe.states
    assert transition(Transition.TRANSITION_ACTIVATE)
    probe.wait_for(lambda: probe.states, "the state on activation")
    assert transition(Transition.TRANSITION_DEACTIVATE)
    assert transition(Transition.TRANSITION_CLEANUP)
    assert transition(Transition.TRANSITION_CONFIGURE) and transition(Transition.TRANSITION_ACTIVATE)


def plant_process() -> subprocess.Popen:
    """The plant node as a process (real time, 100 Hz, 1 ms steps), its output captured."""
    return subprocess.Popen([sys.executable, "-m", "crane_reference.ros.plant_node", "--ros-args", "-p",
                             "control_rate:=100", "-p", "integrator.step:=0.001"], env=os.environ,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.slow
@pytest.mark.parametrize("signal_number", [signal.SIGINT, signal.SIGTERM])
def test_the_process_ends_with_0_on_a_signal(signal_number):
    process = plant_process()
    context = rclpy.Context()
    rclpy.init(context=context)
    received: list = []
    try:
        node = Node("listener", context=context)
        node.create_subscription(JointState, f"/{NODE_NAME}/joint_states", received.append, 100)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        deadline = time.monotonic() + 60.0
        while len(received) < 20 and time.monotonic() < deadline and process.poll() is None:
            executor.spin_once(timeout_sec=0.1)
        node.destroy_node()
    finally:
        context.try_shutdown()
        process.send_signal(signal_number)
        stdout, stderr = process.communicate(timeout=30)
    assert len(received) >= 20, stderr
    assert process.returncode == 0, stderr
    assert "Traceback" not in stderr + stdout, stderr


@pytest.mark.slow
def test_a_stopped_process_counts_the_periods_it_missed():
    """The plant's process stopped for about 0.5 s (SIGSTOP, as a machine too busy for it would leave it) at
    100 Hz in real time: the periods due meanwhile are missed, counted in /diagnostics' ``missed_ticks`` (the
    stop's length over the period, less the one that runs at once on waking) at WARN, and the states go on.  The
    count before the stop is read once two reports in a row agree on it (periods missed while the plant starts are
    reported up to a diagnostics period later)."""
    period = 0.01
    process = plant_process()
    context = rclpy.Context()
    rclpy.init(context=context)
    states: list = []
    reports: list[tuple[int, dict[str, str]]] = []
    try:
        node = Node("listener", context=context)
        node.create_subscription(JointState, f"/{NODE_NAME}/joint_states", states.append, 1000)
        node.create_subscription(DiagnosticArray, "/diagnostics", lambda msg: reports.append(
            (msg.status[0].level[0], {kv.key: kv.value for kv in msg.status[0].values})), 100)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)

        def spin_until(condition: Any, what: str, timeout: float = 60.0) -> None:
            wait_for(lambda: executor.spin_once(timeout_sec=0.05) or condition() or process.poll() is not None,
                     what, timeout)
            assert process.poll() is None, process.communicate()[1]

        def steady() -> bool:
            counts = [values.get("missed_ticks") for _, values in reports[-2:]]
            return len(states) >= 20 and len(counts) == 2 and counts[0] is not None and counts[0] == counts[1]

        spin_until(steady, "states and two reports with the same count of missed periods")
        before = int(reports[-1][1]["missed_ticks"])
        stopped = time.monotonic()
        os.kill(process.pid, signal.SIGSTOP)
        time.sleep(0.5)
        os.kill(process.pid, signal.SIGCONT)
        stopped = time.monotonic() - stopped
        count = len(reports)
        spin_until(lambda: any(int(values["missed_ticks"]) > before for _, values in reports[count:]),
                   "the missed periods reported")
        level, values = next((level, values) for level, values in reports[count:]
                             if int(values["missed_ticks"]) > before)
        missed = int(values["missed_ticks"]) - before
        assert level == 1 and stopped / period - 2 <= missed <= stopped / period + 10, (missed, stopped)
        received = len(states)
        spin_until(lambda: len(states) >= received + 20, "states after the stop")
        node.destroy_node()
    finally:
        context.try_shutdown()
        process.send_signal(signal.SIGINT)
        process.communicate(timeout=30)


def test_configuration_errors_name_the_parameter(tmp_path):
    """A setting that does not fit names the parameter; a crane whose first period cannot be integrated (a column
    torque of 1e6 N m from the start: the step does not converge) names the failure, not only that the node is
    unconfigured."""
    crane = spinning_crane(tmp_path / "crane.yaml")
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        with pytest.raises(Exception, match=r"rate = 300.0 Hz with step"):
            CranePlantNode(context=context, parameter_overrides=[Parameter("control_rate", value=300),
                                                                 Parameter("integrator.step", value=1e-3)])
        with pytest.raises(StartupError, match=r"the step from t = 0 s with h = 0.001 s did not converge"):
            CranePlantNode(context=context, parameter_overrides=[Parameter("config_file", value=str(crane))])
    finally:
        context.try_shutdown()


@pytest.mark.slow
def test_the_loop_over_ros_is_crane_reference_track(params):
    """The reference node (sim time, its default step, a preview point every 1 ms as closed_loop.launch.py sets),
    the plant (lock-step) and the example controller, each a node: the plant's motion equals ``crane-reference
    track``'s (the compiled loop in one process, its reference simulated in one call) with the same gains,
    rate and steps, bit for bit."""
    duration = 0.3
    context = rclpy.Context()
    rclpy.init(context=context)
    sim = [Parameter("use_sim_time", value=True)]
    nodes = [CranePlantNode(context=context, parameter_overrides=[Parameter("clock_mode", value="lockstep")]),
             CraneReferenceNode(context=context, parameter_overrides=[
                 *sim, Parameter("preview.points", value=1000), Parameter("preview.horizon", value=0.999)]),
             CraneControllerNode(context=context, parameter_overrides=sim)]
    states: list[JointState] = []
    probe = Node("probe", context=context)
    probe.create_subscription(JointState, f"/{NODE_NAME}/joint_states", states.append, 100000)
    stop = threading.Event()

    def spin(node: Node) -> None:
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        with suppress(ExternalShutdownException):
            while not stop.is_set():
                executor.spin_once(timeout_sec=0.01)

    threads = [threading.Thread(target=spin, args=(node,), daemon=True) for node in (*nodes, probe)]
    for thread in threads:
        thread.start()
    try:
        deadline = time.monotonic() + 120.0
        end_ns = round((1.0 + duration) * NS)
        while not states or states[-1].header.stamp.sec * NS + states[-1].header.stamp.nanosec < end_ns:
            assert time.monotonic() < deadline, f"{len(states)} states in 120 s"
            time.sleep(0.01)
    finally:
        stop.set()
        for thread in threads:
            thread.join()
        for node in (*nodes, probe):
            node.destroy_node()
        context.try_shutdown()
    track = run_tracking(params, TrackingSpec(feedforward="none", duration=duration, reference_step=ONLINE_STEP))
    columns = [track.plant.joint_names.index(joint) for joint in ACTUATED_JOINTS]
    by_tick = {}
    for state in states:  # a repeated state (heartbeat) is the same state
        by_tick.setdefault(round((state.header.stamp.sec * NS + state.header.stamp.nanosec) / 1e6) - 1000, state)
    ticks = round(duration * 1000)
    assert sorted(by_tick)[:ticks + 1] == list(range(ticks + 1))
    over_ros = np.array([by_tick[k].position for k in range(ticks + 1)])
    assert np.array_equal(over_ros, track.plant.q[:ticks + 1, columns])
    assert np.abs(over_ros[-1] - over_ros[0]).max() > 1e-2  # it moved


@pytest.mark.slow
@pytest.mark.parametrize("feedforward", ["none", "reference"])
def test_crane_reference_loop_is_crane_reference_track_as_a_user_runs_them(tmp_path, feedforward):
    """``crane-reference loop --feedforward F`` (three processes, lock-step; with ``reference`` the controller adds
    the preview's efforts) and ``crane-reference track --feedforward F``, each command line as a user types it
    (the defaults on both sides), write the same summary over 1 s: every metric equal but the energy balance
    (the messages do not carry the energies) and the real-time factor."""
    summaries = []
    for command in (["loop"], ["track"]):
        out = tmp_path / command[0]
        result = subprocess.run([sys.executable, "-m", "crane_reference.cli", *command, "--feedforward", feedforward,
                                 "--duration", "1", "--out", str(out)], env=os.environ, capture_output=True,
                                text=True, timeout=600)
        assert result.returncode == 0, result.stderr
        summaries.append(json.loads((out / "summary.json").read_text())[f"pd_ff-{feedforward}"])
        if command == ["loop"]:
            assert f"crane-reference track --model flexible --feedforward {feedforward} --rate 1000 --duration 1" \
                in result.stdout
    over_ros, track = summaries
    assert math.isnan(over_ros.pop("energy_balance_error_j"))
    for summary in summaries:
        summary.pop("real_time_factor")
    track.pop("energy_balance_error_j")
    assert over_ros == track


@pytest.mark.slow
def test_crane_reference_loop_on_a_crane_without_a_start_fails_naming_why(tmp_path):
    """``crane-reference loop`` with a crane that has no static equilibrium (test_failures' trolley, free on the
    inclined jib): exit code 1 and a LoopError with what each node said, the reason of the first to end (the
    plant or the controller: it cannot start, exit code 1) among them, and no traceback."""
    from test_ros_node import _trolley_crane

    crane = tmp_path / "trolley.yaml"
    crane.write_text(_trolley_crane((CONFIG / "loader_crane.yaml").read_text()))
    result = subprocess.run([sys.executable, "-m", "crane_reference.cli", "loop", "--config", str(crane),
                             "--duration", "0.2", "--out", str(tmp_path / "out")], env=os.environ, capture_output=True,
                            text=True, timeout=600)
    assert result.returncode == 1 and result.stderr.startswith("crane-reference loop: "), result.stderr
    assert "Traceback" not in result.stderr, result.stderr
    said = dict(re.findall(r"(crane_\w+) \(exit code (-?\d+)\) said: ", result.stderr))
    assert set(said) == {"crane_reference", "crane_plant", "crane_controller"}, result.stderr
    # the plant and the controller each end with 1 unless the loop's SIGINT to all came first (the other's end)
    assert "1" in (said["crane_plant"], said["crane_controller"]) and set(said.values()) <= {"0", "1", "-2"}
    assert "cannot start: static equilibrium not found: largest unbalanced generalized force" in result.stderr
    assert " N on roll " in result.stderr and not (tmp_path / "out").exists()


def test_the_controller_refuses_unknown_and_bad_parameters():
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        with pytest.raises(ParameterError, match=r"unknown parameter.*gains.knuckle.q"):
            CraneControllerNode(context=context, parameter_overrides=[Parameter("gains.knuckle.q", value=1.0)])
        with pytest.raises(ParameterError, match=r"gains.boom_luff.p = -1.0: must be a number in \[0, 1e\+12\]"):
            CraneControllerNode(context=context, parameter_overrides=[Parameter("gains.boom_luff.p", value=-1.0)])
        with pytest.raises(ParameterError, match=r"joints = .*must name each of"):
            CraneControllerNode(context=context, parameter_overrides=[Parameter("joints", value=["knuckle"])])
    finally:
        context.try_shutdown()


def test_a_message_rclpy_cannot_convert_is_lost_with_a_warning_and_other_errors_propagate():
    """The spin loop's step (``ros.running.spin_once``) goes on after rclpy's conversion error of a taken message,
    warning, and raises any other error."""
    from crane_reference.ros.running import LOST_MESSAGE, spin_once

    class Executor:
        def __init__(self, error):
            self.error, self.calls = error, 0

        def spin_once(self, timeout_sec=None):
            self.calls += 1
            raise self.error

    class Logger:
        def __init__(self):
            self.warnings = []

        def warning(self, message, **_):
            self.warnings.append(message)

    logger = Logger()
    node = type("Node", (), {"get_logger": lambda self: logger})()
    lost = Executor(RuntimeError(f"{LOST_MESSAGE} '0' to Python object (#define PYBIND11_DETAILED_ERROR_MESSAGES)"))
    spin_once(lost, node, 0.1)
    assert lost.calls == 1 and len(logger.warnings) == 1 and "lost" in logger.warnings[0]
    with pytest.raises(RuntimeError, match="something else"):
        spin_once(Executor(RuntimeError("something else")), node)


@pytest.mark.slow
def test_a_real_time_loop_starts_its_reference_once_the_plant_runs(params):
    """``crane-reference loop`` in real time (100 Hz, 1 s): the reference node is activated after the plant, so the
    loop runs and is recorded from the first state of the plant after the reference's first sample (the two
    activations apart: well under 0.3 s), where the plant is still at rest at its held start and the reference has
    barely left its own start: its column less than 0.01 rad off (the column drive turns it that much in 0.06 s),
    its luff within the two starts' difference (the boom bends under the two ways E is held: the reference's E by
    its constraint, the plant's by its joints).  (With the reference node starting itself, the plant's first
    command chased a motion under way: here its first step did not converge, or the recording began 0.5-0.8 s
    late.)"""
    from crane_reference.ros.loop import run_loop

    recording = run_loop(1.0, "realtime", 100)
    held = held_start(Scenario(params, "flexible")).q
    names = list(recording.joint_names)
    column, luff = names.index("column_slew"), names.index("boom_luff")
    assert recording.t[0] < 0.3 and recording.t[-1] > 0.95
    assert abs(recording.q[0, column] - held[column]) < 1e-9
    assert abs(recording.reference_q[0, column] - held[column]) < 0.01
    assert abs(recording.reference_q[0, luff] - held[luff]) < 5e-3


@pytest.mark.slow
def test_a_loop_whose_plant_stops_ends_with_why(tmp_path):
    """A plant that stops mid-run (a column torque of 1e6 N m from 0.2 s: its step there does not converge; the
    node stays up, at ERROR) leaves ``crane-reference loop`` without new states: it ends with a LoopError after
    ``STALL_TIMEOUT`` that says so, with the plant's own words, instead of waiting for ever."""
    from crane_reference.ros.loop import STALL_TIMEOUT, LoopError, run_loop

    crane = spinning_crane(tmp_path / "crane.yaml", start=0.2)
    began = time.monotonic()
    with pytest.raises(LoopError) as error:
        run_loop(2.0, "lockstep", 1000, config_file=str(crane))
    said = str(error.value)
    assert said.startswith(f"the plant published no new state for {STALL_TIMEOUT:g} s of wall time, after 0.200 s")
    assert "[crane_plant]: the plant stopped: the step from t = 0.2 s with h = 0.001 s did not converge" in said
    assert time.monotonic() - began < 120.0

"""Benchmark of the crane_reference node: publishing rate, timing and re-target latency.

For each rate (default 100, 500 and 1000 Hz) it starts ``python -m crane_reference.ros.node`` in its own
process (an isolated ROS domain, localhost only), subscribes to ``joint_states`` and /diagnostics from this
process and, after a warm-up, records for ``--duration`` seconds (default 30):

* achieved rate: messages received / duration;
* period: standard deviation of the time between receptions, and the p99 and maximum of
  |period - 1 / rate| (the period error);
* delivery lag: reception time - stamp (both system time), mean and p99;
* missed samples: stamps absent from the received sequence, plus the samples the node itself held
  because it ran late and the times its stamps leapt (from /diagnostics: held_late, stamp_leaps);
* CPU share of the node (user + system time of its process and of the solver's process / wall time,
  100 % = one core; also each process alone) and the solver's real-time factor it reports (/diagnostics'
  ``real_time_factor``, over the second before each report: ``real_time_factor`` is the median of the reports
  of the measured seconds in which the solver computed, ``real_time_factor_min`` the smallest);
* latency from a parameter change (``ellipse.a``, through the parameter service) to the reception of
  the first sample that uses it (the node reports that sample's stamp in /diagnostics as
  ``retarget_stamp_s``), over ``--changes`` changes, and from the node's acceptance of the change to that
  sample's stamp (``retarget_accepted_s`` to ``retarget_stamp_s``, both on the node's clock), and the
  node's margin: how long before that stamp the sample was ready (``retarget_margin_s``, smallest of the
  changes; ``margin_*`` for the commands below); samples held late while the changes and the commands
  below were made (held_late_commands), and during each kind (``held_late_retargets`` for these changes,
  ``held_late_goals``, ``held_late_stream_commands`` for the pause, resume, speed change and re-target of the
  smoothness windows);
* the ~/retarget action, over ``--changes`` goals (alternating ellipse.a 3.1 / 3.0 m on the paper's crane, blend
  0.5 s; with ``--config`` another crane, the changes relative to its task): the time from sending a goal to
  its acceptance (``goal_accepted_max_ms``), the result's ``path_stamp`` - ``blend_stamp`` less the blend time
  (``goal_blend_span_error_max_ms``: 0 at speed 1, a period at most from rounding, more where samples were held),
  and the time from the reception of the sample stamped ``path_stamp`` to the reception of the result
  (``goal_result_after_path_max_ms``: the action's poll of 0.1 s at most, plus delivery);
* smoothness of the commands: the largest change of the slew's velocity between two received samples
  (rad/s) in normal running and after ~/pause, resume, a speed_scaling change to 0.5 and a re-target
  (each window: the ramp time plus 0.5 s; the flexible boom's 70 Hz bending makes the column's velocity
  oscillate between samples in normal running too);
* with ``--flood N``: N random parameter requests at 50 Hz through the parameter services (valid and
  invalid values of ellipse.*, z.*, speed_scaling and unknown names; single and atomic requests), then
  stamp gaps longer than two periods, non-finite positions or velocities, requests without a response
  and whether a valid change still takes effect afterwards;
* the node's CPU over its floor (issue 29's ratio): the floor is the CPU share of a process that only publishes
  the node's messages, paced (the samples' two serialized messages at the rate, the preview at its rate,
  /diagnostics once a second), with a subscriber in another process on the topics the node's run subscribes to
  (the joint states and /diagnostics), plus that of the
  compiled steps alone at the node's ``integrator.step`` for real-time motion, both measured just before and
  just after each rate's run and averaged (``floor_publish_percent``, ``floor_steps_percent``, ``floor_percent``,
  ``cpu_over_floor``), and its parts: the node's process over the publish-only process
  (``node_over_publish_floor``) and the solver's process over the steps alone (``solver_over_steps``); the
  targets are printed under the table;
* the wall time of a step of the node's solver in Pinocchio ABA (``solver_step_aba``: ``integrator.step`` /
  (real-time factor x ABA time), its computing's wall time per step) beside the CPU time of a step of the
  compiled steps alone (``steps_alone_step_aba``, from ``floor_steps_percent``), with Pinocchio's ABA on the
  exported URDF timed before and after each rate's run (``aba_us``, averaged): the solver's speed in units that
  this machine's drifting speed leaves unchanged;
* the CPU share of each thread of the node's and the solver's processes over the measured seconds, by the names
  the node gives its threads (``[threads]``: ``ref_publisher``, ``ref_frames``, ``ref_diagnostics``, rclpy's
  executor in the main thread, Fast DDS's ``dds.*`` threads);
* the time from SIGINT (sent while active) to the node's exit (``exit_after_sigint_s``);
* with ``--hang``, first: the solver's process stopped (SIGSTOP) under a node publishing at 100 Hz: the seconds
  until /diagnostics reports it at ERROR, a deactivate's answer and SIGINT to the node's exit;
* with ``--busy N``: all of the above with N processes that only spin (at the default priority) beside each node run,
  not beside the floor's measurements: how the node holds up on a busy machine (the CPU ratios then count its
  share of a contended machine);
* first (``--message-costs``), in this process: what the node's publisher spends per sample to stamp and
  publish ~/joint_states and ~/end_effector_pose (rows of a batch serialized at once, as the node does, and
  message objects, for comparison), alone and with a subscriber of the joint states in another process, the
  CPU share of a process that only publishes them at each rate (the floor of publishing from rclpy), and the
  cost of building and publishing ~/markers with a full trail.

Run: ``.venv/bin/python benchmarks/bench_node.py [--duration 30] [--rates 100 500 1000] [--model flexible]
[--flood 300] [--busy 1] [-p command_lead:=0.05 ...]``.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import rclpy
from common import aba_time, print_table, process_cpu_seconds, run_times
from crane_reference_interfaces.action import Retarget
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rclpy.action import ActionClient
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import MarkerArray

from crane_reference.base.health import Level
from crane_reference.interface import messages
from crane_reference.interface.serialized import SerializedJointState, SerializedPose
from crane_reference.model.config import load_config
from crane_reference.model.parameters import Task
from crane_reference.motion.simulation import Scenario
from crane_reference.motion.steps import ONLINE_STEP
from crane_reference.ros.message_types import rclpy_types
from crane_reference.ros.parameters import SPECS
from crane_reference.ros.publishing import MARKER_RATE, TRAIL_POINTS
from crane_reference.stream.ahead import REFILL
from crane_reference.stream.reference_stream import ReferenceStream
from crane_reference.stream.sample import ReferenceRows
from crane_reference.stream.schedule import Counters

NS = 10**9
NODE = "crane_reference"
WARM_UP = 2.0  # [s] after the first message


@dataclass(frozen=True)
class Crane:
    """The crane under test: its file (None: the packaged one), its targets and its slew joint (whose velocity
    measures the commands' smoothness).  The parameter changes are relative to its targets: the paper's crane's
    ellipse.a goes 3.0 -> 3.1 -> 3.0 m."""

    config: str | None
    task: Task
    slew: str

    @staticmethod
    def of(config: str | None, model: str) -> Crane:
        scenario = Scenario(load_config(config), model)
        return Crane(config, scenario.task, scenario.model.joint_names[scenario.slew.joint])

    def ellipse_a(self, share: float) -> float:
        """ellipse.a stretched by ``share`` of its third (the paper's crane: 3 m + share x 1 m)."""
        return self.task.ellipse_a * (1.0 + share / 3.0)

    @property
    def node_parameters(self) -> list[str]:
        return [] if self.config is None else ["-p", f"config_file:={self.config}"]


@dataclass
class Recorder:
    """Receptions of joint_states (monotonic and system time, stamp, the ``slew`` joint's velocity), the last
    diagnostics values and every real-time factor reported (monotonic time [ns], value)."""

    slew: str
    monotonic: list[int] = field(default_factory=list)
    system: list[int] = field(default_factory=list)
    stamps: list[int] = field(default_factory=list)
    slew_velocity: list[float] = field(default_factory=list)
    finite: list[bool] = field(default_factory=list)
    diagnostics: dict[str, str] = field(default_factory=dict)
    real_time_factors: list[tuple[int, float]] = field(default_factory=list)
    reports: int = 0  # the node's /diagnostics statuses received

    def joint_state(self, msg: JointState) -> None:
        self.monotonic.append(time.monotonic_ns())
        self.system.append(time.time_ns())
        self.stamps.append(msg.header.stamp.sec * NS + msg.header.stamp.nanosec)
        self.slew_velocity.append(msg.velocity[list(msg.name).index(self.slew)])
        self.finite.append(bool(np.all(np.isfinite(msg.position)) and np.all(np.isfinite(msg.velocity))))

    def diagnostic(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.startswith(NODE):
                self.diagnostics = {kv.key: kv.value for kv in status.values}
                self.reports += 1
                if "real_time_factor" in self.diagnostics:
                    self.real_time_factors.append((time.monotonic_ns(), float(self.diagnostics["real_time_factor"])))


def descendants(pid: int) -> list[int]:
    """The process ``pid`` and all its living descendants (the node's solver process)."""
    found = [pid]
    for task in os.listdir(f"/proc/{pid}/task"):
        with open(f"/proc/{pid}/task/{task}/children", encoding="ascii") as children:
            for child in children.read().split():
                found += descendants(int(child))
    return found


def thread_seconds(pid: int) -> dict[str, float]:
    """User + system CPU time [s] of each thread of the process ``pid`` and its descendants, by process and thread
    name (``node/ref_publisher``, ``solver/python``; the node names its threads for the operating system), summed
    over threads of one name (threads that ended are not counted)."""
    tick = os.sysconf("SC_CLK_TCK")
    seconds: dict[str, float] = {}
    for number, process in enumerate(descendants(pid)):
        for task in os.listdir(f"/proc/{process}/task"):
            try:
                with open(f"/proc/{process}/task/{task}/comm", encoding="utf-8") as comm:
                    name = comm.read().strip()
                with open(f"/proc/{process}/task/{task}/stat", encoding="ascii") as stat:
                    fields = stat.read().rsplit(")", 1)[1].split()
            except FileNotFoundError:  # the thread ended meanwhile
                continue
            key = f"{'node' if number == 0 else 'solver'}/{name}"
            seconds[key] = seconds.get(key, 0.0) + (int(fields[11]) + int(fields[12])) / tick
    return seconds


def cpu_seconds(pid: int) -> tuple[float, float]:
    """User + system CPU time [s] of a process (all its threads) and of its descendants (the solver's)."""
    times = [process_cpu_seconds(process) for process in descendants(pid)]
    return times[0], sum(times[1:])


def spin_for(executor: SingleThreadedExecutor, seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=min(0.05, max(end - time.monotonic(), 0.0)))


def spin_until(executor: SingleThreadedExecutor, condition, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > end:
            return False
        executor.spin_once(timeout_sec=0.01)
    return True


def held_late_now(executor: SingleThreadedExecutor, recorder: Recorder) -> float:
    """The samples the node has held late so far, from the first /diagnostics it publishes from now on."""
    reports = recorder.reports
    spin_until(executor, lambda: recorder.reports > reports, 3.0)
    return float(recorder.diagnostics.get("held_late", 0))


def measure_latency(executor: SingleThreadedExecutor, client: AsyncParameterClient, recorder: Recorder,
                    changes: int, crane: Crane) -> tuple[list[float], list[float], list[float]]:
    """Seconds from sending each ellipse.a change to receiving the first sample that uses it, from its
    acceptance by the node (its clock, /diagnostics retarget_accepted_s) to that sample's stamp, and how
    long before that stamp the node had the sample ready (retarget_margin_s)."""
    latencies, after_acceptance, margins = [], [], []
    for i in range(changes):
        previous = recorder.diagnostics.get("retarget_stamp_s")
        sent = time.monotonic_ns()
        future = client.set_parameters([Parameter("ellipse.a", value=crane.ellipse_a(0.1 if i % 2 == 0 else 0.0))])
        if not spin_until(executor, future.done, 10.0) or not future.result().results[0].successful:
            raise RuntimeError(f"parameter change {i} failed: {future.result() if future.done() else 'timeout'}")
        if not spin_until(executor, lambda p=previous: recorder.diagnostics.get("retarget_stamp_s") not in (None, p),
                          5.0):
            raise RuntimeError("the node did not report the re-target in /diagnostics")
        effective = round(float(recorder.diagnostics["retarget_stamp_s"]) * NS)
        spin_until(executor, lambda e=effective: recorder.stamps and recorder.stamps[-1] >= e, 10.0)
        first = next(i for i, s in enumerate(recorder.stamps) if s >= effective)
        latencies.append((recorder.monotonic[first] - sent) / NS)
        after_acceptance.append(float(recorder.diagnostics["retarget_stamp_s"])
                                - float(recorder.diagnostics["retarget_accepted_s"]))
        spin_until(executor, lambda: "retarget_margin_s" in recorder.diagnostics, 5.0)
        margins.append(float(recorder.diagnostics.get("retarget_margin_s", "nan")))
        spin_for(executor, 1.0)
    return latencies, after_acceptance, margins


def measure_goals(executor: SingleThreadedExecutor, subscriber: Node, recorder: Recorder, goals: int, crane: Crane,
                  blend: float = 0.5) -> dict[str, float]:
    """``goals`` re-targets through ~/retarget: acceptance time, blend span error and result delay (module doc)."""
    action = ActionClient(subscriber, Retarget, f"/{NODE}/retarget")
    if not action.wait_for_server(timeout_sec=10.0):
        raise RuntimeError("no ~/retarget action server")
    accepted, span_error, after_path = [], [], []
    for i in range(goals):
        sent = time.monotonic_ns()
        task = crane.task
        future = action.send_goal_async(Retarget.Goal(ellipse_a=crane.ellipse_a(0.1 if i % 2 == 0 else 0.0),
                                                      ellipse_b=task.ellipse_b, z_increment=task.z_increment,
                                                      z_rise_time=task.rise_time, blend_time=blend))
        if not spin_until(executor, future.done, 10.0) or not future.result().accepted:
            raise RuntimeError(f"goal {i} not accepted")
        accepted.append((time.monotonic_ns() - sent) / NS)
        result_future = future.result().get_result_async()
        if not spin_until(executor, result_future.done, 10.0 + blend):
            raise RuntimeError(f"no result of goal {i}")
        received = time.monotonic_ns()
        result = result_future.result().result
        if result.error_code != Retarget.Result.SUCCESSFUL:
            raise RuntimeError(f"goal {i}: {result.error_string}")
        path = result.path_stamp.sec * NS + result.path_stamp.nanosec
        blend_stamp = result.blend_stamp.sec * NS + result.blend_stamp.nanosec
        span_error.append((path - blend_stamp) / NS - blend)
        if not spin_until(executor, lambda p=path: recorder.stamps and recorder.stamps[-1] >= p, 5.0):
            raise RuntimeError(f"goal {i}: no sample stamped path_stamp received")
        first = next(j for j, s in enumerate(recorder.stamps) if s >= path)
        after_path.append((received - recorder.monotonic[first]) / NS)
        spin_for(executor, 0.5)
    action.destroy()
    return {"goal_accepted_max_ms": 1e3 * max(accepted), "goal_blend_span_error_max_ms": 1e3 * max(span_error),
            "goal_result_after_path_max_ms": 1e3 * max(after_path)}


def call(executor: SingleThreadedExecutor, client, request, timeout: float = 10.0):
    future = client.call_async(request)
    if not spin_until(executor, future.done, timeout):
        raise RuntimeError(f"no response to {request}")
    return future.result()


def command_smoothness(executor: SingleThreadedExecutor, subscriber: Node, client: AsyncParameterClient,
                       recorder: Recorder, ramp: float, crane: Crane) -> dict[str, float]:
    """Largest per-sample change of the slew's velocity in normal running and after each command."""
    pause = subscriber.create_client(SetBool, f"/{NODE}/pause")
    windows, margins = {}, {}

    def window(name: str, command) -> None:
        start = len(recorder.stamps)
        command()
        spin_for(executor, ramp + 0.5)
        windows[name] = (start, len(recorder.stamps))
        margin = recorder.diagnostics.get(f"{'speed_scaling' if name.startswith('speed') else name}_margin_s")
        margins[name] = float("nan") if margin is None else float(margin)

    windows["normal"] = (len(recorder.stamps), len(recorder.stamps))
    spin_for(executor, ramp + 0.5)
    windows["normal"] = (windows["normal"][0], len(recorder.stamps))
    window("pause", lambda: call(executor, pause, SetBool.Request(data=True)))
    spin_for(executor, 1.0)
    window("resume", lambda: call(executor, pause, SetBool.Request(data=False)))
    def set_parameter(name: str, value: float) -> None:
        spin_until(executor, client.set_parameters([Parameter(name, value=value)]).done, 10.0)

    window("speed_0.5", lambda: set_parameter("speed_scaling", 0.5))
    window("retarget", lambda: set_parameter("ellipse.a", crane.ellipse_a(0.05)))
    set_parameter("speed_scaling", 1.0)
    velocity = np.array(recorder.slew_velocity)
    return {**{f"dv_{name}_rad_s": float(np.max(np.abs(np.diff(velocity[a:b])))) for name, (a, b) in windows.items()},
            **{f"margin_{name}_ms": 1e3 * margin for name, margin in margins.items()}}


def flood(executor: SingleThreadedExecutor, client: AsyncParameterClient, recorder: Recorder, requests: int,
          rate: int, crane: Crane) -> dict[str, float]:
    """``requests`` random parameter requests at 50 Hz; then gaps, NaN, unanswered and a valid change (the
    values' ranges scaled to the crane's targets: the paper's ellipse.a 2.5-3.5 m, ellipse.b 1.6-2.4 m)."""
    rng = np.random.default_rng(7)
    a, b = crane.task.ellipse_a, crane.task.ellipse_b
    values = {"ellipse.a": (a * 2.5 / 3.0, a * 3.5 / 3.0, 40.0), "ellipse.b": (0.8 * b, 1.2 * b, -1.0),
              "z.increment": (0.0, 0.4, 9.0), "z.rise_time": (2.0, 8.0, 0.0), "speed_scaling": (0.3, 1.0, 2.0)}
    first = len(recorder.stamps)
    futures = []
    for i in range(requests):
        if rng.random() < 0.1:
            parameters = [Parameter("no_such_parameter", value=1.0)]
        else:
            names = rng.choice(list(values), size=rng.integers(1, 3), replace=False)
            parameters = []
            for name in names:
                low, high, invalid = values[name]
                value = invalid if rng.random() < 0.3 else float(rng.uniform(low, high))
                parameters.append(Parameter(str(name), value=float(value) if rng.random() < 0.8 else math.nan))
        futures.append(client.set_parameters_atomically(parameters) if i % 2 else client.set_parameters(parameters))
        spin_for(executor, 1.0 / 50.0)
    spin_until(executor, lambda: all(f.done() for f in futures), 120.0)
    unanswered = sum(not f.done() for f in futures)
    spin_for(executor, 2.0)
    check = client.set_parameters([Parameter("ellipse.a", value=a), Parameter("ellipse.b", value=b),
                                   Parameter("speed_scaling", value=1.0)])
    spin_until(executor, check.done, 30.0)
    spin_until(executor, lambda: float(recorder.diagnostics.get("target_ellipse_a_m", "nan")) == a, 10.0)
    stamps = np.array(recorder.stamps[first:])
    gaps = np.diff(stamps) > 2 * NS // rate
    return {"flood_requests": requests, "flood_unanswered": unanswered, "flood_gaps": int(gaps.sum()),
            "flood_non_finite": int(len(stamps) - sum(recorder.finite[first:])),
            "flood_valid_change_after": bool(check.done() and all(r.successful for r in check.result().results)
                                              and float(recorder.diagnostics.get("target_ellipse_a_m", "nan")) == a)}


def start_node(domain: int, parameters: list[str], crane: Crane) -> subprocess.Popen:
    """The reference node of ``crane`` in a process of its own on the ROS domain ``domain``, with the node
    ``parameters`` (``NAME:=VALUE``); its stderr piped."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    return subprocess.Popen([sys.executable, "-m", "crane_reference.ros.node", "--ros-args", *crane.node_parameters,
                             *(arg for parameter in parameters for arg in ("-p", parameter))],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


def probe_node(domain: int, name: str) -> tuple[rclpy.Context, Node, SingleThreadedExecutor]:
    """A node of this process on the ROS domain ``domain``, in a context of its own, with its executor."""
    os.environ.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    context = rclpy.Context()
    rclpy.init(context=context)
    node = Node(name, context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    return context, node, executor


def run(rate: int, duration: float, model: str, changes: int, domain: int, flood_requests: int,
        parameters: list[str], crane: Crane) -> dict[str, float]:
    node = start_node(domain, [f"publish_rate:={rate}", f"model:={model}", "status_period:=3600.0", *parameters],
                      crane)
    context, subscriber, executor = probe_node(domain, "bench_subscriber")
    recorder = Recorder(crane.slew)
    subscriber.create_subscription(JointState, "/crane_reference/joint_states", recorder.joint_state, 10000)
    subscriber.create_subscription(DiagnosticArray, "/diagnostics", recorder.diagnostic, 100)
    client = AsyncParameterClient(subscriber, NODE)
    try:
        if not spin_until(executor, lambda: recorder.stamps, 60.0):
            raise RuntimeError(f"no joint_states within 60 s: {node.stderr.read() if node.poll() is not None else ''}")
        spin_for(executor, WARM_UP)
        first, cpu0, threads0 = len(recorder.stamps), cpu_seconds(node.pid), thread_seconds(node.pid)
        t0 = time.monotonic()
        before = {k: float(recorder.diagnostics.get(k, 0)) for k in ("held_late", "stamp_leaps")}
        spin_for(executor, duration)
        wall, cpu = time.monotonic() - t0, np.subtract(cpu_seconds(node.pid), cpu0)
        threads = {name: 100.0 * (seconds - threads0.get(name, 0.0)) / wall
                   for name, seconds in thread_seconds(node.pid).items()}
        busiest = sorted(threads.items(), key=lambda item: -item[1])
        print(f"[threads] {rate} Hz, % of a core: " + ", ".join(f"{name} {share:.1f}" for name, share in busiest
                                                                if share >= 0.05))
        last = len(recorder.stamps)
        spin_until(executor, lambda: float(recorder.diagnostics.get("published", 0)) > 0, 2.0)
        late = {k: float(recorder.diagnostics.get(k, 0)) - before[k] for k in before}
        factors = [value for at, value in recorder.real_time_factors
                   if t0 * NS < at <= (t0 + wall) * NS and math.isfinite(value)]  # inf: nothing computed
        held = [held_late_now(executor, recorder)]  # after normal running, then after each kind of command
        latencies, after_acceptance, margins = (measure_latency(executor, client, recorder, changes, crane)
                                                if changes else ([float("nan")],) * 3)
        held.append(held_late_now(executor, recorder))
        goals = measure_goals(executor, subscriber, recorder, changes, crane) if changes else {}
        held.append(held_late_now(executor, recorder))
        smoothness = command_smoothness(executor, subscriber, client, recorder, 1.0, crane)
        held.append(held_late_now(executor, recorder))
        flooded = flood(executor, client, recorder, flood_requests, rate, crane) if flood_requests else {}
    finally:
        signalled = time.monotonic()
        node.send_signal(signal.SIGINT)
        _, stderr = node.communicate(timeout=30)
        exit_after = time.monotonic() - signalled
        executor.shutdown()
        subscriber.destroy_node()
        context.try_shutdown()
    received = np.array(recorder.monotonic[first:last]) / NS
    stamps = np.array(recorder.stamps[first:last])
    lag = (np.array(recorder.system[first:last]) - stamps) / NS
    periods = np.diff(received)
    error = np.abs(periods - 1.0 / rate)
    expected = (stamps[-1] - stamps[0]) * rate // NS + 1
    return {
        "rate_hz": rate, "achieved_hz": len(received) / wall, "period_std_ms": 1e3 * periods.std(),
        "period_error_p99_ms": 1e3 * np.percentile(error, 99), "period_error_max_ms": 1e3 * error.max(),
        "lag_mean_ms": 1e3 * lag.mean(), "lag_p99_ms": 1e3 * np.percentile(lag, 99),
        "missed": int(expected - len(stamps)), "held_late": int(late["held_late"]),
        "stamp_leaps": int(late["stamp_leaps"]),
        "cpu_percent": 100.0 * cpu.sum() / wall, "cpu_node_process_percent": 100.0 * cpu[0] / wall,
        "cpu_solver_process_percent": 100.0 * cpu[1] / wall,
        "real_time_factor": float(np.median(factors)) if factors else math.nan,
        "real_time_factor_min": min(factors, default=math.nan),
        "latency_median_ms": 1e3 * float(np.median(latencies)), "latency_max_ms": 1e3 * float(np.max(latencies)),
        "effect_after_acceptance_max_ms": 1e3 * float(np.max(after_acceptance)),
        "margin_retarget_min_ms": 1e3 * float(np.min(margins)),
        "held_late_commands": int(held[-1] - held[0]), "held_late_retargets": int(held[1] - held[0]),
        "held_late_goals": int(held[2] - held[1]), "held_late_stream_commands": int(held[3] - held[2]),
        **goals, **smoothness, **flooded, "exit_code": node.returncode, "exit_after_sigint_s": exit_after,
        "traceback": "Traceback" in stderr,
    }


SUBSCRIBER = """
import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from sensor_msgs.msg import JointState
from diagnostic_msgs.msg import DiagnosticArray
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
rclpy.init()
node = Node("bench_messages_subscriber")
node.create_subscription(JointState, "/bench_joint_states", lambda msg: None, 1000)
node.create_subscription(DiagnosticArray, "/bench_diagnostics", lambda msg: None, 100)
try:
    rclpy.spin(node)
except (KeyboardInterrupt, ExternalShutdownException):
    pass
except RuntimeError:  # a message taken while SIGINT shuts the context down fails to convert
    if rclpy.ok():
        raise
"""


TARGET_OVER_FLOOR, TARGET_STEP_ABA, TARGET_P99_MS, TARGET_MAX_MS_100HZ, TARGET_EXIT_S = 1.3, 8.3, 2.0, 5.0, 1.0


def hang_probe(model: str, domain: int, crane: Crane) -> dict[str, float]:
    """The solver's process stopped (SIGSTOP) while the node publishes at 100 Hz: the seconds until /diagnostics
    reports it at ERROR (``hang_error_after_s``), a deactivate's answer (``hang_deactivate_s``) and SIGINT to the
    node's exit (``hang_exit_after_sigint_s``)."""
    node = start_node(domain, ["publish_rate:=100", f"model:={model}"], crane)
    context, probe, executor = probe_node(domain, "bench_hang")
    recorder = Recorder(crane.slew)
    probe.create_subscription(JointState, f"/{NODE}/joint_states", recorder.joint_state, 1000)
    errors: list[float] = []
    error = rclpy_types().byte(Level.ERROR)
    probe.create_subscription(DiagnosticArray, "/diagnostics", lambda msg: errors.extend(
        time.monotonic() for status in msg.status if status.name.startswith(NODE) and status.level == error), 100)
    change_state = probe.create_client(ChangeState, f"/{NODE}/change_state")
    try:
        if not spin_until(executor, lambda: len(recorder.stamps) > 100, 60.0):
            raise RuntimeError("no joint_states within 60 s")
        solver = descendants(node.pid)[1]
        os.kill(solver, signal.SIGSTOP)
        stopped = time.monotonic()
        if not spin_until(executor, lambda: errors, 10.0):
            raise RuntimeError("no ERROR in /diagnostics within 10 s of the solver's stop")
        error_after = errors[0] - stopped
        asked = time.monotonic()
        response = call(executor, change_state, ChangeState.Request(transition=Transition(
            id=Transition.TRANSITION_DEACTIVATE)), timeout=30.0)
        deactivated = time.monotonic() - asked
    finally:
        signalled = time.monotonic()
        node.send_signal(signal.SIGINT)
        node.communicate(timeout=30)
        exit_after = time.monotonic() - signalled
        executor.shutdown()
        probe.destroy_node()
        context.try_shutdown()
    return {"hang_error_after_s": error_after, "hang_deactivate_s": deactivated,
            "hang_deactivate_success": bool(response.success), "hang_exit_after_sigint_s": exit_after,
            "hang_exit_code": node.returncode}


def message_costs(model: str, domain: int, rates: list[int], details: bool, config: str | None = None
                  ) -> dict[int, float]:
    """This process's CPU share [%] when it only publishes the node's messages at each of ``rates``, with a
    subscriber in another process on the joint states and the diagnostics, as the node's run has (the floor of the
    node's publishing in rclpy: no stream, no clock, no schedule): ~/joint_states and ~/end_effector_pose as rows
    of a batch serialized at once, each stamped as it goes out, ~/reference_preview (built once, the default
    preview) at the default preview rate and /diagnostics (built once, with the node's keys) once a second; with
    ``details``, print the publisher's per-sample costs of the first two alone and with the subscriber and that
    share both for the serialized messages and for message objects, and the markers' cost."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    os.environ.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    context = rclpy.Context()
    rclpy.init(context=context)
    node = Node("bench_messages", context=context)
    subscriber = None
    try:
        types, stream = rclpy_types(), ReferenceStream(load_config(config), model)
        stream.compute(0.1)
        sample, names = stream.sample(0.05), list(stream.joint_names)
        joints = node.create_publisher(JointState, "/bench_joint_states", 10)
        poses = node.create_publisher(PoseStamped, "/bench_pose", 10)
        previews = node.create_publisher(JointTrajectory, "/bench_preview", 10)
        statuses = node.create_publisher(DiagnosticArray, "/bench_diagnostics", 10)
        batch = ReferenceRows.repeated(sample, 1000)  # a batch of frames, serialized at once as the node does
        joint_rows = SerializedJointState(serialize_message(messages.joint_state(types, 0, names, sample))).rows(batch)
        pose_rows = SerializedPose(serialize_message(messages.end_effector_pose(types, 0, "world", sample))).rows(batch)
        kept = {"joint": None, "pose": None}
        preview_joints, points = list(stream.model.actuated_joints), SPECS["preview.points"].default
        preview = messages.reference_preview(
            types, 0, "world", preview_joints, [names.index(j) for j in preview_joints],
            messages.preview_offsets(SPECS["preview.horizon"].default, points - 1), [sample] * points)
        status = messages.diagnostics(types, 0, NODE, NODE, 0, "RUNNING", messages.diagnostic_values(
            "RUNNING", sample, 10.0, max(rates), float(max(rates)), Counters().as_dict(), stream.targets, 1.0, "",
            {"frames_ready": 0, "blend_time_s": "2"}))

        def one_sample(k: int) -> None:
            """As the node publishes: a row of a batch serialized at once, stamped and published as bytes."""
            joints.publish(joint_rows.stamped(k % len(joint_rows), k))
            poses.publish(pose_rows.stamped(k % len(pose_rows), k))

        def one_message_object(k: int) -> None:
            """As the node published before: message objects filled again and converted by rclpy."""
            kept["joint"] = messages.joint_state(types, k, names, sample, kept["joint"])
            kept["pose"] = messages.end_effector_pose(types, k, "world", sample, kept["pose"])
            joints.publish(kept["joint"])
            poses.publish(kept["pose"])

        def per_sample(publish: Callable[[int], None], count: int = 5000) -> tuple[float, float]:
            """Wall and CPU time (this process, every thread) per sample, back to back."""
            wall, cpu = time.perf_counter(), time.process_time()
            for k in range(count):
                publish(k)
            return (time.perf_counter() - wall) / count, (time.process_time() - cpu) / count

        def paced(rate: int, publish: Callable[[int], None], seconds: float = 5.0) -> float:
            """CPU share of this process [%] publishing samples at ``rate`` Hz (sleeping until each period's
            start), the preview every round(rate / preview.rate) samples and /diagnostics once a second."""
            start, cpu = time.monotonic(), time.process_time()
            k, decimation = 0, max(1, round(rate / SPECS["preview.rate"].default))
            while (now := time.monotonic()) - start < seconds:
                publish(k)
                if k % decimation == 0:
                    previews.publish(preview)
                if k % rate == 0:
                    statuses.publish(status)
                k += 1
                time.sleep(max(0.0, start + k / rate - now))
            return 100.0 * (time.process_time() - cpu) / (time.monotonic() - start)

        ways = {"serialized (the node)": one_sample, "message objects": one_message_object}
        alone = {way: per_sample(publish) for way, publish in ways.items()} if details else {}
        subscriber = subprocess.Popen([sys.executable, "-c", SUBSCRIBER], env=env)
        if not spin_until_matched(joints, statuses, timeout=30.0):
            raise RuntimeError("the subscriber process did not match the bench topics within 30 s")
        if not details:
            return {rate: paced(rate, one_sample) for rate in rates}
        node_floors = {}
        for way, publish in ways.items():
            (alone_wall, alone_cpu), (with_wall, with_cpu) = alone[way], per_sample(publish)
            floors = {rate: paced(rate, publish) for rate in rates}
            node_floors = node_floors or floors
            print(f"[messages] {way}: joint_states and pose stamped and published, per sample: alone "
                  f"{alone_wall * 1e6:.1f} us (CPU {alone_cpu * 1e6:.1f} us), with a subscriber of the joint states in "
                  f"another process {with_wall * 1e6:.1f} us (CPU {with_cpu * 1e6:.1f} us, every thread of this "
                  "process)")
            print(f"[messages] {way}: CPU of a process that only publishes them, paced (floor of the node's "
                  "publishing): " + ", ".join(f"{share:.1f} % at {rate} Hz" for rate, share in floors.items()))
        ellipse = messages.points(types, messages.ellipse_points(3.0, 2.0, 2.3))  # kept, as the node does
        trail = messages.points(types, np.tile(sample.ee_position, (TRAIL_POINTS, 1)))
        markers = node.create_publisher(MarkerArray, "/bench_markers", 10)
        start = time.perf_counter()
        for _ in range(50):
            markers.publish(messages.markers(types, 0, "world", ellipse, trail))
        per_markers = (time.perf_counter() - start) / 50
        print(f"[messages] ~/markers built and published with {TRAIL_POINTS} trail points: {per_markers * 1e3:.2f} ms "
              f"(at {MARKER_RATE:g} Hz while subscribed)")
        return node_floors
    finally:
        if subscriber is not None:
            subscriber.send_signal(signal.SIGINT)
            try:
                subscriber.wait(timeout=10)
            except subprocess.TimeoutExpired:  # a helper that hangs on its way out must not end the benchmark
                print("[messages] the subscriber did not exit on SIGINT within 10 s: killed")
                subscriber.kill()
                subscriber.wait()
        node.destroy_node()
        context.try_shutdown()


def steps_alone_percent(model: str, step: float, seconds: float = 5.0, paced: bool = False,
                        config: str | None = None) -> float:
    """CPU share [%] of the integrator's compiled steps alone at ``step`` [s] for motion in real time (compiled
    runs of 0.25 s from rest, only each run's last row evaluated): the least a solver of this motion spends.
    ``paced``: runs of the node's REFILL seconds, each when its motion is due in wall time, as the node's solver
    computes (information beside the floor: this machine spends more on the same runs after idle gaps)."""
    scenario = Scenario(load_config(config), model)
    run_times(scenario, step, 0.25, every_row=False)  # kernels loaded
    cpu = time.process_time()
    run_times(scenario, step, seconds, every_row=False, chunk=REFILL if paced else 0.25, paced=paced)
    return 100.0 * (time.process_time() - cpu) / seconds


def floor_parts(model: str, domain: int, rate: int, step: float, config: str | None = None) -> tuple[float, float]:
    """The two parts of the node's floor at ``rate`` Hz [% of a core]: a paced process that only publishes the
    node's serialized messages (:func:`message_costs`) and the compiled steps alone (:func:`steps_alone_percent`).
    Measured before and after each node run: this machine's speed drifts within minutes."""
    return (message_costs(model, domain, [rate], False, config)[rate],
            steps_alone_percent(model, step, config=config))


def node_step(parameters: list[str]) -> float:
    """The node's integrator step [s]: ``integrator.step`` if given among ``parameters``, else the default."""
    given = [float(p.split(":=", 1)[1]) for p in parameters if p.split(":=", 1)[0] == "integrator.step"]
    return given[-1] if given else ONLINE_STEP


def spin_until_matched(*publishers: Any, timeout: float) -> bool:
    """Wait until every publisher has a subscriber (False after ``timeout`` seconds)."""
    deadline = time.monotonic() + timeout
    while any(p.get_subscription_count() == 0 for p in publishers):
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=30.0, help="measured seconds per rate (default 30)")
    parser.add_argument("--rates", type=int, nargs="+", default=[100, 500, 1000])
    parser.add_argument("--model", choices=("flexible", "rigid"), default="flexible")
    parser.add_argument("--config", help="crane file (default: the packaged crane, the paper's)")
    parser.add_argument("--changes", type=int, default=5, help="parameter changes for the latency (default 5)")
    parser.add_argument("--domain-id", type=int, default=os.getpid() % 100 + 1)
    parser.add_argument("--message-costs", action="store_true", help="first print the publisher's message costs")
    parser.add_argument("--flood", type=int, default=0, metavar="N", help="N random parameter requests at 50 Hz")
    parser.add_argument("--hang", action="store_true", help="first the hung-solver probe (SIGSTOP): the time to "
                        "ERROR, a deactivate's answer and SIGINT to exit")
    parser.add_argument("--busy", type=int, default=0, metavar="N",
                        help="N processes that only spin beside each node run (a busy machine)")
    parser.add_argument("-p", "--parameter", action="append", default=[], metavar="NAME:=VALUE",
                        help="a further node parameter, e.g. -p command_lead:=0.05 (repeatable)")
    args = parser.parse_args()
    if args.message_costs:
        message_costs(args.model, args.domain_id, args.rates, True, args.config)
    step = node_step(args.parameter)
    scenario = Scenario(load_config(args.config), args.model)
    crane = Crane.of(args.config, args.model)
    if args.hang:
        probe = hang_probe(args.model, args.domain_id, crane)
        print("[hang] " + ", ".join(f"{name} {value:.3f}" if isinstance(value, float) else f"{name} {value}"
                                    for name, value in probe.items()))
    rows = []
    for rate in args.rates:
        before, aba_before = floor_parts(args.model, args.domain_id, rate, step, args.config), aba_time(scenario)
        busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.busy)]
        try:
            row = run(rate, args.duration, args.model, args.changes, args.domain_id, args.flood, args.parameter, crane)
        finally:
            for process in busy:
                process.kill()
                process.wait()
        after, aba_after = floor_parts(args.model, args.domain_id, rate, step, args.config), aba_time(scenario)
        publishing, steps = ((a + b) / 2 for a, b in zip(before, after, strict=True))
        aba = (aba_before + aba_after) / 2
        print(f"[floor] {rate} Hz: publish-only {before[0]:.1f} / {after[0]:.1f} %, compiled steps alone at "
              f"h = {step * 1e3:g} ms {before[1]:.1f} / {after[1]:.1f} % (before / after the node's run); the same "
              f"steps paced in {REFILL:g} s runs as the node's solver computes them: "
              f"{steps_alone_percent(args.model, step, paced=True, config=args.config):.1f} % (not part of the floor)")
        row.update(floor_publish_percent=publishing, floor_steps_percent=steps, floor_percent=publishing + steps,
                   node_over_publish_floor=row["cpu_node_process_percent"] / publishing,
                   solver_over_steps=row["cpu_solver_process_percent"] / steps,
                   cpu_over_floor=row["cpu_percent"] / (publishing + steps),
                   aba_us=1e6 * aba, steps_alone_step_aba=steps / 100.0 * step / aba,
                   solver_step_aba=step / (row["real_time_factor"] * aba))
        rows.append(row)
    print_table(f"crane_reference node, {scenario.params.name} {args.model} model ({scenario.model.dof} DOF), "
                f"{args.duration:g} s per rate, {os.cpu_count()} CPUs"
                + (f", {args.busy} busy processes beside it" if args.busy else ""), rows)
    print(f"targets: cpu_over_floor <= {TARGET_OVER_FLOOR} (the median of 5 runs), solver_step_aba <= "
          f"{TARGET_STEP_ABA}, period_error_p99_ms <= {TARGET_P99_MS}, period_error_max_ms <= {TARGET_MAX_MS_100HZ} "
          f"at 100 Hz, held_late_commands 0, exit_after_sigint_s <= {TARGET_EXIT_S}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

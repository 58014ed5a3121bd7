"""The closed loop over ROS (issue 31's figures): the plant node in real time and the loop in lock-step.

    python benchmarks/bench_loop.py [--only tick realtime lockstep executors] [--duration 60]
                                    [--lockstep-duration 5] [--rate 1000]

1. [tick] In this process: the plant's control period (PlantServer.tick: the compiled period and the state), its
   state alone, the same periods in one compiled call (Plant.follow) and filling its three serialized messages,
   per period (the best of 5 blocks of 400 periods), as a multiple of one Pinocchio ABA call on the same chain
   measured in this run; the CPU share [%] of those periods alone at ``--rate``.
2. [realtime] The reference node, the plant (``clock_mode`` realtime, ``--rate``) and the example controller as
   processes (``crane-reference loop``'s parameters), for a window of ``--duration`` s of wall time that opens once
   the plant's diagnostics show its time running: between the plant's diagnostics before and after the window
   (by their stamps), its periods run and missed (/diagnostics ``ticks`` and ``missed_ticks``, see
   control/pacing.py) and how far its time advanced; in the window, the commands answered and the
   command-to-state latency (in this process: from a command's arrival to the arrival of the next state, which
   is the first under it; p50, p99, largest; this process takes them unread with the EventsExecutor, to leave the
   cores to the loop), the plant process's CPU share beside its floor measured in this
   run: a paced process that only publishes the plant's three serialized messages at the rate (a subscriber in
   another process) plus the periods alone ([tick]); the CPU share of every process of the loop (the reference
   node with its solver's process) and of this one.
3. [lockstep] The three in lock-step (as ``crane-reference loop``) for ``--lockstep-duration`` s of the plant's
   time after its first 0.1 s: seconds of the plant per second of wall time, and each process's CPU share (the
   reference node with its solver's process).
4. [executors] What taking a topic costs with rclpy's executors: this process takes the commands a paced process
   publishes at ``--rate`` (std_msgs/Float64MultiArray of three efforts) for 10 s, with the SingleThreadedExecutor
   and with the EventsExecutor (``rclpy.experimental``) in turn: its CPU share [%] with each.

ROS_DOMAIN_ID is this process's (set it apart from other ROS traffic), the next one for [lockstep]; discovery on
localhost.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import subprocess
import sys
import time
from contextlib import ExitStack, suppress

import numpy as np
import rclpy
from common import aba_time, process_cpu_seconds
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, Vector3Stamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from crane_reference.control.controller import JointController, JointGains
from crane_reference.control.plant_server import PlantServer, PlantSettings
from crane_reference.interface import messages
from crane_reference.interface.bringup import PLANT_NODE, closed_loop_parameters
from crane_reference.interface.serialized import SerializedJointState, SerializedPose, SerializedVector3
from crane_reference.model.config import load_config
from crane_reference.motion.simulation import Scenario
from crane_reference.ros.loop import bring_up, closed_loop_processes
from crane_reference.ros.message_types import rclpy_types

SUBSCRIBER = """
import signal
import threading
import rclpy
from geometry_msgs.msg import PoseStamped, Vector3Stamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState
stop = threading.Event()
signal.signal(signal.SIGINT, lambda *_: stop.set())
rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
node = Node("bench_loop_subscriber")
for kind, topic in ((JointState, "/bench/joint_states"), (PoseStamped, "/bench/pose"),
                    (Vector3Stamped, "/bench/tip")):
    node.create_subscription(kind, topic, lambda msg: None, 1000)
executor = SingleThreadedExecutor()
executor.add_node(node)
while not stop.is_set():
    executor.spin_once(timeout_sec=0.1)
node.destroy_node()
rclpy.try_shutdown()
"""


PUBLISHER = """
import sys
import time
import rclpy
from std_msgs.msg import Float64MultiArray
rclpy.init()
node = rclpy.create_node("bench_loop_commands")
publisher = node.create_publisher(Float64MultiArray, "/bench/commands", 10)
while publisher.get_subscription_count() == 0:
    time.sleep(0.01)
rate, seconds = float(sys.argv[1]), float(sys.argv[2])
message = Float64MultiArray(data=[0.0, 0.0, 0.0])
start, k = time.monotonic(), 0
while (now := time.monotonic()) - start < seconds:
    publisher.publish(message)
    k += 1
    time.sleep(max(0.0, start + k / rate - now))
node.destroy_node()
rclpy.try_shutdown()
"""


def writers(server: PlantServer) -> tuple:
    """The plant node's three serialized-message writers for ``server``'s state."""
    types, state = rclpy_types(), server.state()
    return (SerializedJointState(serialize_message(messages.joint_state(types, 0, server.published, state))),
            SerializedPose(serialize_message(messages.end_effector_pose(types, 0, "world", state))),
            SerializedVector3(serialize_message(messages.tip_deflection(types, 0, server.deflection_frame,
                                                                        state.deflection))))


def tick_costs(rate: int, blocks: int = 5, periods: int = 400) -> float:
    """[tick]: prints the per-period costs (each the best of ``blocks`` blocks of ``periods`` periods, as ABA is
    timed); returns the CPU share [%] of the periods alone at ``rate``."""
    params = load_config()
    server = PlantServer(params, PlantSettings(rate=float(rate), all_coordinates=True))
    joint, pose, tip = writers(server)
    state = server.tick(0.0)
    tick = read = fill = math.inf
    for _ in range(blocks):
        start = time.perf_counter()
        for _ in range(periods):
            state = server.tick(0.0)
        tick = min(tick, (time.perf_counter() - start) / periods)
        start = time.perf_counter()
        for _ in range(periods):
            server.state()
        read = min(read, (time.perf_counter() - start) / periods)
        start = time.perf_counter()
        for k in range(periods):
            joint.fill(k, state), pose.fill(k, state), tip.fill(k, state.deflection)
        fill = min(fill, (time.perf_counter() - start) / periods)
    compiled = follow_cost(server, periods)
    aba = aba_time(Scenario(params, "flexible"))
    print(f"[tick] the same periods in one compiled call (Plant.follow of {periods} ticks under the held efforts): "
          f"{compiled * 1e6:.0f} us = {compiled / aba:.1f} ABA per period")
    print(f"[tick] a control period (PlantServer.tick) {tick * 1e6:.0f} us = {tick / aba:.1f} ABA, of which its "
          f"state (PlantServer.state) {read * 1e6:.1f} us = {read / aba:.1f} ABA; filling the three messages "
          f"{fill * 1e6:.1f} us; Pinocchio ABA {aba * 1e6:.2f} us")
    share = 100.0 * tick * rate
    print(f"[tick] the periods alone at {rate} Hz: {share:.1f} % of a core")
    return share


def follow_cost(server: PlantServer, periods: int, blocks: int = 5) -> float:
    """[s] per period of ``server``'s plant (at its start) stepping ``periods`` periods in one compiled call under
    the efforts that hold it (:meth:`Plant.follow`: a controller with no gain and these efforts as its
    feedforward), the best of ``blocks`` calls."""
    plant, period = server.plant, server.settings.period
    hold = np.tile(server.hold_efforts(server.q), (periods + 1, 1))
    zeros = np.zeros((periods, hold.shape[1]))
    best = math.inf
    for _ in range(blocks):
        controller = JointController([JointGains(0.0, 0.0)] * hold.shape[1], period)
        ends = plant.t + period * np.arange(1, periods + 1)
        start = time.perf_counter()
        plant.follow(ends, zeros, zeros, hold[:-1], hold, controller)
        best = min(best, (time.perf_counter() - start) / periods)
    return best


def publish_floor(rate: int, seconds: float = 5.0) -> float:
    """CPU share [%] of this process publishing the plant's three serialized messages at ``rate``, paced, with a
    subscriber in another process."""
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("bench_loop_floor", context=context)
    subscriber = subprocess.Popen([sys.executable, "-c", SUBSCRIBER], env=os.environ)
    try:
        server = PlantServer(load_config(), PlantSettings(rate=float(rate), all_coordinates=True))
        state, (joint, pose, tip) = server.state(), writers(server)
        publishers = [node.create_publisher(kind, topic, 10) for kind, topic in (
            (JointState, "/bench/joint_states"), (PoseStamped, "/bench/pose"), (Vector3Stamped, "/bench/tip"))]
        deadline = time.monotonic() + 30.0
        while any(p.get_subscription_count() == 0 for p in publishers) and time.monotonic() < deadline:
            time.sleep(0.05)
        start, cpu, k = time.monotonic(), time.process_time(), 0
        while (now := time.monotonic()) - start < seconds:
            publishers[0].publish(joint.fill(k, state))
            publishers[1].publish(pose.fill(k, state))
            publishers[2].publish(tip.fill(k, state.deflection))
            k += 1
            time.sleep(max(0.0, start + k / rate - now))
        return 100.0 * (time.process_time() - cpu) / (time.monotonic() - start)
    finally:
        subscriber.send_signal(signal.SIGINT)
        subscriber.wait(timeout=10)
        node.destroy_node()
        context.try_shutdown()


def realtime(rate: int, duration: float, periods_share: float) -> None:
    """[realtime]: prints the plant's periods run and missed, latency and CPU beside its floor."""
    floor = publish_floor(rate)
    parameters = closed_loop_parameters("realtime", rate)
    context = rclpy.Context()
    rclpy.init(context=context)
    states, commands, diagnostics = [], [], []
    try:
        with closed_loop_processes(parameters) as processes:
            node = rclpy.create_node("bench_loop_listener", context=context)
            node.create_subscription(JointState, f"/{PLANT_NODE}/joint_states",
                                     lambda msg: states.append(time.monotonic()), 10000, raw=True)
            node.create_subscription(Float64MultiArray, f"/{PLANT_NODE}/commands",
                                     lambda msg: commands.append(time.monotonic()), 10000, raw=True)
            node.create_subscription(DiagnosticArray, "/diagnostics", lambda msg: diagnostics.extend(
                dict({kv.key: kv.value for kv in status.values}, stamp=msg.header.stamp.sec + msg.header.stamp.nanosec
                     * 1e-9, level=int.from_bytes(status.level, "little"), message=status.message)
                for status in msg.status if status.name.startswith(f"{PLANT_NODE}:")), 100)
            starting = SingleThreadedExecutor(context=context)
            starting.add_node(node)
            bring_up(starting, node, processes, parameters, time.monotonic() + 600.0)
            starting.remove_node(node)
            from rclpy.experimental import EventsExecutor  # rclpy >= 7.1.4

            executor = EventsExecutor(context=context)  # this listener takes as little of the cores as it can
            executor.add_node(node)
            deadline = time.monotonic() + 600.0
            # the loop closed: the plant took commands (its time runs) and its diagnostics say so
            while ((len(commands) < 100 or not diagnostics or int(diagnostics[-1]["ticks"]) == 0)
                   and time.monotonic() < deadline):
                executor.spin_once(timeout_sec=0.05)
            if not diagnostics or int(diagnostics[-1]["ticks"]) == 0:
                raise RuntimeError("the plant did not run within 600 s of its start (no diagnostics with ticks)")
            before = diagnostics[-1]
            states.clear(), commands.clear()
            pids = {name: [process.pid, *descendants(process.pid)] for name, process in processes.items()}
            cpu = {name: sum(map(process_cpu_seconds, group)) for name, group in pids.items()}
            cpu["this listener"] = time.process_time()
            start = time.monotonic()
            while time.monotonic() - start < duration:
                executor.spin_once(timeout_sec=0.05)
            wall = time.monotonic() - start
            now = {name: sum(map(process_cpu_seconds, group)) for name, group in pids.items()}
            now["this listener"] = time.process_time()
            shares = {name: 100.0 * (now[name] - cpu[name]) / wall for name in cpu}
            ended = time.time()  # the plant's diagnostics are stamped with its node's (system) clock
            while diagnostics[-1]["stamp"] < ended and time.monotonic() - start < duration + 10.0:
                executor.spin_once(timeout_sec=0.05)  # the first diagnostics after the window
            node.destroy_node()
    finally:
        context.try_shutdown()
    after = diagnostics[-1]
    advanced = float(after["time_s"]) - float(before["time_s"])
    between = after["stamp"] - before["stamp"]
    missed = int(after["missed_ticks"]) - int(before["missed_ticks"])
    ticks = int(after["ticks"]) - int(before["ticks"])
    arrivals = np.array(states)
    following = np.searchsorted(arrivals, commands)
    latency = np.array([arrivals[i] - c for i, c in zip(following, commands, strict=True) if i < arrivals.size])
    print(f"[realtime] {rate} Hz: {ticks} periods run and {missed} missed in the {between:.2f} s between the plant's "
          f"diagnostics before and after the {wall:.0f} s window (by their stamps), the plant's time at "
          f"{advanced / between:.3f} of real time; in the window {len(commands)} commands answered, command-to-state "
          f"latency p50 {np.median(latency) * 1e3:.2f} ms, p99 {np.quantile(latency, 0.99) * 1e3:.2f} ms, largest "
          f"{latency.max() * 1e3:.2f} ms")
    if ticks + missed < round(between * rate) - 2:  # the periods due: the plant stopped running them
        said = {(d["level"], d["message"]) for d in diagnostics if d["stamp"] >= before["stamp"] and d["level"]}
        print("[realtime] the plant did not run every period due; its diagnostics in the window said: "
              + ("; ".join(f"level {level}: {message}" for level, message in sorted(said)) or "nothing but OK"))
    share = shares[PLANT_NODE]
    print(f"[realtime] plant process CPU {share:.1f} % of a core; floor {floor + periods_share:.1f} % (publishing "
          f"only {floor:.1f} % + the periods alone {periods_share:.1f} %), ratio {share / (floor + periods_share):.2f}")
    print("[realtime] CPU of each process [% of a core]: " + ", ".join(f"{name} {value:.0f}" for name, value in
                                                                       shares.items())
          + f"; {sum(shares.values()):.0f} in all of {100 * os.cpu_count()}")


def lockstep(rate: int, duration: float) -> None:
    """[lockstep]: prints the plant's seconds per wall second and each process's CPU share."""
    os.environ["ROS_DOMAIN_ID"] = str(int(os.environ["ROS_DOMAIN_ID"]) % 100 + 1)  # apart from [realtime]'s nodes
    context = rclpy.Context()
    rclpy.init(context=context)
    stamps: list[int] = []
    try:
        with closed_loop_processes(closed_loop_parameters("lockstep", rate)) as processes:
            node = rclpy.create_node("bench_loop_listener", context=context)
            node.create_subscription(JointState, f"/{PLANT_NODE}/joint_states", lambda msg: stamps.append(
                msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec), 10000)
            executor = SingleThreadedExecutor(context=context)
            executor.add_node(node)
            deadline = time.monotonic() + 600.0
            while (not stamps or stamps[-1] - stamps[0] < 10**8) and time.monotonic() < deadline:  # 0.1 s run
                executor.spin_once(timeout_sec=0.05)
            pids = {name: [process.pid, *descendants(process.pid)] for name, process in processes.items()}
            cpu = {name: sum(map(process_cpu_seconds, group)) for name, group in pids.items()}
            first, start = stamps[-1], time.monotonic()
            while stamps[-1] - first < round(duration * 10**9):
                count = len(stamps)
                executor.spin_once(timeout_sec=0.05)
                if len(stamps) == count and time.monotonic() - start > 60.0 + 100.0 * duration:
                    raise RuntimeError(f"the loop stalled at the plant's {(stamps[-1] - stamps[0]) / 1e9:.3f} s")
            wall = time.monotonic() - start
            shares = {name: 100.0 * (sum(map(process_cpu_seconds, group)) - cpu[name]) / wall
                      for name, group in pids.items()}
            simulated = (stamps[-1] - first) / 10**9
            node.destroy_node()
    finally:
        context.try_shutdown()
    print(f"[lockstep] {simulated:g} s of the plant at {rate} Hz in {wall:.1f} s of wall time: "
          f"{simulated / wall:.3f} s of the plant per s of wall time; CPU " +
          ", ".join(f"{name} {share:.0f} %" for name, share in shares.items()) + " of a core")


def executors(rate: int, seconds: float = 10.0) -> None:
    """[executors]: prints this process's CPU share taking ``rate`` Hz of commands with each executor."""
    from rclpy.experimental import EventsExecutor  # rclpy >= 7.1.4

    for name, make in (("SingleThreadedExecutor", lambda context: SingleThreadedExecutor(context=context)),
                       ("EventsExecutor", lambda context: EventsExecutor(context=context))):
        context = rclpy.Context()
        rclpy.init(context=context)
        received: list[Float64MultiArray] = []
        with ExitStack() as stack:
            stack.callback(context.try_shutdown)
            node = rclpy.create_node("bench_loop_executor", context=context)
            node.create_subscription(Float64MultiArray, "/bench/commands", received.append, 1000)
            executor = make(context)
            executor.add_node(node)
            publisher = subprocess.Popen([sys.executable, "-c", PUBLISHER, str(rate), str(seconds)])
            stack.callback(publisher.kill)
            deadline = time.monotonic() + 30.0
            while not received and time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.05)
            count, cpu, start = len(received), time.process_time(), time.monotonic()
            while publisher.poll() is None:
                executor.spin_once(timeout_sec=0.05)
            share = 100.0 * (time.process_time() - cpu) / (time.monotonic() - start)
            print(f"[executors] {name}: {len(received) - count} commands taken at {rate} Hz, {share:.1f} % of a core")
            node.destroy_node()


def descendants(pid: int) -> list[int]:
    """The processes started by ``pid`` (the reference node's solver process), from /proc."""
    children = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            with suppress(OSError), open(f"/proc/{entry}/stat", encoding="ascii") as stat:
                if int(stat.read().rsplit(")", 1)[1].split()[1]) == pid:
                    children += [int(entry), *descendants(int(entry))]
    return children


SECTIONS = ("tick", "realtime", "lockstep", "executors")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--only", nargs="+", choices=SECTIONS, default=SECTIONS)
    parser.add_argument("--duration", type=float, default=60.0, help="[realtime] wall seconds")
    parser.add_argument("--lockstep-duration", type=float, default=5.0, help="[lockstep] seconds of the plant")
    parser.add_argument("--rate", type=int, default=1000, help="control rate [Hz]")
    args = parser.parse_args()
    os.environ.setdefault("ROS_DOMAIN_ID", str(os.getpid() % 100 + 1))
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    print(f"# bench_loop {time.strftime('%Y-%m-%d %H:%M')} on {os.cpu_count()} cores")
    share = tick_costs(args.rate) if "tick" in args.only or "realtime" in args.only else 0.0
    if "realtime" in args.only:
        realtime(args.rate, args.duration, share)
    if "lockstep" in args.only:
        lockstep(args.rate, args.lockstep_duration)
    if "executors" in args.only:
        executors(args.rate)
    return 0


if __name__ == "__main__":
    sys.exit(main())

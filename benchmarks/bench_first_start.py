"""Time to the first results on a fresh machine (issue 10's "no compile wait"): with an empty numba cache
(a new temporary XDG_CACHE_HOME) it times, as a user would run them,

1. ``crane-reference compile`` (what ``scripts/setup.sh`` runs last),
2. ``crane-reference simulate --model flexible --duration 0.5`` (process start to exit, and the kernels'
   ready time it prints),
3. ``python -m crane_reference.ros.node``: process start to the first ``~/joint_states`` received.

Run: ``.venv/bin/python benchmarks/bench_first_start.py`` (about two minutes: the compilation).
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import tempfile
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import JointState

BIN = os.path.dirname(sys.executable)


def timed(command: list[str], env: dict[str, str]) -> tuple[float, str]:
    start = time.perf_counter()
    result = subprocess.run(command, env=env, capture_output=True, text=True, check=True)
    return time.perf_counter() - start, result.stdout


def first_joint_state(env: dict[str, str]) -> float:
    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    context = rclpy.Context()
    rclpy.init(context=context)
    probe = Node("first_start_probe", context=context)
    received: list[JointState] = []
    probe.create_subscription(JointState, "/crane_reference/joint_states", received.append, 10)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(probe)
    start = time.perf_counter()
    node = subprocess.Popen([sys.executable, "-m", "crane_reference.ros.node"], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        while not received and time.perf_counter() - start < 600:
            executor.spin_once(timeout_sec=0.02)
        return time.perf_counter() - start
    finally:
        node.send_signal(signal.SIGINT)
        node.wait(timeout=30)
        executor.shutdown()
        probe.destroy_node()
        context.try_shutdown()


def main() -> int:
    with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as out:
        env = dict(os.environ, XDG_CACHE_HOME=cache, ROS_DOMAIN_ID=str(os.getpid() % 100 + 1),
                   ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
        env.pop("NUMBA_CACHE_DIR", None)
        compile_s, _ = timed([f"{BIN}/crane-reference", "compile"], env)
        simulate_s, printed = timed([f"{BIN}/crane-reference", "simulate", "--model", "flexible", "--duration",
                                     "0.5", "--out", out], env)
        ready = re.search(r"kernels ready in ([0-9.]+) s", printed)
        node_s = first_joint_state(env)
    print(f"[first-start] empty cache: crane-reference compile {compile_s:.1f} s (the end of scripts/setup.sh)")
    print(f"[first-start] then: simulate (0.5 s, flexible) {simulate_s:.1f} s from process start to exit "
          f"(kernels ready in {ready.group(1) if ready else '?'} s); node: first ~/joint_states {node_s:.1f} s "
          "after process start")
    return 0


if __name__ == "__main__":
    sys.exit(main())

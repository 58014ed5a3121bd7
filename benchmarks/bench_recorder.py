"""Benchmark of `crane-reference record` recording the live node: completeness, throughput and CPU.

For each storage (default mcap and sqlite3) and publish rate (default 100 and 1000 Hz) it starts
``python -m crane_reference.ros.node`` in its own process (an isolated ROS domain, localhost only), then
``python -m crane_reference.cli record -o DIR --storage S`` with the node's default topics, lets it
record for ``--duration`` seconds and stops it with SIGINT (the Ctrl-C path).  From the bag, read back
with rosbags:

* joint_states messages in the bag, and how many stamps are missing between the first and last one
  (the node stamps sample k with start + k / rate, so the expected count follows from the stamps);
* end-effector poses and diagnostics in the bag;
* bag size and write throughput (messages and MB per second of recording);
* CPU share of the recorder process (user + system time / wall time, 100 % = one core);
* the recorder's exit code, whether it printed a traceback, and whether the bag opens;
* when the first message came: after the recorder started (its own report, ``first_message_s``) and after its
  process was launched (``launch_to_first_message_s``, with Python's start and the imports).

Run: ``.venv/bin/python benchmarks/bench_recorder.py [--duration 20] [--rates 100 1000] [--storages mcap sqlite3]``.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from common import print_table, process_cpu_seconds
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.typesys import Stores, get_typestore

from crane_reference.interface.reference_bag import DIAGNOSTICS, END_EFFECTOR_POSE, JOINT_STATES

NS = 10**9
START_TIMEOUT = 60.0  # [s] for the node to come up and the recorder to see its topics


def bag_contents(path: Path) -> tuple[np.ndarray, dict[str, int], int | None]:
    """joint_states header stamps [ns], the message count per topic and the bag's first timestamp [ns]."""
    stamps, counts = [], {}
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        first = reader.start_time if reader.message_count else None
        for connection in reader.connections:
            counts[connection.topic] = counts.get(connection.topic, 0) + connection.msgcount
        joints = [c for c in reader.connections if c.topic == JOINT_STATES]
        for connection, _, raw in reader.messages(connections=joints):
            header = reader.deserialize(raw, connection.msgtype).header
            stamps.append(header.stamp.sec * NS + header.stamp.nanosec)
    return np.array(stamps, dtype=np.int64), counts, first


def run(storage: str, rate: int, duration: float, domain: int, workdir: Path) -> dict[str, object]:
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    node = subprocess.Popen([sys.executable, "-m", "crane_reference.ros.node", "--ros-args", "-p",
                             f"publish_rate:={rate}", "-p", "model:=flexible"],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    bag = workdir / f"{storage}_{rate}hz"
    try:
        time.sleep(3.0)  # let the node start publishing; the recorder also adds topics that appear later
        launched_ns = time.time_ns()  # the node clock of the bag's timestamps is the system clock
        recorder = subprocess.Popen([sys.executable, "-m", "crane_reference.cli", "record", "-o", str(bag),
                                     "--storage", storage], env=env, stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True)
        start, cpu0 = time.monotonic(), process_cpu_seconds(recorder.pid)
        time.sleep(duration)
        cpu, wall = process_cpu_seconds(recorder.pid) - cpu0, time.monotonic() - start
        recorder.send_signal(signal.SIGINT)
        stdout, stderr = recorder.communicate(timeout=START_TIMEOUT)
    finally:
        node.send_signal(signal.SIGINT)
        try:
            node.wait(timeout=30)
        finally:
            node.kill()
    try:
        stamps, counts, first_ns = bag_contents(bag)
        opens = True
    except (AnyReaderError, OSError) as error:  # reported in the table; the benchmark goes on
        stamps, counts, first_ns, opens = np.array([], dtype=np.int64), {}, None, False
        stderr += f"\n{error}"
    expected = int((stamps[-1] - stamps[0]) * rate // NS + 1) if stamps.size else 0
    size = sum(f.stat().st_size for f in bag.rglob("*") if f.is_file()) if bag.exists() else 0
    messages = sum(counts.values())
    first = next((line.split("came ")[1].split()[0] for line in stdout.splitlines()
                  if "the first message came" in line), "nan")
    return {
        "storage": storage, "rate_hz": rate, "first_message_s": float(first),
        "launch_to_first_message_s": (first_ns - launched_ns) / NS if first_ns is not None else float("nan"),
        "joint_states": int(stamps.size),
        "missing_stamps": expected - int(np.unique(stamps).size), "poses": counts.get(END_EFFECTOR_POSE, 0),
        "diagnostics": counts.get(DIAGNOSTICS, 0), "messages_per_s": messages / wall,
        "mb_per_s": size / 1e6 / wall, "bag_mb": size / 1e6, "recorder_cpu_percent": 100.0 * cpu / wall,
        "exit_code": recorder.returncode, "traceback": "Traceback" in stderr, "bag_opens": opens,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=20.0, help="recorded seconds per case (default 20)")
    parser.add_argument("--rates", type=int, nargs="+", default=[100, 1000])
    parser.add_argument("--storages", nargs="+", choices=["mcap", "sqlite3"], default=["mcap", "sqlite3"])
    parser.add_argument("--domain-id", type=int, default=os.getpid() % 100 + 1)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_recorder_") as workdir:
        rows = [run(storage, rate, args.duration, args.domain_id, Path(workdir))
                for storage in args.storages for rate in args.rates]
    print_table(f"crane-reference record of the flexible node, {args.duration:g} s per case, "
                f"{os.cpu_count()} CPUs", rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())

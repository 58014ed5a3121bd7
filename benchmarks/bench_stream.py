"""Benchmark of the online stream without ROS: what the node's worker spends per sample and per command.

For the flexible crane at the node's default step (``ONLINE_STEP``), in one process:

* the quaternions of 20 rotation matrices by scipy's ``Rotation``, with and without its orthonormality check
  (the stream converts the rows it reads, :func:`~crane_reference.stream.sample.quaternions`);
* ``ReferenceStream.compute``: CPU milliseconds per second of motion (solver plus bookkeeping; the full
  evaluation of a step is left to the reads);
* ``ReferenceStream.samples``: microseconds per sample, one at a time and in batches of 20 (the node's
  refill at 100 Hz), at the computed steps and between them (interpolated);
* a re-target: the reachability check (``check_targets``, run in the node's parameter callback before
  the change is accepted), ``retarget`` itself (restart at the computed step, blend), then the motion of
  20 samples after it;
* E's reach from the column's axis (the node's ranges of ellipse.a and ellipse.b, found at configure);
* the solver side of the node's reference server (``StreamSolver.frames`` asked as the server asks it:
  batches of REFILL seconds of frames, its compute slice, previews at 10 Hz) at 1000 and 100 Hz: CPU seconds per
  second of stream, and the part that pickling and unpickling the batches (the pipe to the solver
  process) takes of it.

Each figure is the median of ``--repeats`` timings.  Run: ``.venv/bin/python benchmarks/bench_stream.py``.
"""

from __future__ import annotations

import argparse
import pickle
import time

import numpy as np
from common import call_seconds
from scipy.spatial.transform import Rotation

from crane_reference.model.config import load_config
from crane_reference.model.parameters import Task
from crane_reference.motion.steps import ONLINE_STEP
from crane_reference.stream.ahead import COMPUTE_SLICE, LOOKAHEAD, REFILL, RELEASE_KEEP
from crane_reference.stream.reference_stream import ReferenceStream
from crane_reference.stream.sample import quaternions
from crane_reference.stream.schedule import FrameSchedule
from crane_reference.stream.solver_messages import StreamSpec
from crane_reference.stream.stream_solver import StreamSolver
from crane_reference.stream.targets import reach

STEP = ONLINE_STEP  # [s], the node's default
BATCH = 20


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()

    rotations = Rotation.random(BATCH, random_state=1).as_matrix()
    checked = call_seconds(lambda: Rotation.from_matrix(rotations).as_quat(), args.repeats, median=True)
    trusted = call_seconds(lambda: quaternions(rotations), args.repeats, median=True)
    print(f"[quaternion] {BATCH} rotation matrices at once: scipy's Rotation.from_matrix(...).as_quat() "
          f"{checked / BATCH * 1e6:5.2f} us per matrix, without its orthonormality check (the stream's "
          f"quaternions) {trusted / BATCH * 1e6:5.2f} us")

    stream = ReferenceStream(load_config(), "flexible", STEP)
    stream.compute(0.5)
    motion = 5.0
    start = time.process_time()
    stream.compute(0.5 + motion)
    cpu = time.process_time() - start
    print(f"[compute] {cpu / motion * 1e3:7.1f} ms of CPU per s of motion (real-time factor {motion / cpu:.1f})")

    for name, offset in (("at the steps", 0.0), ("between steps", 0.37 * STEP)):
        taus = [1.0 + i * STEP + offset for i in range(BATCH)]
        one = call_seconds(lambda taus=taus: [stream.sample(tau) for tau in taus], args.repeats, median=True) / BATCH
        many = call_seconds(lambda taus=taus: stream.samples(taus), args.repeats, median=True) / BATCH
        print(f"[sample] {name:<14} {one * 1e6:7.1f} us per sample one at a time, {many * 1e6:7.1f} us in batches "
              f"of {BATCH}")

    checks, retargets, after = [], [], []
    for i in range(args.repeats):
        tau = stream.computed_until - 0.5
        targets = Task(3.1 if i % 2 == 0 else 3.0, 2.0, 0.2, 5.0)
        start = time.perf_counter()
        stream.check_targets(targets)
        checks.append(time.perf_counter() - start)
        start = time.perf_counter()
        stream.retarget(tau, targets, checked=True)
        retargets.append(time.perf_counter() - start)
        start = time.perf_counter()
        stream.compute(tau + BATCH * STEP)
        stream.samples([tau + j * STEP for j in range(BATCH)])
        after.append(time.perf_counter() - start)
        stream.compute(tau + 1.0)
    print(f"[retarget] reachability check {np.median(checks) * 1e3:6.1f} ms, retarget (restart, blend) "
          f"{np.median(retargets) * 1e3:6.1f} ms, the first {BATCH} samples after it {np.median(after) * 1e3:6.1f} ms "
          f"(medians of {args.repeats})")

    task, scenario = stream.targets, stream.scenario
    heights = (scenario.z_static, scenario.z_static + task.z_increment)
    start = time.perf_counter()
    low, high = reach(scenario, task.ellipse_b, heights, stream.singular_value_margin)
    seconds = time.perf_counter() - start
    print(f"[reach] E's reach from the column's axis at z = {heights[0]:.3f} and {heights[1]:.3f} m (the node's "
          f"ranges of ellipse.a and ellipse.b): [{low:g}, {high:g}] m, found in {seconds * 1e3:.0f} ms (at configure)")

    config = load_config()
    for rate in (1000, 100):
        solver = StreamSolver(StreamSpec(config, "flexible", STEP, 2.0, config.task, warm_up=False))
        schedule = FrameSchedule(rate, rate, 0.1, 1.0, solver.info().start)

        def serve(seconds: float, schedule: FrameSchedule = schedule, solver: StreamSolver = solver,
                  rate: int = rate) -> float:
            """Frames for ``seconds`` of stream, published as soon as made; the pickling time [s]."""
            pickling, end = 0.0, schedule.made_k + round(seconds * rate)
            while schedule.made_k < end:
                plan = schedule.plan()
                request = schedule.request(plan, max(1, round(REFILL * rate)), 1.0, 10, max(1, rate // 10),
                                           COMPUTE_SLICE)
                batch = solver.frames(request, RELEASE_KEEP + LOOKAHEAD)
                start = time.perf_counter()
                pickle.loads(pickle.dumps(batch))
                pickling += time.perf_counter() - start
                schedule.accept(batch, plan)
                schedule.next_k = schedule.made_k
            return pickling

        serve(1.0)
        motion = 10.0
        start = time.process_time()
        pickling = serve(motion)
        cpu = time.process_time() - start
        print(f"[server] solver side at {rate:4d} Hz: {cpu / motion:.3f} s of CPU per s of stream "
              f"(pickling the batches {pickling / motion:.3f} s of it)")


if __name__ == "__main__":
    main()

"""``crane-reference loop``: the closed loop over ROS without launch, and its recording.

Starts the reference node, the plant and the example controller as processes of their own (the parameters
of :func:`~crane_reference.interface.bringup.closed_loop_parameters`, as ``launch/closed_loop.launch.py``),
records the plant's states, E's pose, the tip deflection and the reference node's samples until the plant
has run ``duration`` s, then ends the three with SIGINT (each must exit with code 0).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import rclpy
import yaml
from geometry_msgs.msg import PoseStamped, Vector3Stamped
from lifecycle_msgs.msg import State, Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rclpy.executors import Executor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from sensor_msgs.msg import JointState

from ..interface.bringup import (
    CLOCK_START,
    CONTROLLER_NODE,
    PLANT_NODE,
    REALTIME_START,
    LoopRecording,
    closed_loop_parameters,
    missing_messages,
)
from ..interface.messages import NODE_NAME
from ..model.units import NANOSECONDS
from .running import spin_once

MODULES = {NODE_NAME: "crane_reference.ros.node", PLANT_NODE: "crane_reference.ros.plant_node",
           CONTROLLER_NODE: "crane_reference.ros.controller_node"}
START_TIMEOUT = 600.0  # [s] of wall time for the three to start (a first start compiles the kernels)
EXIT_TIMEOUT = 30.0  # [s] after SIGINT
DISCOVERY_GRACE = 0.5  # [s] after the recorder sees the plant's publishers, before the plant is activated
ANSWER_TIMEOUT = 10.0  # [s] for an answer of a lifecycle service (then the state is asked)
STALL_TIMEOUT = 10.0  # [s] of wall time without a new state of a plant that moved (it stopped, or the loop hangs)
COMPLETE_TIMEOUT = 10.0  # [s] of wall time after the loop's end for the messages still in flight


class LoopError(RuntimeError):
    """The loop did not run to its end (a node failed or did not start)."""


def _stamp_ns(msg) -> int:
    return msg.header.stamp.sec * NANOSECONDS + msg.header.stamp.nanosec


def run_loop(duration: float, clock_mode: str = "lockstep", control_rate: int = 1000, model: str = "flexible",
             config_file: str = "", progress: Callable[[float], None] | None = None,
             feedforward: str = "none") -> LoopRecording:
    """Run the loop for ``duration`` s of the plant's time with the controller's ``feedforward`` and return what it
    recorded (``progress`` gets the plant's time)."""
    return _record(duration, closed_loop_parameters(clock_mode, control_rate, model, config_file,
                                                    feedforward=feedforward), progress)


@contextmanager
def closed_loop_processes(parameters: dict[str, dict[str, object]]) -> Iterator[dict[str, subprocess.Popen]]:
    """The three nodes as processes with ``parameters`` by node name, their output to files (a pipe nobody reads
    would block a node once full); on leaving, SIGINT to each, and :class:`LoopError` if one did not exit with
    code 0, or for a :class:`LoopError` inside, with the end of each one's output."""
    with tempfile.TemporaryDirectory(prefix="crane_loop_") as directory:
        params_file = Path(directory) / "loop.yaml"
        params_file.write_text(yaml.safe_dump({name: {"ros__parameters": values}
                                               for name, values in parameters.items()}))
        logs = {name: Path(directory) / f"{name}.log" for name in parameters}
        processes = {}
        for name in parameters:
            with logs[name].open("w") as log:
                processes[name] = subprocess.Popen([sys.executable, "-m", MODULES[name], "--ros-args", "-r",
                                                    f"__node:={name}", "--params-file", str(params_file)],
                                                   env=os.environ, stdout=log, stderr=subprocess.STDOUT)
        try:
            yield processes
        except LoopError as error:
            codes = _end(processes)
            raise LoopError(f"{error}; " + "; ".join(f"{name} (exit code {code}) said: {_tail(logs[name])}"
                                                     for name, code in codes.items())) from None
        except BaseException:
            _end(processes)
            raise
        codes = _end(processes)
        failed = [name for name, code in codes.items() if code != 0]
        if failed:
            raise LoopError("; ".join(f"{name} exited with {codes[name]}: {_tail(logs[name])}" for name in failed))


def _tail(log: Path, characters: int = 2000) -> str:
    return log.read_text(errors="replace")[-characters:]


def _end(processes: dict[str, subprocess.Popen]) -> dict[str, int]:
    """SIGINT to each process still running; their exit codes."""
    for process in processes.values():
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
    codes = {}
    for name, process in processes.items():
        try:
            codes[name] = process.wait(timeout=EXIT_TIMEOUT)
        except subprocess.TimeoutExpired:
            process.kill()
            codes[name] = process.wait()
    return codes


TRANSITIONS = {"configure": (Transition.TRANSITION_CONFIGURE, State.PRIMARY_STATE_UNCONFIGURED,
                              State.PRIMARY_STATE_INACTIVE),
               "activate": (Transition.TRANSITION_ACTIVATE, State.PRIMARY_STATE_INACTIVE, State.PRIMARY_STATE_ACTIVE)}
"""A lifecycle transition's id, the state it leaves and the one it reaches."""


def bring_up(executor: Executor, node: Node, processes: dict[str, subprocess.Popen],
             parameters: dict[str, dict[str, object]], start_by: float) -> None:
    """Bring up the loop ``processes`` started with ``parameters`` through the lifecycle services, from ``node``
    spun by ``executor``, by the monotonic time ``start_by``: in lock-step configure the plant (which does not
    start itself), in real time the two lifecycle nodes in turn (:data:`~..interface.bringup.REALTIME_START`);
    before the plant is activated, wait until ``node`` sees its publishers (so that a recorder there hears the
    first state: DDS discovery takes its time, longer under load).  :class:`LoopError` if a node ends, refuses or
    does not answer in time."""

    def until(done: Callable[[], bool], what: str) -> None:
        while not done():
            spin_once(executor, node, 0.05)
            ended = [name for name, process in processes.items() if process.poll() is not None]
            if ended:
                raise LoopError(f"{', '.join(ended)} ended before the loop started")
            if time.monotonic() > start_by:
                raise LoopError(f"{what} within {START_TIMEOUT:g} s")

    def send(service, request):
        """``request``'s future, once ``service`` is ready."""
        until(service.service_is_ready, f"no lifecycle service of {service.srv_name}")
        return service.call_async(request)

    def answered(future) -> bool:
        """Whether ``future`` is done within ANSWER_TIMEOUT (a request or its answer can be lost while the service's
        discovery is under way)."""
        wait = time.monotonic() + ANSWER_TIMEOUT
        until(lambda: future.done() or time.monotonic() > wait, "a lifecycle service did not answer")
        return future.done()

    def transition(name: str, which: str) -> None:
        """Take the node ``name`` through the transition ``which`` (:data:`TRANSITIONS`): asked again if it is still
        where it was without an answer (lost), waited for while it is on the way."""
        number, before, reached = TRANSITIONS[which]
        if which == "activate" and name == PLANT_NODE:
            until(lambda: all(node.count_publishers(f"/{PLANT_NODE}/{topic}") for topic in
                              ("joint_states", "end_effector_pose", "tip_deflection")),
                  f"the recorder saw no publisher of {PLANT_NODE}")
            grace = time.monotonic() + DISCOVERY_GRACE  # for the plant's side of the discovery (near ours)
            until(lambda: time.monotonic() > grace, "")
        change, state = (node.create_client(kind, f"/{name}/{service}")
                         for kind, service in ((ChangeState, "change_state"), (GetState, "get_state")))
        request = ChangeState.Request(transition=Transition(id=number))
        future = send(change, request)
        while not answered(future):
            query = send(state, GetState.Request())
            now = query.result().current_state.id if answered(query) else None
            if now == reached:
                break
            if now == before:  # still where it was: the request was lost
                future = send(change, request)
        else:
            if not future.result().success:
                raise LoopError(f"{name} refused its lifecycle transition {which}")
        node.destroy_client(change)
        node.destroy_client(state)

    lockstep = parameters[PLANT_NODE]["clock_mode"] == "lockstep"
    for name, which in ((PLANT_NODE, "configure"), (PLANT_NODE, "activate")) if lockstep else REALTIME_START:
        transition(name, which)


def _record(duration: float, parameters: dict[str, dict[str, object]],
            progress: Callable[[float], None] | None) -> LoopRecording:
    """The recorder's subscriptions first, then the nodes (:func:`closed_loop_processes`), the plant activated
    once the recorder sees it (:func:`bring_up`): it hears them from their first messages on."""
    context = rclpy.Context()
    rclpy.init(context=context)
    states, poses, deflections, references = {}, {}, {}, {}
    names: list[tuple[str, ...]] = []
    reference_names: list[tuple[str, ...]] = []
    try:
        node = rclpy.create_node("crane_loop_recorder", context=context)

        def on_state(msg: JointState) -> None:
            names[:] = [tuple(msg.name)]
            states.setdefault(_stamp_ns(msg), (msg.position, msg.velocity, msg.effort))

        # transient local, as the publishers (closed_loop_parameters): what they sent before the recorder's
        # subscription was matched (DDS discovery takes its time) still comes
        kept = QoSProfile(depth=100000, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(JointState, f"/{PLANT_NODE}/joint_states", on_state, kept)
        node.create_subscription(PoseStamped, f"/{PLANT_NODE}/end_effector_pose", lambda msg: poses.setdefault(
            _stamp_ns(msg), (*(getattr(msg.pose.position, a) for a in "xyz"),
                             *(getattr(msg.pose.orientation, a) for a in "xyzw"))), kept)
        node.create_subscription(Vector3Stamped, f"/{PLANT_NODE}/tip_deflection", lambda msg: deflections.setdefault(
            _stamp_ns(msg), tuple(getattr(msg.vector, a) for a in "xyz")), kept)

        def on_reference(msg: JointState) -> None:
            reference_names[:] = [tuple(msg.name)]
            references.setdefault(_stamp_ns(msg), (msg.position, msg.velocity))

        node.create_subscription(JointState, f"/{NODE_NAME}/joint_states", on_reference, kept)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        held_plant = {**parameters, PLANT_NODE: {**parameters[PLANT_NODE], "autostart": False}}
        with closed_loop_processes(held_plant) as processes:
            start_by = time.monotonic() + START_TIMEOUT
            bring_up(executor, node, processes, held_plant, start_by)
            started = None
            lockstep = parameters[PLANT_NODE]["clock_mode"] == "lockstep"
            first = last = None  # in lock-step the plant's first state is stamped CLOCK_START: the run's origin
            heard, count = time.monotonic(), 0  # when the plant's last new state came, and the states then
            while last is None or last - first < round(duration * NANOSECONDS):  # then exactly duration is kept
                spin_once(executor, node, 0.05)
                ended = [name for name, process in processes.items() if process.poll() is not None]
                if ended:
                    raise LoopError(f"{', '.join(ended)} ended before the loop did")
                if states:
                    first, last = round(CLOCK_START * NANOSECONDS) if lockstep else min(states), max(states)
                    if started is None:
                        started = time.monotonic()
                    if progress is not None:
                        progress((last - first) / NANOSECONDS)
                    if len(states) > count:
                        heard, count = time.monotonic(), len(states)
                    elif count > 1 and time.monotonic() - heard > STALL_TIMEOUT:  # once it moved (a lock-step
                        # plant repeats its first state while the reference node comes up)
                        raise LoopError(f"the plant published no new state for {STALL_TIMEOUT:g} s of wall time, "
                                        f"after {(last - first) / NANOSECONDS:.3f} s of {duration:g} s")
                elif time.monotonic() > start_by:
                    raise LoopError(f"no state of the plant within {START_TIMEOUT:g} s")
            wall = time.monotonic() - started
            end = first + round(duration * NANOSECONDS)
            plant, reference = parameters[PLANT_NODE], parameters[NODE_NAME]

            def missing() -> dict[str, int]:
                return missing_messages(states, poses, deflections, references, first, end,
                                        NANOSECONDS // int(plant["control_rate"]),
                                        NANOSECONDS // int(reference["publish_rate"]),
                                        lockstep)

            complete_by = time.monotonic() + COMPLETE_TIMEOUT
            while missing() and time.monotonic() < complete_by:  # the last messages in flight
                spin_once(executor, node, 0.01)
            lost = missing()
            if lost:
                raise LoopError("the recording lacks " + ", ".join(f"{count} {topic}" for topic, count in lost.items())
                                + f" of the loop's first {duration:g} s (still missing {COMPLETE_TIMEOUT:g} s after "
                                "its end): its summary would not be the loop's")
        node.destroy_node()
    finally:
        context.try_shutdown()
    reference_stamps = np.array(sorted(references), dtype=np.int64)
    inside = range(reference_stamps[0], reference_stamps[-1] + 1)  # the reference is interpolated, never held
    stamps = np.array(sorted(k for k in states if k <= end and k in inside and k in poses and k in deflections),
                      dtype=np.int64)
    columns = [reference_names[0].index(name) for name in names[0]]  # the plant's order
    reference = [np.array([references[k][i] for k in reference_stamps])[:, columns] for i in (0, 1)]
    seconds = (stamps - first) / NANOSECONDS
    interpolated = [np.column_stack([np.interp(stamps, reference_stamps, column) for column in values.T])
                    for values in reference]
    return LoopRecording(names[0], seconds, *(np.array([states[k][i] for k in stamps]) for i in range(3)),
                         np.array([poses[k][:3] for k in stamps]), np.array([poses[k][3:] for k in stamps]),
                         np.array([deflections[k] for k in stamps]), *interpolated, wall)

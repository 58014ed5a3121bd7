"""An example controller node for the crane plant: ``ros2 run crane_reference controller``.

Written to be replaced by a user's own controller, as the ros2/examples nodes are: it subscribes to the
reference node's ``~/reference_preview`` (trajectory_msgs/JointTrajectory) and to the plant's
``~/joint_states``, and answers each measured state with a command on the plant's ``~/commands``
(std_msgs/Float64MultiArray, one effort per joint of ``joints``); the decisions are
:class:`~crane_reference.control.preview_tracking.PreviewTracker`'s (the preview sampled as
joint_trajectory_controller samples its trajectory, then a PD/PID tick).

Parameters (:mod:`.controller_parameters`): ``joints``; the gains per joint ``gains.<joint>.p``, ``.d`` and
``.i``; ``.d`` is the D action the plant's drives apply, so it must equal the plant's ``drive_damping.<joint>``
(the defaults agree); ``control_rate`` [Hz], the plant's, for the integral; ``feedforward``: ``none`` (default)
or ``reference``, the preview's efforts (the reference node's ``preview.effort:=true``: the constraint forces at
these joints, without the drive's torque, which the plant applies itself); the three topics.  The preview's
subscription takes rclpy's ``qos_overrides`` (closed_loop.launch.py makes it transient-local on both ends, so
that a controller started late still gets the last preview).
"""

from __future__ import annotations

import sys

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from trajectory_msgs.msg import JointTrajectory

from ..control.controller import JointGains
from ..control.preview_tracking import Preview, PreviewTracker
from ..interface.bringup import CONTROLLER_NODE
from ..model.units import NANOSECONDS
from .controller_parameters import declare_controller
from .publishing import OVERRIDABLE
from .running import run_node

NODE_NAME = CONTROLLER_NODE
DEPTH = 10

def _columns_of(rows, columns: list[int], what: str) -> np.ndarray:
    """The ``columns`` of each of ``rows`` (sequences of numbers); ValueError naming ``what`` if one is short."""
    if any(len(row) <= max(columns) for row in rows):
        raise ValueError(f"{what}: one value per joint name is needed")
    return np.array([[row[c] for c in columns] for row in rows], dtype=float)


def _stamp_ns(msg) -> int:
    return msg.header.stamp.sec * NANOSECONDS + msg.header.stamp.nanosec


class CraneControllerNode(Node):
    """Tracks the reference preview on the plant; see the module documentation."""

    def __init__(self, node_name: str = NODE_NAME, **kwargs) -> None:
        super().__init__(node_name, **{"automatically_declare_parameters_from_overrides": True, **kwargs})
        params = declare_controller(self)
        gains = [JointGains(params.gains_p[joint], params.gains_d[joint], params.gains_i[joint])
                 for joint in params.joints]
        self.tracker = PreviewTracker(params.joints, gains, 1.0 / params.control_rate, params.feedforward)
        reference, state, command = params.reference_topic, params.state_topic, params.command_topic
        self._commands = self.create_publisher(Float64MultiArray, command, DEPTH)
        self.create_subscription(JointTrajectory, reference, self._on_preview, DEPTH,
                                 qos_overriding_options=OVERRIDABLE)
        self.create_subscription(JointState, state, self._on_state, DEPTH)
        self.get_logger().info(f"tracking {reference} on {state}, commanding {command} ({', '.join(params.joints)})")

    def _columns(self, names: list[str], what: str) -> list[int] | None:
        missing = [joint for joint in self.tracker.joints if joint not in names]
        if missing:
            self.get_logger().error(f"{what} lacks {', '.join(missing)}", throttle_duration_sec=5.0)
            return None
        return [names.index(joint) for joint in self.tracker.joints]

    def _on_preview(self, msg: JointTrajectory) -> None:
        columns = self._columns(list(msg.joint_names), "the reference preview")
        if columns is None or not msg.points:
            return
        start = _stamp_ns(msg)
        try:
            times = np.array([start + p.time_from_start.sec * NANOSECONDS + p.time_from_start.nanosec
                              for p in msg.points], dtype=np.int64)
            fields = [_columns_of([getattr(p, name) for p in msg.points], columns, f"reference preview {name}")
                      for name in ("positions", "velocities", "accelerations")]
            efforts = (_columns_of([p.effort for p in msg.points], columns, "reference preview effort")
                       if self.tracker.feedforward == "reference" and all(len(p.effort) for p in msg.points)
                       else None)
            preview = Preview(times, *fields, efforts)
            self.tracker.check(preview)
        except ValueError as error:
            self.get_logger().error(f"dropped: {error}", throttle_duration_sec=1.0)
            return
        if not self._plant_listens():
            self.tracker.preview = preview
            return
        self._send(self.tracker.take_preview(preview))

    def _plant_listens(self) -> bool:
        """Whether a subscriber of the commands is matched: until then no state is answered (a command sent
        before would be lost, and a lock-step plant would wait for ever; it repeats its state meanwhile)."""
        return self._commands.get_subscription_count() > 0

    def _on_state(self, msg: JointState) -> None:
        columns = self._columns(list(msg.name), "the plant's joint states")
        if columns is None or not self._plant_listens():
            return
        try:
            q, qd = (_columns_of([values], columns, f"plant state {name}")[0]
                     for values, name in ((msg.position, "position"), (msg.velocity, "velocity")))
            command = self.tracker.take_state(_stamp_ns(msg), q, qd)
        except ValueError as error:
            self.get_logger().error(f"dropped: {error}", throttle_duration_sec=1.0)
            return
        self._send(command)

    def _send(self, command) -> None:
        if command is not None:
            self._commands.publish(Float64MultiArray(data=[float(u) for u in command]))


def main(args: list[str] | None = None) -> int:
    """Run the controller until SIGINT / SIGTERM (:func:`~.running.run_node`)."""
    return run_node(CraneControllerNode, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())

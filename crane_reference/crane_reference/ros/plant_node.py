"""ROS 2 node simulating the actuated crane as a plant for a controller: ``ros2 run crane_reference plant``.

A managed (lifecycle) node that only wires: the plant is the ROS-free
:class:`~crane_reference.control.plant_server.PlantServer` (the crane of the config without programmed
constraints: flexible boom, supports, column drive; effort commands with the drives' damping, refusals, the
hold command on a timeout); the parameters are :mod:`.plant_parameters`.

* ``~/commands`` (std_msgs/Float64MultiArray): one effort [N m] per joint of the ``joints`` parameter, in
  its order, as a ros2_control forward command controller publishes them.  Refused commands are counted and
  reported in /diagnostics, and never applied.
* After each control period: ``~/joint_states`` (sensor_msgs/JointState: q, qd and the actuator torque of the
  joints, or of every coordinate with ``all_coordinates``), ``~/end_effector_pose`` (geometry_msgs/PoseStamped,
  E in ``frame_id``) and ``~/tip_deflection`` (geometry_msgs/Vector3Stamped, the boom tip's deflection from
  its rigid chord in the first boom element's link), stamped with the end of the period.  The three take
  rclpy's ``qos_overrides`` (e.g. a deeper history for a recorder that may lag).
* ``clock_mode`` realtime: a period every period of the steady clock (a thread of its own paces them,
  :mod:`~crane_reference.control.pacing`: after a stall the periods it skipped are missed, counted in
  /diagnostics' ``missed_ticks`` at the next wake-up; while they run, Python's thread switch interval is
  :data:`~crane_reference.base.threads.SWITCH_INTERVAL`), stamped with the node's clock; the plant's time
  (and its column drive's program) starts with the first command, until which its held start is published
  every period;
  lockstep: the node publishes /clock (``clock_start`` plus the plant's time) and advances one period per
  command received, so nodes with ``use_sim_time`` run in step with it, deterministically; while no command
  comes, it publishes /clock and the state again every :data:`HEARTBEAT` s of wall time (for nodes that
  joined late: a controller answers a state stamp once).
* ``configure`` builds the plant (held at rest at its start), ``activate`` runs it, ``deactivate`` stops the
  periods (the plant's time stands still), ``cleanup`` drops it; ``autostart`` (default) configures and
  activates at construction.
"""

from __future__ import annotations

import sys
import threading
import time
from dataclasses import replace

from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.serialization import serialize_message
from rosgraph_msgs.msg import Clock as ClockMessage
from std_msgs.msg import Float64MultiArray

from ..base.health import CANNOT, StartupError, startup_health
from ..base.threads import real_time_switching, start_named
from ..control.pacing import Pacing
from ..control.plant_server import CommandRefusedError, PlantServer, PlantState, plant_health
from ..interface import messages
from ..interface.bringup import PLANT_NODE
from ..interface.serialized import SerializedJointState, SerializedPose, SerializedVector3
from ..model.config import ConfigError, load_config
from ..model.units import NANOSECONDS
from ..motion.integration import IntegrationError
from ..motion.programmed_motion import ProjectionError
from ..motion.simulation import SOLVER_FAILURES
from .message_types import rclpy_types
from .parameter_spec import check, pre_set_callback
from .plant_parameters import declare_plant
from .publishing import OVERRIDABLE, run_until_shutdown
from .running import run_node

NODE_NAME = PLANT_NODE
HEARTBEAT = 0.5  # [s] of wall time between repetitions of an unanswered lock-step state


class CranePlantNode(LifecycleNode):
    """Simulates the actuated crane under effort commands; see the module documentation."""

    def __init__(self, node_name: str = NODE_NAME, **kwargs) -> None:
        """Declare and read the parameters; with ``autostart`` configure and activate (StartupError if it
        cannot configure).  ``kwargs`` go to :class:`rclpy.node.Node`."""
        super().__init__(node_name, **{"automatically_declare_parameters_from_overrides": True, **kwargs})
        self._types = rclpy_types()
        self._params, self._specs = declare_plant(self)
        self.add_pre_set_parameters_callback(pre_set_callback(self, self._specs))
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self._server: PlantServer | None = None
        self._lock = threading.Lock()  # the server: the command callbacks and the real-time thread
        self._running = threading.Event()  # the real-time thread runs while set
        self._thread: threading.Thread | None = None
        self._outputs: dict[str, object] = {}
        self._made: dict[str, object] = {}  # the serialized messages' writers
        self._activity = "unconfigured"
        self._failure = ""
        self._missed = 0  # real-time periods missed (control/pacing.py) since configured
        self._missed_reported = 0
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_subscription(Float64MultiArray, messages.COMMANDS_TOPIC, self._on_command, messages.PUBLISHER_DEPTH)
        self._diagnostics = self.create_publisher(self._types.DiagnosticArray, messages.DIAGNOSTICS_TOPIC,
                                                  messages.PUBLISHER_DEPTH)
        self.create_timer(messages.DIAGNOSTICS_PERIOD, self._publish_diagnostics, clock=self._steady)
        self._heard = False  # a command came since the last heartbeat
        self.create_timer(HEARTBEAT, self._heartbeat, clock=self._steady)
        if self._params.autostart:
            if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                raise StartupError(self._activity.removeprefix(f"{CANNOT} configure: "))
            self.trigger_activate()

    # -- lifecycle --------------------------------------------------------------------------------------

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Build the plant at rest at its held start and create the publishers."""
        v = self._params
        try:
            self._server = PlantServer(load_config(v.config_file or None), v.settings())
        except (ConfigError, ValueError, *SOLVER_FAILURES) as error:  # a start that cannot run: say why
            self._activity = f"{CANNOT} configure: {error}"
            self.get_logger().error(self._activity)
            return TransitionCallbackReturn.FAILURE
        types = self._types
        depth = messages.PUBLISHER_DEPTH
        self._outputs = {
            name: self.create_lifecycle_publisher(message_type, topic, depth, qos_overriding_options=OVERRIDABLE)
            for name, message_type, topic in (("joints", types.JointState, messages.JOINT_STATES_TOPIC),
                                              ("pose", types.PoseStamped, messages.END_EFFECTOR_POSE_TOPIC),
                                              ("deflection", types.Vector3Stamped, messages.TIP_DEFLECTION_TOPIC))}
        if v.clock_mode == "lockstep":
            self._outputs["clock"] = self.create_lifecycle_publisher(ClockMessage, messages.CLOCK_TOPIC, depth)
        self._made = {}
        self._failure = ""
        self._missed = self._missed_reported = 0
        self._activity = "inactive: configured; activate to run"
        self.get_logger().info(f"configured: the {v.model} crane as a plant, {v.control_rate} Hz {v.clock_mode}, "
                               f"commands for {', '.join(v.joints)}")
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Run: publish the state now; in real time start the periods, in lock-step wait for commands.  A plant
        whose integration failed does not run again (cleanup and configure make a new one)."""
        if self._failure:
            self.get_logger().error(f"not activated: the plant stopped ({self._failure}); cleanup and configure")
            return TransitionCallbackReturn.FAILURE
        result = super().on_activate(state)
        self._activity = f"active ({self._params.clock_mode})"
        self._publish(self._server.state())
        if self._params.clock_mode == "realtime":
            self._running.set()
            self._thread = start_named(run_until_shutdown(self, self._run_periods), "plant_periods")
        return result

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop_periods()
        self._activity = "inactive: the plant's time stands still; activate to run"
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release()
        self._activity = "unconfigured"
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release()
        self._activity = "finalized"
        return TransitionCallbackReturn.SUCCESS

    def _stop_periods(self) -> None:
        self._running.clear()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join()
            self._thread = None

    def _release(self) -> None:
        self._stop_periods()
        for publisher in self._outputs.values():
            self.destroy_lifecycle_publisher(publisher)
        self._outputs, self._made, self._server = {}, {}, None

    def _active(self) -> bool:
        return self._server is not None and self._outputs["joints"].is_activated and not self._failure

    # -- periods and commands (executor thread) ---------------------------------------------------------

    def _seconds(self) -> float:
        return self._steady.now().nanoseconds / NANOSECONDS

    def _run_periods(self) -> None:
        """The real-time periods (a thread): each waits until due, then advances and publishes; until the first
        command the plant is held at its start (its time stands still) and its state is published each period."""
        with real_time_switching():
            pacing, before = Pacing(self._server.settings.period, self._seconds()), self._missed
            while self._running.is_set():
                wait = pacing.wait(self._seconds())
                self._missed = before + pacing.missed
                if wait > 0.0:
                    time.sleep(wait)  # at most a period: a deactivation is noticed within one
                    continue
                try:
                    if self._server.accepted:
                        self._advance(self._seconds())
                    else:
                        with self._lock:
                            state = self._server.state()
                        self._publish(state)
                except Exception as error:  # anything else that goes wrong stops the plant, at ERROR
                    if self.context.ok():
                        self._fail(f"{type(error).__name__}: {error}")
                    return
                pacing.ran()

    def _on_command(self, msg: Float64MultiArray) -> None:
        """~/commands: accepted or refused (counted, WARN); in lock-step a period follows either way (under the
        last accepted command), so that the loop never stalls."""
        if not self._active():
            self.get_logger().warn(f"command ignored: the plant is {self._activity}", throttle_duration_sec=1.0)
            return
        lockstep = self._params.clock_mode == "lockstep"
        self._heard = True
        with self._lock:
            now = self._server.t if lockstep else self._seconds()
            try:
                self._server.command(msg.data, now)
            except CommandRefusedError as error:
                self.get_logger().warn(f"command refused: {error}", throttle_duration_sec=1.0)
        if lockstep:
            self._advance(now)

    def _advance(self, now: float) -> None:
        server = self._server
        timeouts = server.timeouts
        try:
            with self._lock:
                state = server.tick(now)
        except (IntegrationError, ProjectionError) as error:
            self._fail(str(error))
            return
        if server.timeouts > timeouts:
            self.get_logger().warn(f"no command for {server.settings.command_timeout:g} s: applying the hold command "
                                   "(the efforts that hold the configuration where the timeout began)")
        self._publish(state)

    def _fail(self, reason: str) -> None:
        """The plant stops (its periods end); /diagnostics reports ``reason`` at ERROR."""
        self._failure = reason
        self._running.clear()
        self.get_logger().error(f"the plant stopped: {reason}")

    def _publish(self, state: PlantState) -> None:
        """The state's messages, serialized once and then filled in place
        (:mod:`~crane_reference.interface.serialized`), after /clock in lock-step."""
        v, types = self._params, self._types
        if v.clock_mode == "lockstep":
            # integer nanoseconds: clock_start + ticks periods, never drifting off the reference's samples
            stamp_ns = (round(v.clock_start * NANOSECONDS)
                        + self._server.ticks * round(self._server.settings.period * NANOSECONDS))
            self._outputs["clock"].publish(ClockMessage(clock=messages.time_msg(types, stamp_ns)))
        else:
            stamp_ns = self.get_clock().now().nanoseconds
        made = self._made  # one read: a parameter change may replace it meanwhile
        if not made:  # the writers of this configuration and these frames
            prefix = v.frame_prefix
            made = self._made = {
                "joints": SerializedJointState(serialize_message(messages.joint_state(
                    types, 0, self._server.published, state))),
                "pose": SerializedPose(serialize_message(messages.end_effector_pose(
                    types, 0, prefix + v.frame_id, state))),
                "deflection": SerializedVector3(serialize_message(messages.tip_deflection(
                    types, 0, prefix + self._server.deflection_frame, state.deflection)))}
        self._outputs["joints"].publish(made["joints"].fill(stamp_ns, state))
        self._outputs["pose"].publish(made["pose"].fill(stamp_ns, state))
        self._outputs["deflection"].publish(made["deflection"].fill(stamp_ns, state.deflection))

    def _heartbeat(self) -> None:
        """Lock-step: the current state again if no command came since the last heartbeat."""
        if self._params.clock_mode == "lockstep" and self._active() and not self._heard:
            with self._lock:
                state = self._server.state()
            self._publish(state)
        self._heard = False

    def _publish_diagnostics(self) -> None:
        if self._server is None:
            health = startup_health(self._activity)
            level, message, values = health.level, health.message, {}
        else:
            missed = self._missed
            health = plant_health(self._server, self._activity, self._failure, missed, missed - self._missed_reported)
            self._missed_reported = missed
            level, message, values = health.level, health.message, health.values
        self._diagnostics.publish(messages.diagnostics(self._types, self.get_clock().now().nanoseconds,
                                                       f"{self.get_name()}: plant", self.get_fully_qualified_name(),
                                                       level, message, values))

    # -- parameters -------------------------------------------------------------------------------------

    def _validate_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        reason = check(parameters, self._specs)
        return SetParametersResult(successful=reason is None, reason=reason or "")

    def _apply_parameters(self, parameters: list[Parameter]) -> None:
        """The values that may change while it runs: the timeout (from the next period on) and the frames."""
        changed = {p.name: p.value for p in parameters if p.name in ("command_timeout", "frame_id", "frame_prefix")}
        self._params = replace(self._params, **changed)
        if self._server is not None and "command_timeout" in changed:
            self._server.settings = self._params.settings()
        self._made = {}  # the frames may have changed

    def destroy_node(self) -> None:
        """Stop the real-time periods, then destroy the node."""
        self._stop_periods()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """Run the plant node until SIGINT / SIGTERM (:func:`~.running.run_node`)."""
    return run_node(CranePlantNode, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())

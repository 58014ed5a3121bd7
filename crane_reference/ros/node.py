"""ROS 2 node publishing the crane's programmed motion as a reference: ``ros2 run crane_reference node``.

A managed (lifecycle) node, and a thin one: the reference itself is served by a ROS-free
:class:`~crane_reference.stream.server.ReferenceServer` (the frame schedule, computing ahead, commands and
their timing), whose solver runs in a process of its own (``solver_process``, default) or in a thread.
The node declares the parameters (:mod:`crane_reference.ros.parameters`), wires the ROS clock, publishers
and services to the server and turns its samples into messages (:mod:`crane_reference.interface.messages`).

Lifecycle
    Constructing the node declares the parameters and starts /diagnostics (every second of wall time, in
    every state: what it is doing while it starts, why it cannot, or the stream's figures).
    ``configure`` starts the solver (it makes its kernels ready: compiled on a first start, else loaded,
    and says which), computes the start and the first second of motion and creates the publishers;
    ``activate`` publishes; ``deactivate`` ramps a moving reference to rest, publishes it to the first
    sample at rest and stops; ``cleanup`` / ``shutdown`` end the solver.  ``autostart`` (default) runs
    configure and activate at construction.

Clocks and stamps
    Sample k is stamped ``start + k / publish_rate`` (integer nanoseconds), where ``start`` is the node
    clock's time when publishing begins; it is never the time a message happens to be sent
    (:mod:`~crane_reference.ros.publishing` publishes each at its stamp).  ``use_sim_time`` is honoured:
    the samples follow /clock; with no /clock published ROS time stays at zero, so nothing is published
    (/diagnostics says why) until /clock runs; the services and parameters keep working.  Jumps of the
    clock never make stamps go back or skip motion (the server re-anchors), and diagnostics WARN about
    them.

Commands
    A re-target (``ellipse.*``, ``z.*`` parameters), a speed change (``speed_scaling``) and ``~/pause``
    take effect at the last sample stamped within ``command_lead`` seconds of their acceptance (at least the
    one after the next to be published); diagnostics
    give both instants (``{command}_accepted_s``, ``{command}_stamp_s``) and how long before the second
    the command's first sample was ready (``{command}_margin_s``).  Speed changes and pauses are C2
    ramps of the stream's time warp.  ``~/restart`` (back to the static-equilibrium start: a position
    jump) is done while inactive only and published from the next activation.  Parameter values are
    validated in the on-set callback (table of :mod:`~crane_reference.ros.parameters`, then the server's
    target check) and applied in the post-set callback, so ``set_parameters_atomically`` of ellipse.a and
    ellipse.b is one re-target, and a rejected change leaves the stream untouched.  Should the solver
    fall behind, fail, or make a sample that is not finite, the last valid sample is held (zero velocity)
    and diagnostics say so.

Topics (all in the node's namespace but /diagnostics): ``~/joint_states`` (sensor_msgs/JointState),
``~/end_effector_pose`` (geometry_msgs/PoseStamped), ``~/reference_preview`` (trajectory_msgs/JointTrajectory
of ``preview.joints``, at ``preview.rate``), ``/diagnostics`` (diagnostic_msgs/DiagnosticArray, 1 Hz),
``~/markers`` (visualization_msgs/MarkerArray, 10 Hz while subscribed: target ellipse and E's trail),
``~/robot_description`` (std_msgs/String, transient local); subscribed: ``~/speed_scaling`` (std_msgs/Float64).
Services: ``~/restart`` (std_srvs/Trigger), ``~/pause`` (std_srvs/SetBool).
"""

from __future__ import annotations

import gc
import sys
import threading
from contextlib import suppress

import rclpy
from rcl_interfaces.msg import FloatingPointRange, SetParametersResult
from rclpy.exceptions import ParameterNotDeclaredException
from rclpy.executors import ExternalShutdownException
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from std_msgs.msg import Float64
from std_srvs.srv import SetBool, Trigger

from ..interface import messages
from ..model.config import ConfigError, load_config
from ..model.units import NANOSECONDS
from ..motion.simulation import SOLVER_FAILURES
from ..stream.health import CANNOT
from ..stream.reference_stream import PAUSED, RUNNING
from ..stream.server import CommandRefusedError, ReferenceServer, Reply
from ..stream.solver import LocalSolver, SolverProcess, SolverStoppedError, StreamSpec
from ..stream.targets import UnreachableTargetError
from . import settings
from .message_types import rclpy_types
from .parameters import (
    PARAMETERS,
    SPECS,
    NodeParameters,
    ParameterError,
    coerce_parameters,
    declare,
)
from .publishing import DiagnosticsPublisher, SamplePublisher

NODE_NAME = messages.NODE_NAME


class StartupError(RuntimeError):
    """The node cannot start (unusable configuration or target)."""


class CraneReferenceNode(LifecycleNode):
    """Publishes the reference of the crane's programmed motion; see the module documentation."""

    def __init__(self, node_name: str = NODE_NAME, **kwargs) -> None:
        """Declare and read the parameters, publish diagnostics, and with ``autostart`` configure and
        activate.

        ``kwargs`` go to :class:`rclpy.node.Node` (``context``, ``parameter_overrides``, ``cli_args``...).
        Raises :class:`StartupError`, :class:`~crane_reference.model.config.ConfigError` or
        :class:`~crane_reference.ros.parameters.ParameterError` if a parameter is unusable, or with
        ``autostart`` if it cannot be configured.
        """
        super().__init__(node_name, **kwargs)
        self._types = rclpy_types()
        self._server: ReferenceServer | None = None
        self._publisher: SamplePublisher | None = None
        self._stop = threading.Event()  # the node is being destroyed
        self._starting = "unconfigured"  # the diagnostics' message while not publishing
        self._diagnostics = DiagnosticsPublisher(self, self._types, self._doing, lambda: self._server, self._stop)
        try:
            config_file = declare(self, SPECS["config_file"])
            config = load_config(config_file or None)
            self._params = NodeParameters.from_values(
                {"config_file": config_file,
                 **{spec.name: declare(self, spec, config) for spec in PARAMETERS if spec.name != "config_file"}})
            self._check_overrides()
        except Exception as error:
            self._fail_start(error)
            raise
        except BaseException:  # KeyboardInterrupt while starting
            self._stop.set()
            raise
        self._rate = self._params.publish_rate
        self.add_pre_set_parameters_callback(self._pre_set_parameters)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.create_service(Trigger, "~/restart", self._on_restart)
        self.create_service(SetBool, "~/pause", self._on_pause)
        self.create_subscription(Float64, messages.SPEED_SCALING_TOPIC, self._on_speed_scaling,
                                 messages.PUBLISHER_DEPTH)
        self._status_timer = self.create_timer(self._params.status_period, self._log_status)
        if self._params.autostart:
            if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                self._stop.set()
                raise StartupError(self._starting.removeprefix(f"{CANNOT} configure: "))
            self.trigger_activate()

    def _fail_start(self, error: Exception) -> None:
        """Report in /diagnostics (ERROR) and stop the diagnostics thread: the node cannot start."""
        self._starting = f"{CANNOT} start: {error}"
        with suppress(Exception):  # the context may be shutting down already
            self._diagnostics.publish()
        self._stop.set()

    def _doing(self) -> str:
        """What the node is doing, for the diagnostics while it does not publish."""
        if self._publisher is not None and self._publisher.waiting_for_clock:
            return "activating: waiting for /clock (use_sim_time is true and ROS time is 0)"
        return self._starting

    def _stopping(self) -> bool:
        """Whether the node is being destroyed or its context shut down (SIGINT, SIGTERM)."""
        return self._stop.is_set() or not self.context.ok()

    def _now(self) -> int:
        return self.get_clock().now().nanoseconds

    # -- lifecycle --------------------------------------------------------------------------------------

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Load the crane and the task, start the solver (kernels made ready, the start and the first second
        of motion computed), create the publishers; the server computes ahead from here on."""
        try:
            config_file = self._params.config_file
            config = load_config(config_file or None)
            where = "in its own process" if self._params.solver_process else "in this process"
            self._starting = (f"configuring: starting the solver {where}; it makes its kernels ready (compiled on a "
                              "first start, else loaded) and computes the start")
            self.get_logger().info(f"starting the solver {where} (with an empty kernel cache it compiles for a minute "
                                   "or two; `crane-reference compile` after installing does it ahead)")
            server = ReferenceServer(self._start_solver(config), self._rate, self._params.command_lead,
                                     settings.preview(self._params))
            messages_settings = settings.publish_settings(self._params, server.info.joint_names)
        except (StartupError, ConfigError, ParameterError) as error:
            self._starting = f"{CANNOT} configure: {error}"
            self.get_logger().error(self._starting)
            return TransitionCallbackReturn.FAILURE
        except SolverStoppedError as error:  # shutting down while the solver started
            self._starting = f"{CANNOT} configure: {error}"
            return TransitionCallbackReturn.FAILURE
        self._server = server
        self.get_logger().info(f"solver {server.info.kernels}")
        self._offer_reach(server)
        self._publisher = SamplePublisher(self, self._types, server, messages_settings)
        self._resume_on_activate = False
        self._starting = "inactive: configured, computing ahead; activate to publish"
        self.get_logger().info(f"configured: the {self._params.model} crane ({len(server.info.joint_names)} joints, "
                               f"config {config_file or 'packaged default'})")
        return TransitionCallbackReturn.SUCCESS

    def _start_solver(self, config) -> LocalSolver | SolverProcess:
        """The solver of the parameters' stream, in its own process or here (StartupError if the targets
        have no consistent start)."""
        v = self._params
        targets = v.targets()
        spec = StreamSpec(config=config, model=v.model, step=v.integrator_step, blend_time=v.blend_time,
                          targets=targets, drive_torque=v.drive_torque, drive_duration=v.drive_duration,
                          speed_scaling=v.speed_scaling, ramp_time=v.speed_scaling_ramp_time)
        try:
            return SolverProcess(spec, self._stopping) if v.solver_process else LocalSolver(spec)
        except UnreachableTargetError as error:
            raise StartupError(f"ellipse.* / z.* = {targets}: {error}") from error
        except SOLVER_FAILURES as error:
            raise StartupError(f"no consistent start for the targets {targets}: {error}") from error

    def _offer_reach(self, server: ReferenceServer) -> None:
        """Narrow the ranges of ellipse.a and ellipse.b (what rqt_reconfigure's sliders and rclpy's range check
        use) to the crane's reach at its start and target heights (:func:`~crane_reference.stream.targets.reach`);
        every change is still checked around the whole ellipse."""
        low, high = server.reach(self._params.ellipse_b, (0.0, self._params.z_increment))
        for name in ("ellipse.a", "ellipse.b"):
            spec = SPECS[name]
            descriptor = spec.descriptor()
            descriptor.floating_point_range = [FloatingPointRange(from_value=low, to_value=high, step=0.0)]
            descriptor.additional_constraints = (
                f"must be a number in [{low:g}, {high:g}] m: E's reach from the column's axis at the start and "
                "target heights (computed at configure); the whole ellipse is checked when it is set")
            self.set_descriptor(name, descriptor)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Publish from the next sample on (stamps continue from the clock's present time); a reference
        stopped by a deactivation resumes along a speed ramp."""
        self._starting = "activating: waiting for the first second of motion"
        if self._server.stream.state == PAUSED and self._resume_on_activate and self._server.computing:
            self._server.command("resume", accepted_ns=self._now())
        self._resume_on_activate = False
        self._publisher.start()
        self.get_logger().info(f"publishing the {self._params.model} crane's reference at {self._rate} Hz")
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Bring a moving reference to rest along a speed ramp, publish it to the first sample at rest, then
        stop publishing (the reference is held there)."""
        stream = self._server.stream
        self._resume_on_activate = stream.state == RUNNING and stream.rate > 0.0
        self._server.come_to_rest(self._now(), self._stop)
        self._stop_publishing()
        self._starting = "inactive: publishing stopped; activate to publish again"
        self.get_logger().info("deactivated: the reference is at rest and no longer published")
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """End the solver and release the server and the publishers."""
        self._release()
        self._starting = "unconfigured"
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop_publishing()
        self._release()
        self._starting = "finalized"
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop_publishing()
        self._release()
        self._starting = "unconfigured after an error in a transition"
        return TransitionCallbackReturn.SUCCESS

    def _stop_publishing(self) -> None:
        if self._publisher is not None:
            self._publisher.stop()

    def _release(self) -> None:
        server, publisher, self._server, self._publisher = self._server, self._publisher, None, None
        if server is not None:
            server.close()
        if publisher is not None:
            publisher.destroy()

    # -- set-up ---------------------------------------------------------------------------------------

    def _pre_set_parameters(self, parameters: list[Parameter]) -> list[Parameter]:
        """The pre-set callback (the only one: rclpy concatenates the lists its pre-set callbacks return), run
        before rclpy's own checks: reject parameters this node does not have, naming them and the node's
        parameters (rclpy's own message lists neither), then :func:`~.parameters.coerce_parameters`."""
        unknown = [p.name for p in parameters if not self.has_parameter(p.name)]
        if unknown:
            raise ParameterNotDeclaredException(
                f"{', '.join(unknown)}: not a parameter of {self.get_fully_qualified_name()}; its parameters are "
                f"{self._parameter_names()}")
        return coerce_parameters(parameters)

    def _parameter_names(self) -> str:
        return ", ".join(sorted(self.get_parameters_by_prefix("")))

    def _check_overrides(self) -> None:
        """Refuse to start with a parameter override (``-p``, a params file) for a name the node lacks."""
        unknown = sorted(name for name in self._parameter_overrides
                         if not self.has_parameter(name) and not name.startswith("qos_overrides."))
        if unknown:
            raise StartupError(f"unknown parameter(s) {', '.join(unknown)}; the node's parameters are "
                               f"{self._parameter_names()}")

    def _lifecycle_state(self) -> str:
        """The primary lifecycle state, from what the transitions set up: a server after configure, a
        publisher thread after activate."""
        if self._server is None:
            return "unconfigured"
        return "active" if self._publisher.active else "inactive"

    # -- commands (executor threads) ------------------------------------------------------------------

    def _on_restart(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """~/restart (while inactive): back to the static-equilibrium start of the current targets, also out of
        ERROR (refused while active: the reference would jump under a controller that follows it)."""
        state = self._lifecycle_state()
        if state == "inactive":
            reply = self._server.restart_reply(self._now())
            if reply.success:
                self._publisher.trail.clear()
                self._resume_on_activate = False
        else:
            reply = Reply(False, f"refused while {state}: " + (
                "a restart makes the reference jump to the start, so it is done while inactive (deactivate, restart, "
                "activate)" if state == "active" else "configure the node first"))
        response.success, response.message = reply.success, reply.message
        self.get_logger().info(reply.message)
        return response

    def _on_pause(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        """~/pause: data true holds the reference (zero velocity), data false resumes it."""
        reply = (self._server.pause(request.data, self._now()) if self._server is not None
                 else Reply(False, f"refused while {self._lifecycle_state()}: configure first"))
        response.success, response.message = reply.success, reply.message
        self.get_logger().info(f"~/pause {request.data}: {reply.message}")
        return response

    def _on_speed_scaling(self, msg: Float64) -> None:
        """~/speed_scaling (std_msgs/Float64): sets the speed_scaling parameter (same checks and ramp)."""
        result = self.set_parameters([Parameter("speed_scaling", Parameter.Type.DOUBLE, float(msg.data))])[0]
        if not result.successful:
            self.get_logger().error(f"~/speed_scaling rejected: {result.reason}", throttle_duration_sec=1.0)

    def _validate_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        """On-set callback: :func:`.settings.refusal`."""
        reason = settings.refusal(parameters, self._params, self._server)
        return SetParametersResult(successful=reason is None, reason=reason or "")

    def _apply_parameters(self, parameters: list[Parameter]) -> None:
        """Post-set callback: apply accepted values (:func:`.settings.apply`)."""
        names = [p.name for p in parameters if p.name in SPECS]
        self._params = self._params.changed(parameters)
        if "status_period" in names:
            self._status_timer.timer_period_ns = round(self._params.status_period * NANOSECONDS)
            self._status_timer.reset()
        server = self._server
        if server is None:  # the values are read at configure
            return
        if set(settings.MESSAGE_PARAMETERS) & set(names):
            self._publisher.settings = settings.publish_settings(self._params, server.info.joint_names)
        try:
            for line in settings.apply(server, self._params, names, self._now()):
                self.get_logger().info(line)
        except CommandRefusedError as error:  # the solver stopped since the on-set check
            self.get_logger().error(f"{', '.join(names)} set but not applied: {error}")

    def _log_status(self) -> None:
        """One-line status: stream time, E, residual, achieved rate, state."""
        server = self._server
        sample = server.last_sample()[0] if server is not None else None
        if sample is None:
            return
        x, y, z = sample.ee_position
        self.get_logger().info(
            f"t={sample.t:.3f} s E=({x:.3f}, {y:.3f}, {z:.3f}) m residual={sample.residual_distance:.1e} m "
            f"rate={self._diagnostics.achieved_rate:.1f} Hz state={server.stream.state}")

    def destroy_node(self) -> None:
        """Stop the publisher and diagnostics threads and the solver, then destroy the node."""
        self._stop.set()
        self._stop_publishing()
        if self._server is not None:
            self._server.close()
            self._server = None
        self._diagnostics.join()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """Run the node until SIGINT / shutdown; exit code 0, or 1 if it cannot start.

    ``args`` are the command line arguments for ``rclpy.init`` (``None``: ``sys.argv``), e.g.
    ``['--ros-args', '-p', 'ellipse.a:=3.5']``.
    """
    rclpy.init(args=args)
    node = None
    try:
        node = CraneReferenceNode()
        gc.freeze()  # the start-up's objects (modules, kernels, the stream) out of the collector's full passes,
        rclpy.spin(node)  # which would otherwise hold the GIL over all of them while samples are due
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (StartupError, ConfigError, ParameterError) as error:
        rclpy.logging.get_logger(NODE_NAME).fatal(f"cannot start: {error}")
        return 1
    except Exception:
        if rclpy.ok():
            raise  # a real failure; otherwise SIGINT / SIGTERM shut the context down while starting
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())

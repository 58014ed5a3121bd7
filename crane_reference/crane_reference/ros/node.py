"""ROS 2 node publishing the crane's programmed motion as a reference: ``ros2 run crane_reference node``.

A managed (lifecycle) node that only wires, as ros2/demos' lifecycle talker does: the reference is served by the
ROS-free :class:`~crane_reference.stream.server.ReferenceServer` (frame schedule, computing ahead, commands and
their timing; its solver in a process of its own or a thread); the parameters are one declared table
(:mod:`.parameters`) whose changes :mod:`.parameter_policy` refuses or applies; :mod:`.publishing` sends each sample at
its stamp, ~/markers and /diagnostics.  ``configure`` starts the solver (kernels made ready, the start and the
first second of motion computed) and creates the publishers; ``activate`` publishes; ``deactivate`` ramps a
moving reference to rest, publishes it to the first sample at rest and stops; ``cleanup`` / ``shutdown`` end
the solver; ``autostart`` (default) configures and activates at construction.  The topics, services,
parameters and their timing are those of the README's "The node".
"""

from __future__ import annotations

import gc
import sys
import threading
from contextlib import suppress

import rclpy
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import JumpThreshold, TimeJump
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from std_msgs.msg import Float64
from std_srvs.srv import SetBool, Trigger

from ..base.health import CANNOT, StartupError
from ..interface import messages
from ..model.config import ConfigError, load_config
from ..model.units import NANOSECONDS
from ..stream.reference_stream import PAUSED, RUNNING
from ..stream.served import CommandRefusedError
from ..stream.server import ReferenceServer
from ..stream.solver_messages import SolverStoppedError
from . import parameter_policy, service_replies
from .message_types import rclpy_types
from .parameter_spec import ParameterError, pre_set_callback
from .parameters import SPECS, declare_all, declare_from_config, reach_descriptor
from .publishing import DiagnosticsPublisher, SamplePublisher
from .retarget_action import RetargetActionServer
from .running import spin_once
from .sample_encoder import SampleEncoder

NODE_NAME = messages.NODE_NAME


class CraneReferenceNode(LifecycleNode):
    """Publishes the reference of the crane's programmed motion; see the module documentation."""

    def __init__(self, node_name: str = NODE_NAME, **kwargs) -> None:
        """Declare and read the parameters, publish diagnostics, and with ``autostart`` configure and activate;
        ``kwargs`` go to :class:`rclpy.node.Node`.  Raises ParameterError if a parameter's override is refused by
        the table or names no parameter.  A configure that fails (a target out of reach, a crane file that does
        not load, no consistent start), with ``autostart`` too, leaves the node unconfigured, saying why at ERROR
        with the remedy: set what it names, then configure."""
        super().__init__(node_name, **{"automatically_declare_parameters_from_overrides": True, **kwargs})
        self._types = rclpy_types()
        self._server: ReferenceServer | None = None
        self._publisher: SamplePublisher | None = None
        self._stop = threading.Event()  # the node is being destroyed
        self._activity = "unconfigured"  # the diagnostics' message while not publishing
        self._diagnostics = DiagnosticsPublisher(self, self._types, self._current_activity, lambda: self._server,
                                                 self._stop)
        try:
            self._params, self._pending = declare_all(self)
        except Exception as error:
            self._fail_start(error)
            raise
        except BaseException:  # KeyboardInterrupt while starting
            self._stop.set()
            raise
        self.add_pre_set_parameters_callback(pre_set_callback(self, SPECS))
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.create_service(Trigger, "~/restart", self._on_restart)
        self.create_service(SetBool, "~/pause", self._on_pause)
        self._retarget = RetargetActionServer(self, self._types, lambda: self._server, lambda: self._params,
                                              lambda: self._lifecycle_state() == "active",
                                              self._params.action_monitor_rate)
        self.create_subscription(Float64, messages.SPEED_SCALING_TOPIC, self._on_speed_scaling,
                                 messages.PUBLISHER_DEPTH)
        self._status_timer = self.create_timer(self._params.status_period, self._diagnostics.log_status)
        self._jump_handle = self.get_clock().create_jump_callback(  # a looped bag, a simulator reset
            JumpThreshold(min_forward=None, min_backward=Duration(nanoseconds=-1), on_clock_change=True),
            post_callback=self._clock_jumped)
        if self._params.autostart and self.trigger_configure() == TransitionCallbackReturn.SUCCESS:
            self.trigger_activate()

    def _fail_start(self, error: Exception) -> None:
        """Report in /diagnostics (ERROR) and stop the diagnostics thread: the node cannot start."""
        self._activity = f"{CANNOT} start: {error}"
        with suppress(Exception):  # the context may be shutting down already
            self._diagnostics.publish()
        self._stop.set()

    def _current_activity(self) -> str:
        """What the node is doing, for the diagnostics while it does not publish."""
        if self._publisher is not None and self._publisher.waiting_for_clock:
            return "activating: waiting for /clock (use_sim_time is true and ROS time is 0)"
        return self._activity

    def _clock_jumped(self, jump: TimeJump) -> None:
        """rclpy's jump callback: a jump back goes to the server, which re-anchors beyond its catch-up limit."""
        if self._server is not None and jump.delta.nanoseconds < 0:
            self._server.clock_went_back(self._now())

    def _stopping(self) -> bool:
        """Whether the node is being destroyed or its context shut down (SIGINT, SIGTERM)."""
        return self._stop.is_set() or not self.context.ok()

    def _now(self) -> int:
        return self.get_clock().now().nanoseconds

    # -- lifecycle --------------------------------------------------------------------------------------

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Load the crane and the task, start the solver (kernels made ready, the start and the first second
        of motion computed), create the publishers; the server computes ahead from here on."""
        solver = None
        try:
            config = load_config(self._params.config_file or None)
            if self._pending:  # the crane file could not be loaded at construction: its defaults now
                self._params = declare_from_config(self, self._pending, config, self._params)
                self._pending = ()
            v = self._params
            where = "in its own process" if v.solver_process else "in this process"
            self._activity = (f"configuring: starting the solver {where}; it makes its kernels ready (compiled on a "
                              "first start, else loaded) and computes the start")
            self.get_logger().info(f"starting the solver {where} (with an empty kernel cache it compiles for a minute "
                                   "or two; `crane-reference compile` after installing does it ahead)")
            solver = parameter_policy.start_solver(v, config, self._stopping)
            messages_settings = parameter_policy.publish_settings(v, solver.info.joint_names)
            encode = SampleEncoder(self._types, solver.info.joint_names, messages_settings.frame_id)
            server = ReferenceServer(solver, v.publish_rate, v.command_lead, parameter_policy.preview(v),
                                     encode=encode)
        except (StartupError, ConfigError, ParameterError) as error:
            if solver is not None:  # the preview's joints are not the model's
                solver.close()
            self._activity = (f"{CANNOT} configure: {error}; unconfigured: set the parameter it names (or mend the "
                              "crane file), then configure")
            self.get_logger().error(self._activity)
            return TransitionCallbackReturn.FAILURE
        except SolverStoppedError as error:  # shutting down while the solver started
            self._activity = f"{CANNOT} configure: {error}"
            return TransitionCallbackReturn.FAILURE
        self._server = server
        self.get_logger().info(f"solver {server.info.kernels}")
        low, high = server.reach(v.ellipse_b, (0.0, v.z_increment))
        for name in ("ellipse.a", "ellipse.b"):  # the ranges narrowed to E's reach (rqt_reconfigure's sliders)
            self.set_descriptor(name, reach_descriptor(SPECS[name], low, high))
        self._publisher = SamplePublisher(self, self._types, server, messages_settings, encode)
        self._resume_on_activate = False
        self._activity = "inactive: configured, computing ahead; activate to publish"
        self.get_logger().info(f"configured: the {v.model} crane ({len(server.info.joint_names)} joints, "
                               f"config {v.config_file or 'packaged default'})")
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Publish from the next sample on (stamps continue from the clock's present time); a reference
        stopped by a deactivation resumes along a speed ramp."""
        self._activity = "activating: waiting for the first second of motion"
        if self._server.stream.state == PAUSED and self._resume_on_activate and self._server.computing:
            self._server.command("resume", accepted_ns=self._now())
        self._resume_on_activate = False
        result = super().on_activate(state)  # the lifecycle publishers enabled before the thread publishes
        self._publisher.start()
        self.get_logger().info(f"publishing the {self._params.model} crane's reference at "
                               f"{self._params.publish_rate} Hz")
        return result

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Bring a moving reference to rest along a speed ramp, publish it to the first sample at rest, then
        stop publishing (the reference is held there)."""
        stream = self._server.stream
        self._resume_on_activate = stream.state == RUNNING and stream.target_speed > 0.0
        at_rest = self._server.come_to_rest(self._now(), self._stop)
        self._stop_publishing()
        self._activity = "inactive: publishing stopped; activate to publish again"
        if at_rest:
            self.get_logger().info("deactivated: the reference is at rest and no longer published")
        else:
            self.get_logger().error(f"deactivated: the solver stopped ({self._server.schedule.fault or 'closed'}), so "
                                    "the reference stopped at its held sample, not at rest; cleanup and configure "
                                    "start a new solver")
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """End the solver and release the server and the publishers."""
        self._release()
        self._activity = "unconfigured"
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._finish("finalized")

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._finish("unconfigured after an error in a transition")

    def _finish(self, doing: str) -> TransitionCallbackReturn:
        self._stop_publishing()
        self._release()
        self._activity = doing
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
            reply = service_replies.restart_reply(self._server, self._now())
            if reply.success:
                self._publisher.trail.clear()
                self._resume_on_activate = False
        else:
            reply = service_replies.Reply(False, f"refused while {state}: " + (
                "a restart makes the reference jump to the start, so it is done while inactive (deactivate, restart, "
                "activate)" if state == "active" else "configure the node first"))
        response.success, response.message = reply.success, reply.message
        self.get_logger().info(reply.message)
        return response

    def _on_pause(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        """~/pause: data true holds the reference (zero velocity), data false resumes it."""
        reply = (service_replies.pause_reply(self._server, request.data, self._now()) if self._server is not None
                 else service_replies.Reply(False, f"refused while {self._lifecycle_state()}: configure first"))
        response.success, response.message = reply.success, reply.message
        self.get_logger().info(f"~/pause {request.data}: {reply.message}")
        return response

    def _on_speed_scaling(self, msg: Float64) -> None:
        """~/speed_scaling (std_msgs/Float64): sets the speed_scaling parameter (same checks and ramp)."""
        result = self.set_parameters([Parameter("speed_scaling", Parameter.Type.DOUBLE, float(msg.data))])[0]
        if not result.successful:
            self.get_logger().error(f"~/speed_scaling rejected: {result.reason}", throttle_duration_sec=1.0)

    def _validate_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        """On-set callback: :func:`.parameter_policy.refusal`."""
        reason = parameter_policy.refusal(parameters, self._params, self._server)
        return SetParametersResult(successful=reason is None, reason=reason or "")

    def _apply_parameters(self, parameters: list[Parameter]) -> None:
        """Post-set callback: apply accepted values (:func:`.parameter_policy.apply`)."""
        names = [p.name for p in parameters if p.name in SPECS]
        self._params = self._params.changed(parameters)
        if "status_period" in names:
            self._status_timer.timer_period_ns = round(self._params.status_period * NANOSECONDS)
            self._status_timer.reset()
        server = self._server
        if server is None:  # the values are read at configure
            return
        if set(parameter_policy.MESSAGE_PARAMETERS) & set(names):
            self._publisher.settings = parameter_policy.publish_settings(self._params, server.info.joint_names)
        try:
            for line in parameter_policy.apply(server, self._params, names, self._now()):
                self.get_logger().info(line)
        except CommandRefusedError as error:  # the solver stopped since the on-set check
            self.get_logger().error(f"{', '.join(names)} set but not applied: {error}")

    def destroy_node(self) -> None:
        """Stop the publisher and diagnostics threads and the solver, then destroy the node."""
        self._stop.set()
        self._stop_publishing()
        if self._server is not None:
            self._server.close()
            self._server = None
        self._diagnostics.join()
        self._retarget.destroy()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """Run the node until SIGINT / shutdown; exit code 0, or 1 if a parameter's override is refused (a failed
    configure leaves it running, unconfigured).

    ``args`` are the command line arguments for ``rclpy.init`` (``None``: ``sys.argv``), e.g.
    ``['--ros-args', '-p', 'ellipse.a:=3.5']``.
    """
    rclpy.init(args=args)
    node = None
    try:
        node = CraneReferenceNode()
        gc.freeze()  # the start-up's objects (modules, kernels, the stream) out of the collector's full passes,
        executor = SingleThreadedExecutor()  # which would otherwise hold the GIL over all of them while samples
        executor.add_node(node)  # are due
        while node.context.ok():
            spin_once(executor, node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ParameterError as error:
        rclpy.logging.get_logger(NODE_NAME).fatal(f"{CANNOT} start: {error}")
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

"""The node's ``~/retarget`` action (crane_reference_interfaces/action/Retarget): re-targets with goal, feedback
and result, served as joint_trajectory_controller serves ``follow_joint_trajectory``.

* A goal is refused (REJECTED at the goal response, the reason in the log, as joint_trajectory_controller refuses
  an invalid trajectory) while the node is not active, or if its targets or blend time are not allowed: they are
  checked as the target parameters are (:func:`.parameter_policy.refusal`: their ranges, NaN, E's reach).
* An accepted goal is checked again as it begins; one that has become invalid meanwhile is aborted with
  ``INVALID_GOAL`` and the reason.  Otherwise it re-targets the stream over its blend time
  (:class:`~crane_reference.stream.retarget_goal.RetargetGoal`) and sets the target parameters to its targets,
  so that they show the targets in force.
* Feedback at ``monitor_rate`` (the node's ``action_monitor_rate``, Hz of wall time): the stamp of the last
  sample published, the blend's progress and E's distance to the new path.
* The result, once the first sample on the new path is published: its stamp and that of the blend's first sample.
* A newer goal, or a change of the target parameters, pre-empts a goal (aborted, ``PREEMPTED``: rclpy ends a goal
  as canceled only after a cancel request, where joint_trajectory_controller cancels it), unless its first sample
  on the new path was published before (then it succeeds, also between two monitor ticks); a cancel sets the
  target parameters back to those before the goal (their blend, over ``blend_time``, brings the old path back); a
  goal is aborted (``STOPPED``) if the node stops publishing, its solver stops or its stream goes to ERROR first,
  or the node is destroyed.  While the stream is paused (speed 0) a goal waits.
"""

from __future__ import annotations

from collections.abc import Callable

from crane_reference_interfaces.action import Retarget
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.action.server import ServerGoalHandle
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.task import Future

from ..interface import messages
from ..interface.messages import MessageTypes
from ..motion.simulation import SOLVER_FAILURES
from ..stream.reference_stream import ERROR
from ..stream.retarget_goal import PREEMPTED, REACHED, STOPPED, GoalEnd, RetargetGoal
from ..stream.served import CommandRefusedError
from ..stream.server import ReferenceServer
from .parameter_policy import refusal
from .parameter_spec import field_name
from .parameters import TARGET_PARAMETERS, NodeParameters
from .service_replies import sample_named

OUTCOME_CODES = {REACHED: Retarget.Result.SUCCESSFUL, PREEMPTED: Retarget.Result.PREEMPTED,
                 STOPPED: Retarget.Result.STOPPED}
"""The result's error code of each way a goal ends (:class:`~crane_reference.stream.retarget_goal.GoalEnd`)."""
GOAL_FIELDS = {name: field_name(name) for name in TARGET_PARAMETERS}
"""The target parameters and the goal fields that carry them."""


def goal_parameters(request: Retarget.Goal) -> list[Parameter]:
    """The target parameters a goal sets, then ``blend_time`` if it gives one (0: the node's)."""
    targets = [Parameter(name, value=float(getattr(request, field))) for name, field in GOAL_FIELDS.items()]
    return targets + ([Parameter("blend_time", value=float(request.blend_time))] if request.blend_time != 0.0 else [])


class RetargetActionServer:
    """See the module documentation."""

    def __init__(self, node: Node, types: MessageTypes, server: Callable[[], ReferenceServer | None],
                 params: Callable[[], NodeParameters], active: Callable[[], bool], monitor_rate: float) -> None:
        """Serve ``~/retarget`` on ``node``; ``server``, ``params`` and ``active`` give the node's server (None
        while unconfigured), its parameter values and whether it publishes; an active goal is checked at
        ``monitor_rate`` [Hz]."""
        self._node, self._types = node, types
        self._server, self._params, self._active = server, params, active
        self._goal: tuple[ServerGoalHandle, RetargetGoal, Future] | None = None
        self._action = ActionServer(node, Retarget, "~/retarget", self._execute, goal_callback=self._on_goal,
                                    cancel_callback=self._on_cancel)
        self._timer = node.create_timer(1.0 / monitor_rate, self._tick, clock=Clock(clock_type=ClockType.STEADY_TIME),
                                        autostart=False)  # runs while a goal is active

    def destroy(self) -> None:
        """End an active goal (STOPPED) and the action server."""
        if self._goal is not None:
            self._end_active(self._goal[0].abort, Retarget.Result.STOPPED, "the node was destroyed")
        self._timer.cancel()
        self._node.destroy_timer(self._timer)
        self._action.destroy()

    def _on_goal(self, request: Retarget.Goal) -> GoalResponse:
        """Refuse goals while the node is not active, and goals whose targets or blend time are not allowed (as
        joint_trajectory_controller refuses an invalid goal)."""
        server = self._server()
        if server is None or not self._active():
            reason = "the node is not active"
        else:
            try:
                reason = refusal(goal_parameters(request), self._params(), server)
            except (CommandRefusedError, *SOLVER_FAILURES) as error:
                reason = f"{type(error).__name__}: {error}"
        if reason is None:
            return GoalResponse.ACCEPT
        self._node.get_logger().error(f"~/retarget goal refused: {reason}")
        return GoalResponse.REJECT

    def _on_cancel(self, goal_handle: ServerGoalHandle) -> CancelResponse:
        return CancelResponse.ACCEPT

    async def _execute(self, goal_handle: ServerGoalHandle) -> Retarget.Result:
        """Check the goal, re-target, then wait for its end (:meth:`_tick` finishes it)."""
        request, params, server = goal_handle.request, self._params(), self._server()
        parameters = goal_parameters(request)
        targets, blend = parameters[:len(GOAL_FIELDS)], parameters[len(GOAL_FIELDS):]
        Result = Retarget.Result
        if goal_handle.is_cancel_requested:
            return self._end_goal(goal_handle, goal_handle.canceled, Result.CANCELED, "canceled before it began")
        if server is None or not self._active():
            return self._end_goal(goal_handle, goal_handle.abort, Result.STOPPED, "the node is no longer active")
        if server.stream.state == ERROR:
            return self._end_goal(goal_handle, goal_handle.abort, Result.STOPPED,
                             f"the stream is in ERROR ({server.stream.last_error})")
        try:
            server.check_computing()  # a stopped solver is STOPPED, not an invalid goal
            reason = refusal(parameters, params, server)
            if reason is not None:
                return self._end_goal(goal_handle, goal_handle.abort, Result.INVALID_GOAL, reason)
            goal = RetargetGoal(server, params.changed(targets).targets(), params.changed(blend).blend_time,
                                self._node.get_clock().now().nanoseconds)
        except (CommandRefusedError, *SOLVER_FAILURES) as error:
            return self._end_goal(goal_handle, goal_handle.abort, Result.STOPPED, f"{type(error).__name__}: {error}")
        self._preempt("a newer goal took over")
        result = self._node.set_parameters_atomically(targets)  # the targets in force: no second re-target
        if not result.successful:
            self._node.get_logger().error(f"~/retarget: the target parameters were not set: {result.reason}")
        done = Future()
        self._goal = goal_handle, goal, done
        self._timer.reset()
        self._node.get_logger().info(f"~/retarget: re-targeting to {goal.targets} from "
                                     f"{sample_named(server, goal.blend.k)} over {goal.blend_time:g} s")
        return await done

    def _tick(self) -> None:
        """Feedback of the active goal, or its end: reached, canceled, pre-empted or stopped."""
        if self._goal is None:
            return
        goal_handle, goal, _ = self._goal
        end = goal.end(self._serving(goal))
        if end is not None:
            self._end_by_outcome(end)
        elif goal_handle.is_cancel_requested:
            result = self._node.set_parameters_atomically([Parameter(name, value=getattr(goal.previous, field))
                                                           for name, field in TARGET_PARAMETERS.items()])
            self._end_active(goal_handle.canceled, Retarget.Result.CANCELED,
                             f"canceled: blending back to {goal.previous}" if result.successful
                             else f"canceled, but the targets before it were refused: {result.reason}")
        else:
            published = goal.server.last_sample()
            if published.sample is not None:
                feedback = goal.feedback(published.sample, published.stamp_ns)
                goal_handle.publish_feedback(Retarget.Feedback(
                    stamp=messages.time_msg(self._types, feedback.stamp_ns), progress=feedback.progress,
                    ellipse_error=feedback.ellipse_error, height_error=feedback.height_error))

    def _preempt(self, why: str) -> None:
        """End the active goal as a newer command takes over: reached if its new path was published, else
        pre-empted for ``why``."""
        if self._goal is not None:
            goal = self._goal[1]
            self._end_by_outcome(goal.end(self._serving(goal), preempted_by=why) or GoalEnd(PREEMPTED, why))

    def _serving(self, goal: RetargetGoal) -> bool:
        """Whether the goal's server still publishes for it."""
        return self._server() is goal.server and self._active()

    def _end_by_outcome(self, end: GoalEnd) -> None:
        """End the active goal as ``end`` says: succeeded if reached, else aborted with the outcome's code."""
        goal_handle = self._goal[0]
        self._end_active(goal_handle.succeed if end.outcome == REACHED else goal_handle.abort,
                         OUTCOME_CODES[end.outcome], end.message)

    def _end_active(self, end: Callable[[], None], code: int, message: str) -> None:
        """End the active goal with ``end`` (succeed, abort, canceled), the result ``code`` and ``message``."""
        goal_handle, goal, done = self._goal
        self._goal = None
        self._timer.cancel()
        done.set_result(self._end_goal(goal_handle, end, code, message, goal.blend_stamp_ns, goal.path_stamp_ns))

    def _end_goal(self, goal_handle: ServerGoalHandle, end: Callable[[], None], code: int, message: str,
                  blend_stamp_ns: int | None = None, path_stamp_ns: int | None = None) -> Retarget.Result:
        """End ``goal_handle`` with ``end`` and its result: ``code``, ``message`` and the stamps (zero if not
        published)."""
        end()
        if code == Retarget.Result.SUCCESSFUL:  # a call site per severity: rclpy refuses to change it at one
            self._node.get_logger().info(f"~/retarget goal {message or 'reached'}")
        else:
            self._node.get_logger().warning(f"~/retarget goal {message}")
        return Retarget.Result(error_code=code, error_string=message,
                               blend_stamp=messages.time_msg(self._types, blend_stamp_ns or 0),
                               path_stamp=messages.time_msg(self._types, path_stamp_ns or 0))

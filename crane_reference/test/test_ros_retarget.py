"""The node's ``~/retarget`` action with an rclpy action client, as another process would use it: the result's
stamps against the published path (E's poses on the old and the new ellipse), cancel, pre-emption, refusal while
not active and invalid goals."""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
from action_msgs.msg import GoalStatus
from crane_reference_interfaces.action import Retarget
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rclpy.action import ActionClient
from rclpy.parameter import Parameter
from test_ros_node import NODE, NS, Harness, change_state, diagnostic_messages, stamp_ns

from crane_reference.ros.node import CraneReferenceNode
from crane_reference.ros.parameter_policy import refusal
from crane_reference.ros.retarget_action import goal_parameters

RATE = 100  # [Hz]
ON_PATH = 1e-9  # E's ellipse residual (5.1) on the path (as the node's parameter test)


class Client:
    """An action client of the node's ~/retarget on the harness's probe node, with each goal's feedback."""

    def __init__(self, ros: Harness) -> None:
        self.ros = ros
        self.action = ActionClient(ros.probe, Retarget, f"/{NODE}/retarget")
        assert self.action.wait_for_server(timeout_sec=10.0)
        # the server's services answer before its feedback publisher has discovered this client: a goal sent
        # earlier loses its first feedback messages (volatile, as rclpy's action topics are)
        ros.wait_for(lambda: ros.node.count_subscribers(f"/{NODE}/retarget/_action/feedback") >= 1,
                     "the node to discover the client's feedback subscription")

    def send(self, feedback: list | None = None, **goal: float) -> Any:
        """The goal handle of ``goal`` (the node's targets by default) once the node answered it."""
        request = Retarget.Goal(**{"ellipse_a": 3.0, "ellipse_b": 2.0, "z_increment": 0.2, "z_rise_time": 5.0, **goal})
        future = self.action.send_goal_async(request, feedback_callback=None if feedback is None else
                                             lambda message: feedback.append(message.feedback))
        return self.ros.result(future)

    def result(self, goal_handle: Any, timeout: float = 15.0) -> Any:
        """The goal's status and result."""
        return self.ros.result(goal_handle.get_result_async(), timeout)


def ns(stamp: Any) -> int:
    return stamp.sec * NS + stamp.nanosec


def received_poses(ros: Harness) -> list:
    """The poses of E received so far (a snapshot: the list grows while the test reads it)."""
    return [m for _, m in list(ros.received["pose"])]


def ellipse_residuals(poses: list, a: float, b: float) -> tuple[np.ndarray, np.ndarray]:
    """Stamps [ns] of ``poses`` of E and their residuals of the ellipse (5.1) with semi-axes a, b."""
    p = np.array([[m.pose.position.x, m.pose.position.y] for m in poses])
    return np.array([stamp_ns(m) for m in poses]), (p[:, 0] / a) ** 2 + (p[:, 1] / b) ** 2 - 1.0


def test_a_goal_gets_feedback_and_the_stamp_from_which_the_published_path_is_the_new_one(ros: Harness) -> None:
    node = ros.start(publish_rate=RATE, model="rigid")
    client = Client(ros)
    ros.published_for(0.3)
    feedback: list = []
    blend = 0.8
    goal_handle = client.send(feedback, ellipse_a=3.3, ellipse_b=2.2, blend_time=blend)
    assert goal_handle.accepted
    answer = client.result(goal_handle)
    assert answer.status == GoalStatus.STATUS_SUCCEEDED, answer.result.error_string
    result = answer.result
    assert result.error_code == Retarget.Result.SUCCESSFUL
    blend_stamp, path_stamp = ns(result.blend_stamp), ns(result.path_stamp)
    # at speed 1 the blend spans blend_time of stamps, to a period (samples held by a late solver delay it)
    assert blend * NS - NS // RATE <= path_stamp - blend_stamp <= (blend + 0.2) * NS
    ros.wait_until_stamp(path_stamp + NS // 2)
    poses = received_poses(ros)
    stamps, old = ellipse_residuals(poses, 3.0, 2.0)
    _, new = ellipse_residuals(poses, 3.3, 2.2)
    before, after = stamps < blend_stamp, stamps >= path_stamp
    assert before.sum() > 10 and after.sum() > 10
    assert np.abs(old[before]).max() < ON_PATH and np.abs(new[after]).max() < ON_PATH
    assert np.abs(new[before]).min() > 1e-3 and np.abs(old[after]).min() > 1e-3
    middle = (stamps > blend_stamp + NS * blend / 4) & (stamps < path_stamp - NS * blend / 4)
    assert np.abs(new[middle]).min() > 1e-4 and np.abs(old[middle]).min() > 1e-4  # blending: on neither
    # feedback at the monitor rate: progress from 0 towards 1, E's distance to the new ellipse shrinking
    monitor_period = 1.0 / node.get_parameter("action_monitor_rate").value
    ros.wait_for(lambda: len(feedback) >= blend / monitor_period - 2, "the goal's feedback")
    progress = [f.progress for f in feedback]
    assert progress == sorted(progress) and 0.0 <= progress[0] < 0.5 and 0.5 < progress[-1] <= 1.0
    assert abs(feedback[0].ellipse_error) > 1e-3 and abs(feedback[-1].ellipse_error) < abs(feedback[0].ellipse_error)
    assert all(math.isfinite(f.height_error) for f in feedback)
    assert node.get_parameter("ellipse.a").value == 3.3 and node.get_parameter("ellipse.b").value == 2.2
    assert node.get_parameter("blend_time").value == 2.0  # the goal's blend time was its own


def test_a_newer_goal_preempts_and_a_cancel_blends_the_old_targets_back(ros: Harness) -> None:
    node = ros.start(publish_rate=RATE, model="rigid", blend_time=0.5)  # the blend back after a cancel
    client = Client(ros)
    first = client.send(ellipse_a=3.2, blend_time=3.0)
    assert first.accepted
    ros.published_for(0.3)
    second = client.send(ellipse_a=3.4, blend_time=3.0)
    answer = client.result(first)
    assert answer.status == GoalStatus.STATUS_ABORTED and answer.result.error_code == Retarget.Result.PREEMPTED
    assert node.get_parameter("ellipse.a").value == 3.4
    ros.published_for(0.3)
    ros.result(second.cancel_goal_async())
    answer = client.result(second)
    canceled = time.monotonic()
    assert answer.status == GoalStatus.STATUS_CANCELED and answer.result.error_code == Retarget.Result.CANCELED
    assert node.get_parameter("ellipse.a").value == 3.2  # the targets before the canceled goal
    ros.wait_for(lambda: ros.received["pose"][-1][0] > canceled + 0.5 + 0.3, "the blend back", 10.0)
    _, back = ellipse_residuals(received_poses(ros), 3.2, 2.0)
    assert np.abs(back[-10:]).max() < ON_PATH  # E on the path before the canceled goal again
    # a change of the target parameters pre-empts a goal too
    third = client.send(ellipse_b=2.3, blend_time=3.0)
    ros.published_for(0.3)
    (changed,) = ros.set_parameters(Parameter("ellipse.b", value=1.9))
    assert changed.successful, changed.reason
    answer = client.result(third)
    assert answer.status == GoalStatus.STATUS_ABORTED and answer.result.error_code == Retarget.Result.PREEMPTED


def test_a_goal_reached_between_monitor_ticks_succeeds_when_a_newer_goal_comes(ros: Harness) -> None:
    """Its new path published before the newer goal (the monitor, at 0.1 Hz, has not looked since), the first goal
    succeeds with the stamp of the first sample on it."""
    ros.start(publish_rate=RATE, model="rigid", action_monitor_rate=0.1)
    client = Client(ros)
    blend = 0.2
    first = client.send(ellipse_a=3.2, blend_time=blend)
    assert first.accepted
    def on_new_path() -> bool:  # the last 5 samples on the new ellipse and off the old one (both hold x = 0,
        # where E starts at rest)
        return (abs(ellipse_residuals(received_poses(ros), 3.2, 2.0)[1][-5:]).max() < ON_PATH
                and abs(ellipse_residuals(received_poses(ros), 3.0, 2.0)[1][-5:]).min() > 1e-6)

    ros.wait_for(on_new_path, "the first goal's new path")
    client.send(ellipse_a=3.4, blend_time=3.0)
    answer = client.result(first)
    assert answer.status == GoalStatus.STATUS_SUCCEEDED, answer.result.error_string
    path_stamp = ns(answer.result.path_stamp)
    stamps, new = ellipse_residuals(received_poses(ros), 3.2, 2.0)
    assert path_stamp > ns(answer.result.blend_stamp) > 0
    assert np.abs(new[stamps >= path_stamp][:10]).max() < ON_PATH < np.abs(new[stamps < path_stamp][-1])


def test_invalid_goals_are_rejected_naming_the_field_and_the_stream_goes_on(ros: Harness) -> None:
    """As joint_trajectory_controller refuses an invalid goal: REJECTED at the goal response (which carries no
    reason), the reason, the field and what is allowed, logged as :func:`refusal` words it for the goal."""
    node = ros.start(publish_rate=RATE, model="rigid")
    client = Client(ros)
    for goal, expected in (({"ellipse_a": math.nan}, "ellipse.a = nan: must be a number in [0.1, 20] m"),
                           ({"blend_time": -1.0}, "blend_time = -1.0: must be a number in [0.01, 600] s"),
                           ({"ellipse_a": 19.0}, "not reachable")):
        request = Retarget.Goal(**{"ellipse_a": 3.0, "ellipse_b": 2.0, "z_increment": 0.2, "z_rise_time": 5.0, **goal})
        assert expected in refusal(goal_parameters(request), node._params, node._server)
        assert not client.send(**goal).accepted
    count = len(ros.received["joint_states"])
    ros.wait_for(lambda: len(ros.received["joint_states"]) > count + RATE // 2, "samples after the refusals")


def test_a_goal_is_stopped_by_a_deactivation(ros: Harness) -> None:
    ros.start(publish_rate=RATE, model="rigid", speed_scaling__ramp_time=0.2)
    client = Client(ros)
    transitions = ros.probe.create_client(ChangeState, f"/{NODE}/change_state")
    assert transitions.wait_for_service(timeout_sec=10.0)  # discovered before the goal: its blend outlasts the call
    goal_handle = client.send(ellipse_a=3.2, blend_time=30.0)
    assert goal_handle.accepted
    ros.published_for(0.2)
    deactivate = ChangeState.Request(transition=Transition(id=Transition.TRANSITION_DEACTIVATE))
    assert ros.call(transitions, deactivate).success
    answer = client.result(goal_handle)
    assert answer.status == GoalStatus.STATUS_ABORTED and answer.result.error_code == Retarget.Result.STOPPED
    assert ns(answer.result.blend_stamp) > 0 and ns(answer.result.path_stamp) == 0


def test_goals_are_refused_while_the_node_is_not_active(ros: Harness) -> None:
    node = CraneReferenceNode(context=ros.context, parameter_overrides=[
        Parameter("autostart", value=False), Parameter("publish_rate", value=RATE), Parameter("model", value="rigid")])
    ros.node = node
    ros.spin(node)
    client = Client(ros)
    assert not client.send().accepted  # unconfigured
    assert change_state(ros, Transition.TRANSITION_CONFIGURE)
    ros.wait_for(lambda: any(m.startswith("inactive") for m in diagnostic_messages(ros)), "inactive diagnostics")
    assert not client.send().accepted  # inactive
    assert change_state(ros, Transition.TRANSITION_ACTIVATE)
    answer = client.result(client.send(ellipse_a=3.1, blend_time=0.2))
    assert answer.status == GoalStatus.STATUS_SUCCEEDED, answer.result.error_string

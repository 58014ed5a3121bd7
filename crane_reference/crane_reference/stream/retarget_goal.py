"""A re-target as a goal: the blend to new targets followed to the sample from which the new path holds.

What the node's ``~/retarget`` action serves, without ROS.  A :class:`RetargetGoal` re-targets the stream
(:meth:`~.server.ReferenceServer.retarget`): E's task constraints, the ellipse (5.1) and the height (5.2), blend C2
from those in force to the goal's over its blend time (in motion time) from the command point of its acceptance.
For a published sample, :meth:`RetargetGoal.feedback` gives the blend's progress and E's distance to the new path;
the goal is reached when the first sample at or after the blend's end is published, and
:attr:`RetargetGoal.path_stamp_ns` is then that sample's stamp.  :meth:`RetargetGoal.end` says how it ended:
reached; pre-empted once the stream's targets are no longer the goal's or a newer command takes over (a newer goal,
a change of the target parameters: a re-target that begins before this blend's end drops its milestones, so a
superseded goal is never reached), unless it was reached first; stopped when the server no longer serves it, its
solver stopped, it stopped publishing (a goal accepted before publishing begins, as just after activation, waits
for it) or its stream is in ERROR.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from ..model.parameters import Task
from ..motion.simulation import paper_task_constraints
from .reference_stream import ERROR
from .sample import ReferenceSample
from .served import RetargetBlend
from .server import ReferenceServer

REACHED, PREEMPTED, STOPPED = "reached", "preempted", "stopped"


class RetargetFeedback(NamedTuple):
    """A goal's progress at a published sample stamped ``stamp_ns``: the blend's progress in motion time (0 at its
    start, 1 from its end on), E's distance [m] to the new ellipse along the ray from its centre in x-y (positive
    outside) and E's height [m] above the new path's height at the sample's motion time."""

    stamp_ns: int
    progress: float
    ellipse_error: float
    height_error: float


class GoalEnd(NamedTuple):
    """How a goal ended: ``outcome`` (:data:`REACHED`, :data:`PREEMPTED` or :data:`STOPPED`) and why."""

    outcome: str
    message: str


class RetargetGoal:
    """See the module documentation."""

    def __init__(self, server: ReferenceServer, targets: Task, blend_time: float, accepted_ns: int) -> None:
        """Re-target ``server``'s stream to ``targets`` (already checked:
        :meth:`~.server.ReferenceServer.check_targets`) over ``blend_time`` s from the command point of its
        acceptance at ``accepted_ns``.  Raises what the server's command raises."""
        self.server = server
        self.previous = server.stream.targets
        self.targets = targets
        self.blend_time = blend_time
        self.blend: RetargetBlend = server.retarget(targets, blend_time, accepted_ns)
        # publishing ending stops the goal once it has published for it (not before it begins: after activation)
        self._publishing_at_start = server.publishing
        self._published_at_start = server.schedule.counters.published
        self._ellipse, self._height = paper_task_constraints(targets, server.info.z_static).constraints

    @property
    def blend_stamp_ns(self) -> int | None:
        """The stamp [ns] of the first sample published at or after the blend's start, None until it is published."""
        return self.blend.first.stamp_ns

    @property
    def path_stamp_ns(self) -> int | None:
        """The stamp [ns] of the first sample published on the new path, None until it is published."""
        return self.blend.end.stamp_ns

    @property
    def superseded(self) -> bool:
        """Whether the stream's targets are no longer the goal's (a newer re-target took over)."""
        return self.server.stream.targets != self.targets

    def end(self, serving: bool, preempted_by: str = "") -> GoalEnd | None:
        """How the goal has ended, or None while it goes on; ``serving``: whether its server still publishes for
        the goal's owner (false once the node deactivates or replaces the server); ``preempted_by``: why a newer
        command takes over now, if one does (a goal whose new path was published before is reached all the
        same)."""
        stream = self.server.stream
        if self.path_stamp_ns is not None:
            return GoalEnd(REACHED, "")
        if preempted_by or self.superseded:
            return GoalEnd(PREEMPTED, preempted_by or "a newer re-target took over")
        stopped_publishing = not self.server.publishing and (
            self._publishing_at_start or self.server.schedule.counters.published > self._published_at_start)
        if not (serving and self.server.computing) or stopped_publishing:
            return GoalEnd(STOPPED, "publishing or the solver stopped before the new path")
        if stream.state == ERROR:
            return GoalEnd(STOPPED, f"the stream is in ERROR ({stream.last_error})")
        return None

    def feedback(self, sample: ReferenceSample, stamp_ns: int) -> RetargetFeedback:
        """The goal's progress at ``sample`` published with the stamp ``stamp_ns``: the progress is
        (t - t_0) / T_blend between 0 and 1, with t the sample's motion time, t_0 the blend's start; E's distance
        to the ellipse (5.1) of semi-axes a, b is |p_xy| (1 - 1 / rho) with rho^2 = (x / a)^2 + (y / b)^2 = Phi_1 + 1;
        its height error is Phi_2 = z_E - z_E,a(t) of (5.2).  The constraints' profiles a(t), b(t), z_E,a(t) give
        the values (plain Python: the node's process runs no compiled kernel for it)."""
        p, t = sample.ee_position, sample.t
        a, b = self._ellipse.a(t)[0], self._ellipse.b(t)[0]
        rho = math.hypot(p[0] / a, p[1] / b)
        radius = math.hypot(p[0], p[1])
        return RetargetFeedback(
            stamp_ns, min(max((t - self.blend.start) / self.blend_time, 0.0), 1.0),
            radius * (1.0 - 1.0 / rho) if rho > 0.0 else -min(a, b),  # at the centre: the nearest ellipse point
            float(p[2] - self._height.z(t)[0]))

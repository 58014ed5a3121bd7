"""Re-targets as goals (:mod:`crane_reference.stream.retarget_goal`) without ROS: the stamps a goal reports are
checked against the published path itself (E on the old ellipse before the blend, on the new one from the path
stamp on), its feedback against the task's constraints (5.1)-(5.2) written out here."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator

import numpy as np
import pytest
from test_server import NS, PERIOD, RATE, STEP, publish, sample, spec, wait_ready
from test_simulation import quintic_z

from crane_reference.stream.retarget_goal import PREEMPTED, REACHED, STOPPED, RetargetGoal
from crane_reference.stream.sample import ReferenceSample
from crane_reference.stream.served import Preview
from crane_reference.stream.server import ReferenceServer
from crane_reference.stream.solver import LocalSolver

BLEND = 0.4  # [s] of motion time
ON_PATH = 1e-6  # [m]: E this close to a constraint's surface (its residual in metres) is on it


def ellipse_residual(position: np.ndarray, a: float, b: float) -> np.ndarray:
    """(5.1): (x / a)^2 + (y / b)^2 - 1 for positions (N, 3)."""
    return (position[:, 0] / a) ** 2 + (position[:, 1] / b) ** 2 - 1.0


@pytest.fixture
def server() -> Iterator[ReferenceServer]:
    served = ReferenceServer(LocalSolver(spec()), RATE, 0.05, Preview(0.2, 4, 10))
    try:
        wait_ready(served)
        yield served
    finally:
        served.close()


def test_the_path_stamp_is_where_the_published_path_becomes_the_new_one(server: ReferenceServer) -> None:
    server.begin(NS)
    before = publish(server, NS, 0.5)
    old = server.stream.targets
    new = dataclasses.replace(old, ellipse_a=old.ellipse_a + 0.3, ellipse_b=old.ellipse_b - 0.2)
    server.check_targets(new)
    goal = RetargetGoal(server, new, BLEND, before[-1].stamp_ns)
    assert goal.blend_stamp_ns is None and goal.path_stamp_ns is None
    assert goal.previous == old and not goal.superseded
    out = before + publish(server, before[-1].stamp_ns + PERIOD, BLEND + 0.3)
    stamps = np.array([o.stamp_ns for o in out])
    t = np.array([sample(o).t for o in out])
    position = np.array([sample(o).ee_position for o in out])
    path = goal.path_stamp_ns
    assert path is not None
    blend_first = int(np.searchsorted(stamps, goal.blend_stamp_ns))
    assert stamps[blend_first] == goal.blend_stamp_ns and t[blend_first] >= goal.blend.start > t[blend_first - 1]
    # the stamps a period apart at speed 1: the blend spans BLEND of them, to a period
    assert abs((path - goal.blend_stamp_ns) / NS - BLEND) <= 1.0 / RATE + STEP
    a0, b0, a1, b1 = old.ellipse_a, old.ellipse_b, new.ellipse_a, new.ellipse_b
    on_old = np.abs(ellipse_residual(position, a0, b0)) * min(a0, b0) < ON_PATH
    on_new = np.abs(ellipse_residual(position, a1, b1)) * min(a1, b1) < ON_PATH
    assert on_old[stamps < goal.blend_stamp_ns].all() and not on_new[stamps < goal.blend_stamp_ns].any()
    assert on_new[stamps >= path].all() and not on_old[stamps >= path].any()
    middle = (stamps > goal.blend_stamp_ns + NS * BLEND / 4) & (stamps < path - NS * BLEND / 4)
    assert middle.any() and not (on_old | on_new)[middle].any()  # blending: on neither
    assert (t[stamps >= path] >= goal.blend.start + BLEND - 1e-12).all()
    assert (t[stamps < path] < goal.blend.start + BLEND).all()
    assert goal.end(serving=True).outcome == REACHED


def test_feedback_is_the_distance_to_the_new_path(server: ReferenceServer) -> None:
    server.begin(NS)
    before = publish(server, NS, 0.2)
    old = server.stream.targets
    new = dataclasses.replace(old, ellipse_a=old.ellipse_a + 0.2, z_increment=old.z_increment + 0.1, rise_time=3.0)
    server.check_targets(new)
    goal = RetargetGoal(server, new, BLEND, before[-1].stamp_ns)
    z_static = server.info.z_static
    last = sample(before[-1])
    for t, offset, outward, up, progress in ((goal.blend.start + BLEND / 4, (1, 0), 0.1, 0.05, 0.25),
                                              (goal.blend.start - 0.1, (0, 1), -0.2, -0.02, 0.0),
                                              (goal.blend.start + 2 * BLEND, (0.6, 0.8), 0.3, 0.0, 1.0)):
        z_path = float(quintic_z(np.array(t), z_static, new.z_increment, new.rise_time))
        direction = np.array(offset, dtype=float)
        on_ellipse = direction / np.sqrt((direction[0] / new.ellipse_a) ** 2 + (direction[1] / new.ellipse_b) ** 2)
        xy = on_ellipse + outward * direction / np.linalg.norm(direction)
        probe = dataclasses.replace(last, t=t, ee_position=np.array([*xy, z_path + up]))
        feedback = goal.feedback(probe, 123)
        assert feedback.stamp_ns == 123
        assert feedback.progress == pytest.approx(progress, abs=1e-12)
        assert feedback.ellipse_error == pytest.approx(outward, abs=1e-12)
        assert feedback.height_error == pytest.approx(up, abs=1e-12)


def test_a_newer_retarget_preempts_a_goal_which_is_then_never_reached(server: ReferenceServer) -> None:
    """A re-target that begins within a goal's blend replaces the path the goal was heading for: the goal ends
    pre-empted, and no sample of the newer blend is taken for its path."""
    server.begin(NS)
    before = publish(server, NS, 0.2)
    old = server.stream.targets
    first = dataclasses.replace(old, ellipse_a=old.ellipse_a + 0.2)
    goal = RetargetGoal(server, first, BLEND, before[-1].stamp_ns)
    during = publish(server, before[-1].stamp_ns + PERIOD, BLEND / 2)
    assert goal.end(serving=True) is None
    server.retarget(dataclasses.replace(first, ellipse_b=old.ellipse_b + 0.1), BLEND, during[-1].stamp_ns)
    publish(server, during[-1].stamp_ns + PERIOD, 2 * BLEND)  # past both blends' ends
    assert goal.superseded and goal.end(serving=True).outcome == PREEMPTED
    assert goal.blend_stamp_ns is not None and goal.path_stamp_ns is None


def test_a_goal_reached_before_a_newer_command_stays_reached(server: ReferenceServer) -> None:
    """The newer command's reason pre-empts a goal still on its way, not one whose new path was published."""
    server.begin(NS)
    before = publish(server, NS, 0.2)
    old = server.stream.targets
    goal = RetargetGoal(server, dataclasses.replace(old, ellipse_a=old.ellipse_a + 0.2), BLEND, before[-1].stamp_ns)
    during = publish(server, before[-1].stamp_ns + PERIOD, BLEND / 2)
    end = goal.end(serving=True, preempted_by="a newer goal took over")
    assert end == (PREEMPTED, "a newer goal took over") and not goal.superseded
    after = publish(server, during[-1].stamp_ns + PERIOD, BLEND)  # past the blend's end
    server.retarget(dataclasses.replace(old, ellipse_b=old.ellipse_b + 0.1), BLEND, after[-1].stamp_ns)
    assert goal.superseded and goal.end(serving=True, preempted_by="a newer goal took over").outcome == REACHED
    assert goal.path_stamp_ns in [o.stamp_ns for o in after]


def test_a_goal_stops_with_publishing(server: ReferenceServer) -> None:
    server.begin(NS)
    before = publish(server, NS, 0.2)
    goal = RetargetGoal(server, dataclasses.replace(server.stream.targets, ellipse_a=3.2), BLEND,
                        before[-1].stamp_ns)
    assert goal.end(serving=True) is None and goal.end(serving=False).outcome == STOPPED
    server.end()
    assert goal.end(serving=True).outcome == STOPPED


def test_a_goal_accepted_before_publishing_begins_waits_for_it(server: ReferenceServer) -> None:
    """Accepted between activation and the first sample (the look-ahead being made), a goal goes on; it is
    reached once publishing begins and passes the blend, and a second one stops when publishing ends."""
    goal = RetargetGoal(server, dataclasses.replace(server.stream.targets, ellipse_a=3.2), BLEND, NS)
    assert not server.publishing and goal.end(serving=True) is None
    server.begin(NS)
    out = publish(server, NS, BLEND + 0.1)
    assert goal.end(serving=True) == (REACHED, "") and goal.path_stamp_ns in [o.stamp_ns for o in out]
    server.end()
    waiting = RetargetGoal(server, dataclasses.replace(server.stream.targets, ellipse_b=1.6), BLEND, NS)
    assert goal.end(serving=True) == (REACHED, "") and waiting.end(serving=True) is None
    server.begin(out[-1].stamp_ns + PERIOD)
    publish(server, out[-1].stamp_ns + PERIOD, 0.05)
    server.end()
    assert waiting.end(serving=True).outcome == STOPPED


def test_feedback_with_e_on_the_column_axis_is_the_nearest_ellipse_point(server: ReferenceServer) -> None:
    """E on the ellipse's centre (no ray to the ellipse): inside by the smaller semi-axis."""
    server.begin(NS)
    before = publish(server, NS, 0.1)
    targets = server.stream.targets
    goal = RetargetGoal(server, targets, BLEND, before[-1].stamp_ns)
    probe: ReferenceSample = dataclasses.replace(sample(before[-1]), ee_position=np.array([0.0, 0.0, 1.0]))
    assert goal.feedback(probe, 0).ellipse_error == -min(targets.ellipse_a, targets.ellipse_b)

"""ReferenceStream without ROS: compiled runs of several steps against one step at a time.

The stream computes ahead in compiled runs of :data:`CHUNK_STEPS` steps and keeps the solver state
only at their ends; a re-target inside a run rewinds to the run's start and steps to the re-target
instant again.  A stream asked for one step at a time keeps every state and never re-steps: both must
give the same reference, before and after a re-target that falls inside a run.
"""

from __future__ import annotations

import numpy as np

from crane_reference.model.config import load_config
from crane_reference.stream.reference_stream import CHUNK_STEPS, ReferenceStream, TaskTargets

STEP = 1e-3  # [s]
RETARGET_AT = 0.2037  # [s], inside the eleventh run of CHUNK_STEPS steps
END = 0.8  # [s], after the 0.5 s blend


def follow(stream: ReferenceStream, until: float, one_step_at_a_time: bool) -> None:
    if not one_step_at_a_time:
        stream.compute(until)
        return
    while stream.computed_until < until:
        stream.compute(stream.computed_until + 0.5 * STEP)


def test_chunked_and_stepwise_streams_agree_across_a_retarget():
    params = load_config()
    targets = TaskTargets(ellipse_a=3.2, ellipse_b=2.1, z_increment=0.1, rise_time=5.0)
    streams = []
    for one_step_at_a_time in (False, True):
        stream = ReferenceStream(params, "flexible", step=STEP, blend_time=0.5)
        follow(stream, 0.35, one_step_at_a_time)
        stream.retarget(RETARGET_AT, targets)
        follow(stream, END, one_step_at_a_time)
        streams.append(stream)
    assert CHUNK_STEPS > 1 and RETARGET_AT % (CHUNK_STEPS * STEP) > STEP  # the re-target is inside a run
    for tau in np.linspace(0.0, END, 241):
        chunked, stepwise = (s.sample(tau) for s in streams)
        np.testing.assert_array_equal(chunked.q, stepwise.q)
        np.testing.assert_array_equal(chunked.qd, stepwise.qd)
        np.testing.assert_array_equal(chunked.effort, stepwise.effort)
    # the re-target took effect: E heads for the new ellipse
    p = streams[0].sample(END).ee_position
    assert abs((p[0] / 3.2) ** 2 + (p[1] / 2.1) ** 2 - 1.0) < 1e-9

"""The publishing schedule (:mod:`crane_reference.stream.schedule`) without ROS: which sample goes out
when, commands, held samples, leaps of the stamps after a clock jump, and frames made from a real stream."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

from crane_reference.model.parameters import Task
from crane_reference.model.units import NANOSECONDS
from crane_reference.stream.reference_stream import ReferenceStream
from crane_reference.stream.schedule import Frame, FrameBatch, FrameSchedule, checked, make_frames

RATE = 100  # [Hz]
LEAD = 0.25  # [s]


@pytest.fixture(scope="module")
def stream_factory(params):
    return lambda: ReferenceStream(params, "rigid", step=1e-3)


def schedule_with(sample, frames: int = 0, lookahead: int = 100) -> FrameSchedule:
    schedule = FrameSchedule(RATE, lookahead, LEAD, 1.0, sample)
    plan = schedule.plan()
    schedule.accept(FrameBatch([Frame(k, k / RATE, sample) for k in range(frames)], 0, False), plan)
    return schedule


def test_due_samples_are_consecutive_and_the_stamps_leap_with_a_clock_jump(stream_factory):
    sample = stream_factory().sample(0.0)
    schedule = schedule_with(sample, frames=300, lookahead=300)
    # at 25 ms after the start samples 0, 1, 2 are due (stamps 0, 10, 20 ms)
    assert schedule.anchored(25_000_000, 0) == 0
    assert [k for k, _ in schedule.due(25_000_000, 0)] == [0, 1, 2]
    assert [k for k, _ in schedule.due(25_000_000, 0)] == []
    # within the catch-up limit (1 s) a late publisher catches up: every sample, none skipped
    assert schedule.anchored(1_025_000_000, 0) == 0
    assert [k for k, _ in schedule.due(1_025_000_000, 0)] == list(range(3, 103))
    # the clock jumps 60 s ahead: sample 103 is stamped now, the motion goes on from frame 103
    now = 61_025_000_000
    start = schedule.anchored(now, 0)
    assert start + 103 * NANOSECONDS // RATE == now and schedule.counters.stamp_leaps == 1
    batch = schedule.due(now, start)
    assert [(k, frame.k) for k, frame in batch] == [(103, 103)]
    # the clock goes back 120 s: the start stays (stamps never go back) and nothing is due until it returns
    assert schedule.anchored(now - 120 * NANOSECONDS, start) == start
    assert schedule.due(now - 120 * NANOSECONDS, start) == []
    assert [k for k, _ in schedule.due(now + 10_000_000, start)] == [104]
    assert schedule.counters.stamp_leaps == 1


def test_a_missing_frame_holds_the_last_published_sample(stream_factory):
    stream = stream_factory()
    stream.compute(0.5)
    moving = stream.sample(0.3)
    assert np.max(np.abs(moving.qd)) > 0.0
    schedule = schedule_with(moving)
    assert schedule.outgoing(0, None) is None  # nothing published yet: nothing to hold
    assert schedule.outgoing(0, Frame(0, 0.3, moving)).sample is moving
    held = schedule.outgoing(1, None)
    np.testing.assert_array_equal(held.sample.q, moving.q)
    assert held.sample.held and np.all(held.sample.qd == 0.0) and np.all(held.sample.qdd == 0.0)
    assert schedule.counters.published == 2 and schedule.counters.held_late == 1


def test_commands_take_effect_within_the_lead_and_replace_the_frames(stream_factory):
    sample = stream_factory().sample(0.0)
    schedule = schedule_with(sample, frames=80)
    period = NANOSECONDS // RATE
    schedule.due(5 * period, 0)  # samples 0..5 published (stamps k * period from 0)
    accepted = 5 * period + 3_000_000  # 3 ms after sample 5's stamp
    k, tau = schedule.command_point(accepted, 0)
    assert k == 5 + round(LEAD * RATE) and tau == pytest.approx(k / RATE)  # stamped LEAD - 3 ms after acceptance
    assert k * period <= accepted + LEAD * NANOSECONDS < (k + 1) * period
    assert schedule.command_point(accepted - NANOSECONDS, 0)[0] == 7  # a late acceptance: the one after the next
    assert schedule.command_point()[0] == 6  # nothing published: the next frame
    plan = schedule.plan()  # a plan made before the command
    schedule.after_command(k, tau)
    assert [f.k for f in schedule.frames] == list(range(6, k))
    assert schedule.plan().k == k and schedule.plan().tau == tau
    assert not schedule.accept(FrameBatch([Frame(80, 0.8, sample)], 0, False), plan)  # made for the old buffer: dropped
    # with fewer frames made than the lead, the command applies at the next frame to make
    short = schedule_with(sample, frames=10)
    assert short.command_point(0, 0) == (10, pytest.approx(0.1))


def test_frames_are_the_stream_sampled_at_the_rate_with_decimated_previews(stream_factory):
    stream, truth = stream_factory(), stream_factory()
    schedule = FrameSchedule(RATE, 100, LEAD, 1.0, stream.sample(0.0))
    plan = schedule.plan()
    batch = make_frames(stream, schedule.request(plan, 20, 0.2, 5, 4, None))
    frames = batch.frames
    assert not batch.busy and [f.k for f in frames] == list(range(20))
    assert [f.k for f in frames if f.preview is not None] == [0, 4, 8, 12, 16] and batch.next_preview_k == 20
    truth.compute(0.5)
    for frame in frames:
        assert frame.tau == pytest.approx(frame.k / RATE, abs=1e-12)
        np.testing.assert_array_equal(frame.sample.q, truth.sample(frame.tau).q)
    preview = frames[4].preview
    np.testing.assert_array_equal([p.t for p in preview], [truth.sample(0.04 + 0.04 * (i + 1)).t for i in range(5)])
    assert schedule.accept(batch, plan) and schedule.plan().k == 20


def test_a_non_finite_frame_is_replaced_by_the_last_valid_sample_held(stream_factory):
    valid = stream_factory().sample(0.0)
    schedule = schedule_with(valid)
    for field in ("q", "qd"):
        broken = dataclasses.replace(valid, **{field: np.full_like(valid.qd, np.nan if field == "q" else np.inf)})
        frame, fault = checked(Frame(3, 0.03, broken, [broken]), valid)
        assert frame.k == 3 and frame.preview is None and frame.sample.held and "non-finite" in fault
        np.testing.assert_array_equal(frame.sample.q, valid.q)
        assert np.all(frame.sample.qd == 0.0)
        schedule.accept(FrameBatch([frame], 1, False, non_finite=1, fault=fault), schedule.plan())
    assert schedule.counters.held_non_finite == 2 and "non-finite" in schedule.fault


def test_after_a_command_samples_come_first_then_previews_on_their_cadence(stream_factory):
    """After a re-target the frames within a quarter of the look-ahead from publishing are made before their
    preview horizon is computed (without their previews); from there on a frame due a preview waits for it.
    Previews keep the cadence from the command's frame and resume by the end of that window (with a compute
    budget, as in the node)."""
    stream = stream_factory()
    decimation, lookahead = 10, 100
    schedule = FrameSchedule(RATE, lookahead, 0.1, 1.0, stream.sample(0.0))

    def fill(budget: float | None) -> list[int]:
        with_preview = []
        while schedule.room > 0 or stream.computed_until < schedule.made_tau + 1.0:
            plan = schedule.plan()
            batch = make_frames(stream, schedule.request(plan, min(plan.room, 20), 1.0, 5, decimation, budget))
            schedule.accept(batch, plan)
            with_preview += [f.k for f in batch.frames if f.preview is not None]
        return with_preview

    fill(None)
    schedule.due(NANOSECONDS // 2, 0)  # published up to 0.5 s
    k, tau = schedule.command_point(NANOSECONDS // 2 + 1, 0)
    schedule.after_command(k, tau)
    stream.retarget(tau, Task(3.1, 2.0, 0.2, 5.0))
    window_end = schedule.next_k + lookahead // 4
    previews = fill(0.005)
    assert k == round(0.6 * RATE) and k < window_end  # the last sample stamped within the 0.1 s lead
    assert previews[0] == k + decimation * math.ceil((window_end - k) / decimation)  # the urgent ones go without
    assert all(b - a == decimation for a, b in itertools.pairwise(previews))


def test_a_frame_batch_crosses_a_pipe_unchanged(stream_factory):
    """A batch pickled (as it crosses to the node's process, its fields stacked) and read back equals the
    batch made: every field of every sample, the previews, held samples and the batch's accounts."""
    import pickle

    stream = stream_factory()
    schedule = FrameSchedule(RATE, 100, LEAD, 1.0, stream.sample(0.0))
    made = make_frames(stream, schedule.request(schedule.plan(), 12, 0.2, 5, 4, None))
    held = Frame(12, 0.12, made.frames[-1].sample.hold())
    batch = dataclasses.replace(made, frames=[*made.frames, held], compute_wall=0.25, non_finite=1, fault="why")
    read = pickle.loads(pickle.dumps(batch))

    def same(a, b) -> None:
        for name in (f.name for f in dataclasses.fields(a)):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
            assert type(getattr(a, name)) is type(getattr(b, name)), name

    assert [f.preview is None for f in read.frames] == [f.preview is None for f in batch.frames]
    assert sum(f.preview is not None for f in batch.frames) == 3 and read.frames[-1].sample.held
    for mine, theirs in zip(batch.frames, read.frames, strict=True):
        assert (mine.k, mine.tau, mine.horizon) == (theirs.k, theirs.tau, theirs.horizon)
        same(mine.sample, theirs.sample)
        for p, r in zip(mine.preview or [], theirs.preview or [], strict=True):
            same(p, r)
    assert (read.next_preview_k, read.busy, read.compute_wall, read.compute_motion, read.non_finite, read.fault) == (
        batch.next_preview_k, batch.busy, batch.compute_wall, batch.compute_motion, batch.non_finite, batch.fault)

"""The publishing schedule (:mod:`crane_reference.stream.schedule`) without ROS: which sample goes out
when, commands, held samples, leaps of the stamps after a clock jump, and frames made from a real stream."""

from __future__ import annotations

import dataclasses
import itertools
import math
from typing import NamedTuple

import numpy as np
import pytest

from crane_reference.model.parameters import Task
from crane_reference.model.units import NANOSECONDS
from crane_reference.stream.frame_maker import FRAME_CHUNK, checked, make_frames
from crane_reference.stream.frames import FrameBatch, Frames
from crane_reference.stream.reference_stream import ReferenceStream
from crane_reference.stream.sample import ReferenceRows, ReferenceSample
from crane_reference.stream.schedule import FrameSchedule

RATE = 100  # [Hz]
LEAD = 0.25  # [s]


@pytest.fixture(scope="module")
def stream_factory(params):
    return lambda: ReferenceStream(params, "rigid", step=1e-3)


class Frame(NamedTuple):
    """One row of stacked frames, as an object."""

    k: int
    tau: float
    sample: ReferenceSample
    preview: list[ReferenceSample] | None
    horizon: float


def frame_of(frames: Frames, row: int) -> Frame:
    preview = frames.previews.get(row)
    return Frame(frames.k + row, float(frames.tau[row]), frames.samples.row(row),
                 None if preview is None else preview.rows(), frames.horizon)


def frames_of(sample, k: int, count: int) -> Frames:
    """Frames k .. k + count - 1 at their stream times, each ``sample``."""
    return Frames(k, np.arange(k, k + count) / RATE, ReferenceRows.repeated(sample, count))


def ks(schedule: FrameSchedule) -> list[int]:
    """The frames in the schedule's buffer."""
    return [k for frames in schedule.frames for k in range(frames.k, frames.end)]


def schedule_with(sample, frames: int = 0, lookahead: int = 100) -> FrameSchedule:
    schedule = FrameSchedule(RATE, lookahead, LEAD, 1.0, sample)
    plan = schedule.plan()
    schedule.accept(FrameBatch(frames_of(sample, 0, frames), 0, False), plan)
    return schedule


def test_due_samples_are_consecutive_and_the_stamps_leap_with_a_clock_jump(stream_factory):
    sample = stream_factory().sample(0.0)
    schedule = schedule_with(sample, frames=300, lookahead=300)
    # at 25 ms after the start samples 0, 1, 2 are due (stamps 0, 10, 20 ms)
    assert schedule.anchored(25_000_000, 0) == 0
    assert [k for k, *_ in schedule.due(25_000_000, 0)] == [0, 1, 2]
    assert [k for k, *_ in schedule.due(25_000_000, 0)] == []
    # within the catch-up limit (1 s) a late publisher catches up: every sample, none skipped
    assert schedule.anchored(1_025_000_000, 0) == 0
    assert [k for k, *_ in schedule.due(1_025_000_000, 0)] == list(range(3, 103))
    # the clock jumps 60 s ahead: sample 103 is stamped now, the motion goes on from frame 103
    now = 61_025_000_000
    start = schedule.anchored(now, 0)
    assert start + 103 * NANOSECONDS // RATE == now and schedule.counters.stamp_leaps == 1
    batch = schedule.due(now, start)
    assert [(k, frames.k + row) for k, frames, row in batch] == [(103, 103)]
    # the clock goes back 120 s: the start stays (stamps never go back) and nothing is due until it returns
    assert schedule.anchored(now - 120 * NANOSECONDS, start) == start
    assert schedule.due(now - 120 * NANOSECONDS, start) == []
    assert [k for k, *_ in schedule.due(now + 10_000_000, start)] == [104]
    assert schedule.counters.stamp_leaps == 1


def test_a_missing_frame_holds_the_last_published_sample(stream_factory):
    stream = stream_factory()
    stream.compute(0.5)
    moving = stream.sample(0.3)
    assert np.max(np.abs(moving.qd)) > 0.0
    schedule = schedule_with(moving)
    assert schedule.outgoing(0, None, -1) is None  # nothing published yet: nothing to hold
    made = frames_of(moving, 0, 1)
    assert schedule.outgoing(0, made, 0) == (made, 0)
    frames, row = schedule.outgoing(1, None, -1)
    held = frames.samples.row(row)
    np.testing.assert_array_equal(held.q, moving.q)
    assert held.held and np.all(held.qd == 0.0) and np.all(held.qdd == 0.0)
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
    assert ks(schedule) == list(range(0, k)) and schedule.ready == k - 6  # 0..5 published
    assert schedule.plan().k == k and schedule.plan().tau == tau
    assert not schedule.accept(FrameBatch(frames_of(sample, 80, 1), 0, False), plan)  # made for the old buffer: dropped
    # with fewer frames made than the lead, the command applies at the next frame to make
    short = schedule_with(sample, frames=10)
    assert short.command_point(0, 0) == (10, pytest.approx(0.1))


def test_frames_are_the_stream_sampled_at_the_rate_with_decimated_previews(stream_factory):
    stream, truth = stream_factory(), stream_factory()
    schedule = FrameSchedule(RATE, 100, LEAD, 1.0, stream.sample(0.0))
    plan = schedule.plan()
    batch = make_frames(stream, schedule.request(plan, 20, 0.2, 5, 4, None))
    frames = [frame_of(batch.frames, row) for row in range(len(batch.frames))]
    assert not batch.busy and [f.k for f in frames] == list(range(20))
    assert [f.k for f in frames if f.preview is not None] == [0, 4, 8, 12, 16] and batch.next_preview_k == 20
    truth.compute(0.5)
    for frame in frames:
        assert frame.tau == pytest.approx(frame.k / RATE, abs=1e-12)
        np.testing.assert_array_equal(frame.sample.q, truth.sample(frame.tau).q)
    preview = frames[4].preview
    expected = [truth.sample(0.04 + 0.04 * (i + 1)) for i in range(5)]
    np.testing.assert_array_equal([p.t for p in preview], [e.t for e in expected])
    for point, sampled in zip(preview, expected, strict=True):  # read with the frames, as the stream's own samples
        for name in ("q", "qd", "qdd", "effort", "ee_position"):
            np.testing.assert_allclose(getattr(point, name), getattr(sampled, name), rtol=1e-12, atol=1e-12)
    assert schedule.accept(batch, plan) and schedule.plan().k == 20


def test_a_non_finite_frame_is_replaced_by_the_last_valid_sample_held(stream_factory):
    """Frames 0..4: a valid one, one with NaN in q, one with inf in qd (both become frame 0 held: the last valid
    before them), a valid one whose preview has NaN (dropped), and one that starts with NaN (the request's last
    valid sample held)."""
    stream = stream_factory()
    stream.compute(0.5)
    valid, later, before = stream.sample(0.3), stream.sample(0.31), stream.sample(0.29)
    nan_q = dataclasses.replace(valid, q=np.full_like(valid.q, np.nan))
    inf_qd = dataclasses.replace(valid, qd=np.full_like(valid.qd, np.inf))
    samples = ReferenceRows.stack([valid, nan_q, inf_qd, later])
    previews = {1: ReferenceRows.stack([valid]), 3: ReferenceRows.stack([nan_q]), 0: ReferenceRows.stack([later])}
    frames, non_finite, fault = checked(Frames(0, np.arange(4) / RATE, samples, previews), before)
    rows = [frames.samples.row(i) for i in range(4)]
    assert non_finite == 2 and "non-finite" in fault and set(frames.previews) == {0}
    for row in rows[1:3]:
        np.testing.assert_array_equal(row.q, valid.q)
        np.testing.assert_array_equal(row.effort, valid.effort)
        assert row.held and np.all(row.qd == 0.0) and np.all(row.qdd == 0.0)
    np.testing.assert_array_equal(rows[3].qd, later.qd)
    assert not rows[0].held and not rows[3].held
    first, count, _ = checked(Frames(0, np.zeros(1), ReferenceRows.stack([nan_q])), before)
    assert count == 1 and first.samples.row(0).held
    np.testing.assert_array_equal(first.samples.row(0).q, before.q)
    schedule = schedule_with(valid)
    schedule.accept(FrameBatch(frames, 4, False, non_finite=non_finite, fault=fault), schedule.plan())
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
            with_preview += sorted(batch.frames.k + row for row in batch.frames.previews)
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
    """A batch pickled (as it crosses to the node's process: its arrays as they are) and read back equals the
    batch made: every field of every sample, the previews, held samples and the batch's accounts."""
    import pickle

    stream = stream_factory()
    schedule = FrameSchedule(RATE, 100, LEAD, 1.0, stream.sample(0.0))
    made = make_frames(stream, schedule.request(schedule.plan(), 12, 0.2, 5, 4, None))
    held = Frames.held(12, [0.12], made.frames.samples.row(11))
    frames = Frames(0, np.concatenate((made.frames.tau, held.tau)),
                    ReferenceRows(*(np.concatenate((a, b))
                                    for a, b in zip(made.frames.samples, held.samples, strict=True))),
                    made.frames.previews, made.frames.horizon)
    batch = dataclasses.replace(made, frames=frames, compute_wall=0.25, non_finite=1, fault="why")
    read = pickle.loads(pickle.dumps(batch))
    assert len(batch.frames.previews) == 3 and read.frames.samples.row(12).held
    for row in range(13):
        mine, theirs = frame_of(batch.frames, row), frame_of(read.frames, row)
        assert (mine.k, mine.tau, mine.horizon, mine.preview is None) == (theirs.k, theirs.tau, theirs.horizon,
                                                                          theirs.preview is None)
        for a, b in [(mine.sample, theirs.sample), *zip(mine.preview or [], theirs.preview or [], strict=True)]:
            for name in (f.name for f in dataclasses.fields(a)):
                np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
                assert type(getattr(a, name)) is type(getattr(b, name)), name
    assert (read.next_preview_k, read.busy, read.compute_wall, read.compute_motion, read.non_finite, read.fault) == (
        batch.next_preview_k, batch.busy, batch.compute_wall, batch.compute_motion, batch.non_finite, batch.fault)


def test_an_interrupted_request_makes_its_urgent_frames_only(stream_factory):
    """With a request waiting (interrupted), frames close to publishing are still made from the motion computed;
    frames further ahead are not (the batch is busy: the worker asks again), and the motion stays computed."""
    stream = stream_factory()
    stream.compute(1.5)
    schedule = FrameSchedule(RATE, 100, LEAD, 1.0, stream.sample(0.0))
    waiting = np.ones(1, dtype=np.uint8)  # a set stop flag
    urgent = make_frames(stream, schedule.request(schedule.plan(), 10, 0.2, 5, 4, 0.005), waiting)
    assert len(urgent.frames) == 10 and urgent.frames.k == 0
    schedule.accept(urgent, schedule.plan())
    schedule.made_k = schedule.urgent_until  # the next frames are beyond the urgent window
    later = make_frames(stream, schedule.request(schedule.plan(), 10, 0.2, 5, 4, 0.005), waiting)
    assert not len(later.frames) and later.busy and stream.computed_until >= 1.5


def test_a_request_that_comes_while_frames_are_made_ends_them_and_they_are_made_again(stream_factory, monkeypatch):
    """Frames that are not urgent are made FRAME_CHUNK at a time: the stop flag set while the first chunk is made (a
    request came) ends the request with no frames (busy, the preview cadence unchanged); the next request makes them,
    equal to those of a stream that was never stopped, previews included."""
    stream, truth = stream_factory(), stream_factory()
    stream.compute(4.0)
    schedule = FrameSchedule(RATE, 1000, LEAD, 1.0, stream.sample(0.0))
    schedule.made_k = schedule.urgent_until  # the next frames are beyond the urgent window
    request = schedule.request(schedule.plan(), 3 * FRAME_CHUNK, 0.2, 5, 40, 0.25)
    stop, samples, chunks = np.zeros(1, dtype=np.uint8), stream.samples, []

    def request_comes_during_the_first_chunk(taus):
        if len(taus) >= FRAME_CHUNK:  # a chunk of frames (and their previews)
            chunks.append(taus)
            stop[0] = len(chunks) == 1
        return samples(taus)

    monkeypatch.setattr(stream, "samples", request_comes_during_the_first_chunk)
    stopped = make_frames(stream, request, stop)
    assert stopped.busy and not len(stopped.frames) and stopped.next_preview_k == request.plan.next_preview_k
    stop[0] = 0
    made, expected = make_frames(stream, request, stop), make_frames(truth, request)
    assert len(made.frames) == 3 * FRAME_CHUNK and sorted(made.frames.previews) == sorted(expected.frames.previews)
    for mine, theirs in zip(made.frames.samples, expected.frames.samples, strict=True):
        np.testing.assert_array_equal(mine, theirs)
    for row, preview in expected.frames.previews.items():
        np.testing.assert_array_equal(made.frames.previews[row].q, preview.q)


def test_after_a_command_the_last_valid_sample_is_the_frame_before_it(stream_factory):
    """A frame that is not finite after a command is replaced by the frame before the command point held, not by
    the last of the frames the command dropped."""
    stream = stream_factory()
    schedule = FrameSchedule(RATE, 100, LEAD, 1.0, stream.sample(0.0))
    made = make_frames(stream, schedule.request(schedule.plan(), 30, 0.2, 5, 4, None))
    schedule.accept(made, schedule.plan())
    schedule.after_command(10, float(made.frames.tau[10]))
    np.testing.assert_array_equal(schedule.last_valid.q, made.frames.samples.q[9])
    assert schedule.last_valid.t == made.frames.samples.t[9]

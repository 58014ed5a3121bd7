"""The solver's side of the pipe: the frames of a :class:`~.frames.FrameRequest` made from the reference stream
(:func:`make_frames`), after computing ahead far enough for them and their previews; a frame that is not finite
is replaced by the last valid sample held (:func:`checked`)."""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from .frames import FrameBatch, FrameRequest, Frames
from .reference_stream import ReferenceStream
from .sample import ReferenceRows, ReferenceSample

TIME_TOLERANCE = 1e-9  # [s], rounding slack when comparing stream times
COMPUTE_MARGIN = 0.05  # [s] of motion computed beyond the preview horizon
FRAME_CHUNK = 100  # frames that are not urgent are made this many at a time (a waiting request ends them)


def make_frames(stream: ReferenceStream, request: FrameRequest, stop: np.ndarray | None = None) -> FrameBatch:
    """The frames of ``request`` as far as the motion is computed, after computing ahead far enough for
    them and for their previews (or until the ``stop`` flag is set: a request is waiting for the solver; then only
    urgent frames are made, the motion computed so far is kept and the batch is busy; frames that are not urgent
    are made FRAME_CHUNK at a time, and the flag set meanwhile drops them too).  A frame due a
    preview waits until its horizon is computed, so previews keep their cadence; an urgent frame (just after
    a command) is made as soon as its own motion is computed, without the preview due to it if its horizon
    is not computed yet (the next one is due a decimation later: the cadence stays).  A frame that is not
    finite is replaced by the last valid sample held (:func:`checked`)."""
    plan, count, horizon = request.plan, request.count, request.horizon
    dt = 1.0 / request.rate
    tau, next_preview_k = plan.tau, plan.next_preview_k
    ahead = tau + count * dt + horizon + COMPUTE_MARGIN
    frames_until = tau + (count - 1) * dt + 2 * TIME_TOLERANCE
    before = stream.computed_until
    target = frames_until if plan.k < request.urgent_until else ahead  # urgent: the frames' own motion only
    wall = motion = 0.0
    if before < target:
        start = time.perf_counter()
        stream.compute(target, request.compute_budget, stop)
        if math.isfinite(stream.computed_until):
            wall, motion = time.perf_counter() - start, stream.computed_until - before
    times = tau + dt * np.arange(count)  # in ERROR: the motion up to its last valid step, held beyond

    def waited() -> FrameBatch | None:
        """No frames (busy) if a request waits: it comes first (a command may drop these frames); urgent frames
        are made still."""
        if plan.k >= request.urgent_until and stop is not None and stop[0]:
            return FrameBatch(Frames(plan.k, times[:0], stream.samples(times[:0])), plan.next_preview_k, True, wall,
                              motion)
        return None

    if batch := waited():
        return batch
    computed_until = stream.computed_until
    made = int(np.count_nonzero(times <= computed_until - TIME_TOLERANCE))
    previewed = []  # the rows with a preview
    decimation = max(1, request.decimation)
    row = max(0, next_preview_k - plan.k)
    while row < made:  # the frames due a preview, in turn
        if computed_until >= float(times[row]) + horizon:
            previewed.append(row)
        elif plan.k + row >= request.urgent_until:
            made = row  # this frame's preview is not computed yet: make it on a later call
            break
        next_preview_k = plan.k + row + decimation  # (urgent, not computed: it goes without)
        row += decimation
    parts, points = [], request.points
    previews: dict[int, ReferenceRows] = {}
    for first in range(0, made, FRAME_CHUNK):  # a chunk's frames and their previews read at once
        if batch := waited():
            return batch
        end = min(made, first + FRAME_CHUNK)
        rows = [row for row in previewed if first <= row < end]
        read = stream.samples(np.concatenate((times[first:end],
                                              stream.preview_times(times[rows], horizon, points).ravel())))
        parts.append(read.take(slice(0, end - first)))
        for i, row in enumerate(rows):
            start = end - first + i * points
            previews[row] = read.take(slice(start, start + points))
    samples = ReferenceRows.concatenated(parts) if parts else stream.samples(times[:0])
    frames, non_finite, fault = checked(Frames(plan.k, times[:made], samples, previews, horizon), request.last_valid)
    return FrameBatch(frames, next_preview_k, computed_until < ahead, wall, motion, non_finite, fault)


def checked(frames: Frames, last_valid: ReferenceSample) -> tuple[Frames, int, str]:
    """``frames`` with each frame that is not finite replaced by the last valid sample before it (or
    ``last_valid``) held, and previews that are not finite dropped; how many were replaced and the fault that
    says why ("" if none): NaN is never published."""
    samples = frames.samples
    previews = {row: p for row, p in frames.previews.items() if np.all(p.finite())}
    bad = np.flatnonzero(~samples.finite())
    if not bad.size:
        return (frames if len(previews) == len(frames.previews) else replace(frames, previews=previews)), 0, ""
    samples = ReferenceRows(*(field.copy() for field in samples))
    for row in bad.tolist():
        held = (samples.row(row - 1) if row else last_valid).hold()
        for name, values in zip(ReferenceRows._fields, samples, strict=True):
            values[row] = getattr(held, name)
        previews.pop(row, None)
    tau = float(frames.tau[bad[-1]])
    return (replace(frames, samples=samples, previews=previews), int(bad.size),
            f"non-finite sample at stream time {tau:.3f} s: holding the last valid one")

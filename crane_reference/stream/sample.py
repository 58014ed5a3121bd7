"""One instant of the online reference, and how it is made from the computed motion."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from dataclasses import fields as dataclass_fields

import numpy as np
from scipy.spatial.transform import Rotation

from ..motion.trajectory import Sample, generalized_effort, hermite_segment, stack_samples


@dataclass(frozen=True)
class ReferenceSample:
    """One instant of the reference (SI units, world frame {0}): motion time ``t`` [s], q, qd, qdd,
    the generalized effort of constraints and drive, E's position and quaternion (x, y, z, w) of link
    4's frame, the largest constraint distance [m]; ``held``: a held sample (paused or failed)."""

    t: float
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    effort: np.ndarray
    ee_position: np.ndarray
    ee_quaternion: np.ndarray
    residual_distance: float
    held: bool

    def hold(self) -> ReferenceSample:
        """This sample held: same position and effort, zero velocity and acceleration."""
        zero = np.zeros_like(self.qd)
        return replace(self, qd=zero, qdd=zero.copy(), held=True)

    def is_finite(self) -> bool:
        """Whether every number is finite (a NaN or infinity propagates into the sum)."""
        arrays = (self.q, self.qd, self.qdd, self.effort, self.ee_position, self.ee_quaternion)
        return math.isfinite(np.concatenate(arrays).sum() + self.residual_distance)


SampleColumns = tuple[np.ndarray, ...]
"""The fields of :class:`ReferenceSample` stacked per sample, in field order (:func:`columns`)."""


def columns(samples: list[ReferenceSample]) -> SampleColumns:
    """The samples' fields stacked, one array per field: a few arrays instead of one per sample and field,
    which pickle (to the node's process) at a fraction of the cost."""
    return tuple(np.array([getattr(s, f.name) for s in samples]) for f in dataclass_fields(ReferenceSample))


def from_columns(stacked: SampleColumns) -> list[ReferenceSample]:
    """The samples of :func:`columns` again (their arrays are rows of the stacked ones)."""
    t, q, qd, qdd, effort, position, quaternion, residual, held = stacked
    return [ReferenceSample(*row) for row in zip(t.tolist(), q, qd, qdd, effort, position, quaternion,
                                                 residual.tolist(), held.tolist(), strict=True)]


def reference_samples(rows: dict[str, np.ndarray], drive_joint: int) -> list[ReferenceSample]:
    """The references at computed steps, from their :class:`~crane_reference.motion.trajectory.Sample`
    fields stacked per step (one quaternion conversion for all of them)."""
    effort = generalized_effort(rows["constraint_forces"], rows["drive_torque"], drive_joint)
    quaternions = Rotation.from_matrix(rows["ee_rotation"]).as_quat()
    residuals = np.max(rows["residual_distance"], axis=-1).tolist()
    return [ReferenceSample(*fields, False) for fields in zip(
        rows["t"].tolist(), rows["q"], rows["qd"], rows["qdd"], effort, rows["ee_position"], quaternions, residuals,
        strict=True)]


def reference_sample(s: Sample, drive_joint: int) -> ReferenceSample:
    """The reference at one computed step."""
    return reference_samples(stack_samples([s]), drive_joint)[0]


def between(a: list[ReferenceSample], b: list[ReferenceSample], t: np.ndarray, poses) -> list[ReferenceSample]:
    """The references at a[i].t < t[i] < b[i].t: q cubic Hermite in q and qd, qd cubic Hermite in qd and qdd
    (both :func:`~crane_reference.motion.trajectory.hermite_segment`), qdd and effort linear; E's pose from
    ``poses(q)`` -> (positions (N, 3), rotation matrices (N, 3, 3)), the kinematics at the interpolated q."""
    def stacked(side: list[ReferenceSample], name: str) -> np.ndarray:
        return np.array([getattr(sample, name) for sample in side])

    start = stacked(a, "t")
    h = (stacked(b, "t") - start)[:, None]
    s = (np.asarray(t, dtype=float)[:, None] - start[:, None]) / h
    qd0, qd1, qdd0, qdd1 = stacked(a, "qd"), stacked(b, "qd"), stacked(a, "qdd"), stacked(b, "qdd")
    q = hermite_segment(s, h, stacked(a, "q"), qd0, stacked(b, "q"), qd1)
    qd = hermite_segment(s, h, qd0, qdd0, qd1, qdd1)
    qdd = (1 - s) * qdd0 + s * qdd1
    effort = (1 - s) * stacked(a, "effort") + s * stacked(b, "effort")
    positions, rotations = poses(q)
    quaternions = Rotation.from_matrix(rotations).as_quat()
    residuals = np.maximum(stacked(a, "residual_distance"), stacked(b, "residual_distance")).tolist()
    return [ReferenceSample(*fields, False) for fields in zip(
        np.asarray(t, dtype=float).tolist(), q, qd, qdd, effort, positions, quaternions, residuals, strict=True)]


def warped(sample: ReferenceSample, rate: float, rate_change: float) -> ReferenceSample:
    """``sample`` of the motion at its own time t, published at a rate dt/dtau = ``rate`` changing by
    ``rate_change`` per second of publish time: velocity r q'(t), acceleration r^2 q''(t) + r' q'(t)
    (see :mod:`~.time_warp`).  Unchanged at r = 1, r' = 0."""
    if rate == 1.0 and rate_change == 0.0:
        return sample
    return replace(sample, qd=rate * sample.qd, qdd=rate * rate * sample.qdd + rate_change * sample.qd)

"""One instant of the online reference, and how it is made from the computed motion."""

from __future__ import annotations

import inspect
import math
from dataclasses import dataclass, replace
from dataclasses import fields as dataclass_fields
from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from ..motion.trajectory import hermite_segment


@dataclass(frozen=True)
class ReferenceSample:
    """One instant of the reference (SI units, world frame {0}): motion time ``t`` [s], q, qd, qdd,
    ``effort``: the generalized force of constraints and drive (the constraint forces, plus the drive's torque
    on its joint), ``feedforward``: the generalized force a controller adds (the constraint forces alone: the
    plant applies the drive's torque itself), E's position and quaternion (x, y, z, w) of link 4's frame, the
    largest constraint distance [m]; ``held``: a held sample (paused or failed)."""

    t: float
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    effort: np.ndarray
    feedforward: np.ndarray
    ee_position: np.ndarray
    ee_quaternion: np.ndarray
    residual_distance: float
    held: bool

    def hold(self) -> ReferenceSample:
        """This sample held: same position, effort and feedforward, zero velocity and acceleration."""
        zero = np.zeros_like(self.qd)
        return replace(self, qd=zero, qdd=zero.copy(), held=True)

    def is_finite(self) -> bool:
        """Whether every number is finite (a NaN or infinity propagates into the sum)."""
        arrays = (self.q, self.qd, self.qdd, self.effort, self.feedforward, self.ee_position, self.ee_quaternion)
        return math.isfinite(np.concatenate(arrays).sum() + self.residual_distance)


class ReferenceRows(NamedTuple):
    """Reference samples stacked, one row per sample: the fields of :class:`ReferenceSample` (t (N,), q, qd,
    qdd, effort and feedforward (N, n), ee_position (N, 3), ee_quaternion (N, 4), residual_distance (N,), held
    (N,)).  The stream makes and moves samples in this form; a few arrays pickle (to the node's process) at a
    fraction of the cost of one object per sample."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    effort: np.ndarray
    feedforward: np.ndarray
    ee_position: np.ndarray
    ee_quaternion: np.ndarray
    residual_distance: np.ndarray
    held: np.ndarray

    @classmethod
    def stack(cls, samples: list[ReferenceSample]) -> ReferenceRows:
        """``samples`` stacked."""
        return cls(*(np.array([getattr(s, f.name) for s in samples]) for f in dataclass_fields(ReferenceSample)))

    @classmethod
    def concatenated(cls, parts: list[ReferenceRows]) -> ReferenceRows:
        """The rows of ``parts`` in turn."""
        return parts[0] if len(parts) == 1 else cls(*(np.concatenate(field) for field in zip(*parts, strict=True)))

    @classmethod
    def repeated(cls, sample: ReferenceSample, count: int) -> ReferenceRows:
        """``sample`` ``count`` times."""
        return cls(*(np.repeat(np.asarray(getattr(sample, f.name))[None], count, axis=0)
                     for f in dataclass_fields(ReferenceSample)))

    def take(self, index: np.ndarray) -> ReferenceRows:
        """The rows ``index``."""
        return ReferenceRows(*(field[index] for field in self))

    def row(self, i: int) -> ReferenceSample:
        """Row i as a :class:`ReferenceSample` (its arrays are rows of the stacked ones)."""
        return ReferenceSample(float(self.t[i]), self.q[i], self.qd[i], self.qdd[i], self.effort[i],
                               self.feedforward[i], self.ee_position[i], self.ee_quaternion[i],
                               float(self.residual_distance[i]), bool(self.held[i]))

    def rows(self) -> list[ReferenceSample]:
        """One :class:`ReferenceSample` per row (its arrays are rows of the stacked ones)."""
        return [ReferenceSample(*row) for row in zip(self.t.tolist(), self.q, self.qd, self.qdd, self.effort,
                                                     self.feedforward, self.ee_position, self.ee_quaternion,
                                                     self.residual_distance.tolist(), self.held.tolist(),
                                                     strict=True)]

    def finite(self) -> np.ndarray:
        """(N,): whether every number of a row is finite."""
        total = (self.q.sum(axis=1) + self.qd.sum(axis=1) + self.qdd.sum(axis=1) + self.effort.sum(axis=1)
                 + self.feedforward.sum(axis=1) + self.ee_position.sum(axis=1) + self.ee_quaternion.sum(axis=1)
                 + self.residual_distance)
        return np.isfinite(total)


_TRUSTED = {"assume_valid": True} if "assume_valid" in inspect.signature(Rotation.from_matrix).parameters else {}
"""scipy >= 1.17 can skip its orthonormality check (a fifth of the cost); older ones always make it."""


def quaternions(rotations: np.ndarray) -> np.ndarray:
    """The quaternions (x, y, z, w) of rotation matrices (N, 3, 3) from the kinematics, which are orthonormal to
    round-off (scipy's check of that skipped where scipy can)."""
    if not len(rotations):
        return np.empty((0, 4))
    return Rotation.from_matrix(rotations, **_TRUSTED).as_quat()


def between(a: ReferenceRows, b: ReferenceRows, t: np.ndarray, poses) -> ReferenceRows:
    """The references at a.t[i] < t[i] < b.t[i]: q cubic Hermite in q and qd, qd cubic Hermite in qd and qdd
    (both :func:`~crane_reference.motion.trajectory.hermite_segment`), qdd, effort and feedforward linear; E's pose from
    ``poses(q)`` -> (positions (N, 3), rotation matrices (N, 3, 3)), the kinematics at the interpolated q."""
    t = np.asarray(t, dtype=float)
    h = (b.t - a.t)[:, None]
    s = (t - a.t)[:, None] / h
    q = hermite_segment(s, h, a.q, a.qd, b.q, b.qd)
    qd = hermite_segment(s, h, a.qd, a.qdd, b.qd, b.qdd)
    qdd = (1 - s) * a.qdd + s * b.qdd
    effort = (1 - s) * a.effort + s * b.effort
    feedforward = (1 - s) * a.feedforward + s * b.feedforward
    positions, rotations = poses(q)
    return ReferenceRows(t, q, qd, qdd, effort, feedforward, positions, quaternions(rotations),
                   np.maximum(a.residual_distance, b.residual_distance), np.zeros(t.size, dtype=bool))


def warped(samples: ReferenceRows, rate: np.ndarray, rate_change: np.ndarray) -> ReferenceRows:
    """``samples`` of the motion at their own times t, published at rates dt/dtau = ``rate`` (N,) changing by
    ``rate_change`` (N,) per second of publish time: velocity r q'(t), acceleration r^2 q''(t) + r' q'(t)
    (see :mod:`~.time_warp`).  Unchanged at r = 1, r' = 0."""
    if np.all(rate == 1.0) and not np.any(rate_change):
        return samples
    r, r_change = rate[:, None], rate_change[:, None]
    return samples._replace(qd=r * samples.qd, qdd=r * r * samples.qdd + r_change * samples.qd)

"""One instant of the online reference, and how it is made from the computed motion."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from ..motion.trajectory import Sample, cubic_hermite, generalized_effort


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
        return bool(np.isfinite(sum(float(np.sum(a)) for a in arrays) + self.residual_distance))


def reference_sample(s: Sample, drive_joint: int) -> ReferenceSample:
    """The reference at a computed step."""
    effort = generalized_effort(s.constraint_forces, s.drive_torque, drive_joint)
    quaternion = Rotation.from_matrix(s.ee_rotation).as_quat()
    return ReferenceSample(s.t, s.q, s.qd, s.qdd, effort, s.ee_position, quaternion,
                           float(np.max(s.residual_distance)), False)


def between(a: ReferenceSample, b: ReferenceSample, t: float, pose) -> ReferenceSample:
    """The reference at a.t < t < b.t: q cubic Hermite in q and qd, qd cubic Hermite in qd and qdd (both
    :func:`~crane_reference.motion.trajectory.cubic_hermite`), qdd and effort linear; E's pose
    ``pose(q)`` -> (position, rotation matrix) from the kinematics at the interpolated q."""
    times = np.array([a.t, b.t])
    q = cubic_hermite(t, times, np.stack((a.q, b.q)), np.stack((a.qd, b.qd)))
    qd = cubic_hermite(t, times, np.stack((a.qd, b.qd)), np.stack((a.qdd, b.qdd)))
    s = (t - a.t) / (b.t - a.t)
    p, R = pose(q)
    return ReferenceSample(t, q, qd, (1 - s) * a.qdd + s * b.qdd, (1 - s) * a.effort + s * b.effort, p,
                           Rotation.from_matrix(R).as_quat(), max(a.residual_distance, b.residual_distance), False)


def warped(sample: ReferenceSample, rate: float, rate_change: float) -> ReferenceSample:
    """``sample`` of the motion at its own time t, published at a rate dt/dtau = ``rate`` changing by
    ``rate_change`` per second of publish time: velocity r q'(t), acceleration r^2 q''(t) + r' q'(t)
    (see :mod:`~.time_warp`).  Unchanged at r = 1, r' = 0."""
    if rate == 1.0 and rate_change == 0.0:
        return sample
    return replace(sample, qd=rate * sample.qd, qdd=rate * rate * sample.qdd + rate_change * sample.qd)

"""The example controller node's decisions, without ROS: the reference node's preview sampled as
joint_trajectory_controller samples its trajectory, and a :class:`~.controller.JointController` tick on each
measured state of the plant.

The reference at time t comes from the latest preview that spans t (points at t_i = stamp + time_from_start_i,
in integer nanoseconds, so that a state stamped on a point gets that point exactly):
q cubic Hermite in the points' positions and velocities, qd cubic Hermite in their velocities and
accelerations (:func:`~crane_reference.motion.trajectory.cubic_hermite`; exact at the points), and the
points' efforts linear, as joint_trajectory_controller interpolates them.  The plant's state stamped t gets
the command of the controller's tick there,

    u = tau_ff + kp (q_ref - q) + kd qd_ref + ki I    (:mod:`.controller`; the drive subtracts kd qd),

sent for the plant's next period (held over it); with no preview spanning t yet (at the start, before the
reference node's first preview), the state waits for one.  The feedforward tau_ff is the preview's effort at
t (``feedforward`` "reference": the reference node's ``preview.effort``, the constraint forces at these joints
without the drive's torque, which the plant applies itself) or zero ("none").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..model.units import NANOSECONDS
from ..motion.trajectory import cubic_hermite
from .controller import JointController, JointGains


@dataclass(frozen=True)
class Preview:
    """A preview's points: times [ns] (P,) (int64), positions, velocities, accelerations and efforts (P, J) of the
    joints (efforts None for a preview without them)."""

    times_ns: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    efforts: np.ndarray | None = None

    def __post_init__(self) -> None:
        """ValueError naming the field for a preview that cannot be sampled: times not strictly increasing, or
        values that are not finite or not one row per point."""
        times = np.asarray(self.times_ns)
        if times.ndim != 1 or times.size == 0 or np.any(np.diff(times) <= 0):
            raise ValueError("reference preview: the points' times (stamp + time_from_start) must increase strictly")
        for name in ("positions", "velocities", "accelerations", "efforts"):
            if getattr(self, name) is None and name == "efforts":
                continue
            values = np.asarray(getattr(self, name), dtype=float)
            if values.ndim != 2 or values.shape[0] != times.size:
                raise ValueError(f"reference preview: {name} must give every joint at every point")
            if not np.all(np.isfinite(values)):
                raise ValueError(f"reference preview: {name} must be finite")

    def spans(self, t_ns: int) -> bool:
        return bool(self.times_ns[0] <= t_ns <= self.times_ns[-1])

    def at(self, t_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """q_ref and qd_ref at t_ns [ns] (inside the preview)."""
        seconds = (self.times_ns - self.times_ns[0]) / NANOSECONDS
        t = np.asarray([(t_ns - self.times_ns[0]) / NANOSECONDS])
        return (cubic_hermite(t, seconds, self.positions, self.velocities)[0],
                cubic_hermite(t, seconds, self.velocities, self.accelerations)[0])

    def effort_at(self, t_ns: int) -> np.ndarray:
        """The efforts at t_ns [ns] (inside a preview with efforts), linear between the points (numpy's interp: a
        point's own at a point)."""
        seconds = (self.times_ns - self.times_ns[0]) / NANOSECONDS
        t = (t_ns - self.times_ns[0]) / NANOSECONDS
        return np.array([np.interp(t, seconds, column) for column in np.asarray(self.efforts, dtype=float).T])


PREVIEW_FEEDFORWARDS = ("none", "reference")
"""The tracker's feedforward: none, or the reference preview's efforts (those of
:data:`~.feedforward.FEEDFORWARDS` a controller of the preview can have)."""


class PreviewTracker:
    """The module docstring's controller for ``joints`` with ``gains``, ticking every ``period`` [s], with the
    ``feedforward`` of :data:`PREVIEW_FEEDFORWARDS`."""

    def __init__(self, joints: Sequence[str], gains: Sequence[JointGains], period: float, feedforward: str = "none"):
        if feedforward not in PREVIEW_FEEDFORWARDS:
            raise ValueError(f"feedforward = {feedforward!r}: must be one of {', '.join(PREVIEW_FEEDFORWARDS)}")
        self.joints = tuple(joints)
        self.feedforward = feedforward
        self.controller = JointController(gains, period)
        self.preview: Preview | None = None
        self._pending: tuple[int, np.ndarray, np.ndarray] | None = None
        self._answered = -1  # the stamp [ns] of the last state answered

    def check(self, preview: Preview) -> None:
        """ValueError for a preview this tracker cannot use: without efforts for the feedforward "reference"."""
        if self.feedforward == "reference" and preview.efforts is None:
            raise ValueError("reference preview: no efforts for feedforward 'reference' (set preview.effort:=true on "
                             "the reference node)")

    def take_preview(self, preview: Preview) -> np.ndarray | None:
        """A new preview (:meth:`check`-ed); the command for a waiting state if it spans that state's time, else
        None."""
        self.check(preview)
        self.preview = preview
        return self._tick() if self._pending is not None else None

    def take_state(self, t_ns: int, q: np.ndarray, qd: np.ndarray) -> np.ndarray | None:
        """The plant's state stamped t_ns [ns] (q, qd of ``joints``): the command u [N m] for its next period, or None
        while no preview spans t (the state then waits for one) and for a state not after the last answered (a
        lock-step plant repeats a state until a command comes: one command per period, so that the loop stays
        deterministic).  ValueError for q or qd that are not finite."""
        q, qd = np.asarray(q, dtype=float), np.asarray(qd, dtype=float)
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))):
            raise ValueError("plant state: position and velocity must be finite")
        if t_ns <= self._answered:
            return None
        self._pending = (t_ns, q, qd)
        return self._tick()

    def _tick(self) -> np.ndarray | None:
        t_ns, q, qd = self._pending
        if self.preview is None or not self.preview.spans(t_ns):
            return None
        feedforward = (self.preview.effort_at(t_ns) if self.feedforward == "reference"
                       else np.zeros(len(self.joints)))
        self._pending, self._answered = None, t_ns
        q_ref, qd_ref = self.preview.at(t_ns)
        return self.controller(q_ref - q, qd_ref, qd, feedforward)

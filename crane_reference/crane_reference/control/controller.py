"""Joint-space feedback: PID per actuated joint, the D action in the joint drive, with torque limits.

A joint drive closes a fast velocity loop, so its D action acts continuously on the measured joint
velocity: the plant gets the damping kd on the joint (:class:`~.plant.Plant` ``joint_damping``, exact in
the integrator).  The rest runs at the controller's ticks t_k (rate f_c) on the reference sample there:

    tau = u_k - kd qd,    u_k = tau_ff + kp e + kd qd_ref + ki I_k,    I_k+1 = I_k + e / f_c,

with e = q_ref - q; u_k holds over the period (the feedforward part may run linearly over it, see
:mod:`.closed_loop`).  A torque-controlled joint with a 1 kHz zero-order-held D term on the flexible boom
is unstable: the luff and knuckle joints carry only the first rigid element's inertia at high frequency
(a small fraction of the whole boom's: ``bench_tracking.py --only inertia`` prints both), so kd h / J far
exceeds 2.  Torques beyond a limit
are cut to +-limit at the tick and counted (never silently): the saturated ticks are reported, and the
integral does not grow while its joint is saturated (conditional integration, the usual anti-windup);
between ticks the drive's D action may move the torque past the limit by kd |delta qd|.  Gains follow
from a closed-loop bandwidth by :func:`bandwidth_gains` or are given per joint.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..dynamics.closed_loop import controller_tick
from ..dynamics.structures import ControllerArrays

CONTROLLERS = ("pd", "pid")


@dataclass(frozen=True)
class JointGains:
    """One joint's gains and torque limit: kp [N m/rad], kd [N m s/rad], ki [N m/(rad s)], ``limit`` [N m]
    (inf: none)."""

    kp: float
    kd: float
    ki: float = 0.0
    limit: float = math.inf

    def __post_init__(self) -> None:
        for name in ("kp", "kd", "ki"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"gain {name} = {value}: must be a finite number >= 0")
        if not self.limit > 0.0:
            raise ValueError(f"torque limit = {self.limit}: must be > 0 N m (inf for none)")


def bandwidth_gains(inertia: float, bandwidth: float, damping_ratio: float, integral: bool = False,
                    limit: float = math.inf) -> JointGains:
    """Gains that give a joint seen as J qdd = tau (J = ``inertia`` [kg m^2], the diagonal of M) the
    closed-loop natural frequency w = 2 pi ``bandwidth`` [Hz] and ``damping_ratio`` zeta: kp = J w^2,
    kd = 2 zeta J w; with ``integral`` ki = kp w / 10 (the integral's pole a decade below w)."""
    if not (math.isfinite(bandwidth) and bandwidth > 0.0):
        raise ValueError(f"bandwidth = {bandwidth}: must be a finite frequency > 0 Hz")
    if not (math.isfinite(damping_ratio) and damping_ratio > 0.0):
        raise ValueError(f"damping ratio = {damping_ratio}: must be a finite number > 0")
    omega = 2.0 * math.pi * bandwidth
    kp = inertia * omega**2
    return JointGains(kp, 2.0 * damping_ratio * inertia * omega, kp * omega / 10.0 if integral else 0.0, limit)


class JointController:
    """The loop of the module docstring for the joints of ``gains``, ticking every ``period`` [s]."""

    def __init__(self, gains: Sequence[JointGains], period: float):
        self.gains = tuple(gains)
        self.period = period
        self._kp, self.damping, self._ki, self._limit = (np.array([getattr(g, name) for g in self.gains])
                                                         for name in ("kp", "kd", "ki", "limit"))
        """``damping``: kd per joint [N m s/rad], the D action the plant's joint drives apply."""
        self._integral = np.zeros(len(self.gains))
        self.saturated_ticks = np.zeros(len(self.gains), dtype=np.int64)
        """Ticks at which each joint's torque was cut to its limit."""
        self.ticks = 0

    @property
    def arrays(self) -> ControllerArrays:
        """The controller as the compiled loop ticks it (:func:`~crane_reference.dynamics.closed_loop.controller_tick`;
        its integral and saturated ticks updated in place)."""
        return ControllerArrays(self._kp, self.damping, self._ki, self._limit, self.period, self._integral,
                                self.saturated_ticks)

    def __call__(self, error: np.ndarray, reference_rate: np.ndarray, rate: np.ndarray,
                 feedforward: np.ndarray) -> np.ndarray:
        """u_k [N m] of this tick for the joint errors e, the reference's and the measured joint velocities
        and the feedforward (the torque u_k - kd qd within the limits); advances the integral."""
        self.ticks += 1
        return controller_tick(self._kp, self.damping, self._ki, self._limit, self.period, self._integral,
                               self.saturated_ticks, *(np.asarray(x, dtype=float) for x in (error, reference_rate,
                                                                                               rate, feedforward)))

"""Joint-space feedback: a digital PID per actuated joint with torque limits.

At each tick t_k of the controller (rate f_c) the joint errors e = q_ref - q and de = qd_ref - qd of the
reference sample at t_k give

    tau_k = tau_ff + kp e + kd de + ki I_k,    I_k+1 = I_k + e / f_c,

held over the period (the feedforward tau_ff may vary linearly over it, see
:mod:`.closed_loop`).  A torque beyond its limit is cut to +-limit and counted (never silently): the
saturated ticks are reported, and the integral does not grow while its joint is saturated (conditional
integration, the usual anti-windup).  Gains follow from a closed-loop bandwidth by :func:`bandwidth_gains`
or are given per joint.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

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
    """The digital PID of the module docstring for the joints of ``gains``, ticking every ``period`` [s]."""

    def __init__(self, gains: Sequence[JointGains], period: float):
        self.gains = tuple(gains)
        self.period = period
        self._kp, self._kd, self._ki, self._limit = (np.array([getattr(g, name) for g in self.gains])
                                                     for name in ("kp", "kd", "ki", "limit"))
        self._integral = np.zeros(len(self.gains))
        self.saturated_ticks = np.zeros(len(self.gains), dtype=np.int64)
        """Ticks at which each joint's torque was cut to its limit."""
        self.ticks = 0

    def __call__(self, error: np.ndarray, error_rate: np.ndarray, feedforward: np.ndarray) -> np.ndarray:
        """The torques [N m] of this tick (within the limits); advances the integral."""
        wanted = feedforward + self._kp * error + self._kd * error_rate + self._ki * self._integral
        torque = np.clip(wanted, -self._limit, self._limit)
        saturated = torque != wanted
        self.saturated_ticks += saturated
        self.ticks += 1
        self._integral += np.where(saturated, 0.0, error * self.period)
        return torque

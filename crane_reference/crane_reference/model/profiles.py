"""Smooth scalar time functions f(t) with their first two derivatives (targets, motor angles, blends).

Every profile returns ``(f, df/dt, d2f/dt2)`` at a time t [s], or at each of an array of times
(elementwise: the formulas have no branches, so a run of steps gets its targets in one call).

The quintic step of eq. (5.2),
s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5, has zero first and second derivatives at both ends, so
joining or blending profiles with it keeps f twice continuously differentiable (C2).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


class Profile(Protocol):
    def __call__(self, t: float | np.ndarray) -> tuple: ...


def quintic_step(tau: float | np.ndarray) -> tuple:
    """s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5 for tau in [0, 1] (0 before, 1 after), with s', s''
    (the polynomial at tau clipped to [0, 1]: s, s', s'' are exactly 0, 0, 0 and 1, 0, 0 at the ends)."""
    tau = np.clip(tau, 0.0, 1.0)
    return (tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2),
            30.0 * tau**2 * (1.0 - tau) ** 2,
            60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau))


@dataclass(frozen=True)
class Constant:
    value: float

    def __call__(self, t: float | np.ndarray) -> tuple:
        zero = np.zeros_like(t, dtype=float)
        return self.value + zero, zero, zero


@dataclass(frozen=True)
class QuinticRise:
    """f(t) = start + increment * s((t - t0) / duration): eq. (5.2) with z_inc = ``increment``."""

    start: float
    increment: float
    t0: float
    duration: float

    def __call__(self, t: float | np.ndarray) -> tuple:
        s, ds, dds = quintic_step((t - self.t0) / self.duration)
        return (self.start + self.increment * s,
                self.increment * ds / self.duration,
                self.increment * dds / self.duration**2)


@dataclass(frozen=True)
class Blend:
    """C2 transition from ``old`` to ``new`` over [t0, t0 + duration]:
    f = (1 - s) f_old + s f_new with s the quintic step of (t - t0) / duration."""

    old: Profile
    new: Profile
    t0: float
    duration: float

    def __call__(self, t: float | np.ndarray) -> tuple:
        s, ds, dds = quintic_step((t - self.t0) / self.duration)
        f0, d0, dd0 = self.old(t)
        f1, d1, dd1 = self.new(t)
        ds, dds = ds / self.duration, dds / self.duration**2
        gap, dgap, ddgap = f1 - f0, d1 - d0, dd1 - dd0
        return (f0 + s * gap,
                d0 + ds * gap + s * dgap,
                dd0 + dds * gap + 2.0 * ds * dgap + s * ddgap)

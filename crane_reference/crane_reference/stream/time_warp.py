"""Speed scaling of the reference: motion time t as a smooth function of publish time tau.

The rate r = dt/dtau in [0, 1] (1: the programmed motion at its own speed, 0: at rest) moves between
values along ramps of fixed duration T,

    r(tau) = r0 + (r1 - r0) S(x),   x = (tau - tau0) / T in [0, 1],   S(x) = 10x^3 - 15x^4 + 6x^5,
    t(tau) = t0 + T (r0 x + (r1 - r0) I(x)),   I(x) = int_0^x S = 5x^4/2 - 3x^5 + x^6,

and stays at r1 after the ramp.  S has zero first and second derivatives at both ends, so r is C2: a
reference q(t(tau)) published at publish time keeps position, velocity

    dq/dtau = r q'(t),

and acceleration

    d2q/dtau2 = r^2 q''(t) + (dr/dtau) q'(t)

continuous through every change.  A change asked for during a ramp starts when that ramp ends, so every
ramp starts from a constant rate and r never leaves [min, max] of the rates asked for (no overshoot, in
particular never negative).  Pausing is a ramp to 0 (the motion stops smoothly where it is); resuming a
ramp back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from ..model.profiles import quintic_step


def _ramp_integral(x: float) -> float:
    """I(x) = int_0^x S(s) ds of the quintic step S."""
    return x**4 * (2.5 - 3.0 * x + x * x)


@dataclass(frozen=True)
class RateRamp:
    """From publish time ``tau0`` (motion time ``t0``) the rate moves from r0 to r1 over ``duration``
    seconds, then stays at r1."""

    tau0: float
    t0: float
    r0: float
    r1: float
    duration: float

    @property
    def end(self) -> float:
        return self.tau0 + self.duration

    def at(self, tau: float) -> tuple[float, float, float]:
        """t, r and dr/dtau at publish time tau >= tau0."""
        T = self.duration
        if tau >= self.end:
            return self.t0 + T * (self.r0 + 0.5 * (self.r1 - self.r0)) + self.r1 * (tau - self.end), self.r1, 0.0
        x = (tau - self.tau0) / T
        s, ds, _ = quintic_step(x)
        step = self.r1 - self.r0
        return self.t0 + T * (self.r0 * x + step * _ramp_integral(x)), self.r0 + step * s, step * ds / T


class TimeWarp:
    """Motion time of publish time under speed scaling (see the module documentation)."""

    def __init__(self, ramp_time: float, rate: float = 1.0, tau0: float = 0.0, t0: float = 0.0):
        self.ramp_time = check_ramp_time(ramp_time)
        self._ramps = [RateRamp(tau0, t0, check_rate(rate), rate, self.ramp_time)]

    @property
    def target(self) -> float:
        """The rate the warp is at or moving to."""
        return self._ramps[-1].r1

    def _ramp(self, tau: float) -> RateRamp:
        for ramp in reversed(self._ramps):
            if tau >= ramp.tau0:
                return ramp
        return self._ramps[0]

    def at(self, tau: float) -> tuple[float, float, float]:
        """Motion time t, rate r and dr/dtau at publish time tau."""
        ramp = self._ramp(tau)
        return ramp.at(max(tau, ramp.tau0))

    def at_times(self, taus: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`at` of each publish time of ``taus`` (N,): arrays t, r and dr/dtau; at once where the last
        ramp has ended (a constant rate), one by one elsewhere."""
        taus = np.asarray(taus, dtype=float)
        last = self._ramps[-1]
        if taus.size and taus.min() >= last.end:
            t_end = last.at(last.end)[0]
            return t_end + last.r1 * (taus - last.end), np.full(taus.size, last.r1), np.zeros(taus.size)
        t, r, dr = np.array([self.at(tau) for tau in taus.tolist()], dtype=float).reshape(-1, 3).T
        return t, r, dr

    def set_rate(self, tau: float, rate: float) -> float:
        """Move to ``rate`` from publish time tau, or from the end of a ramp under way; returns when the
        new ramp starts."""
        check_rate(rate)
        last = self._ramps[-1]
        start = max(tau, last.end) if last.r0 != last.r1 else max(tau, last.tau0)
        t, r, _ = self.at(start)
        self._ramps.append(RateRamp(start, t, r, rate, self.ramp_time))
        return start

    def settled_at(self) -> float:
        """Publish time at which the last ramp ends."""
        return self._ramps[-1].end

    def publish_time(self, t: float) -> float:
        """The first publish time at which motion time t is reached (infinite if it never is: at rest
        before)."""
        for i, ramp in enumerate(self._ramps):
            upto = self._ramps[i + 1].tau0 if i + 1 < len(self._ramps) else math.inf
            t_end_ramp = ramp.at(min(ramp.end, upto))[0]
            if t <= ramp.t0:
                return ramp.tau0
            if t <= t_end_ramp:
                return brentq(lambda tau, ramp=ramp: ramp.at(tau)[0] - t, ramp.tau0, min(ramp.end, upto), xtol=1e-12)
            if upto > ramp.end and ramp.r1 > 0.0:
                tau = ramp.end + (t - t_end_ramp) / ramp.r1
                if tau <= upto:
                    return tau
        return math.inf

    def release(self, tau: float) -> None:
        """Forget ramps that ended before the one in force at publish time tau."""
        while len(self._ramps) > 1 and self._ramps[1].tau0 <= tau:
            del self._ramps[0]


def check_rate(rate: float) -> float:
    if not (isinstance(rate, float | int) and 0.0 <= rate <= 1.0):
        raise ValueError(f"speed_scaling = {rate!r}: must be a number in [0, 1]")
    return float(rate)


def check_ramp_time(seconds: float) -> float:
    if not (math.isfinite(seconds) and seconds > 0.0):
        raise ValueError(f"speed_scaling ramp time = {seconds!r}: must be a finite number > 0 s")
    return float(seconds)

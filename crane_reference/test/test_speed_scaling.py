"""Speed scaling and smooth pause (:mod:`crane_reference.stream.time_warp`): the warp against quadrature
of its rate, the published derivatives against finite differences of the published positions, and the
continuity of velocity and acceleration through pause, resume, speed changes and a re-target."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from crane_reference.model.parameters import Task
from crane_reference.stream.reference_stream import ReferenceStream
from crane_reference.stream.time_warp import TimeWarp

RAMP = 0.4  # [s]


def test_motion_time_is_the_integral_of_the_rate():
    warp = TimeWarp(RAMP, 1.0)
    warp.set_rate(0.5, 0.3)
    warp.set_rate(0.6, 0.0)  # asked for during the first ramp: starts when it ends
    warp.set_rate(2.0, 1.0)
    rate = lambda tau: warp.at(tau)[1]  # noqa: E731
    breaks = [0.5, 0.9, 1.3, 2.0, 2.4]
    for tau in np.linspace(0.0, 3.0, 61):
        assert warp.at(tau)[0] == pytest.approx(quad(rate, 0.0, tau, points=[b for b in breaks if b < tau],
                                                     epsabs=1e-13)[0], abs=1e-10)
        h = 1e-6
        assert warp.at(tau)[2] == pytest.approx((rate(tau + h) - rate(tau - h)) / (2 * h), abs=1e-5)
        assert 0.0 <= rate(tau) <= 1.0
    tau = (1.0 - 0.9) / RAMP  # on the way down from 0.3 (reached at 0.9 s) to 0, along the quintic step of (5.2)
    assert rate(1.0) == pytest.approx(0.3 * (1.0 - (10 * tau**3 - 15 * tau**4 + 6 * tau**5)), rel=1e-12)
    assert rate(1.5) == 0.0 and rate(2.5) == 1.0
    t = warp.at(2.7)[0]
    assert warp.publish_time(t) == pytest.approx(2.7, abs=1e-9)
    assert warp.publish_time(warp.at(1.8)[0] + 1e-6) == pytest.approx(2.0, abs=0.05)  # resumes after the rest


def test_the_warp_at_many_times_is_the_warp_at_each():
    """The vectorised path (after the last ramp) and the one-by-one path give the scalar values exactly."""
    warp = TimeWarp(RAMP, 1.0)
    warp.set_rate(0.5, 0.3)
    for taus in (np.linspace(0.0, 1.2, 97), np.linspace(1.0, 3.0, 41)):  # through the ramp; after it
        t, r, dr = warp.at_times(taus)
        np.testing.assert_array_equal(np.column_stack((t, r, dr)), [warp.at(tau) for tau in taus])


def published(stream: ReferenceStream, taus: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    samples = []
    for tau in taus:
        stream.compute(tau + 0.05)
        samples.append(stream.sample(tau))
    return (np.array([s.q for s in samples]), np.array([s.qd for s in samples]), np.array([s.qdd for s in samples]))


@pytest.mark.slow
def test_pause_resume_override_and_retarget_keep_velocity_and_acceleration_continuous(params):
    stream = ReferenceStream(params, "rigid", step=1e-3, blend_time=0.5, ramp_time=RAMP)
    dt = 1e-3
    # normal running from 1.1 s (after the drive's torque step at 1 s, a jump of the programmed acceleration)
    stream.compute(1.7)
    stream.pause(1.5)
    stream.compute(2.5)
    stream.resume(2.5)
    stream.compute(3.5)
    stream.set_speed_scaling(3.3, 0.5)
    stream.compute(4.1)
    stream.retarget(4.0, Task(ellipse_a=3.2, ellipse_b=2.1, z_increment=0.2, rise_time=5.0))
    taus = np.arange(1.1, 5.0, dt)
    q, qd, qdd = published(stream, taus)
    # the published derivatives are those of the published positions (chain rule of the warp): central
    # differences agree to their own truncation error on the crane's vibration, far below what a missing
    # factor r in the velocity or r' q' in the acceleration would leave (|1 - r| |q'| and |r'| |q'|)
    velocity_error = np.max(np.abs((q[2:] - q[:-2]) / (2 * dt) - qd[1:-1]))
    acceleration_error = np.max(np.abs((qd[2:] - qd[:-2]) / (2 * dt) - qdd[1:-1]))
    speed = np.max(np.abs(qd[taus < 1.5]))
    assert velocity_error < 1e-3 * speed
    assert acceleration_error < 1e-2 * speed / RAMP
    # at rest between the end of the pause ramp and the resume: same position, zero velocity
    rest = (taus > 1.5 + RAMP) & (taus < 2.5)
    assert np.all(np.abs(qd[rest]) < 1e-15) and np.ptp(q[rest], axis=0).max() < 1e-15
    # per-sample changes through the events stay of the order of normal running (a stop within one sample
    # would change the velocity by |q'| itself, about 500 times the largest change in normal running)
    dv, da = np.max(np.abs(np.diff(qd, axis=0)), axis=1), np.max(np.abs(np.diff(qdd, axis=0)), axis=1)
    normal, events = taus[1:] < 1.5, taus[1:] >= 1.5
    assert dv[events].max() <= 3.0 * dv[normal].max()
    assert da[events].max() <= 3.0 * da[normal].max()
    assert speed > 100 * dv[normal].max()


@pytest.mark.parametrize("ramp", [RAMP, 1.0])  # 1.0: the motion comes to rest on a step of the integrator
def test_a_pause_computes_the_ramp_to_rest_beyond_the_motion_computed_before(params, ramp):
    """A pause asked for where little motion is computed ahead (as just after a re-target): the motion along the
    ramp to rest is still computed, so the whole ramp is published, and it is the motion of a stream that was
    never paused, at the motion time where the ramp comes to rest (the integral of the rate: quadrature)."""
    paused, running = ReferenceStream(params, "rigid", step=1e-3, ramp_time=ramp), ReferenceStream(params, "rigid",
                                                                                                   step=1e-3)
    paused.compute(0.1)
    paused.pause(paused.computed_until)
    start = paused.computed_until
    paused.compute(start + ramp + 0.5)
    assert paused.computed_until == np.inf  # at rest: every later sample is available
    rest = paused.sample(start + ramp + 0.5)
    warp = TimeWarp(ramp, 1.0)
    warp.set_rate(start, 0.0)
    t_rest = start + quad(lambda tau: warp.at(tau)[1], start, start + ramp, epsabs=1e-13)[0]
    assert rest.t == pytest.approx(t_rest, abs=1e-9) and np.all(rest.qd == 0.0)
    running.compute(t_rest + 0.01)
    np.testing.assert_allclose(rest.q, running.sample(t_rest).q, atol=1e-9)

"""The integrator's error against scipy's DOP853 at a tight tolerance, for convergence-order tests."""

from __future__ import annotations

import numpy as np

from crane_reference.motion.programmed_motion import ProgrammedMotion
from crane_reference.motion.simulation import MotionStepper, Scenario, simulate, simulate_reference
from crane_reference.motion.steps import ONLINE_STEP


def errors_against_dop853(motion: ProgrammedMotion, q0: np.ndarray, duration: float, steps: tuple[float, ...],
                          spacing: float) -> list[float]:
    """The largest coordinate error [rad or m] of the integrator at each of ``steps`` [s] over ``duration`` [s],
    on a grid of ``spacing`` [s], against DOP853 at rtol 1e-11."""
    times = np.round(np.arange(0.0, duration + 1e-9, spacing), 9)
    reference = simulate_reference(motion, q0, duration, times, rtol=1e-11, atol=1e-13)
    errors = []
    for step in steps:
        tr = simulate(motion, q0, duration, step=step)
        on_reference = np.array([np.interp(times, tr.t, tr.q[:, k]) for k in range(tr.q.shape[1])]).T
        errors.append(float(np.max(np.abs(on_reference - reference.q))))
    return errors


def second_of_steps(scenario: Scenario, end: float = 1.0, **integrator: object):
    """The state after ``end`` seconds (1 s: the drive's jump at 1 s included) at the node's step from the scenario's
    static equilibrium at rest, with the integrator's attributes set as ``integrator`` gives them."""
    q0 = scenario.equilibrium.q
    stepper = MotionStepper(scenario.motion, 0.0, q0, np.zeros_like(q0), ONLINE_STEP)
    for name, value in integrator.items():
        setattr(stepper.integrator, name, value)
    stepper.advance_until(end)
    assert stepper.state.t == end
    return stepper.state

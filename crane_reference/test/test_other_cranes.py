"""The integrator's properties on the example cranes of config/ (not only the paper's), against independent truths.

* Energy balance: on the loader crane (fixed base, a damped telescopic stage) the energy-balance error, the
  work of the drive, the constraint forces and the dampers against the change of energy, falls about fourfold
  when the step halves (second order).
* Convergence: the loader crane's motion through its drive's torque jump against scipy's DOP853 at rtol 1e-11:
  halving the step cuts the error about fourfold.
* Rest: the knuckle-boom crane (a URDF, a spring drive held by its motor) started in its static equilibrium
  stays at rest to round-off.
* Vibration: a mode of the knuckle-boom crane's linearisation (scipy's eigensolver on its tangent stiffness and
  reduced mass, :mod:`crane_reference.analysis.modal`), excited alone, rings at its frequency in the integrated
  motion.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from convergence import errors_against_dop853
from cranes import CONFIG

from crane_reference.analysis.modal import linearise, modal_analysis
from crane_reference.model.chain import VARIANTS
from crane_reference.model.config import load_config
from crane_reference.model.profiles import Constant
from crane_reference.motion.constraints import paper_constraints
from crane_reference.motion.integration import ExactFrequencyTrapezoidal
from crane_reference.motion.programmed_motion import ProgrammedMotion
from crane_reference.motion.simulation import MotionStepper, Scenario, simulate

ROUND_OFF_VELOCITY = 1e-10  # [rad/s, m/s], as the paper crane's rest test
HELD = 100.0  # [s] a drive start beyond every run: the motor holds its start angle


@pytest.fixture(scope="module")
def loader() -> Scenario:
    return Scenario(load_config(CONFIG / "loader_crane.yaml"), "rigid")


def test_loader_energy_balance_is_second_order(loader):
    errors = []
    for step in (4e-3, 2e-3):
        tr = simulate(loader.motion, loader.equilibrium.q, 3.0, step=step)
        scale = np.max(np.abs(tr.work_drive))
        errors.append(np.max(np.abs(tr.energy_balance_error)) / scale)
    assert np.max(np.abs(tr.work_damping)) > 0.0  # the stage's damper works
    assert errors[0] / errors[1] >= 3.0, f"relative errors {errors}: not second order"
    assert errors[1] < 1e-4


def test_loader_converges_with_second_order_against_dop853(loader):
    errors = errors_against_dop853(loader.motion, loader.equilibrium.q, 1.5, (4e-3, 2e-3), 4e-3)
    assert errors[0] / errors[1] >= 3.5, f"errors {errors}: not second order"


def _held_knuckle_boom_crane(variant: str) -> tuple[ProgrammedMotion, np.ndarray]:
    """The knuckle-boom crane, undamped, its motor holding the slew, E held on the ellipse at its static height:
    the motion and its static equilibrium."""
    params = load_config(CONFIG / "knuckle_boom_crane.yaml").with_beam_damping(0.0)
    params = replace(params, drive=replace(params.drive, start=HELD))
    scenario = Scenario(params, variant)
    task = scenario.task
    motion = ProgrammedMotion(scenario.dynamics, paper_constraints(Constant(task.ellipse_a), Constant(task.ellipse_b),
                                                                   Constant(scenario.z_static)))
    return motion, scenario.equilibrium.q


@pytest.mark.parametrize("variant", VARIANTS)
def test_knuckle_boom_crane_rests_at_round_off(variant):
    motion, q = _held_knuckle_boom_crane(variant)
    integrator = ExactFrequencyTrapezoidal(motion, tolerance=1e-12)
    state = integrator.start(0.0, q, np.zeros(motion.dof))
    worst = 0.0
    for _ in range(2000):
        state = integrator.step(state, state.t + 1e-3)
        worst = max(worst, float(np.max(np.abs(state.qd))))
    assert worst < ROUND_OFF_VELOCITY


def test_a_knuckle_boom_crane_mode_rings_at_its_frequency():
    """The first mode that bends the main boom in its luffing plane, started alone with a small velocity along its
    shape phi (phi^T M phi = 1): its modal coordinate y = phi^T M (q - q_eq) swings at the mode's frequency
    (from the zero crossings of 0.5 s, some 23 periods), to 1e-5 (the exact-frequency step)."""
    motion, q = _held_knuckle_boom_crane("flexible")
    modes = modal_analysis(linearise(motion, 0.0, q))
    k = next(k for k in range(modes.frequencies.size)
             if modes.strain_energy["main_boom bending, luffing plane"][k] > 0.5)
    phi, omega = modes.shapes[:, k], 2.0 * np.pi * modes.frequencies[k]
    amplitude = 1e-5  # [sqrt(kg) m]: micro-radians at the boom
    stepper = MotionStepper(motion, 0.0, q, amplitude * omega * phi, 5e-4)
    rows = stepper.advance_until(0.5)
    M = motion.solve(0.0, q, np.zeros_like(q)).dynamics.M
    y = (rows.q - q) @ M @ phi
    t = rows.t
    crossings = np.flatnonzero(np.sign(y[:-1]) != np.sign(y[1:]))
    at = t[crossings] - y[crossings] * (t[crossings + 1] - t[crossings]) / (y[crossings + 1] - y[crossings])
    frequency = (at.size - 1) / (2.0 * (at[-1] - at[0]))
    assert np.max(np.abs(y)) == pytest.approx(amplitude, rel=0.05)
    assert frequency == pytest.approx(modes.frequencies[k], rel=1e-5)

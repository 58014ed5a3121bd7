"""The integrator's numerical pieces (crane_reference.motion.integration), against independent truths.

* The modal terms of a step: Delta M_r = M_r Phi diag(c) Phi^T M_r with the modes from scipy's generalized
  symmetric eigensolver and c from the exact-frequency formula, at the crane's reduced mass.
* A run's evaluated rows: which rows get the full evaluation does not change the motion (bit for bit),
  and the reactions of an evaluated row are lambda = (A A^T)^-1 A (M qdd + h - Q) assembled from the
  unconstrained terms in numpy at the row's q, qd and the integrator's qdd.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import eigh

from crane_reference.dynamics import kernels
from crane_reference.motion.integration import CUTOFF, ExactFrequencyTrapezoidal
from crane_reference.motion.simulation import MotionStepper, Scenario

STEP = 1e-3  # [s]


@pytest.fixture(scope="module")
def scenario(params):
    return Scenario(params, "flexible")


def _reduced_mass(scenario, q):
    """M_r = B^T M B at q (on the constraints, at rest)."""
    solution = scenario.motion.solve(0.0, q, np.zeros_like(q))
    B = solution.velocity_map
    return B.T @ solution.dynamics.M @ B


def _terms(scenario, q, t):
    motion = scenario.motion
    settings = ExactFrequencyTrapezoidal(motion).settings
    return kernels.modal_correction(_reduced_mass(scenario, q), STEP, t, motion.dynamics.drive.kernel_parameters(0.0),
                                    motion.partition, motion.dynamics.chain, settings)


def test_modal_inertia_is_the_exact_frequency_correction_of_scipys_modes(scenario):
    """Undamped crane: with K_r phi = omega^2 M_r phi (scipy.linalg.eigh, Phi^T M_r Phi = I) and
    c = 1 - ((omega h / 2) / tan(omega h / 2))^2 below the cutoff, Delta M_r = M_r Phi diag(c) Phi^T M_r."""
    motion = scenario.motion
    q = scenario.equilibrium.q
    reduced_mass = _reduced_mass(scenario, q)
    independent = list(motion.partition.independent)
    stiffness = motion.dynamics.chain.stiffness[np.ix_(independent, independent)].copy()
    j = independent.index(motion.dynamics.chain.drive_joint)
    stiffness[j, j] += motion.dynamics.drive.kernel_parameters(0.0)[1]  # the drive's spring s_dr
    omega_squared, phi = eigh(stiffness, reduced_mass)
    omega_h = np.sqrt(np.maximum(omega_squared, 0.0)) * STEP
    resolved = omega_h < CUTOFF
    c = np.zeros_like(omega_h)
    half = 0.5 * omega_h[resolved]
    c[resolved] = 1.0 - (half / np.tan(half)) ** 2
    expected = reduced_mass @ phi @ np.diag(c) @ phi.T @ reduced_mass
    terms = _terms(scenario, q, 0.0)
    assert np.max(np.abs(terms.inertia - expected)) <= 1e-9 * np.max(np.abs(expected))


def test_evaluated_rows_do_not_change_the_motion_and_hold_the_kkt_reactions(scenario):
    motion = scenario.motion
    stepper = MotionStepper(motion, 0.0, scenario.equilibrium.q, np.zeros_like(scenario.equilibrium.q), STEP)
    stepper.advance_until(0.5)
    state, settings = stepper.state, stepper.integrator.settings
    times = state.t + STEP * np.arange(1, 41)
    coefficients = motion.constraints.coefficients_at(times)
    drives = motion.dynamics.drive.kernel_parameters(times)

    def run(evaluated):
        return kernels.integration_run(state.q, state.qd, state.solution.qdd, state.solution.velocity_map,
                                       state.correction, state.t, times,
                                       coefficients, drives, motion.partition, motion.dynamics.chain, settings,
                                       evaluated)

    every = run(np.ones(times.size, dtype=bool)).rows
    sparse_mask = np.arange(times.size) % 7 == 3
    sparse = run(sparse_mask).rows
    for name in ("q", "qd", "qdd", "ee_position", "ee_rotation", "ee_velocity"):
        np.testing.assert_array_equal(getattr(sparse, name), getattr(every, name))
    shown = sparse_mask.copy()
    shown[-1] = True  # the last row always carries the evaluation
    assert np.all(np.isnan(sparse.reactions[~shown])) and np.all(np.isfinite(sparse.reactions[shown]))
    np.testing.assert_array_equal(sparse.reactions[shown], every.reactions[shown])
    for i in np.flatnonzero(shown):
        solution = motion.solve(times[i], every.q[i], every.qd[i])
        d, A = solution.dynamics, solution.constraints.A
        imbalance = d.M @ every.qdd[i] + d.h - d.Q
        expected = np.linalg.solve(A @ A.T, A @ imbalance)
        np.testing.assert_allclose(every.reactions[i], expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())

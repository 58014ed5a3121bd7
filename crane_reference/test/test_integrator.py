"""The integrator's numerical pieces (crane_reference.motion.integration), against independent truths.

* The modal terms of a step: Delta M_r = M_r Phi diag(c) Phi^T M_r with the modes from scipy's generalized
  symmetric eigensolver and c from the exact-frequency formula, at the crane's reduced mass.
* The modal terms tracked from one configuration to another (the resolved modes by subspace iteration and
  Rayleigh-Ritz) against scipy's modes at the second, across a near-degenerate pair that turns.
* The modal terms refreshed by subspace iteration from the last modes (n_rfe = 12, where guard modes fit) against
  scipy's modes at the new configuration, across a near-degenerate pair that turns; and a second of steps with the
  refresh iterated against one with the full eigenproblem at every refresh.
* The Newton iteration matrix at the step's first iterate against the Jacobian of the step's residual by
  central differences.
* The modal correction's refresh: a change of the equation's coefficient, not a kick: the slow motion of
  a run refreshing every 1 ms and one refreshing every 5 ms agree, as the continuous-coefficient method
  they approximate (converting the accelerations at each refresh kicked it and made them differ).
* A run's evaluated rows: which rows get the full evaluation does not change the motion (bit for bit),
  and the reactions of an evaluated row are lambda = (A A^T)^-1 A (M qdd + h - Q) assembled from the
  unconstrained terms in numpy at the row's q, qd and the integrator's qdd; rows evaluated after the run
  equal those evaluated in it.
* The Newton iteration's predictor: exact for accelerations quadratic in time; a run cut into several
  compiled calls equals the run in one.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest
from convergence import second_of_steps
from cranes import CONFIG
from scipy.linalg import eigh
from scipy.signal import butter, sosfiltfilt
from velocity_map import random_velocity_map

from crane_reference.dynamics.modal_correction import (
    GUARD_MODES,
    iteration_factor,
    modal_correction,
    refreshed_correction,
    stiffness_product,
    tracked_correction,
)
from crane_reference.dynamics.runs import integration_run
from crane_reference.dynamics.step import (
    add_modal_terms,
    first_iterate,
    predicted_accelerations,
    refresh_inputs,
    step_residual,
)
from crane_reference.dynamics.structures import ACCOUNTS, ModalCorrection, Partition
from crane_reference.model.config import load_config
from crane_reference.motion.integration import CUTOFF, UNRESOLVED_DAMPING, ExactFrequencyTrapezoidal, stop_flag
from crane_reference.motion.simulation import MotionStepper, Scenario
from crane_reference.motion.steps import ANALYSIS_STEP, ONLINE_STEP

STEP = 1e-3  # [s]


@pytest.fixture(scope="module")
def scenario(params):
    return Scenario(params, "flexible")


def _reduced_mass(scenario, q):
    """M_r = B^T M B at q (on the constraints, at rest)."""
    solution = scenario.motion.solve(0.0, q, np.zeros_like(q))
    B = solution.velocity_map
    return B.T @ solution.dynamics.M @ B


def _terms(scenario, q, t, h=STEP):
    motion = scenario.motion
    settings = ExactFrequencyTrapezoidal(motion).settings
    return modal_correction(_reduced_mass(scenario, q), h, t, motion.dynamics.drive.kernel_parameters(0.0),
                                    motion.partition, motion.dynamics.chain, settings)


def _scipy_modes(scenario, q):
    """M_r at q and scipy.linalg.eigh's modes of the pencil (K_r, M_r), K_r = K[ic, ic] plus the drive's spring
    s_dr on psi2: omega^2 and Phi (Phi^T M_r Phi = I)."""
    motion = scenario.motion
    reduced_mass = _reduced_mass(scenario, q)
    independent = list(motion.partition.independent)
    stiffness = motion.dynamics.chain.stiffness[np.ix_(independent, independent)].copy()
    j = independent.index(motion.dynamics.chain.drive_joint)
    stiffness[j, j] += motion.dynamics.drive.kernel_parameters(0.0)[1]  # the drive's spring s_dr
    omega_squared, phi = eigh(stiffness, reduced_mass)
    return reduced_mass, np.maximum(omega_squared, 0.0), phi


NODE_BANDWIDTH = 2.0 * np.pi * 800.0
"""[rad/s]: the modes the node's step (0.5 ms) resolves, omega h < 0.8 pi, are those below 800 Hz."""


@pytest.mark.parametrize("h", [STEP, ANALYSIS_STEP])
def test_modal_terms_are_the_exact_frequency_correction_of_scipys_modes(scenario, h):
    """Undamped crane: with K_r phi = omega^2 M_r phi (scipy.linalg.eigh) and u = omega h, Delta M_r =
    M_r Phi diag(c) Phi^T M_r and D_u = M_r Phi diag(e) Phi^T M_r with c = 1 - ((u / 2) / tan(u / 2))^2, e = 0
    below omega_c = min(cutoff / h, 2 pi 800 Hz) (the cutoff, and the bandwidth the node's step resolves), and
    c = 0, e = 2 zeta omega^2 / omega_c (zeta the unresolved modes' damping ratio at omega_c) at or above it; and the
    step's modal terms D_u v - Delta M_r a (``add_modal_terms``, from the resolved modes and K_r alone) for random v
    and a, and K_r V (``stiffness_product``) with K_r scipy's, for v and two random columns at once.  At 1 ms the
    cutoff decides; at 0.25 ms the bandwidth, and some modes below the cutoff are damped."""
    q = scenario.equilibrium.q
    reduced_mass, omega_squared, phi = _scipy_modes(scenario, q)
    omega = np.sqrt(omega_squared)
    omega_c = min(CUTOFF / h, NODE_BANDWIDTH)
    resolved = omega < omega_c
    assert 0 < (~resolved).sum() < omega.size
    if h < ONLINE_STEP:  # the bandwidth decides: some modes below the cutoff are damped
        assert np.any(~resolved & (omega * h < CUTOFF))
    c, e = np.zeros_like(omega), np.zeros_like(omega)
    half = 0.5 * omega[resolved] * h
    ratio = np.ones_like(half)  # (omega h / 2) / tan(omega h / 2) -> 1 for a mode no spring resists (omega = 0)
    ratio[half > 0.0] = half[half > 0.0] / np.tan(half[half > 0.0])
    c[resolved] = 1.0 - ratio**2
    e[~resolved] = 2.0 * UNRESOLVED_DAMPING * omega[~resolved] ** 2 / omega_c
    terms = _terms(scenario, q, 0.0, h)
    assert terms.resolved == resolved.sum()
    expected = {}
    for name, computed, per_mode in (("inertia", terms.inertia, c), ("damping", terms.damping, e)):
        expected[name] = reduced_mass @ phi @ np.diag(per_mode) @ phi.T @ reduced_mass
        assert np.max(np.abs(computed - expected[name])) <= 1e-9 * np.max(np.abs(expected[name]))
    motion, rng = scenario.motion, np.random.default_rng(4)
    independent, n = motion.partition.independent, q.size
    qd, a = np.zeros(n), rng.normal(size=independent.size)
    qd[independent] = rng.normal(size=independent.size)
    v, drive, chain = qd[independent], motion.dynamics.drive.kernel_parameters(0.0), motion.dynamics.chain
    terms_expected = expected["damping"] @ v - expected["inertia"] @ a
    computed = np.zeros(independent.size)
    add_modal_terms(computed, qd, a, terms, drive, motion.partition, chain)
    assert np.max(np.abs(computed - terms_expected)) <= 1e-9 * np.max(np.abs(terms_expected))
    stiffness = (reduced_mass @ phi) @ np.diag(omega_squared) @ (reduced_mass @ phi).T  # K_r = M_r Phi W^2 Phi^T M_r
    columns = np.column_stack([v, rng.normal(size=(independent.size, 2))])
    expected_springs = stiffness @ columns
    assert np.allclose(stiffness_product(columns, drive, motion.partition, chain), expected_springs, rtol=0.0,
                       atol=1e-9 * np.abs(expected_springs).max())


def _states(scenario, times):
    """The states of the scenario's task at ``times`` (at the node's step from its static equilibrium at rest), and the
    integrator's settings."""
    q0 = scenario.equilibrium.q
    stepper = MotionStepper(scenario.motion, 0.0, q0, np.zeros_like(q0), ONLINE_STEP)
    states = []
    for t in times:
        stepper.advance_until(t)
        states.append(stepper.state)
    return states, stepper.integrator.settings


def _refreshed(scenario, state, correction, drive, chain, settings, h):
    """``refreshed_correction`` of ``correction`` (of the step h) at ``state``: its reduced mass, frames and velocity
    map."""
    motion = scenario.motion
    B = motion.solve(state.t, state.q, np.zeros_like(state.q)).velocity_map
    return refreshed_correction(*refresh_inputs(state.q, B, motion.partition, chain), B, correction, h,
                                state.t, drive, motion.partition, chain, settings)


def _exact_frequency_inertia(mass, omega_squared, phi, resolved, h):
    """Delta M_r = M_r Phi_r diag(c) Phi_r^T M_r, c = 1 - ((omega h / 2) / tan(omega h / 2))^2 (undamped)."""
    half = 0.5 * np.sqrt(omega_squared[:resolved]) * h
    ratio = np.ones_like(half)
    ratio[half > 0.0] = half[half > 0.0] / np.tan(half[half > 0.0])
    on_resolved = mass @ phi[:, :resolved]
    return on_resolved @ np.diag(1.0 - ratio**2) @ on_resolved.T


def test_tracked_modes_follow_scipys_across_a_rotating_near_degenerate_pair(scenario):
    """The default crane at h = 0.5 ms with the modes below omega h = 0.8 pi resolved, at t = 2.405 s and 5 ms later
    (configurations a and b), where the near-degenerate pair near 449 Hz turns within its plane by more than 0.25
    rad (scipy's modes; asserted). The resolved modes of the modal terms at a tracked to b
    (``tracked_correction`` at b's M_r, repeated: a subspace iteration) reach scipy's modes at b: Delta M_r = M_r
    Phi_r diag(c) Phi_r^T M_r to 1e-9, with c of each mode of the pair its own (the Rayleigh-Ritz step turns the
    pair); the damping is b's unresolved modes' D_u (scipy's modes at b, e_u = 2 zeta omega_u^2 h / cutoff), which
    damps none of the resolved ones; and a single tracking from a to b brings Delta M_r 10 times closer to scipy's
    at b than a's was.  Modes whose span degenerates (two alike) are not tracked: the full eigenproblem at b gives
    scipy's Delta M_r there."""
    motion, q0, h = scenario.motion, scenario.equilibrium.q, 5e-4
    stepper = MotionStepper(motion, 0.0, q0, np.zeros_like(q0), h)
    states = []
    for t in (2.405, 2.41):
        stepper.advance_until(t)
        states.append(stepper.state)
    settings = stepper.integrator.settings._replace(cutoff=0.8 * np.pi)
    drive, partition, chain = motion.dynamics.drive.kernel_parameters(0.0), motion.partition, motion.dynamics.chain
    (mass_a, squared_a, phi_a), (mass_b, squared_b, phi_b) = (_scipy_modes(scenario, state.q) for state in states)
    omega_a, omega_b = np.sqrt(squared_a), np.sqrt(squared_b)
    resolved = int(np.sum(omega_b * h < settings.cutoff))
    pair = int(np.argmin(np.abs(omega_b / (2.0 * np.pi) - 448.9)))
    assert resolved == int(np.sum(omega_a * h < settings.cutoff)) and pair + 1 < resolved
    assert np.arccos(abs(phi_a[:, pair] @ mass_b @ phi_b[:, pair])) > 0.25  # the pair turns
    expected_inertia = _exact_frequency_inertia(mass_b, squared_b, phi_b, resolved, h)
    on_unresolved_b = mass_b @ phi_b[:, resolved:]
    e_b = 2.0 * UNRESOLVED_DAMPING * omega_b[resolved:] ** 2 * h / settings.cutoff
    expected_damping = on_unresolved_b @ np.diag(e_b) @ on_unresolved_b.T
    at_a = modal_correction(mass_a, h, 0.0, drive, partition, chain, settings)
    assert at_a.resolved == resolved
    tracked = tracked_correction(mass_b, at_a, states[1].t, drive, partition, chain, settings)
    scale = np.abs(expected_inertia).max()
    assert np.abs(tracked.inertia - expected_inertia).max() <= 0.1 * np.abs(at_a.inertia - expected_inertia).max()
    for _ in range(40):
        tracked = tracked_correction(mass_b, tracked, states[1].t, drive, partition, chain, settings)
    assert np.abs(tracked.inertia - expected_inertia).max() <= 1e-9 * scale
    assert np.abs(tracked.damping - expected_damping).max() <= 1e-9 * np.abs(expected_damping).max()
    degenerate = at_a.modes.copy()
    degenerate[:, 1] = degenerate[:, 0]  # two resolved modes alike: their span degenerates
    fallback = tracked_correction(mass_b, at_a._replace(modes=degenerate), states[1].t, drive, partition, chain,
                                  settings)  # the full eigenproblem at b instead, tested against scipy above
    assert fallback.time == states[1].t and fallback.resolved == resolved
    assert np.abs(fallback.inertia - expected_inertia).max() <= 1e-9 * scale


@pytest.fixture(scope="module")
def refined():
    """The default crane with 12 RFEs per flexible link (n_ic = 40: the resolved modes and the guard modes fit)."""
    return Scenario(load_config().with_rfe_count(12), "flexible")


def test_refreshed_modes_reach_scipys_across_a_rotating_near_degenerate_pair(refined):
    """n_rfe = 12 at the node's step, at t = 1.39 s and one refresh interval (10 ms) later (configurations a and
    b), where the near-degenerate pair near 451 Hz turns within its plane by more than 0.1 rad (scipy's modes;
    asserted). The modal terms of a, refreshed at b by subspace iteration (``refreshed_correction``: the articulated
    solves, not the full eigenproblem: the modes beyond the iterated ones are left zero), equal the exact-frequency
    terms of scipy's modes at b: Delta M_r to 1e-6 of its largest entry, 1000 times closer than a's was; and D_u,
    the unresolved modes' damping (scipy's modes at b, e_u = 2 zeta omega_u^2 h / cutoff), to 1e-6 of the resolved
    modes' part of it, -beta M_r Phi_r diag(omega_r^2) Phi_r^T M_r (D_u = beta K_r less that part, and beta K_r does
    not depend on the modes)."""
    motion, h = refined.motion, ONLINE_STEP
    states, settings = _states(refined, (1.39, 1.40))
    drive, partition, chain = motion.dynamics.drive.kernel_parameters(0.0), motion.partition, motion.dynamics.chain
    (mass_a, squared_a, phi_a), (mass_b, squared_b, phi_b) = (_scipy_modes(refined, state.q) for state in states)
    resolved = int(np.sum(np.sqrt(squared_b) * h < settings.cutoff))
    pair = int(np.argmin(np.abs(np.sqrt(squared_b) / (2.0 * np.pi) - 451.0)))
    assert resolved == int(np.sum(np.sqrt(squared_a) * h < settings.cutoff)) and pair + 1 < resolved
    assert resolved + GUARD_MODES < partition.independent.size
    assert abs(squared_b[pair + 1] / squared_b[pair] - 1.0) < 0.01  # near-degenerate
    assert np.arccos(min(1.0, abs(phi_a[:, pair] @ mass_b @ phi_b[:, pair]))) > 0.1  # the pair turns
    expected_inertia = _exact_frequency_inertia(mass_b, squared_b, phi_b, resolved, h)
    on_unresolved = mass_b @ phi_b[:, resolved:]
    e_u = 2.0 * UNRESOLVED_DAMPING * squared_b[resolved:] * h / settings.cutoff
    expected_damping = on_unresolved @ np.diag(e_u) @ on_unresolved.T
    at_a = modal_correction(mass_a, h, states[0].t, drive, partition, chain, settings)
    refreshed = _refreshed(refined, states[1], at_a, drive, chain, settings, h)
    assert refreshed.resolved == resolved and not np.any(refreshed.modes[:, resolved + GUARD_MODES:])
    on_resolved = mass_b @ phi_b[:, :resolved]
    resolved_part = on_resolved @ np.diag(2.0 * UNRESOLVED_DAMPING * squared_b[:resolved] * h / settings.cutoff) \
        @ on_resolved.T
    inertia_scale, damping_scale = np.abs(expected_inertia).max(), np.abs(resolved_part).max()
    assert np.abs(refreshed.inertia - expected_inertia).max() <= 1e-6 * inertia_scale
    assert np.abs(refreshed.damping - expected_damping).max() <= 1e-6 * damping_scale
    assert np.abs(refreshed.inertia - expected_inertia).max() <= 1e-3 * np.abs(at_a.inertia - expected_inertia).max()


@pytest.mark.parametrize("h", [ONLINE_STEP, ANALYSIS_STEP])
def test_refreshed_modes_reach_scipys_with_a_spring_drive(h):
    """The knuckle-boom crane with 12 RFEs per flexible link, whose column drive is a spring (s_dr = 2e6 N m / rad on
    psi2, an independent coordinate: K_r holds it, and so does the refresh's shifted solve), at t = 1 s and 10 ms
    later: the modal terms of the first, refreshed at the second by subspace iteration (not falling back), equal the
    exact-frequency terms of scipy's modes there, Delta M_r to 1e-6 of its largest entry (the terms of the chain
    without its dampers, for which c has the closed form of the undamped mode); at the node's step and at 0.25 ms,
    where the modes below omega_c = min(0.8 pi / h, 2 pi 800 Hz) are resolved (the bandwidth decides)."""
    scenario = Scenario(load_config(CONFIG / "knuckle_boom_crane.yaml").with_rfe_count(12), "flexible")
    motion = scenario.motion
    chain = motion.dynamics.chain._replace(damping=np.zeros_like(motion.dynamics.chain.damping), damped=False)
    partition = motion.partition
    drive = motion.dynamics.drive.kernel_parameters(0.0)
    assert drive[1] > 0.0 and chain.drive_joint in partition.independent
    states, settings = _states(scenario, (1.0, 1.01))
    (mass_a, _, _), (mass_b, squared_b, phi_b) = (_scipy_modes(scenario, state.q) for state in states)
    omega_c = min(CUTOFF / h, NODE_BANDWIDTH)
    resolved = int(np.sum(np.sqrt(squared_b) < omega_c))
    assert resolved + GUARD_MODES < partition.independent.size
    if h < ONLINE_STEP:  # the bandwidth decides: some modes below the cutoff are damped
        assert np.any((np.sqrt(squared_b) >= omega_c) & (np.sqrt(squared_b) * h < CUTOFF))
    at_a = modal_correction(mass_a, h, states[0].t, drive, partition, chain, settings)
    refreshed = _refreshed(scenario, states[1], at_a, drive, chain, settings, h)
    assert refreshed.resolved == resolved and not np.any(refreshed.modes[:, resolved + GUARD_MODES:])
    expected = _exact_frequency_inertia(mass_b, squared_b, phi_b, resolved, h)
    assert np.abs(refreshed.inertia - expected).max() <= 1e-6 * np.abs(expected).max()


def test_a_second_of_steps_with_the_refresh_iterated_is_the_full_eigenproblems(refined):
    """n_rfe = 12 from its static equilibrium over 1 s at the node's step (the drive's jump at 1 s included): the
    motion with the refresh iterated from the last modes (the last one before the jump did not fall back: the modes
    beyond its guard modes are zero) and with the full eigenproblem at every refresh agree to 1e-9 in q and 1e-7 in
    qd."""
    full, iterated = (second_of_steps(refined, subspace_refresh=subspace_refresh) for subspace_refresh in (False, True))
    last = second_of_steps(refined, 0.995, subspace_refresh=True).correction  # refreshed at 0.99 s (the jump at 1 s
    assert last.resolved > 0 and not np.any(last.modes[:, last.resolved + GUARD_MODES:])  # starts a new equation)
    assert np.abs(iterated.q - full.q).max() <= 1e-9
    assert np.abs(iterated.qd - full.qd).max() <= 1e-7


def test_the_slow_motion_does_not_depend_on_the_refresh_cadence(scenario):
    """2 s of the paper's task at h = 0.5 ms, the modal correction computed every 1 ms and every 5 ms: the
    slew, luff and knuckle angles low-passed at 10 Hz (the controller band) differ by less than 5e-7 rad
    (a refresh that converted the accelerations kicked the slow motion, and this failed)."""
    motion, q0 = scenario.motion, scenario.equilibrium.q
    step = 5e-4
    slow = []
    for refresh in (1e-3, 5e-3):
        stepper = MotionStepper(motion, 0.0, q0, np.zeros_like(q0), step)
        stepper.integrator.refresh_interval = refresh
        rows = stepper.advance_until(2.0)
        columns = [scenario.model.joint_names.index(name) for name in ("column_slew", "boom_luff", "knuckle")]
        slow.append(sosfiltfilt(butter(4, 10.0, fs=1.0 / step, output="sos"), rows.q[:, columns], axis=0))
    inner = slice(round(0.1 / step), -round(0.1 / step))  # away from the filter's end transients
    assert np.abs(slow[0] - slow[1])[inner].max() < 5e-7


def test_evaluated_rows_do_not_change_the_motion_and_hold_the_kkt_reactions(scenario):
    motion = scenario.motion
    stepper = MotionStepper(motion, 0.0, scenario.equilibrium.q, np.zeros_like(scenario.equilibrium.q), STEP)
    stepper.advance_until(0.5)
    state, settings = stepper.state, stepper.integrator.settings
    times = state.t + STEP * np.arange(1, 41)
    coefficients = motion.constraints.coefficients_at(times)
    drives = motion.dynamics.drive.kernel_parameters(times)

    def run(evaluated):
        return integration_run(state.step_start(), times, coefficients, drives, motion.partition,
                               motion.dynamics.chain, settings, evaluated, stop_flag())

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
    # the rows left out, evaluated afterwards by inverse dynamics (no M), are those evaluated in the run
    later = ~shown
    forces, torques, distances = motion.evaluated_rows(times[later], sparse.q[later], sparse.qd[later],
                                                       sparse.qdd[later])
    np.testing.assert_allclose(forces, every.constraint_forces[later], rtol=0,
                               atol=1e-12 * np.abs(every.constraint_forces).max())
    np.testing.assert_array_equal(torques, every.accounts[later, ACCOUNTS.index("drive_torque")])
    np.testing.assert_array_equal(distances, every.residual_distance[later])
    singular_value = ACCOUNTS.index("kdc_min_singular_value")
    np.testing.assert_allclose(sparse.accounts[:, singular_value], every.accounts[:, singular_value], rtol=1e-12)


def test_the_predictor_extrapolates_a_quadratic_exactly():
    """a_1 = 3 a_0 - 3 a_-1 + a_-2 is the quadratic through the three accelerations one step on: exact for
    accelerations quadratic in time; with one earlier value the line through two, with none a_0."""
    h, c = 5e-4, np.array([[0.3, -1.2, 4.0], [2.0, 0.5, -7.0]])  # a(t) = c0 + c1 t + c2 t^2, per coordinate

    def a(t):
        return c[:, 0] + c[:, 1] * t + c[:, 2] * t * t

    t0 = 0.37
    earlier = np.array([a(t0 - h), a(t0 - 2 * h)])
    np.testing.assert_allclose(predicted_accelerations(a(t0), earlier), a(t0 + h), rtol=1e-13)
    earlier[1] = np.nan
    line = a(t0) + (a(t0) - a(t0 - h))
    np.testing.assert_allclose(predicted_accelerations(a(t0), earlier), line, rtol=1e-13)
    earlier[0] = np.nan
    np.testing.assert_array_equal(predicted_accelerations(a(t0), earlier), a(t0))


def test_a_run_does_not_depend_on_how_it_is_cut_into_calls(scenario):
    """The integrator's state carries what its steps use of earlier steps (the predictor's accelerations):
    40 steps in one compiled call and in calls of 1, 7 and 32 steps give the same motion, bit for bit."""
    motion, q0 = scenario.motion, scenario.equilibrium.q
    integrator = ExactFrequencyTrapezoidal(motion)
    start = integrator.run(integrator.start(0.0, q0, np.zeros_like(q0)), STEP * np.arange(1, 401))[0]
    times = start.t + STEP * np.arange(1, 41)
    whole = integrator.run(start, times)[1].q
    state, parts = start, []
    for chunk in (times[:1], times[1:8], times[8:]):
        state, rows = integrator.run(state, chunk)
        parts.append(rows.q)
    np.testing.assert_array_equal(np.concatenate(parts), whole)


def test_a_run_stopped_by_its_flag_from_another_thread_goes_on_bit_for_bit(scenario):
    """A stop flag set by another thread while compiled runs are under way ends them after the step in
    progress: fewer steps than asked; continuing from there gives the uncut motion, on the same time grid, bit
    for bit (the stepper's grid index follows the steps taken)."""
    q0 = scenario.equilibrium.q
    whole = MotionStepper(scenario.motion, 0.0, q0, np.zeros_like(q0), STEP).advance_until(10.0)
    stepper = MotionStepper(scenario.motion, 0.0, q0, np.zeros_like(q0), STEP)
    stop = stop_flag()
    timer = threading.Timer(0.02, stop.__setitem__, (0, 1))
    timer.start()
    first = stepper.advance_until(10.0, stop)
    timer.cancel()
    stop[0] = 0
    rest = stepper.advance_until(10.0, stop)
    assert 0 < first.t.size < whole.t.size
    for name in ("t", "q", "qd", "qdd"):
        np.testing.assert_array_equal(np.concatenate((getattr(first, name), getattr(rest, name))),
                                      getattr(whole, name))


@pytest.mark.parametrize("servo", [False, True], ids=["ideal", "servo"])
def test_the_iteration_matrix_is_the_dense_formula(scenario, servo):
    """The factor of the iteration matrix P^T (M + h^2/4 K + h/2 D) B - Delta M_r + h/2 D_u (K with the drive's
    spring s_dr on psi2; P = B, or E_ic for servo-constraints), written out with numpy's dense products, for a
    random M, B and modal correction, a damped chain, and the drive's joint independent or dependent."""
    rng = np.random.default_rng(5)
    chain = scenario.motion.dynamics.chain
    chain = chain._replace(damping=1e-3 * chain.stiffness, damped=True)
    n, spring = chain.stiffness.shape[0], 5e4
    drive = np.array([0.0, spring, 0.0, 0.0])
    for dependent in (scenario.motion.partition.dependent, np.array([chain.drive_joint, n - 1])):
        B, independent = random_velocity_map(rng, n, dependent)
        n_ic = independent.size
        root = rng.normal(size=(n, n))
        M = root @ root.T + n * np.eye(n)
        inertia, damping = (0.01 * (x + x.T) for x in rng.normal(size=(2, n_ic, n_ic)))
        stiffness = chain.stiffness.copy()
        stiffness[chain.drive_joint, chain.drive_joint] += spring
        P = np.eye(n)[:, independent] if servo else B
        expected = P.T @ (M + 0.25 * STEP**2 * stiffness + 0.5 * STEP * chain.damping) @ B - inertia \
            + 0.5 * STEP * damping
        zeros = np.zeros((n_ic, n_ic))
        none = np.zeros(n_ic)
        factor = iteration_factor(M, B, STEP, ModalCorrection(inertia, damping, zeros, 0, 0.0, STEP, 0.0, zeros, none,
                                                                  none, 0.0), drive,
                                          Partition(independent, dependent, independent, dependent, servo), chain)
        matrix = np.linalg.inv(factor) if servo else factor @ factor.T
        np.testing.assert_allclose(matrix, expected, rtol=1e-11, atol=1e-11 * np.abs(expected).max())


def test_newton_matrix_is_the_jacobian_of_the_step_residual(scenario):
    """At a step from t = 1 s (slewing, boom vibrating) the kernel's iteration matrix F, with M and B at the
    step's first iterate (``first_iterate``), against the Jacobian J of the step's residual in a1 by central
    differences: the iteration's error operator I - F^-1 J has a 2-norm below 1e-2 (each correction shrinks
    the next at least a hundredfold), where F with M and B at the step's start leaves one of at least 0.3 (a
    slewing error comes back as boom bending)."""
    motion = scenario.motion
    stepper = MotionStepper(motion, 0.0, scenario.equilibrium.q, np.zeros_like(scenario.equilibrium.q), STEP)
    stepper.advance_until(1.0)
    state, settings, chain, partition = stepper.state, stepper.integrator.settings, motion.dynamics.chain, \
        motion.partition
    t1 = state.t + STEP
    k = motion.constraints.coefficients(t1)
    drive = motion.dynamics.drive.kernel_parameters(t1)
    a0 = state.solution.qdd[partition.integrated]
    correction = state.correction

    def residual(a1):
        return step_residual(a1, state.q, state.qd, a0, correction, STEP, k, drive, partition, chain, settings)

    jacobian = np.empty((a0.size, a0.size))
    for j in range(a0.size):
        delta = np.zeros_like(a0)
        delta[j] = 1e-3 * max(1.0, abs(a0[j]))
        jacobian[:, j] = (residual(a0 + delta) - residual(a0 - delta)) / (2.0 * delta[j])
    first = first_iterate(state.q, state.qd, state.qdd, a0, predicted_accelerations(a0, state.earlier),
                                  STEP, k, partition, chain, settings)
    at_first = motion.solve(t1, first.q, first.qd)
    at_end = iteration_factor(at_first.dynamics.M, at_first.velocity_map, STEP, correction, drive, partition,
                                      chain)
    at_start = iteration_factor(state.solution.dynamics.M, state.solution.velocity_map, STEP, correction,
                                        drive, partition, chain)

    def error_norm(factor):
        return np.linalg.norm(np.eye(a0.size) - np.linalg.solve(factor @ factor.T, jacobian), 2)

    assert error_norm(at_end) < 1e-2
    assert error_norm(at_start) > 0.3

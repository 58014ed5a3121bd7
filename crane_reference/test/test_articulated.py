"""The articulated-body solve (:mod:`crane_reference.dynamics.articulated`) against dense solves built on
Pinocchio's mass matrix (CRBA, on the URDF of the same chain), at random states of every packaged crane's flexible
model and of the default crane with n_rfe = 24: X = M + w (K + s_dr on psi2) + d D solved, with its root block as
the chain gives it, with every joint in it and (K made diagonal) with none; and the reduced system B^T X B a = r
of the task constraints (B from the constraint rows A: B[ic] = I, A B = 0) against numpy's solve and against the
dense factor of the Newton iteration matrix (``iteration_factor``, no modal terms); the iteration matrix with the
modal terms (:mod:`crane_reference.dynamics.iteration_matrix`, Woodbury) against its dense factor; and a second of
steps with either against the other."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from convergence import second_of_steps
from cranes import CONFIG, EXAMPLES
from test_dynamics_pinocchio import pin_configuration
from velocity_map import random_velocity_map

from crane_reference.dynamics.articulated import (
    articulated_factor,
    articulated_solve,
    constrained_factor,
    reduced_solve,
)
from crane_reference.dynamics.chain_dynamics import root_size
from crane_reference.dynamics.evaluation import accelerations_at
from crane_reference.dynamics.inertia import world_pseudo_inertias
from crane_reference.dynamics.iteration_matrix import (
    articulated_iteration_factor,
    dense_iteration_factor,
    iteration_solve,
)
from crane_reference.dynamics.kinematics import forward_kinematics
from crane_reference.dynamics.linalg import cholesky_solve
from crane_reference.dynamics.modal_correction import iteration_factor, modal_correction
from crane_reference.dynamics.structures import Partition
from crane_reference.model.config import load_config
from crane_reference.model.urdf import model_to_urdf
from crane_reference.motion.integration import ExactFrequencyTrapezoidal
from crane_reference.motion.simulation import Scenario
from crane_reference.motion.steps import ONLINE_STEP

STATES = 4
TOLERANCE = 1e-9
"""Largest difference from the dense solution, relative to its largest entry."""
SPRING_WEIGHT, DAMPER_WEIGHT, DRIVE_SPRING = 0.25 * ONLINE_STEP**2, 0.5 * ONLINE_STEP, 2.0e5
"""w = h^2 / 4 and d = h / 2 of the node's step, and a drive spring s_dr [N m/rad] (the check holds for any)."""


@pytest.fixture(scope="module", params=[*EXAMPLES, "crane.yaml n_rfe=24"])
def scenario(request: pytest.FixtureRequest) -> Scenario:
    name = request.param.split()[0]
    params = load_config(CONFIG / name)
    return Scenario(params.with_rfe_count(24) if "n_rfe" in request.param else params, "flexible")


def _states(scenario: Scenario):
    """At STATES random states near the initial configuration (coordinates moved by up to 0.05 rad or m,
    velocities up to 0.5): (S, Hw, A, Pinocchio's M)."""
    motion = scenario.motion
    chain, partition = motion.dynamics.chain, motion.partition
    pin_model = pin.buildModelFromXML(model_to_urdf(scenario.model))
    data = pin_model.createData()
    drive = motion.dynamics.drive.kernel_parameters(0.5)
    rng = np.random.default_rng(7)
    for _ in range(STATES):
        q = scenario.model.initial_q + rng.uniform(-0.05, 0.05, scenario.model.dof)
        qd = rng.uniform(-0.5, 0.5, q.size)
        acc = accelerations_at(q, qd, motion.constraints.coefficients(0.5), drive, partition, chain)
        T, S = forward_kinematics(q, chain.kinds, chain.axes, chain.origins)
        M = pin.crba(pin_model, data, pin_configuration(pin_model, q))
        yield S, world_pseudo_inertias(T, chain.body_joint, chain.body_H), acc.A, np.triu(M) + np.triu(M, 1).T


def _joint_matrix(chain) -> np.ndarray:
    """w (K + s_dr on psi2) + d D."""
    matrix = SPRING_WEIGHT * chain.stiffness + DAMPER_WEIGHT * chain.damping
    matrix[chain.drive_joint, chain.drive_joint] += SPRING_WEIGHT * DRIVE_SPRING
    return matrix


def _velocity_map(A: np.ndarray, partition: Partition) -> np.ndarray:
    """B with A B = 0 and B[ic] = I (the velocity map of (7) for the constraint rows A)."""
    independent, dependent = partition.independent, partition.dependent
    B = np.zeros((A.shape[1], independent.size))
    B[independent] = np.eye(independent.size)
    B[dependent] = -np.linalg.solve(A[:, dependent], A[:, independent])
    return B


def _difference(solution: np.ndarray, dense: np.ndarray) -> float:
    return float(np.abs(solution - dense).max() / np.abs(dense).max())


def test_articulated_solve_is_the_dense_solve_of_pinocchios_mass_matrix_with_the_joint_terms(scenario):
    """x = X^-1 tau for random tau: with the chain's root block (the base's support springs: six joints; none
    for a fixed base) and its dampers, with dampers proportional to the springs, with every joint in the root block,
    and with K diagonal and no root block (the recursion alone)."""
    chain = scenario.motion.dynamics.chain
    n = chain.kinds.size
    rayleigh = chain._replace(damping=1e-3 * chain.stiffness, damped=True)
    diagonal = chain._replace(stiffness=np.diag(np.diag(chain.stiffness)), damping=np.diag(np.diag(chain.damping)),
                              root_size=0)
    assert chain.root_size in (0, 6) and root_size(rayleigh.stiffness, rayleigh.damping) == chain.root_size
    assert root_size(diagonal.stiffness, diagonal.damping) == 0
    rng = np.random.default_rng(1)
    worst = 0.0
    for S, Hw, _, M in _states(scenario):
        for variant in (chain, rayleigh, chain._replace(root_size=n), diagonal):
            tau = rng.normal(size=(n, 3))  # three columns, solved side by side
            dense = np.linalg.solve(M + _joint_matrix(variant), tau)
            factor = articulated_factor(S, Hw, SPRING_WEIGHT, DAMPER_WEIGHT, SPRING_WEIGHT * DRIVE_SPRING, variant)
            worst = max(worst, _difference(articulated_solve(factor, tau), dense))
    assert worst <= TOLERANCE


def test_reduced_solve_is_the_dense_solve_and_the_dense_iteration_factor_of_the_constrained_system(scenario):
    """a with B^T X B a = r (B from the crane's constraint rows A at the state: A B = 0, B[ic] = I) against
    numpy's solve of B^T X B, and against the dense Cholesky factor the step uses, ``iteration_factor`` on
    Pinocchio's M without modal terms (the plain trapezoidal rule's settings)."""
    motion = scenario.motion
    chain, partition = motion.dynamics.chain, motion.partition
    independent = partition.independent
    drive = np.array([0.0, DRIVE_SPRING, 0.0, 0.0])
    settings = ExactFrequencyTrapezoidal(motion).settings._replace(modal=False)
    rng = np.random.default_rng(2)
    worst = 0.0
    for S, Hw, A, M in _states(scenario):
        B = _velocity_map(A, partition)
        r = rng.normal(size=(independent.size, 3))  # three columns, solved side by side
        dense = np.linalg.solve(B.T @ (M + _joint_matrix(chain)) @ B, r)
        factor = constrained_factor(S, Hw, A, SPRING_WEIGHT, DAMPER_WEIGHT, SPRING_WEIGHT * DRIVE_SPRING, chain)
        solution = reduced_solve(factor, independent, r)
        none = modal_correction(B.T @ M @ B, ONLINE_STEP, 0.0, drive, partition, chain, settings)
        factor = iteration_factor(M, B, ONLINE_STEP, none, drive, partition, chain)
        worst = max(worst, _difference(solution, dense),
                    *(_difference(cholesky_solve(factor, r[:, m].copy()), dense[:, m]) for m in range(r.shape[1])))
    assert worst <= TOLERANCE


def test_articulated_iteration_matrix_solves_as_the_dense_one_with_the_modal_terms(scenario):
    """With the modal correction computed at the state (the full eigenproblem of the pencil (K_r, M_r)), the
    iteration matrix solved as Y + U diag(W) U^T (articulated Y with the unresolved modes' damping as beta K,
    Woodbury for the resolved modes' U = M_r Phi_r) against the dense factor of B^T (M + h^2/4 K + h/2 D) B -
    Delta M_r + h/2 D_u formed on Pinocchio's M with the correction's matrices (test_integrator checks those
    against scipy's modes): with the crane's constraints, and with psi2 dependent (a random velocity map B), where
    the drive's spring is in h^2/4 K but not in beta K_r."""
    motion = scenario.motion
    chain, n = motion.dynamics.chain, scenario.model.dof
    drive = np.array([0.0, DRIVE_SPRING, 0.0, 0.0])
    settings = ExactFrequencyTrapezoidal(motion).settings
    rng = np.random.default_rng(3)
    worst = 0.0
    others = [k for k in motion.partition.dependent if k != chain.drive_joint]
    driven = np.array([chain.drive_joint, *others[:1]])  # the springs act on independent coordinates only
    assert not np.any(chain.stiffness[driven]) and not np.any(chain.damping[driven])
    for S, Hw, A, M in _states(scenario):
        B_crane = _velocity_map(A, motion.partition)
        B_driven, free = random_velocity_map(rng, n, driven)
        for B, partition in ((B_crane, motion.partition), (B_driven, Partition(free, driven, free, driven, False))):
            correction = modal_correction(B.T @ M @ B, ONLINE_STEP, 0.0, drive, partition, chain, settings)
            assert correction.resolved > 0
            dense = dense_iteration_factor(M, B, ONLINE_STEP, correction, drive, partition, chain)
            articulated = articulated_iteration_factor(S, Hw, B, ONLINE_STEP, correction, drive, partition, chain)
            r = rng.normal(size=partition.independent.size)
            expected = iteration_solve(dense, r, partition)
            worst = max(worst, _difference(iteration_solve(articulated, r, partition), expected))
    assert worst <= TOLERANCE


@pytest.mark.parametrize("n_rfe", [6, 24])
def test_a_second_of_steps_with_the_articulated_iteration_matrix_is_the_dense_ones(n_rfe):
    """The default crane (n_rfe = 6) and n_rfe = 24 from their static equilibrium over 1 s at the node's step (the
    drive's jump at 1 s included): the motion with the iteration matrix solved by the articulated-body recursion
    and with it factored densely agree to 1e-9 in q and 1e-7 in qd (the Newton iterates differ only by
    round-off)."""
    scenario = Scenario(load_config().with_rfe_count(n_rfe), "flexible")
    dense, articulated = (second_of_steps(scenario, articulated=articulated) for articulated in (False, True))
    assert np.abs(articulated.q - dense.q).max() <= 1e-9
    assert np.abs(articulated.qd - dense.qd).max() <= 1e-7

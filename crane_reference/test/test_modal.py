"""Modal analysis of the constrained crane (:mod:`crane_reference.analysis.modal`), against independent truths.

* A clamped-free uniform beam built with the RFE code: the first three bending frequencies within 2 % of
  Euler-Bernoulli's (beta_n L)^2 / (2 pi) sqrt(E I / (rho A L^4)) at n_rfe = 20.
* A mass on a spring (one prismatic joint): sqrt(k / m) / (2 pi), gravity adding no stiffness.
* A mass held on a circle of radius R by an ideal programmed constraint (two prismatic joints, one
  dependent), with a horizontal spring: omega^2 = k / m + g / R, all of the g / R coming from the
  constraint-curvature term -lambda Phi_qq.
* The analytic gravity and constraint Hessians against central differences of the generalized forces
  Q and A^T lambda (computed by the dynamics and constraint code, not by the Hessians).
* The reduced stiffness K_r = P^T (K_t + K_lambda) B at the static equilibrium equals minus the Jacobian,
  by central differences, of the reduced static forces P^T Q of :func:`reduced_static_forces` with respect
  to the independent coordinates (ideal and servo-constraints, rigid and flexible crane).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from cantilever import cantilever_model
from circle_constraint import CircleXZ
from cranes import NO_DRIVE
from scipy.linalg import eigvalsh

from crane_reference.analysis.modal import (
    CONSTRAINT,
    DRIVE,
    body_mass_matrices,
    constraint_hessian,
    gravity_stiffness,
    linearise,
    linearise_chain,
    modal_analysis,
    scenario_motion,
)
from crane_reference.cli import main
from crane_reference.dynamics.chain_dynamics import CraneDynamics
from crane_reference.model.chain import AXES, PRISMATIC, VARIANTS, Body, ChainModel, Joint
from crane_reference.model.parameters import FlexibleDrive, RigidBody
from crane_reference.motion.constraints import ConstraintSet
from crane_reference.motion.equilibrium import reduced_static_forces
from crane_reference.motion.programmed_motion import REALISATIONS, ProgrammedMotion
from crane_reference.motion.simulation import Scenario

EULER_BERNOULLI_ROOTS = (1.875104068711961, 4.694091132974175, 7.854757438237613)  # cos x cosh x = -1


@pytest.mark.parametrize("plane", ["vertical", "lateral"])
def test_cantilever_matches_euler_bernoulli(paper_params, plane):
    """The crane's steel and section on a slender 10 m beam (L / radius of gyration = 108 vertical, 162
    lateral): rotary inertia, which the RFE bodies include and Euler-Bernoulli neglects, lowers the third
    frequency by ~ (beta_3 r)^2 / 2 < 0.3 %.  Measured errors at n_rfe = 20: +0.04 %, +0.08 %, +0.03 %
    (vertical), +0.05 %, +0.16 %, +0.21 % (lateral)."""
    boom, length = paper_params.boom, 10.0
    model = cantilever_model(length, 20, boom.youngs_modulus, boom.shear_modulus, boom.density, boom.section, plane)
    modes = modal_analysis(linearise_chain(CraneDynamics(model, NO_DRIVE), 0.0, model.initial_q))
    second_moment = boom.section.second_moment_z if plane == "vertical" else boom.section.second_moment_y
    scale = np.sqrt(boom.youngs_modulus * second_moment / (boom.density * boom.section.area * length**4))
    exact = np.array(EULER_BERNOULLI_ROOTS) ** 2 / (2.0 * np.pi) * scale
    errors = modes.frequencies[:3] / exact - 1.0
    assert np.all(np.abs(errors) <= 0.02), f"relative errors {errors}"
    assert np.all(modes.growth_rates == 0.0)


def point_mass_chain(axes: str, stiffness: np.ndarray, mass: float, gravity: float,
                     dependent: tuple[int, ...] = ()) -> ChainModel:
    """A point mass on prismatic joints along ``axes`` (world axes, in order)."""
    joints = tuple(Joint(f"slide_{a}", PRISMATIC, AXES[a], np.eye(4)) for a in axes)
    body = Body("mass", len(axes) - 1, RigidBody(mass, np.zeros(3), np.zeros((3, 3))))
    return ChainModel(variant="point", joints=joints, bodies=(body,), end_effector_joint=len(axes) - 1,
                      end_effector_point=np.zeros(3), gravity=gravity, stiffness=stiffness,
                      support_stiffness=np.zeros_like(stiffness), beam_stiffness=np.zeros_like(stiffness),
                      drive_joint=0, dependent_joints=dependent, initial_q=np.zeros(len(axes)))


def test_spring_mass_frequency():
    """Vertical slide, m = 40 kg, k = 2.5e5 N/m, under gravity (a constant force: no stiffness)."""
    m, k = 40.0, 2.5e5
    model = point_mass_chain("z", np.array([[k]]), m, 9.81)
    modes = modal_analysis(linearise_chain(CraneDynamics(model, NO_DRIVE), 0.0, np.array([-m * 9.81 / k])))
    assert modes.frequencies[0] == pytest.approx(np.sqrt(k / m) / (2.0 * np.pi), rel=1e-12)


def test_mass_on_a_circle_is_a_pendulum():
    """x independent, z dependent; at the bottom (0, -R) the constraint force m g carries the mass and
    the circle's curvature gives the pendulum stiffness m g / R."""
    m, k, R, g = 12.0, 300.0, 0.8, 9.81
    model = point_mass_chain("xz", np.diag([k, 0.0]), m, g, dependent=(1,))
    motion = ProgrammedMotion(CraneDynamics(model, NO_DRIVE), ConstraintSet((CircleXZ(R),)))
    linearisation = linearise(motion, 0.0, np.array([0.0, -R * 0.9]))  # z is projected onto the circle
    assert linearisation.q[1] == pytest.approx(-R, abs=1e-13)
    modes = modal_analysis(linearisation)
    assert modes.frequencies[0] == pytest.approx(np.sqrt(k / m + g / R) / (2.0 * np.pi), rel=1e-12)
    assert modes.strain_energy[CONSTRAINT][0] == pytest.approx((m * g / R) / (k + m * g / R), rel=1e-12)


def off_equilibrium_state(scenario: Scenario) -> tuple[float, np.ndarray]:
    """A consistent configuration away from rest: column slewed, base and RFE angles perturbed."""
    rng = np.random.default_rng(3)
    q = scenario.model.initial_q.copy()
    for k, name in enumerate(scenario.model.joint_names):
        if name.startswith("base_"):
            q[k] += rng.normal(scale=1e-3)
        elif name.startswith("boom_sde"):
            q[k] += rng.normal(scale=1e-2)
    q[scenario.model.drive_joint] += 0.4
    t = 0.7
    return t, scenario.motion.project_positions(t, q)[0]


def central_difference(function, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """d function / dx (columns per coordinate of x)."""
    return np.array([(function(x + h * e) - function(x - h * e)) / (2.0 * h) for e in np.eye(x.size)]).T


@pytest.mark.parametrize("variant", VARIANTS)
def test_hessians_match_finite_differences(params, variant):
    """Gravity: -d(Q + K q)/dq at qd = 0 (the springs' K q removed, the torque drive is constant in q);
    constraints: d(A^T lambda)/dq at fixed lambda.  Agreement to 1e-8 of the largest entry: the central
    differences' own error (round-off of Q + K q, where K q ~ 1e5 N m is added back, over h = 1e-5;
    measured 4e-10 flexible, 6e-11 rigid; constraint term 2e-10)."""
    scenario = Scenario(params, variant)
    dynamics = scenario.dynamics
    t, q = off_equilibrium_state(scenario)
    n = q.size
    K = scenario.model.stiffness
    gravity = -central_difference(lambda x: dynamics.terms(t, x, np.zeros(n)).Q + K @ x, q, h=1e-5)
    analytic = gravity_stiffness(dynamics, q)
    assert np.max(np.abs(analytic - gravity)) <= 1e-8 * np.max(np.abs(analytic))
    assert np.array_equal(analytic, analytic.T)

    multipliers = scenario.motion.solve(t, q, np.zeros(n)).reactions
    constraints = scenario.motion.constraints

    def constraint_force(x: np.ndarray) -> np.ndarray:
        p, C = dynamics.end_effector(x)
        return (constraints.position_jacobian(t, p) @ C).T @ multipliers

    numeric = central_difference(constraint_force, q)
    analytic = constraint_hessian(dynamics, constraints, t, q, multipliers)
    assert np.max(np.abs(analytic - numeric)) <= 1e-8 * np.max(np.abs(analytic))
    masses = body_mass_matrices(dynamics, q)
    assert np.allclose(sum(masses.values()), dynamics.terms(t, q, np.zeros(n)).M, rtol=0.0, atol=1e-10)


@pytest.mark.parametrize("drive", ["torque", "flexible"])
@pytest.mark.parametrize("realisation", REALISATIONS)
@pytest.mark.parametrize("variant", VARIANTS)
def test_reduced_stiffness_is_the_jacobian_of_the_static_forces(params, variant, realisation, drive):
    """At the static equilibrium (qdd = 0, so the linearisation neglects nothing there), K_r = -d(P^T Q)/dx
    with P^T Q from :func:`reduced_static_forces` (dependent coordinates re-projected at every point).
    The default drive is a constant torque at t = 0, which does not change the derivative; the flexible
    drive (s_dr = 2e5 N m/rad) adds its spring on psi2."""
    if drive == "flexible":
        params = dataclasses.replace(params, drive=FlexibleDrive(2e5, 1.0, 0.5, 2.0))
    scenario = Scenario(params, variant)
    motion, q0 = scenario_motion(scenario, realisation)
    assert (DRIVE in linearise(motion, 0.0, q0).stiffness_parts) == (drive == "flexible")
    ic = motion.independent

    def forces(x: np.ndarray) -> np.ndarray:
        q = q0.copy()
        q[ic] = x
        return reduced_static_forces(motion, 0.0, q)[0]

    numeric = -central_difference(forces, q0[ic])
    K_r = linearise(motion, 0.0, q0).reduced_stiffness
    assert np.max(np.abs(K_r - numeric)) <= 1e-9 * np.max(np.abs(K_r))


def test_modes_command(tmp_path, capsys, rigid):
    """The table lists the lowest frequency of the linearisation at the start: sqrt of the smallest eigenvalue of
    K_r x = omega^2 M_r x, solved here with scipy.linalg.eigvalsh on the reduced matrices."""
    assert main(["modes", "--model", "rigid", "--count", "4", "--out", str(tmp_path)]) == 0
    table = capsys.readouterr().out
    linearisation = linearise(rigid.motion, 0.0, rigid.equilibrium.q)
    omega_squared = eigvalsh(linearisation.reduced_stiffness, linearisation.reduced_mass)
    first = np.sqrt(omega_squared[omega_squared > 1.0].min()) / (2.0 * np.pi)
    assert "support springs" in table and f"{first:.3f}" in table
    assert (tmp_path / "modes_rigid_ideal_t0.png").stat().st_size > 10_000

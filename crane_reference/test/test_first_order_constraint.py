"""A first-order (velocity) task constraint through the unchanged solver, against independent truths.

The paper's ellipse (5.1) and height (5.2) plus the areal rate x y' - y x' = a b omega(t)
(:class:`ArealRate`), which makes the column slew psi2 a dependent coordinate: E must run along the
ellipse with the parametric angle rate omega(t), a quintic rise from rest to 0.8 rad/s.

* qdd and lambda of (8) against the KKT system built here, with the areal row of A and of c taken by
  finite differences of Psi(q, qd, t) = x y' - y x' - r(t) computed from E's position and velocity.
* Along the integrated motion: E's parametric angle theta = atan2(y / b, x / a) advances by the
  integral of omega(t) (scipy's quad of the profile), with second-order convergence in the step;
  the velocity constraint holds exactly and the position constraints to 1e-9 m.
* Energy balance: E(t) - E(0) equals the work of the drive and of the constraint forces (the areal
  constraint's reaction does the slewing work), to 1e-4 of that work.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from crane_reference.analysis.modal import linearise
from crane_reference.dynamics.chain_dynamics import CraneDynamics
from crane_reference.model.chain import build_model
from crane_reference.model.config import load_config
from crane_reference.model.drive import make_drive
from crane_reference.model.profiles import Constant, QuinticRise
from crane_reference.motion.constraints import ArealRate, ConstraintSet, EllipseXY, HeightZ
from crane_reference.motion.equilibrium import static_equilibrium
from crane_reference.motion.programmed_motion import ProgrammedMotion
from crane_reference.motion.simulation import paper_task_constraints, simulate

A_AXIS, B_AXIS = 3.0, 2.0  # [m], the paper's ellipse
OMEGA_MAX, OMEGA_RISE = 0.8, 1.0  # [rad/s], [s]
DURATION = 2.0  # [s]
SEED = 11


def areal_task(z_static: float) -> ConstraintSet:
    omega = QuinticRise(0.0, OMEGA_MAX, 0.0, OMEGA_RISE)

    def rate(t: float) -> tuple[float, float, float]:
        return tuple(A_AXIS * B_AXIS * value for value in omega(t))

    z = QuinticRise(z_static, 0.2, 0.0, 5.0)
    return ConstraintSet((EllipseXY(Constant(A_AXIS), Constant(B_AXIS)), HeightZ(z), ArealRate(rate)))


def omega_integral(t: float) -> float:
    """int_0^t omega(s) ds by adaptive quadrature of the profile (independent of the solver)."""
    omega = QuinticRise(0.0, OMEGA_MAX, 0.0, OMEGA_RISE)
    return quad(lambda s: omega(s)[0], 0.0, t, points=[OMEGA_RISE], epsabs=1e-13, epsrel=1e-13)[0]


@pytest.fixture(scope="module")
def rigid():
    params = load_config()
    model = build_model(params, "rigid")
    dynamics = CraneDynamics(model, make_drive(params.drive, params.drive_start))
    z_static = float(dynamics.end_effector(model.initial_q)[0][2])
    start = static_equilibrium(ProgrammedMotion(dynamics, paper_task_constraints(params.task, z_static)),
                               model.initial_q).q
    index = model.joint_names.index
    dependent = (index("boom_luff"), index("knuckle"), index("column_slew"))  # one per constraint, in order
    return ProgrammedMotion(dynamics, areal_task(z_static), dependent=dependent), start


def areal_residual(motion: ProgrammedMotion, t: float, q: np.ndarray, qd: np.ndarray) -> float:
    """Psi = x y' - y x' - a b omega(t) from E's kinematics alone."""
    p, C = motion.dynamics.end_effector(q)
    v = C @ qd
    return p[0] * v[1] - p[1] * v[0] - A_AXIS * B_AXIS * QuinticRise(0.0, OMEGA_MAX, 0.0, OMEGA_RISE)(t)[0]


def test_first_order_row_matches_kkt_with_finite_difference_terms(rigid):
    motion, start = rigid
    dyn = motion.dynamics
    n = dyn.model.dof
    rng = np.random.default_rng(SEED)
    for _ in range(4):
        t = rng.uniform(0.1, 0.9)
        q = start.copy()
        q[dyn.model.drive_joint] += rng.uniform(-0.5, 0.5)
        q, kinematics = motion.project_positions(t, q)
        qd = motion.dependent_velocities(t, q, rng.normal(scale=0.05, size=n), kinematics)
        assert abs(areal_residual(motion, t, q, qd)) <= 1e-12
        solution = motion.solve(t, q, qd)
        terms = dyn.terms(t, q, qd)
        A = solution.constraints.A.copy()
        c = solution.constraints.c.copy()
        # the areal row (index 2) rebuilt by central differences: A_2 = dPsi/dqd, and
        # c_2 = -(dPsi/dq qd + dPsi/dt) since dPsi/dt along the motion = A_2 qdd - c_2 = 0
        step = 1e-6
        A_fd = np.array([(areal_residual(motion, t, q, qd + step * e) - areal_residual(motion, t, q, qd - step * e))
                         / (2 * step) for e in np.eye(n)])
        drift = (areal_residual(motion, t + step, q + step * qd, qd)
                 - areal_residual(motion, t - step, q - step * qd, qd)) / (2 * step)
        assert np.allclose(A[2], A_fd, rtol=0, atol=1e-7)
        assert abs(c[2] + drift) <= 1e-6 * max(1.0, abs(drift))
        A[2], c[2] = A_fd, -drift
        m = A.shape[0]
        kkt = np.zeros((n + m, n + m))
        kkt[:n, :n] = terms.M
        kkt[:n, n:] = -A.T
        kkt[n:, :n] = A
        x = np.linalg.solve(kkt, np.concatenate((terms.Q - terms.h, c)))
        assert np.linalg.norm(solution.qdd - x[:n]) <= 1e-6 * np.linalg.norm(x[:n])
        assert np.linalg.norm(solution.reactions - x[n:]) <= 1e-6 * np.linalg.norm(x[n:])


def parametric_angle_error(motion: ProgrammedMotion, start: np.ndarray, step: float) -> tuple[float, object]:
    trajectory = simulate(motion, start, DURATION, step=step)
    x, y = trajectory.ee_position[:, 0], trajectory.ee_position[:, 1]
    theta = np.unwrap(np.arctan2(y / B_AXIS, x / A_AXIS))
    expected = np.array([omega_integral(t) for t in trajectory.t])
    return float(np.max(np.abs(theta - theta[0] - expected))), trajectory


def test_parametric_angle_follows_the_prescribed_rate(rigid):
    motion, start = rigid
    coarse, _ = parametric_angle_error(motion, start, 2e-3)
    fine, trajectory = parametric_angle_error(motion, start, 1e-3)
    assert omega_integral(DURATION) > 1.0, "E should travel a good part of the ellipse"
    assert fine <= 1e-5, f"theta error {fine:.3g} rad at h = 1 ms"
    assert 3.0 <= coarse / fine <= 5.0, f"second order expected: errors {coarse:.3g}, {fine:.3g}"
    assert np.max(np.abs(trajectory.residual[:, 2])) <= 1e-10, "the velocity constraint holds at every step"
    assert np.max(trajectory.residual_distance[:, :2]) <= 1e-9, "E stays on the ellipse and the height"
    work = np.max(np.abs(trajectory.work_constraints))
    assert work > 100.0, "the areal constraint should do noticeable work"
    assert np.max(np.abs(trajectory.energy_balance_error)) <= 1e-4 * work


def test_equilibrium_and_linearisation_name_their_limit(rigid):
    motion, start = rigid
    with pytest.raises(ValueError, match="holonomic task constraints only"):
        static_equilibrium(motion, start)
    with pytest.raises(ValueError, match="holonomic task constraints only"):
        linearise(motion, 0.0, start)

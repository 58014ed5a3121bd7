"""The programmed motion equations (8) and the constraint terms they use, against independent truths.

* qdd and lambda of :meth:`ProgrammedMotion.solve` (the B^T M / A formulation of (8)) against the
  Lagrange-multiplier (KKT) system [[M, -A^T], [A, 0]] [qdd; lambda] = [Q - h; c] solved here.
* (8) solved again where only the forces jumped (``forces_jumped``) against (8) evaluated afresh there.
* The acceleration-level constraints (6.3)-(6.4) are the second time derivatives of (5.1)-(5.2):
  integrating the full-coordinate ODE qdd = solve(t, q, qd).qdd without any projection keeps the
  position residuals Phi and the velocity residuals A qd - b at the integration-error level.
* Phi_p, Phi_t and the convective term of the ellipse with time-varying semi-axes and of the height
  constraint against finite differences along an analytic path p(t).
* The profiles against finite differences, and QuinticRise against eq. (5.2) written out literally.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from crane_reference.dynamics.chain_dynamics import CraneDynamics
from crane_reference.dynamics.evaluation import evaluate, forces_jumped, step_evaluation
from crane_reference.dynamics.structures import Evaluation
from crane_reference.model.chain import VARIANTS, build_model
from crane_reference.model.config import load_config
from crane_reference.model.drive import make_drive
from crane_reference.model.profiles import Blend, Constant, QuinticRise
from crane_reference.motion.constraints import (
    ConstraintSet,
    EllipseXY,
    EndEffectorConstraint,
    HeightZ,
    paper_constraints,
)
from crane_reference.motion.programmed_motion import ProgrammedMotion
from crane_reference.stream.targets import settled

SEED = 7
SAMPLES = 6
KKT_TOLERANCE = 1e-9  # relative
DRIFT_TOLERANCE = 1e-8  # [1] for Phi_1, [m] for Phi_2; the same for A qd - b [1/s, m/s]
Z_INCREMENT, RISE_TIME = 0.2, 5.0  # the paper's z_inc [m] and our t_c [s]


@dataclass(frozen=True)
class Case:
    dynamics: CraneDynamics
    z_static: float


@pytest.fixture(scope="module")
def cases() -> dict[str, Case]:
    params = load_config()
    drive = make_drive(params.drive, params.drive_start)
    out = {}
    for variant in VARIANTS:
        model = build_model(params, variant)
        dynamics = CraneDynamics(model, drive)
        out[variant] = Case(dynamics, float(dynamics.end_effector(model.initial_q)[0][2]))
    return out


def task(z_static: float, a_blend: bool) -> ConstraintSet:
    """The paper's task (a = 3, b = 2, z rising by 0.2 m over 5 s), optionally with the semi-axis a
    blended from 3 m to 3.5 m over [0.1, 0.6] s (explicit time dependence in the ellipse too)."""
    a = Blend(Constant(3.0), Constant(3.5), t0=0.1, duration=0.5) if a_blend else Constant(3.0)
    return paper_constraints(a, Constant(2.0), QuinticRise(z_static, Z_INCREMENT, 0.0, RISE_TIME))


def random_consistent_state(motion: ProgrammedMotion, rng: np.random.Generator):
    """(t, q, qd) on the constraints: q near configuration (9) (column swung up to +-0.5 rad, base and
    RFE angles perturbed) with q_dc projected, random independent velocities, qd_dc from (7)."""
    model = motion.dynamics.model
    t = rng.uniform(0.0, 1.0)
    q = model.initial_q.copy()
    qd = np.zeros(model.dof)
    for k, name in enumerate(model.joint_names):
        if name.startswith("base_"):
            q[k] += rng.normal(scale=1e-3)
            qd[k] = rng.normal(scale=0.05)
        elif name.startswith("boom_sde"):
            q[k] += rng.normal(scale=1e-2)
            qd[k] = rng.normal(scale=0.3)
        elif name == "column_slew":
            q[k] += rng.uniform(-0.5, 0.5)
            qd[k] = rng.normal(scale=0.5)
    q, kinematics = motion.project_positions(t, q)
    return t, q, motion.dependent_velocities(t, q, qd, kinematics)


@pytest.mark.parametrize("variant", VARIANTS)
def test_solution_equals_kkt_system(cases, variant):
    case = cases[variant]
    motion = ProgrammedMotion(case.dynamics, task(case.z_static, a_blend=True))
    rng = np.random.default_rng(SEED)
    n = case.dynamics.model.dof
    for _ in range(SAMPLES):
        t, q, qd = random_consistent_state(motion, rng)
        solution = motion.solve(t, q, qd)
        dyn = case.dynamics.terms(t, q, qd)  # M, h, Q evaluated on their own, not taken from the solution
        con = solution.constraints  # A, c and the velocity residual of (6.1)-(6.4)
        assert np.allclose(con.A, con.gradients @ dyn.ee_jacobian, rtol=0, atol=1e-12), "A = Phi_p C"
        assert np.max(np.abs(con.velocity_residual)) <= 1e-12, "the sampled state should be consistent"
        m = con.A.shape[0]
        kkt = np.zeros((n + m, n + m))
        kkt[:n, :n] = dyn.M
        kkt[:n, n:] = -con.A.T
        kkt[n:, :n] = con.A
        x = np.linalg.solve(kkt, np.concatenate((dyn.Q - dyn.h, con.c)))
        qdd, multipliers = x[:n], x[n:]
        qdd_error = np.linalg.norm(solution.qdd - qdd) / np.linalg.norm(qdd)
        lambda_error = np.linalg.norm(solution.reactions - multipliers) / np.linalg.norm(multipliers)
        assert qdd_error <= KKT_TOLERANCE, f"qdd: relative error {qdd_error:.3g} at t = {t:.3f}"
        assert lambda_error <= KKT_TOLERANCE, f"lambda: relative error {lambda_error:.3g} at t = {t:.3f}"
        force_error = np.linalg.norm(solution.constraint_forces - con.A.T @ multipliers)
        assert force_error <= KKT_TOLERANCE * np.linalg.norm(con.A.T @ multipliers)


@pytest.mark.parametrize("realisation", ["ideal", "servo"])
def test_forces_jumped_is_a_fresh_evaluation_under_the_new_drive(cases, realisation):
    """The closed loop's restart where only the forces jump (a new command, the drive's torque jump) keeps
    the position and velocity terms of the step's evaluation: it equals, bit for bit, (8) evaluated afresh
    at the same state under the new drive (the column drive's parameters and actuator torques changed)."""
    case = cases["flexible"]
    motion = ProgrammedMotion(case.dynamics, task(case.z_static, a_blend=True), realisation=realisation)
    rng = np.random.default_rng(SEED)
    chain, partition = case.dynamics.chain, motion.partition
    n = case.dynamics.model.dof
    for _ in range(3):
        t, q, qd = random_consistent_state(motion, rng)
        k = motion.constraints.coefficients(t)
        before = np.concatenate((case.dynamics.drive.kernel_parameters(t, True), rng.normal(0.0, 1e3, n)))
        after = np.concatenate((before[:4] + rng.normal(0.0, 1e2, 4), rng.normal(0.0, 1e3, n)))
        step = step_evaluation(q, qd, rng.normal(0.0, 1.0, n), k, before, partition, chain)
        jumped = forces_jumped(step.terms, q, qd, k, after, partition, chain)
        fresh = evaluate(q, qd, k, after, partition, chain)
        for (name, got), (_, expected) in zip(_fields(jumped), _fields(fresh), strict=True):
            np.testing.assert_array_equal(got, expected, err_msg=name)
        assert not np.array_equal(jumped.terms.qdd, evaluate(q, qd, k, before, partition, chain).terms.qdd)


def _fields(e: Evaluation) -> list[tuple[str, object]]:
    """An evaluation's fields by name, those of its terms one by one."""
    return [*(("terms." + name, value) for name, value in zip(e.terms._fields, e.terms, strict=True)),
            *((name, getattr(e, name)) for name in Evaluation._fields if name != "terms")]


def test_dependent_coordinates_must_be_free_of_springs_and_dampers(cases):
    """The integrator's reduced stiffness is K[ic, ic]: a dependent coordinate that carries a spring of the
    model is refused, naming it."""
    case = cases["flexible"]
    chain, dependent = case.dynamics.chain, case.dynamics.model.dependent_joints
    sprung = int(np.flatnonzero(np.diag(chain.stiffness))[0])
    with pytest.raises(ValueError, match=rf"dependent = \({sprung}, {dependent[1]}\): coordinate\(s\) \[{sprung}\] "
                                         "carry a spring or a damper"):
        ProgrammedMotion(case.dynamics, task(case.z_static, False), dependent=(sprung, dependent[1]))


@pytest.mark.parametrize("a_blend", [False, True], ids=["paper-task", "blended-a"])
def test_index_reduced_equations_keep_constraints(cases, a_blend):
    """Full-coordinate ODE (q, qd)' = (qd, solve(t, q, qd).qdd) of the rigid crane over 1 s, no
    projection: if c (eqs. (6.3)-(6.4)) is the second derivative of Phi, the residuals of the
    positions (5.1)-(5.2) and velocities (6.1)-(6.2) only carry integration error.  A wrong term in c
    of size delta would show as a drift of ~delta t^2 / 2."""
    case = cases["rigid"]
    motion = ProgrammedMotion(case.dynamics, task(case.z_static, a_blend))
    model = case.dynamics.model
    n = model.dof
    q0, kinematics = motion.project_positions(0.0, model.initial_q)
    qd0 = np.zeros(n)
    qd0[model.drive_joint] = 0.2  # [rad/s] besides the drive torque: start already slewing
    qd0 = motion.dependent_velocities(0.0, q0, qd0, kinematics)

    def rhs(t: float, y: np.ndarray) -> np.ndarray:
        return np.concatenate((y[n:], motion.solve(t, y[:n], y[n:]).qdd))

    # the torque drive switches off at t = 1 s; stop just before it (forces do not affect the
    # constraint residuals, but keep the right-hand side smooth for the integrator)
    times = np.linspace(0.0, 0.999, 101)
    result = solve_ivp(rhs, (0.0, times[-1]), np.concatenate((q0, qd0)), method="DOP853", rtol=1e-12,
                       atol=1e-12, t_eval=times)
    assert result.success, result.message
    position_drift = velocity_drift = 0.0
    for t, y in zip(result.t, np.ascontiguousarray(result.y.T), strict=True):
        q, qd = y[:n], y[n:]
        p, _ = case.dynamics.end_effector(q)
        position_drift = max(position_drift, np.max(np.abs(motion.constraints.residual(t, p))))
        con = motion.solve(t, q, qd).constraints
        velocity_drift = max(velocity_drift, np.max(np.abs(con.velocity_residual)))
    assert np.ptp(result.y[model.drive_joint]) > 0.3, "the crane should move noticeably"
    assert position_drift <= DRIFT_TOLERANCE, f"Phi drift {position_drift:.3g}"
    assert velocity_drift <= DRIFT_TOLERANCE, f"dPhi/dt drift {velocity_drift:.3g}"


# --- constraint derivatives along an analytic path -------------------------------------------------

A_PROFILE = Blend(Constant(3.0), Constant(3.5), t0=0.1, duration=0.5)
B_PROFILE = Blend(Constant(2.0), QuinticRise(2.0, -0.3, 0.2, 0.6), t0=0.0, duration=0.5)
Z_PROFILE = QuinticRise(2.1, Z_INCREMENT, 0.0, 1.0)
PATH_TIMES = (0.05, 0.15, 0.3, 0.45, 0.58, 0.7)


def path(t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """p(t), p'(t), p''(t) of a smooth analytic end-effector path [m]."""
    w1, w2, w3 = 1.3, 0.9, 2.1
    p = np.array([2.8 * np.cos(w1 * t + 0.2), 1.9 * np.sin(w2 * t + 0.1), 2.0 + 0.1 * np.sin(w3 * t)])
    v = np.array([-2.8 * w1 * np.sin(w1 * t + 0.2), 1.9 * w2 * np.cos(w2 * t + 0.1), 0.1 * w3 * np.cos(w3 * t)])
    a = np.array([-2.8 * w1**2 * np.cos(w1 * t + 0.2), -1.9 * w2**2 * np.sin(w2 * t + 0.1),
                  -0.1 * w3**2 * np.sin(w3 * t)])
    return p, v, a


class AtTime:
    """Phi(t, p), Phi_p, Phi_t and the convective term of one constraint as functions of (t, p), from
    the quadric coefficients (value, first and second time derivative) the constraint gives at t."""

    def __init__(self, constraint: EndEffectorConstraint):
        self.constraint = constraint

    def residual(self, t: float, p: np.ndarray) -> float:
        return self.constraint.quadric(t).residual(p)

    def gradient(self, t: float, p: np.ndarray) -> np.ndarray:
        return self.constraint.quadric(t).gradient(p)

    def time_derivative(self, t: float, p: np.ndarray) -> float:
        return self.constraint.quadric(t).time_derivative(p)

    def convective(self, t: float, p: np.ndarray, v: np.ndarray) -> float:
        return self.constraint.quadric(t).convective(p, v)


CONSTRAINTS = {"ellipse": AtTime(EllipseXY(A_PROFILE, B_PROFILE)), "height": AtTime(HeightZ(Z_PROFILE))}


@pytest.mark.parametrize("name", list(CONSTRAINTS))
def test_constraint_derivatives_by_finite_differences(name):
    constraint = CONSTRAINTS[name]
    step = 1e-5
    for t in PATH_TIMES:
        p, v, acc = path(t)
        # Phi_p: central differences in p at fixed t
        unit = np.eye(3) * step
        fd_gradient = np.array([(constraint.residual(t, p + e) - constraint.residual(t, p - e)) / (2 * step)
                                for e in unit])
        assert np.allclose(constraint.gradient(t, p), fd_gradient, rtol=0, atol=1e-8), (t, fd_gradient)
        # Phi_t: central differences in t at fixed p
        fd_time = (constraint.residual(t + step, p) - constraint.residual(t - step, p)) / (2 * step)
        assert abs(constraint.time_derivative(t, p) - fd_time) <= 1e-8, (t, fd_time)

        # first total derivative along the path: dPhi/dt = Phi_p p' + Phi_t
        def rate(s: float) -> float:
            ps, vs, _ = path(s)
            return constraint.gradient(s, ps) @ vs + constraint.time_derivative(s, ps)

        fd_rate = (constraint.residual(t + step, path(t + step)[0])
                   - constraint.residual(t - step, path(t - step)[0])) / (2 * step)
        assert abs(rate(t) - fd_rate) <= 1e-8, (t, rate(t), fd_rate)
        # second total derivative: d2Phi/dt2 = Phi_p p'' + convective(t, p, p')
        second = constraint.gradient(t, p) @ acc + constraint.convective(t, p, v)
        fd_second = (rate(t + step) - rate(t - step)) / (2 * step)
        assert abs(second - fd_second) <= 1e-7, (t, second, fd_second)
        big = 2e-4  # second differences of Phi itself (larger step: round-off ~ 1e-16 / step^2)
        fd_second_direct = (constraint.residual(t + big, path(t + big)[0]) - 2 * constraint.residual(t, p)
                            + constraint.residual(t - big, path(t - big)[0])) / big**2
        assert abs(second - fd_second_direct) <= 1e-5 * max(1.0, abs(second)), (t, second, fd_second_direct)


def test_ellipse_derivatives_see_the_blend():
    """The blend makes Phi_t and the explicit parts of the convective term non-zero inside
    [0.1, 0.6] s (so the finite-difference test above really checks them) and zero outside."""
    ellipse = CONSTRAINTS["ellipse"]
    p, v, _ = path(0.3)
    constant_axes = AtTime(EllipseXY(Constant(A_PROFILE(0.3)[0]), Constant(B_PROFILE(0.3)[0])))
    assert abs(ellipse.time_derivative(0.3, p)) > 0.1
    assert abs(ellipse.convective(0.3, p, v) - constant_axes.convective(0.3, p, v)) > 0.1
    late = AtTime(EllipseXY(A_PROFILE, Constant(1.7)))
    p, v, _ = path(0.8)
    assert late.time_derivative(0.8, p) == 0.0
    assert late.convective(0.8, p, v) == pytest.approx(2 * v[0] ** 2 / 3.5**2 + 2 * v[1] ** 2 / 1.7**2, rel=1e-14)


# --- profiles --------------------------------------------------------------------------------------


def paper_height(t: float, z_s: float, z_inc: float, t_c: float) -> tuple[float, float, float]:
    """Eq. (5.2) as printed, with its first and second derivatives differentiated by hand."""
    if t >= t_c:
        return z_s + z_inc, 0.0, 0.0
    return (z_s + 10 * z_inc / t_c**3 * t**3 - 15 * z_inc / t_c**4 * t**4 + 6 * z_inc / t_c**5 * t**5,
            30 * z_inc / t_c**3 * t**2 - 60 * z_inc / t_c**4 * t**3 + 30 * z_inc / t_c**5 * t**4,
            60 * z_inc / t_c**3 * t - 180 * z_inc / t_c**4 * t**2 + 120 * z_inc / t_c**5 * t**3)


def test_quintic_rise_is_equation_5_2():
    z_s = 2.100293863
    profile = QuinticRise(z_s, Z_INCREMENT, 0.0, RISE_TIME)
    for t in np.linspace(0.0, 6.0, 61):
        assert np.allclose(profile(t), paper_height(t, z_s, Z_INCREMENT, RISE_TIME), rtol=1e-13, atol=1e-15), t
    assert profile(-1.0) == (z_s, 0.0, 0.0)  # at rest before the rise


PROFILES = {
    "quintic": QuinticRise(2.1, 0.2, 0.3, 5.0),
    "quintic-falling": QuinticRise(1.0, -0.7, -0.2, 0.8),
    "blend-constants": Blend(Constant(3.0), Constant(3.5), t0=0.1, duration=0.5),
    "blend-moving": Blend(QuinticRise(0.0, 1.0, 0.0, 2.0), QuinticRise(0.5, -2.0, 0.3, 1.0), t0=0.2, duration=0.7),
}


@pytest.mark.parametrize("name", list(PROFILES))
def test_profile_derivatives_by_finite_differences(name):
    profile = PROFILES[name]
    step = 1e-6
    # 0.0123 s off the 0.05 s grid keeps every sample > step away from the breakpoints (multiples of
    # 0.1 s), where the third derivative jumps and the differences of f' are not accurate
    for t in np.linspace(-0.5, 6.0, 131) + 0.0123:
        _, df, ddf = profile(t)
        fd_first = (profile(t + step)[0] - profile(t - step)[0]) / (2 * step)
        fd_second = (profile(t + step)[1] - profile(t - step)[1]) / (2 * step)
        assert abs(df - fd_first) <= 1e-7 * max(1.0, abs(df)), (t, df, fd_first)
        assert abs(ddf - fd_second) <= 1e-6 * max(1.0, abs(ddf)), (t, ddf, fd_second)


def test_blend_ends_and_continuity():
    old, new = QuinticRise(0.0, 1.0, 0.0, 2.0), Constant(-0.4)
    blend = Blend(old, new, t0=0.2, duration=0.7)
    assert blend(0.1) == old(0.1)
    assert blend(1.0) == new(1.0)
    for edge in (0.2, 0.9):  # C2: value, rate and curvature continuous across both ends
        before, after = np.array(blend(edge - 1e-9)), np.array(blend(edge + 1e-9))
        assert np.allclose(before, after, rtol=0, atol=1e-6), (edge, before, after)


def test_settled_profiles_drop_finished_blends_also_inside_running_ones():
    """Re-targeting faster than the blend time nests blends; from time t on, the settled profile keeps only the
    blends still running and equals the nested one (to rounding)."""
    innermost = Blend(Constant(3.0), Constant(3.2), t0=0.0, duration=0.5)  # finished at 0.5 s
    middle = Blend(innermost, QuinticRise(3.1, 0.1, 0.5, 1.0), t0=0.4, duration=0.7)  # finished at 1.1 s
    running = Blend(middle, Constant(2.9), t0=1.0, duration=2.0)
    outer = Blend(running, Constant(3.3), t0=1.3, duration=2.0)
    profile = settled(outer, 1.5)
    assert profile == Blend(Blend(QuinticRise(3.1, 0.1, 0.5, 1.0), Constant(2.9), 1.0, 2.0), Constant(3.3), 1.3, 2.0)
    assert settled(outer, 0.2) == outer  # nothing finished yet
    for t in np.linspace(1.5, 4.0, 26):
        assert np.allclose(profile(t), outer(t), rtol=1e-14, atol=1e-14), t


def test_surface_offsets_are_the_ellipse_and_height_written_out():
    """ConstraintSet.surface_offsets (compiled, all rows at once) against the ellipse (5.1) and height (5.2)
    written out: Phi / |Phi_p| with Phi = (x/a)^2 + (y/b)^2 - 1, Phi_p = (2x/a^2, 2y/b^2, 0) and
    Phi = z - z_a(t), Phi_p = (0, 0, 1), with a growing semi-axis a(t)."""
    a, b = QuinticRise(3.0, 0.4, 0.0, 2.0), Constant(2.0)
    z = QuinticRise(1.5, 0.2, 0.0, 5.0)
    constraints = ConstraintSet((EllipseXY(a, b), HeightZ(z)))
    rng = np.random.default_rng(11)
    times = np.sort(rng.uniform(0.0, 3.0, 40))
    positions = rng.uniform(-4.0, 4.0, (40, 3))
    x, y, height = positions.T
    semi_a, semi_b, z_a = (np.array([profile(t)[0] for t in times]) for profile in (a, b, z))
    ellipse = ((x / semi_a) ** 2 + (y / semi_b) ** 2 - 1) / np.hypot(2 * x / semi_a**2, 2 * y / semi_b**2)
    np.testing.assert_allclose(constraints.surface_offsets(times, positions),
                               np.column_stack([ellipse, height - z_a]), rtol=1e-12, atol=1e-14)

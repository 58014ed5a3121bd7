"""Static equilibrium, the RFE discretisation and the rigid limit, against independent truths.

* Started in its static equilibrium with the drive off, the crane stays at rest under the
  integrator (a converged implicit step reproduces rest to round-off).
* The equilibrium satisfies the static KKT condition Q(q) + A^T lambda = 0 on every row except the
  drive's (lambda by least squares here), and the holding torque is zero by symmetry.
* A clamped-free uniform beam discretised with :func:`discretise_beam` has a first bending frequency
  converging to Euler-Bernoulli's 1.875104^2 / (2 pi) sqrt(E I / (rho A L^4)).
* Stiffening the RFE springs makes the flexible crane's trajectory converge to the rigid crane's.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np
import pytest
import scipy.linalg
from cranes import DRIVE_OFF

from crane_reference.dynamics.chain_dynamics import CraneDynamics
from crane_reference.model.chain import AXES, REVOLUTE, VARIANTS, Body, ChainModel, Joint, build_model, homogeneous
from crane_reference.model.description import CraneDescription
from crane_reference.model.drive import TorqueSource, make_drive
from crane_reference.model.parameters import Boom
from crane_reference.model.profiles import Constant, QuinticRise
from crane_reference.model.rfe import discretise_beam
from crane_reference.motion.constraints import paper_constraints
from crane_reference.motion.equilibrium import static_equilibrium
from crane_reference.motion.integration import ExactFrequencyTrapezoidal
from crane_reference.motion.programmed_motion import ProgrammedMotion

HOLD_DURATION, HOLD_STEP = 5.0, 2e-3  # [s]
REST_VELOCITY = 1e-7  # [m/s or rad/s], the brief's bound on |qd| while holding the equilibrium
ROUND_OFF_VELOCITY = 1e-10  # a converged implicit step stays at ~1e-15 here, see test_rest_stays_at_round_off
KKT_TOLERANCE = 1e-6  # [N or N m]
EULER_BERNOULLI_ROOT = 1.875104068711961  # first root of cos(x) cosh(x) = -1


def paper_motion(params: CraneDescription, model: ChainModel, z=None) -> ProgrammedMotion:
    """The paper's task on ``model`` with the default drive; z held at z_E,s unless ``z`` is given
    as a function of z_E,s."""
    dynamics = CraneDynamics(model, make_drive(params.drive, params.drive_start))
    z_static = float(dynamics.end_effector(model.initial_q)[0][2])
    task = params.task
    return ProgrammedMotion(dynamics, paper_constraints(Constant(task.ellipse_a), Constant(task.ellipse_b),
                                                        Constant(z_static) if z is None else z(z_static)))


@dataclass(frozen=True)
class Hold:
    motion: ProgrammedMotion
    q: np.ndarray
    holding_torque: float
    max_velocity: np.ndarray  # max |qd| per step
    seconds: float


@pytest.fixture(scope="module", params=VARIANTS)
def hold(request, params) -> Hold:
    """The static equilibrium with z held at z_E,s, the drive off (t0 = 2 s), integrated for 5 s."""
    motion = paper_motion(params, build_model(params, request.param))
    equilibrium = static_equilibrium(motion, motion.dynamics.model.initial_q, t0=DRIVE_OFF)
    integrator = ExactFrequencyTrapezoidal(motion, tolerance=1e-12)
    start = time.perf_counter()
    state = integrator.start(DRIVE_OFF, equilibrium.q, np.zeros(motion.dof))
    velocities = []
    for _ in range(round(HOLD_DURATION / HOLD_STEP)):
        state = integrator.step(state, state.t + HOLD_STEP)
        velocities.append(np.max(np.abs(state.qd)))
    return Hold(motion, equilibrium.q, equilibrium.holding_torque, np.array(velocities),
                time.perf_counter() - start)


def test_equilibrium_is_held(hold):
    worst = hold.max_velocity.max()
    assert worst < REST_VELOCITY, (f"{hold.motion.dynamics.model.variant}: max |qd| = {worst:.3g} after "
                                   f"{hold.max_velocity.argmax() * HOLD_STEP:.3f} s ({hold.seconds:.2f} s run)")


def test_rest_stays_at_round_off(hold):
    """Started exactly at rest in a stable equilibrium, the motion of the *linear* neighbourhood is
    only round-off, ~1e-15 rad/s, and a converged implicit step keeps it there (the integrator's step
    iterated to a residual of 1e-15).  A step that stops iterating before it has converged behaves like an explicit
    method and can let round-off grow: 1e-10 leaves five orders of magnitude of margin."""
    worst = hold.max_velocity.max()
    first_second = hold.max_velocity[: round(1.0 / HOLD_STEP)].max()
    assert worst < ROUND_OFF_VELOCITY, (f"{hold.motion.dynamics.model.variant}: max |qd| = {worst:.3g} "
                                        f"(first second {first_second:.3g}): rest is not preserved")


def test_equilibrium_satisfies_static_kkt(hold):
    """Q(q_eq) + A^T lambda = 0 at qd = 0 on every row but the drive's: lambda (2 multipliers) by least
    squares over those rows; what is left on the drive row is the holding torque, zero by the
    symmetry of the layout (boom along -y, E at the ellipse's vertex (0, -b))."""
    motion = hold.motion
    model = motion.dynamics.model
    q = hold.q
    terms = motion.dynamics.terms(DRIVE_OFF, q, np.zeros(model.dof))
    p, C = motion.dynamics.end_effector(q)
    assert np.max(np.abs(motion.constraints.residual(DRIVE_OFF, p))) <= 1e-12
    A = motion.constraints.position_jacobian(DRIVE_OFF, p) @ C  # Phi_q = Phi_p C
    rows = np.array([k for k in range(model.dof) if k != model.drive_joint])
    multipliers, *_ = np.linalg.lstsq(A[:, rows].T, -terms.Q[rows], rcond=None)
    residual = terms.Q + A.T @ multipliers
    assert np.max(np.abs(residual[rows])) <= KKT_TOLERANCE, residual
    holding = -residual[model.drive_joint]
    assert abs(holding) <= KKT_TOLERANCE, f"holding torque {holding:.3g} N m"
    assert abs(hold.holding_torque - holding) <= KKT_TOLERANCE, (hold.holding_torque, holding)
    assert np.max(np.abs(multipliers)) > 1e2, "the constraints should carry load (sanity)"


# --- RFE beam against Euler-Bernoulli -----------------------------------------------------------------

# bending plane -> (joint axis, column of spring_stiffness, second moment of area field)
PLANES = {"vertical": ("z", 0, "second_moment_z"), "lateral": ("y", 1, "second_moment_y")}


def clamped_free_frequency(boom: Boom, length: float, rfe_count: int, plane: str) -> float:
    """First bending frequency [Hz] of a clamped-free beam from ``discretise_beam``: element 0 is clamped,
    elements 1 .. n-1 hang on one bending spring each; small vibrations about the straight beam,
    M from the chain's mass matrix at q = 0, K the spring diagonal."""
    axis, column, _ = PLANES[plane]
    beam = discretise_beam(length, rfe_count, boom.youngs_modulus, boom.shear_modulus, boom.density, boom.section)
    n = rfe_count - 1
    joints = tuple(Joint(f"sde{r}", REVOLUTE, AXES[axis], homogeneous(translation=(beam.lengths[r - 1], 0.0, 0.0)))
                   for r in range(1, rfe_count))
    bodies = tuple(Body(f"rfe{r}", r - 1, beam.bodies[r]) for r in range(1, rfe_count))
    K = np.diag(beam.spring_stiffness[:, column])
    model = ChainModel(variant="beam", joints=joints, bodies=bodies, end_effector_joint=n - 1,
                       end_effector_point=np.array([beam.lengths[-1], 0.0, 0.0]), gravity=0.0, stiffness=K,
                       support_stiffness=np.zeros_like(K), beam_stiffness=K, drive_joint=0, dependent_joints=(),
                       initial_q=np.zeros(n))
    M = CraneDynamics(model, TorqueSource(0.0, 0.0, 1.0)).terms(5.0, np.zeros(n), np.zeros(n)).M
    return float(np.sqrt(scipy.linalg.eigh(K, M, eigvals_only=True)[0]) / (2.0 * np.pi))


def euler_bernoulli_frequency(boom: Boom, length: float, plane: str) -> float:
    bending_stiffness = boom.youngs_modulus * getattr(boom.section, PLANES[plane][2])
    return EULER_BERNOULLI_ROOT**2 / (2.0 * np.pi) * np.sqrt(
        bending_stiffness / (boom.density * boom.section.area * length**4))


@pytest.mark.parametrize("plane", list(PLANES))
def test_rfe_beam_converges_to_euler_bernoulli(paper_params, plane):
    """The crane's section and steel on a slender 10 m beam (L / radius of gyration ~ 110 vertical,
    ~160 lateral), so that rotary inertia, which the RFE bodies include and Euler-Bernoulli neglects,
    shifts the frequency by < 0.03 %, well below the discretisation error being checked."""
    boom = paper_params.boom
    length = 10.0
    exact = euler_bernoulli_frequency(boom, length, plane)
    errors = [abs(clamped_free_frequency(boom, length, n, plane) / exact - 1.0) for n in (6, 10, 20)]
    assert errors[2] <= 0.01, f"n_rfe = 20: error {errors[2]:.3%}"
    assert errors[0] > errors[1] > errors[2], f"errors for n_rfe = 6, 10, 20: {errors}"


@pytest.mark.parametrize("plane", list(PLANES))
def test_crane_boom_first_mode_near_euler_bernoulli(paper_params, plane):
    """The crane's own stocky boom (2.546 m): within 1 % at n_rfe = 20 even with rotary inertia."""
    boom = paper_params.boom
    exact = euler_bernoulli_frequency(boom, boom.length, plane)
    error = abs(clamped_free_frequency(boom, boom.length, 20, plane) / exact - 1.0)
    assert error <= 0.01, f"error {error:.3%}"


# --- rigid limit -----------------------------------------------------------------------------------

RIGID_LIMIT_DURATION, RIGID_LIMIT_STEP = 0.5, 1e-3  # [s]; the torque drive is on throughout
STIFFNESS_FACTORS = (1.0, 1e2, 1e4)
ANGLES = ("column_slew", "boom_luff", "knuckle")  # psi2, psi(3,0), psi4


def angle_history(params: CraneDescription, model: ChainModel) -> np.ndarray:
    """psi2, psi(3,0), psi4 at every step of the paper's task (quintic rise of z) from the model's own
    static equilibrium with the default torque drive."""
    motion = paper_motion(params, model, z=lambda z_static: QuinticRise(z_static, params.task.z_increment, 0.0,
                                                                        params.task.rise_time))
    q0 = static_equilibrium(motion, model.initial_q, t0=0.0).q
    integrator = ExactFrequencyTrapezoidal(motion, tolerance=1e-12)
    state = integrator.start(0.0, q0, np.zeros(model.dof))
    columns = [model.index(name) for name in ANGLES]
    history = [state.q[columns]]
    for _ in range(round(RIGID_LIMIT_DURATION / RIGID_LIMIT_STEP)):
        state = integrator.step(state, state.t + RIGID_LIMIT_STEP)
        history.append(state.q[columns])
    return np.array(history)


def test_stiff_rfe_springs_give_the_rigid_crane(params):
    """Max over time of |angle_flexible - angle_rigid| for each of psi2, psi(3,0), psi4 shrinks
    monotonically (roughly as 1 / stiffness) and is below 1e-6 rad at 1e4 times the RFE stiffness.
    The stiffer models have modes up to ~170 kHz (omega h >> 1), which the integrator damps as unresolved."""
    rigid = angle_history(params, build_model(params, "rigid"))
    flexible = build_model(params, "flexible")
    differences = []
    for factor in STIFFNESS_FACTORS:
        boom = factor * flexible.beam_stiffness
        stiffened = dataclasses.replace(flexible, stiffness=flexible.support_stiffness + boom, beam_stiffness=boom)
        differences.append(np.max(np.abs(angle_history(params, stiffened) - rigid), axis=0))
    differences = np.array(differences)  # (factor, angle)
    assert np.ptp(rigid[:, 0]) > 0.1, "the column should slew noticeably in 0.5 s"
    assert np.all(np.diff(differences, axis=0) < 0), f"not monotonic:\n{differences}"
    assert np.all(differences[-1] < 1e-6), f"x1e4: {differences[-1]}"

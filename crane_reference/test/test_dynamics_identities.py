"""Physical identities of :class:`CraneDynamics`, checked against independent truths.

* M(q) is symmetric positive definite (eigenvalues, Cholesky).
* The springs' and dampers' forces K q and D qd, formed in O(n) on the root block and the diagonal beyond it, equal
  numpy's dense products.
* The O(n) inverse dynamics of the integrator's Newton residual (gravity as an upward acceleration of the
  world frame) equals M qdd + h - Q_g assembled from M, h and Q (a second formulation; those three are
  checked against Pinocchio in test_dynamics_pinocchio.py).
* The conservative forces (gravity + springs) are minus the gradient of the potential energy: Q at
  qd = 0 with the drive off against central finite differences of the potential energy.
* Energy conservation of the free, undamped crane: M qdd = Q - h integrated with scipy's DOP853
  conserves E_k + E_p.
* Energy balance of the damped crane: E(t) - E(0) + W_diss(t) = 0, with the dissipated work
  W_diss = int qd^T D qd dt integrated as an extra ODE state and D built here from the Rayleigh
  coefficients and the model's stiffness blocks.

"Free" means no programmed constraints and no drive (a zero TorqueSource, so E_p,dr = 0 and no power
is fed in): nothing holds the boom, which falls and swings about its luff and knuckle joints while
the base rocks on its springs, so every term of M, h and Q is exercised with large motions.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import pytest
from cranes import CONFIG, DRIVE_OFF, EXAMPLES, NO_DRIVE
from scipy.integrate import solve_ivp

from crane_reference.dynamics.chain_dynamics import CraneDynamics
from crane_reference.dynamics.inertia import world_pseudo_inertias
from crane_reference.dynamics.kinematics import forward_kinematics, velocity_terms
from crane_reference.dynamics.terms import add_joint_matrix_product, inverse_dynamics
from crane_reference.model.chain import VARIANTS, ChainModel, build_model
from crane_reference.model.config import load_config
from crane_reference.model.parameters import Damping

SEED = 20240611
SAMPLES = 5
RTOL, ATOL = 1e-10, 1e-12  # DOP853 tolerances for the energy tests
ENERGY_TOLERANCE = 1e-6  # relative to the largest kinetic energy of the run, see energy_history
FD_STEP = 1e-6  # [m or rad], central differences of E_p
FD_TOLERANCE = 1e-7  # relative to max |Q|
SOFT_BOOM = 1e-2  # boom (RFE spring) stiffness factor of the softened flexible model


@pytest.fixture(scope="module")
def models(params) -> dict[str, ChainModel]:
    return {variant: build_model(params, variant) for variant in VARIANTS}


def softened(model: ChainModel, factor: float) -> ChainModel:
    """``model`` with its RFE springs scaled by ``factor`` (support springs unchanged)."""
    boom = factor * model.beam_stiffness
    return dataclasses.replace(model, stiffness=model.support_stiffness + boom, beam_stiffness=boom)


def random_configuration(model: ChainModel, rng: np.random.Generator) -> np.ndarray:
    """Base translations/angles ~1e-2, RFE angles ~0.05 rad, column/luff/knuckle anywhere."""
    q = np.empty(model.dof)
    for k, name in enumerate(model.joint_names):
        if name.startswith("base_"):
            q[k] = rng.normal(scale=1e-2)
        elif name.startswith("boom_sde"):
            q[k] = rng.normal(scale=0.05)
        else:
            q[k] = rng.uniform(-np.pi, np.pi)
    return q


@pytest.mark.parametrize("variant", VARIANTS)
def test_mass_matrix_symmetric_positive_definite(models, variant):
    model = models[variant]
    dynamics = CraneDynamics(model, NO_DRIVE)
    rng = np.random.default_rng(SEED)
    for _ in range(SAMPLES):
        q = random_configuration(model, rng)
        M = dynamics.terms(DRIVE_OFF, q, rng.normal(size=model.dof)).M
        asymmetry = np.max(np.abs(M - M.T)) / np.max(np.abs(M))
        assert asymmetry <= 1e-14, f"M not symmetric: {asymmetry:.3g}"
        eigenvalues = np.linalg.eigvalsh(0.5 * (M + M.T))
        assert eigenvalues[0] > 1e-10 * eigenvalues[-1], f"M not positive definite: {eigenvalues[:3]}"
        np.linalg.cholesky(M)  # raises LinAlgError unless positive definite


@pytest.mark.parametrize("name", EXAMPLES)
def test_joint_matrix_products_equal_the_dense_ones(name):
    """1 - 2.5 K x and 1 - 2.5 D x, added in place in O(n) (dense on the root block, diagonal beyond), against numpy's
    dense products, on each packaged crane with Rayleigh damping on its supports and boom and a damper on every
    joint: the paper's crane has the support springs' root block (its six base joints), the others a fixed base
    (none)."""
    model = build_model(load_config(CONFIG / name), "flexible")
    D = 1e-3 * model.support_stiffness + 1e-4 * model.beam_stiffness
    dynamics = CraneDynamics(dataclasses.replace(model, damping=D), NO_DRIVE,
                             joint_damping=np.linspace(1.0, 2.0, model.dof))
    chain = dynamics.chain
    assert chain.root_size == (6 if name == "crane.yaml" else 0)
    x = np.random.default_rng(SEED + 5).normal(size=model.dof)
    for X in (chain.stiffness, chain.damping):
        dense = 1.0 - 2.5 * (X @ x)
        ours = np.ones(model.dof)
        add_joint_matrix_product(ours, X, x, -2.5, chain)
        assert np.max(np.abs(ours - dense)) <= 1e-13 * np.max(np.abs(dense))


@pytest.mark.parametrize("variant", VARIANTS)
def test_inverse_dynamics_equals_the_assembled_equations(models, variant):
    model = models[variant]
    dynamics = CraneDynamics(model, NO_DRIVE)
    chain = dynamics.chain
    rng = np.random.default_rng(SEED + 2)
    for _ in range(SAMPLES):
        q, qd, qdd = random_configuration(model, rng), rng.normal(size=model.dof), rng.normal(size=model.dof)
        terms = dynamics.terms(DRIVE_OFF, q, qd)
        gravity = terms.Q + model.stiffness @ q  # Q = Q_g - K q with the drive off and no damping
        expected = terms.M @ qdd + terms.h - gravity
        T, S = forward_kinematics(q, chain.kinds, chain.axes, chain.origins)
        Hw = world_pseudo_inertias(T, chain.body_joint, chain.body_H)
        ours = inverse_dynamics(S, Hw, velocity_terms(qd, S), qdd, chain)
        assert np.max(np.abs(ours - expected)) <= 1e-12 * np.max(np.abs(expected))


@pytest.mark.parametrize("variant", VARIANTS)
def test_conservative_forces_are_minus_potential_gradient(models, variant):
    """Q(t, q, 0) = -dE_p/dq with the drive off; also the gravity part alone, Q + K q = -dE_p,g/dq,
    so that the (large) spring forces cannot hide an error in the gravity forces."""
    model = models[variant]
    dynamics = CraneDynamics(model, NO_DRIVE)
    rng = np.random.default_rng(SEED + 1)
    zero = np.zeros(model.dof)

    def potential(q: np.ndarray) -> tuple[float, float]:
        terms = dynamics.terms(DRIVE_OFF, q, zero)
        return dynamics.accounts(DRIVE_OFF, q, zero, terms)[1], terms.gravity_potential

    for _ in range(SAMPLES):
        q = random_configuration(model, rng)
        Q = dynamics.terms(DRIVE_OFF, q, zero).Q
        gradient = np.empty(model.dof)
        gravity_gradient = np.empty(model.dof)
        for k in range(model.dof):
            step = np.zeros(model.dof)
            step[k] = FD_STEP
            (e_plus, g_plus), (e_minus, g_minus) = potential(q + step), potential(q - step)
            gradient[k] = (e_plus - e_minus) / (2.0 * FD_STEP)
            gravity_gradient[k] = (g_plus - g_minus) / (2.0 * FD_STEP)
        error = np.max(np.abs(Q + gradient)) / np.max(np.abs(Q))
        assert error <= FD_TOLERANCE, f"Q + dE_p/dq: relative error {error:.3g}"
        Q_gravity = Q + model.stiffness @ q
        gravity_error = np.max(np.abs(Q_gravity + gravity_gradient)) / np.max(np.abs(Q_gravity))
        assert gravity_error <= FD_TOLERANCE, f"Q_g + dE_p,g/dq: relative error {gravity_error:.3g}"


@dataclass(frozen=True)
class EnergyHistory:
    times: np.ndarray
    kinetic: np.ndarray
    total: np.ndarray  # E_k + E_p
    dissipated: np.ndarray  # W_diss(t) = int_0^t qd^T D qd dt
    nfev: int


def energy_history(model: ChainModel, duration: float, damping: Damping | None, seed: int) -> EnergyHistory:
    """Free motion from q = initial_q with small random velocities, integrated with DOP853 as the
    first-order system (q, qd, W_diss)' = (qd, M^-1 (Q - h), qd^T D qd)."""
    damping = damping or Damping()
    D = damping.support * model.support_stiffness + damping.boom * model.beam_stiffness  # built here
    dynamics = CraneDynamics(dataclasses.replace(model, damping=D), NO_DRIVE)
    n = model.dof

    def rhs(t: float, y: np.ndarray) -> np.ndarray:
        q, qd = y[:n], y[n:2 * n]
        terms = dynamics.terms(t, q, qd)
        return np.concatenate((qd, np.linalg.solve(terms.M, terms.Q - terms.h), [qd @ D @ qd]))

    rng = np.random.default_rng(seed)
    y0 = np.concatenate((model.initial_q, rng.normal(scale=0.05, size=n), [0.0]))
    times = np.linspace(0.0, duration, 201)
    solution = solve_ivp(rhs, (0.0, duration), y0, method="DOP853", rtol=RTOL, atol=ATOL, t_eval=times)
    assert solution.success, solution.message
    kinetic, total = [], []
    for t, y in zip(solution.t, np.ascontiguousarray(solution.y.T), strict=True):
        q, qd = y[:n], y[n:2 * n]
        kinetic_energy, potential_energy = dynamics.accounts(t, q, qd, dynamics.terms(t, q, qd))[:2]
        kinetic.append(kinetic_energy)
        total.append(kinetic_energy + potential_energy)
    return EnergyHistory(solution.t, np.array(kinetic), np.array(total), solution.y[-1], solution.nfev)


def energy_scale(history: EnergyHistory) -> float:
    """Reference energy for relative errors: the largest kinetic energy of the run.

    E_p contains the gravity potential measured from the world origin, an arbitrary datum (E_p of the
    start is ~8 kJ here), so "relative to the total energy" would depend on where z = 0 is.  The
    largest kinetic energy (~1-23 kJ as the boom falls) is the energy actually exchanged between E_k
    and E_p during the run: an error in M, h or Q shows up as a fraction of it, independent of the
    datum.  It is at least the initial kinetic energy, so a near-rest run would not inflate the test.
    """
    return float(np.max(history.kinetic))


# (model, duration [s]): the rigid crane over 5 s; the flexible crane is stiff (RFE modes up to
# ~1.7 kHz force DOP853 to ~3e-5 s steps, ~7e4 evaluations for 0.2 s), so over 0.2 s at full
# stiffness, and over 1 s with the RFE springs softened 100 times (modes / 10).
ENERGY_CASES = {
    "rigid-5s": ("rigid", 1.0, 5.0),
    "flexible-0.2s": ("flexible", 1.0, 0.2),
    "flexible-soft-1s": ("flexible", SOFT_BOOM, 1.0),
}


@pytest.mark.slow
@pytest.mark.parametrize("case", list(ENERGY_CASES))
def test_energy_conserved_in_free_motion(models, case):
    variant, factor, duration = ENERGY_CASES[case]
    history = energy_history(softened(models[variant], factor), duration, None, SEED + 2)
    scale = energy_scale(history)
    drift = np.max(np.abs(history.total - history.total[0])) / scale
    assert scale > 5.0 * history.kinetic[0], "the run should exchange energy well beyond the initial E_k"
    assert drift <= ENERGY_TOLERANCE, f"{case}: energy drift {drift:.3g} of E_k,max = {scale:.4g} J"


# Rayleigh damping: on the rigid crane only the support part acts (the rigid boom has no springs),
# on the softened flexible crane both parts.
DAMPED_CASES = {
    "rigid-5s": ("rigid", 1.0, 5.0),
    "flexible-soft-1s": ("flexible", SOFT_BOOM, 1.0),
}


@pytest.mark.parametrize("case", list(DAMPED_CASES))
def test_damped_energy_balance(models, case):
    variant, factor, duration = DAMPED_CASES[case]
    history = energy_history(softened(models[variant], factor), duration, Damping(support=1e-3, boom=1e-4),
                             SEED + 3)
    scale = energy_scale(history)
    balance = np.max(np.abs(history.total - history.total[0] + history.dissipated)) / scale
    assert balance <= ENERGY_TOLERANCE, f"{case}: E(t) - E(0) + W_diss: {balance:.3g} of {scale:.4g} J"
    # dE/dt = -qd^T D qd <= 0: the energy never rises (beyond the integration error) and is lost
    assert np.all(np.diff(history.total) <= ENERGY_TOLERANCE * scale), "energy rose in a damped run"
    assert history.dissipated[-1] >= 1e-2 * scale, "damping should dissipate a noticeable energy"
    assert history.total[-1] < history.total[0] - 1e-2 * scale

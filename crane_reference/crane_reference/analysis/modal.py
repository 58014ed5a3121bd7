"""Modal analysis of the constrained crane, linearised about a state (t, q, qd) of its programmed motion.

Linearisation.  The motion obeys M qdd + h = Q + R with A qdd = c, where the reaction R is the ideal
constraint force A^T lambda (the paper) or, for servo-constraints, the dependent joints' torques E_dc tau.
The programmed-motion equations (8) keep the rows P^T (P = B, the velocity map d qd / d qd_ic, for ideal
constraints; P = E_ic for servo-constraints, rows on which R has no component).  A perturbation that keeps
the constraints is dq = B dx (x = q_ic), and differentiating P(q)^T (Q(q) - h - M qdd) with respect to x
gives the linearised equations

    M_r ddx + K_r dx = 0,      M_r = P^T M B,      K_r = P^T (K_t + K_lambda) B,

* K_t = -dQ/dq at qd = 0: the spring matrix K (support springs U^T S U and the RFE springs S^(3)), the
  gravity stiffness d2E_p,g/dq2 and, for a flexible drive, s_dr on psi2 (a torque source is constant in q
  and adds nothing).  Analytic: with T_k,ij = S_i S_j T_k for i <= j <= k (joint twists S, see
  :mod:`crane_reference.dynamics.kinematics`), d2E_p,g/dq_i dq_j = g J_3 S_i S_j Hc_j e_4 for i <= j, where Hc_j e_4
  = sum of m [c; 1] over the bodies beyond joint j (:mod:`crane_reference.dynamics.inertia`).
* K_lambda = -sum_i lambda_i Phi_i,qq, the curvature of the constraint surfaces loaded by the constraint
  force (ideal constraints only; it comes from dB/dx^T (Q - h - M qdd) = dB/dx^T (-A^T lambda)).  With
  Phi = p^T Q p + g^T p + c (:mod:`crane_reference.motion.constraints`) and the kinematics Hessian
  d2p/dq_a dq_b = J S_a S_b [p; 1] (a <= b <= joint of E):
  Phi_qq = C^T 2Q C + sum_ab Phi_p . d2p/dq_a dq_b.  It turns the hanging load into a pendulum.
  For servo-constraints P = E_ic is constant and there is no such term; M_r and K_r are then not
  symmetric (the servo torques are not workless), and the eigenproblem is solved as a general one.

Neglected (a frozen-time, "quasi-static" linearisation): d(M qdd + h)/dq (the inertial loads' and the
centrifugal stiffness), dh/dqd (Coriolis / gyroscopic coupling), the Rayleigh damping D (zero in the
paper), and the time variation of B and of the constraints.  At a static equilibrium (qd = 0, qdd = 0)
only the last two matter and the linearisation is exact.

Modes: K_r x = omega^2 M_r x (scipy.linalg.eigh, or eig for servo-constraints), mode shapes in the full
coordinates phi = B x, scaled to phi^T M phi = 1 (ideal) or max |phi| = 1 (servo).  A mode evolves as
exp(s t) with s^2 = -omega^2: frequency |Im s| / (2 pi) and growth rate |Re s| (omega^2 < 0: a
statically unstable direction; complex omega^2, possible only for servo-constraints: flutter).

Each mode is characterised by which springs deform: the split of phi^T (K_t + K_lambda) phi (= omega^2 for
ideal constraints) over the stiffness contributions (support springs, each flexible link's bending in its
x-y plane (a boom's luffing plane), its bending across it and its torsion, joint springs, gravity, constraint
curvature, drive spring); and by which bodies move: the split of phi^T M phi over the bodies (a flexible
link's elements as one).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from ..dynamics.chain_dynamics import CraneDynamics
from ..dynamics.inertia import composite_inertias, mass_matrix, world_pseudo_inertias
from ..dynamics.kinematics import forward_kinematics
from ..model.chain import ChainModel
from ..model.description import CraneDescription
from ..motion.constraints import ConstraintSet
from ..motion.equilibrium import static_equilibrium
from ..motion.programmed_motion import ProgrammedMotion
from ..motion.simulation import Scenario, simulate

BEAM_SPRING_PARTS = {"_bend_vertical": "bending, luffing plane", "_bend_lateral": "bending, horizontal",
                     "_twist": "torsion"}
"""The parts of a flexible link's springs, by RFE angle, labelled ``<link> <part>``."""
SUPPORT = "support springs"
BEAM_SPRINGS = "beam springs"
JOINT_SPRINGS = "joint springs"
GRAVITY = "gravity"
CONSTRAINT = "constraint curvature"
DRIVE = "drive spring"


def gravity_stiffness(dynamics: CraneDynamics, q: np.ndarray) -> np.ndarray:
    """Hessian of the gravity potential, d2E_p,g/dq2 = -dQ_g/dq (n, n), analytic (see module docstring)."""
    chain = dynamics.chain
    kinds, axes, origins, body_joint, body_H = chain.kinds, chain.axes, chain.origins, chain.body_joint, chain.body_H
    n = q.size
    T, S = forward_kinematics(np.ascontiguousarray(q, dtype=float), kinds, axes, origins)
    Hc = composite_inertias(world_pseudo_inertias(T, body_joint, body_H), body_joint, n)
    u = np.einsum("jab,jb->ja", S, Hc[:, :, 3])  # S_j Hc_j e_4
    X = S[:, 2, :] @ u.T  # X_ij = J_3 S_i S_j Hc_j e_4
    return dynamics.model.gravity * (np.triu(X) + np.triu(X, 1).T)


def constraint_hessian(dynamics: CraneDynamics, motion_constraints: ConstraintSet, t: float, q: np.ndarray,
                       weights: np.ndarray) -> np.ndarray:
    """sum_i w_i Phi_i,qq (n, n) of the quadric end-effector constraints at (t, q), analytic."""
    chain = dynamics.chain
    e = chain.ee_joint
    _, S = forward_kinematics(np.ascontiguousarray(q, dtype=float), chain.kinds, chain.axes, chain.origins)
    p, C = dynamics.end_effector(q)
    p_bar = np.append(p, 1.0)
    quadric = motion_constraints.coefficients(t).Q[:, 0, :3, :3]  # (m, 3, 3) (holonomic rows: the p block)
    w = weights @ motion_constraints.position_jacobian(t, p)  # sum_i w_i Phi_i,p
    v = S @ p_bar  # S_b [p; 1]
    v[e + 1:] = 0.0
    W = np.einsum("r,arc->ac", w, S[:, :3, :])  # w^T J S_a
    X = W @ v.T  # rows a > e only meet columns b >= a > e, which are zero
    kinematic = np.triu(X) + np.triu(X, 1).T
    return C.T @ (2.0 * np.einsum("i,iab->ab", weights, quadric)) @ C + kinematic


def body_group(name: str) -> str:
    """Group of a body for energy shares: the rigid finite elements of a beam form one group
    (boom_rfe3 -> boom)."""
    return re.sub(r"_rfe\d+$", "", name)


def body_mass_matrices(dynamics: CraneDynamics, q: np.ndarray) -> dict[str, np.ndarray]:
    """The mass matrix split by body group (:func:`body_group`): M = sum of the parts."""
    chain = dynamics.chain
    kinds, axes, origins, body_joint, body_H = chain.kinds, chain.axes, chain.origins, chain.body_joint, chain.body_H
    n = q.size
    T, S = forward_kinematics(np.ascontiguousarray(q, dtype=float), kinds, axes, origins)
    parts: dict[str, np.ndarray] = {}
    for b, body in enumerate(dynamics.model.bodies):
        Hc = composite_inertias(world_pseudo_inertias(T, body_joint[b:b + 1], body_H[b:b + 1]), body_joint[b:b + 1], n)
        group = body_group(body.name)
        parts[group] = parts.get(group, 0.0) + mass_matrix(S, Hc)
    return parts


def _spring_parts(model: ChainModel) -> dict[str, np.ndarray]:
    """The spring matrix K split into support springs, each flexible link's bending / torsion springs and the
    joint springs."""
    parts = {SUPPORT: model.support_stiffness}
    names = np.array(model.joint_names)
    remaining = model.beam_stiffness.copy()
    for link in model.flexible_links:
        for suffix, label in BEAM_SPRING_PARTS.items():
            mask = np.zeros(model.dof, dtype=bool)
            mask[[k for k in link.springs if names[k].endswith(suffix)]] = True
            if mask.any():
                parts[f"{link.name} {label}"] = np.where(np.outer(mask, mask), model.beam_stiffness, 0.0)
                remaining -= parts[f"{link.name} {label}"]
    if np.any(remaining):  # a chain built without its flexible links named
        parts[BEAM_SPRINGS] = remaining
    joint = model.stiffness - model.support_stiffness - model.beam_stiffness
    if np.any(joint):
        parts[JOINT_SPRINGS] = joint
    return parts


@dataclass(frozen=True)
class Linearisation:
    """Linearised equations M_r ddx + K_r dx = 0 at one state, with everything needed to interpret them.

    ``stiffness_parts`` are full-coordinate (n, n) contributions whose sum is K_t + K_lambda,
    ``body_mass`` the mass matrix split by body group; ``P`` and ``B`` map to the reduced equations
    (``P is B`` for ideal constraints)."""

    t: float
    q: np.ndarray
    joint_names: tuple[str, ...]
    M: np.ndarray
    stiffness_parts: dict[str, np.ndarray]
    B: np.ndarray
    P: np.ndarray
    body_mass: dict[str, np.ndarray]
    symmetric: bool = True
    reactions: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def stiffness(self) -> np.ndarray:
        """K_t + K_lambda (n, n)."""
        return sum(self.stiffness_parts.values())

    @property
    def reduced_mass(self) -> np.ndarray:
        """M_r = P^T M B."""
        return self.P.T @ self.M @ self.B

    @property
    def reduced_stiffness(self) -> np.ndarray:
        """K_r = P^T (K_t + K_lambda) B."""
        return self.P.T @ self.stiffness @ self.B


def tangent_stiffness_parts(dynamics: CraneDynamics, t: float, q: np.ndarray) -> dict[str, np.ndarray]:
    """K_t = -dQ/dq at qd = 0, split into its springs, gravity and drive contributions."""
    parts = _spring_parts(dynamics.model)
    parts[GRAVITY] = gravity_stiffness(dynamics, q)
    drive_stiffness = float(dynamics.drive.kernel_parameters(t)[1])
    if drive_stiffness:
        j = dynamics.model.drive_joint
        parts[DRIVE] = np.zeros_like(parts[GRAVITY])
        parts[DRIVE][j, j] = drive_stiffness
    return parts


def linearise_chain(dynamics: CraneDynamics, t: float, q: np.ndarray) -> Linearisation:
    """The unconstrained chain about (t, q) at rest: M qdd + K_t dq = 0 (B = P = identity)."""
    n = dynamics.model.dof
    terms = dynamics.terms(t, q, np.zeros(n))
    return Linearisation(t, np.array(q, dtype=float), tuple(dynamics.model.joint_names), terms.M,
                         tangent_stiffness_parts(dynamics, t, q), np.eye(n), np.eye(n), body_mass_matrices(dynamics, q))


def linearise(motion: ProgrammedMotion, t: float, q: np.ndarray, qd: np.ndarray | None = None) -> Linearisation:
    """The programmed motion linearised about (t, q, qd) (q_dc re-projected on the constraints first;
    qd = 0 by default).  The reactions are those of :meth:`ProgrammedMotion.solve` at the state."""
    motion.require_holonomic("the linearisation")
    dynamics = motion.dynamics
    q, _ = motion.project_positions(t, np.asarray(q, dtype=float))
    qd = np.zeros_like(q) if qd is None else motion.dependent_velocities(t, q, np.asarray(qd, dtype=float))
    solution = motion.solve(t, q, qd)
    parts = tangent_stiffness_parts(dynamics, t, q)
    if not motion.servo:
        parts[CONSTRAINT] = -constraint_hessian(dynamics, motion.constraints, t, q, solution.reactions)
    return Linearisation(t, q, tuple(dynamics.model.joint_names), solution.dynamics.M, parts, solution.velocity_map,
                         motion.projection(solution), body_mass_matrices(dynamics, q), symmetric=not motion.servo,
                         reactions=solution.reactions)


@dataclass(frozen=True)
class Modes:
    """Natural frequencies and mode shapes of a :class:`Linearisation`, lowest |omega^2| first.

    ``eigenvalues`` omega^2 [1/s^2] (complex for a non-symmetric problem).  A mode evolves as
    exp(s t) with s^2 = -omega^2; ``frequencies`` |Im s| / (2 pi) [Hz] and ``growth_rates`` |Re s| [1/s]
    (zero for a stable undamped mode; omega^2 < 0 is a statically unstable direction, f = 0).
    ``shapes`` (n, m) phi = B x in the full coordinates (real parts for a non-symmetric problem),
    ``reduced_shapes`` (n_ic, m) x; ``strain_energy`` part -> (m,) phi^T K_part phi / sum_parts
    |phi^T K_part phi| (signed shares; the unscaled parts sum to phi^T K phi = omega^2 for ideal
    constraints);
    ``participation`` (n, m) phi_k^2 M_kk / sum_j phi_j^2 M_jj, each coordinate's share of the mode's
    kinetic energy with the mass coupling between coordinates left out (non-negative, sums to 1);
    ``body_energy`` body group -> (m,) each group's share of phi^T M phi (M split by body, exact, sums
    to 1 for ideal constraints; the boom's elements form one group)."""

    linearisation: Linearisation
    eigenvalues: np.ndarray
    frequencies: np.ndarray
    growth_rates: np.ndarray
    shapes: np.ndarray
    reduced_shapes: np.ndarray
    strain_energy: dict[str, np.ndarray]
    participation: np.ndarray
    body_energy: dict[str, np.ndarray]

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.linearisation.joint_names

    def character(self, k: int, threshold: float = 0.2) -> str:
        """The stiffness contributions carrying at least ``threshold`` of mode k's strain energy."""
        shares = sorted(((abs(v[k]), v[k], name) for name, v in self.strain_energy.items()), reverse=True)
        return " + ".join(f"{name} {share:.0%}" for size, share, name in shares if size >= threshold)

    def moving_bodies(self, k: int, threshold: float = 0.2) -> str:
        """The body groups carrying at least ``threshold`` of mode k's kinetic energy."""
        shares = sorted(((v[k], name) for name, v in self.body_energy.items()), reverse=True)
        return " + ".join(f"{name} {share:.0%}" for share, name in shares if share >= threshold)

    def dominant(self, k: int, count: int = 3) -> list[tuple[str, float]]:
        """The ``count`` coordinates with the largest :attr:`participation` in mode k."""
        shares = self.participation[:, k]
        order = np.argsort(-shares)[:count]
        return [(self.joint_names[i], float(shares[i])) for i in order]

    def mass_scaled_shape(self, k: int) -> np.ndarray:
        """phi_j sqrt(M_jj) / max_j |phi_j sqrt(M_jj)|: mode k in comparable (energy) units, signed."""
        scaled = self.shapes[:, k] * np.sqrt(np.diag(self.linearisation.M))
        return scaled / np.max(np.abs(scaled))


def exponents(omega_squared: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(f [Hz], growth rate [1/s]) of s = sqrt(-omega^2): f = |Im s| / (2 pi), growth = |Re s|."""
    s = np.sqrt(-np.asarray(omega_squared, dtype=complex))
    return np.abs(s.imag) / (2.0 * np.pi), np.abs(s.real)


def modal_analysis(linearisation: Linearisation) -> Modes:
    """Solve K_r x = omega^2 M_r x; see the module docstring for scaling and energies."""
    lin = linearisation
    M_r, K_r = lin.reduced_mass, lin.reduced_stiffness
    if lin.symmetric:
        eigenvalues, x = scipy.linalg.eigh(0.5 * (K_r + K_r.T), 0.5 * (M_r + M_r.T))
        order = np.argsort(np.abs(eigenvalues))
    else:
        eigenvalues, x = scipy.linalg.eig(K_r, M_r)
        # rotate each complex eigenvector so that its largest entry is real, then keep the real part
        largest = x[np.argmax(np.abs(x), axis=0), np.arange(x.shape[1])]
        x = np.real(x * np.exp(-1j * np.angle(largest)))
        order = np.lexsort((np.abs(eigenvalues.imag), np.abs(eigenvalues)))
    eigenvalues, x = eigenvalues[order], x[:, order]
    shapes = lin.B @ x
    if not lin.symmetric:
        scale = 1.0 / np.max(np.abs(shapes), axis=0)
        shapes, x = shapes * scale, x * scale
    energies = {name: np.einsum("im,ij,jm->m", shapes, K, shapes) for name, K in lin.stiffness_parts.items()}
    total = np.sum(np.abs(list(energies.values())), axis=0)
    strain = {name: e / total for name, e in energies.items()}
    diagonal = shapes**2 * np.diag(lin.M)[:, None]
    kinetic = {name: np.einsum("im,ij,jm->m", shapes, M, shapes) for name, M in lin.body_mass.items()}
    kinetic_total = np.einsum("im,ij,jm->m", shapes, lin.M, shapes)
    frequencies, growth = exponents(eigenvalues)
    return Modes(lin, eigenvalues, frequencies, growth, shapes, x, strain, diagonal / diagonal.sum(axis=0),
                 {name: e / kinetic_total for name, e in kinetic.items()})


def modal_assurance(phi: np.ndarray, psi: np.ndarray, metric: np.ndarray | None = None) -> float:
    """MAC = (phi^T W psi)^2 / ((phi^T W phi)(psi^T W psi)), W = ``metric`` (identity by default)."""
    W = np.eye(phi.size) if metric is None else metric
    return float((phi @ W @ psi) ** 2 / ((phi @ W @ phi) * (psi @ W @ psi)))


def scenario_motion(scenario: Scenario, realisation: str = "ideal") -> tuple[ProgrammedMotion, np.ndarray]:
    """The scenario's programmed motion with constraint ``realisation`` ("ideal" or "servo") and its
    static equilibrium at t = 0 (each realisation has its own)."""
    if realisation == scenario.motion.realisation:
        return scenario.motion, scenario.equilibrium.q
    motion = ProgrammedMotion(scenario.dynamics, scenario.motion.constraints, realisation=realisation)
    return motion, static_equilibrium(motion, scenario.model.initial_q).q


def modes_at(params: CraneDescription, variant: str = "flexible", t: float = 0.0, realisation: str = "ideal",
             step: float = 1e-3) -> tuple[Modes, ProgrammedMotion]:
    """Modes of the default scenario at time t of its programmed motion: at the static equilibrium for
    t = 0, else at the state (q, qd) reached by the integrator (``step``)."""
    motion, q = scenario_motion(Scenario(params, variant), realisation)
    qd = np.zeros_like(q)
    if t > 0.0:
        trajectory = simulate(motion, q, t, step=step)
        t, q, qd = float(trajectory.t[-1]), trajectory.q[-1], trajectory.qd[-1]
    return modal_analysis(linearise(motion, t, q, qd)), motion

"""Equations of programmed motion (7)-(8) with independent / dependent coordinates (2)-(3).

Partition q into independent q_ic and dependent q_dc (the paper: q_dc = [psi(3,0), psi4], eq. (3.2)).
The velocity form of the constraints, A qd = b (eqs. (6.1)-(6.2), A = Phi_q, b = -Phi_t), split into
K_dc = A[:, dc] and K_ic = A[:, ic], gives the dependent velocities (7)

    qd_dc = K_dc^-1 (b - K_ic qd_ic),   d qd_dc / d qd_ic = Gamma = -K_dc^-1 K_ic.

(The paper prints k_a = [0, dz_E,a/dt] and the rows u, c_1j; the second row must be C_3, from (6.2).)
With B = d qd / d qd_ic (identity on ic, Gamma on dc), the programmed motion equations (8) are

    [ B^T M ]          [ B^T (Q - h) ]
    [   A   ] qdd  =   [      c      ]

i.e. the dynamic equations projected on the independent directions plus the constraint accelerations
(6.3)-(6.4), A qdd = c.  This is equivalent to the Lagrange-multiplier (KKT) form
M qdd + h = Q + A^T lambda, A qdd = c; lambda follows from the solution and A^T lambda is the
generalized constraint force.  Positions of the dependent coordinates are not integrated: they are
found from the position constraints Phi(q_ic, q_dc, t) = 0 by Newton's method with Jacobian K_dc
(coordinate partitioning), so the motion never drifts off the constraints.

First-order (velocity) task constraints Psi(p, p', t) = 0 fit the same equations: their rows of A
are Psi_v C and their rows of c come from dPsi/dt = 0.  The coordinate each one makes dependent
(q_vd) is not fixed by positions, so it is integrated like the independent ones, while its velocity
comes from the constraints; the velocity-level constraints hold exactly at every evaluation.
``dependent[i]`` is the coordinate solved from constraint i.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np

from ..dynamics.chain_dynamics import CraneDynamics, DynamicsTerms
from ..dynamics.evaluation import evaluate
from ..dynamics.projection import PROJECTION_ITERATIONS, dependent_velocities, project_positions, projection_matrix
from ..dynamics.runs import evaluated_rows
from ..dynamics.structures import Evaluation, Partition
from ..model.config import ConfigError
from ..model.description import BASE_JOINTS
from .constraints import ConstraintSet, ConstraintTerms


class ConstraintSingularityError(RuntimeError):
    """K_dc is (nearly) singular: the dependent coordinates cannot be solved for (stretch / fold)."""


class ProjectionError(RuntimeError):
    """The position constraints could not be solved for the dependent coordinates."""


REALISATIONS = ("ideal", "servo")


@dataclass(frozen=True)
class MotionSolution:
    """The result of (8) at one state.

    ``reactions`` are the Lagrange multipliers lambda of Phi (ideal constraints) or the dependent
    joints' torques tau [N m] (servo-constraints); ``constraint_forces`` the generalized force they
    exert, M qdd + h - Q (= A^T lambda, or tau on the dependent coordinates).  ``powers`` are what the
    drive, the constraint forces and the dampers feed into the crane [W] (their time integrals are the
    work terms of the energy balance).
    """

    qdd: np.ndarray
    reactions: np.ndarray
    constraint_forces: np.ndarray
    dynamics: DynamicsTerms
    constraints: ConstraintTerms
    velocity_map: np.ndarray
    kdc_min_singular_value: float
    kinetic_energy: float
    potential_energy: float
    drive_torque: float
    powers: np.ndarray


MIN_SINGULAR_VALUE = 1e-3
"""The smallest singular value of K_dc a programmed motion accepts (below it: a stretch/fold singularity)."""


def _dependent_candidates(dynamics: CraneDynamics) -> list[int]:
    """The coordinates that can be dependent: joints of the links (not the base's, not the drive's) free of
    springs and dampers."""
    model, chain = dynamics.model, dynamics.chain
    free = [k for k in range(model.dof) if not (np.any(chain.stiffness[k]) or np.any(chain.stiffness[:, k])
                                                or np.any(chain.damping[k]) or np.any(chain.damping[:, k]))]
    return [k for k in free if k != model.drive_joint and model.joints[k].name not in BASE_JOINTS]


def _minor_singular_value(dynamics: CraneDynamics, constraints: ConstraintSet, q: np.ndarray,
                          columns: tuple[int, ...]) -> float:
    p, C = dynamics.end_effector(np.ascontiguousarray(q, dtype=float))
    K = constraints.position_jacobian(0.0, p) @ C[:, list(columns)]
    return float(np.linalg.svd(K, compute_uv=False)[-1])


def choose_dependent(dynamics: CraneDynamics, constraints: ConstraintSet, q: np.ndarray,
                     minimum: float = MIN_SINGULAR_VALUE) -> tuple[int, ...]:
    """The dependent coordinates (3.2) for ``constraints`` (holonomic) at the start q: of the joints that can be
    (:func:`_dependent_candidates`), the set whose minor K_dc = Phi_p C[:, dc] of the task Jacobian at t = 0 has
    the largest smallest singular value; :class:`~crane_reference.model.config.ConfigError` naming ``dependent`` when
    none reaches ``minimum``."""
    candidates = _dependent_candidates(dynamics)
    names = dynamics.model.joint_names
    if len(candidates) < constraints.size:
        raise ConfigError(f"dependent = auto: the task has {constraints.size} constraints, and only "
                          f"{len(candidates)} joints ({', '.join(names[k] for k in candidates) or 'none'}) are free of "
                          "springs and dampers and not the drive's: take a spring or damper off a joint, or name "
                          "the dependent joints")
    best, chosen = -1.0, ()
    for columns in combinations(candidates, constraints.size):
        sigma = _minor_singular_value(dynamics, constraints, q, columns)
        if sigma > best:
            best, chosen = sigma, columns
    if not best >= minimum:
        raise ConfigError(f"dependent = auto: no {constraints.size} of the joints "
                          f"{', '.join(names[k] for k in candidates)} "
                         f"(free of springs and dampers, not the drive's) solve the task at the start: the best "
                         f"minor of the task Jacobian, {[names[k] for k in chosen]}, has the smallest singular value "
                         f"{best:.3g} < {minimum:g}; move the start away from a stretch/fold singularity or "
                         "name the dependent joints")
    return tuple(int(k) for k in chosen)


def check_dependent(dynamics: CraneDynamics, constraints: ConstraintSet, q: np.ndarray, dependent: tuple[int, ...],
                    minimum: float = MIN_SINGULAR_VALUE) -> None:
    """:class:`~crane_reference.model.config.ConfigError` naming ``dependent`` unless the named coordinates can solve
    the task at the start q: as many as constraints, free of springs and dampers (not the base's), and K_dc well
    conditioned (smallest singular value >= ``minimum``)."""
    names = dynamics.model.joint_names
    listed = [names[k] for k in dependent]
    if len(dependent) != constraints.size:
        raise ConfigError(f"dependent = {listed}: the task has {constraints.size} constraints and needs as many "
                          "dependent joints")
    free = {*_dependent_candidates(dynamics), dynamics.model.drive_joint}
    sprung = [names[k] for k in dependent if k not in free]
    if sprung:
        raise ConfigError(f"dependent = {listed}: {', '.join(sprung)} carry a spring or a damper, or are the base's; "
                          "the dependent joints must be free of them")
    sigma = _minor_singular_value(dynamics, constraints, q, tuple(dependent))
    if not sigma >= minimum:
        raise ConfigError(f"dependent = {listed}: these joints cannot satisfy the task at the start (smallest "
                          f"singular value of K_dc {sigma:.3g} < {minimum:g}); name other joints, or 'auto'")


POSITION_TOLERANCE = 1e-13
"""[rad or m]: Newton on the position constraints outside the integrator (a start, a check of targets) stops after a
correction this small."""


class ProgrammedMotion:
    """Equations (7)-(8) of a crane model under a :class:`ConstraintSet` (evaluated by the compiled
    kernels of :mod:`crane_reference.dynamics.evaluation`).

    ``realisation`` says who enforces the constraints.  ``"ideal"`` (the paper): ideal forces at E,
    and the dynamic rows of (8) are projected with B on the directions the constraints leave free.
    ``"servo"`` (Blajer and Kolodziejczyk's servo-constraints): torques tau on the dependent joints
    (luff and knuckle), M qdd + h = Q + E_dc tau with A qdd = c; the dynamic rows kept are those of the
    unactuated coordinates, P = E_ic instead of B, and tau = (M qdd + h - Q)_dc.
    """

    def __init__(self, dynamics: CraneDynamics, constraints: ConstraintSet,
                 dependent: tuple[int, ...] | None = None, min_singular_value: float = MIN_SINGULAR_VALUE,
                 realisation: str = "ideal"):
        if realisation not in REALISATIONS:
            raise ValueError(f"realisation = {realisation!r}: must be one of {', '.join(REALISATIONS)}")
        self.realisation = realisation
        self.servo = realisation == "servo"
        model = dynamics.model
        self.dynamics = dynamics
        self.constraints = constraints
        self.dependent = np.array(model.dependent_joints if dependent is None else dependent, dtype=np.int64)
        self.independent = np.array([k for k in range(model.dof) if k not in self.dependent], dtype=np.int64)
        if len(self.dependent) != constraints.size:
            raise ValueError(f"{constraints.size} constraints need as many dependent coordinates, "
                             f"got {len(self.dependent)}")
        chain = dynamics.chain
        sprung = [int(j) for j in self.dependent if np.any(chain.stiffness[j]) or np.any(chain.stiffness[:, j])
                  or np.any(chain.damping[j]) or np.any(chain.damping[:, j])]
        if sprung:
            raise ValueError(f"dependent = {tuple(int(j) for j in self.dependent)}: coordinate(s) {sprung} carry a "
                             "spring or a damper of the model; the dependent coordinates must be free of them (the "
                             "integrator's reduced stiffness and damping are K[ic, ic] and D[ic, ic])")
        orders = constraints.orders
        self.holonomic_dependent = self.dependent[orders == 0]
        """Coordinates solved from the position constraints (the paper's psi(3,0), psi4)."""
        self.velocity_dependent = self.dependent[orders == 1]
        """Coordinates whose velocities first-order constraints fix; their positions are integrated."""
        self.integrated = np.concatenate((self.independent, self.velocity_dependent))
        """Coordinates the integrator advances: independent first, then velocity-dependent."""
        self.partition = Partition(self.independent, self.dependent, self.integrated, self.holonomic_dependent,
                                   self.servo)
        """The partitioning in the layout of the compiled kernels."""
        self.min_singular_value = min_singular_value

    def require_holonomic(self, purpose: str) -> None:
        """Raise unless every task constraint is holonomic (``purpose`` names what needs that)."""
        if self.velocity_dependent.size:
            raise ValueError(f"{purpose} is defined for holonomic task constraints only; this set has "
                             f"{self.velocity_dependent.size} first-order constraint(s)")

    @property
    def dof(self) -> int:
        return self.dynamics.model.dof

    def check_singularity(self, sigma: float) -> None:
        """Raises if the smallest singular value of K_dc = A[:, dc] is below the minimum."""
        if not sigma >= self.min_singular_value:
            raise ConstraintSingularityError(
                f"smallest singular value of K_dc = {sigma:.3g} is below {self.min_singular_value:g}: "
                "the end-effector task is at or near a stretch/fold singularity")

    def project_positions(self, t: float, q: np.ndarray, tolerance: float = POSITION_TOLERANCE,
                          max_iterations: int = PROJECTION_ITERATIONS
                          ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
        """q with q_hd solved from Phi(q, t) = 0 (Newton, Jacobian Phi_p C[:, hd]; the paper's K_dc), and
        (p_E, C) at the returned q; Newton stops after a correction of at most ``tolerance`` [rad or m]."""
        projection = project_positions(np.ascontiguousarray(q, dtype=float), self.constraints.coefficients(t),
                                               self.holonomic_dependent, self.dynamics.chain, tolerance, max_iterations)
        if not projection.solved:
            raise ProjectionError(f"position constraints not met after {max_iterations} Newton iterations at "
                                  f"t = {t:.6g} s: the target is not reachable from here")
        return projection.q, (projection.ee_position, projection.ee_jacobian)

    def dependent_velocities(self, t: float, q: np.ndarray, qd: np.ndarray,
                             kinematics: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """qd with its dependent part solved from the velocity-level constraints (eq. (7) for the paper's);
        ``kinematics`` = (p_E, C) at q if known."""
        p, C = self.dynamics.end_effector(q) if kinematics is None else kinematics
        qd, converged = dependent_velocities(np.ascontiguousarray(qd, dtype=float), p, C,
                                                     self.constraints.coefficients(t), self.dependent)
        if not converged:
            raise ProjectionError(f"velocity constraints not met at t = {t:.6g} s")
        return qd

    def solution_from_evaluation(self, e: Evaluation) -> MotionSolution:
        """Wrap an :class:`~crane_reference.dynamics.structures.Evaluation` of the kernels (checks the
        singularity)."""
        kinetic, potential, torque, drive_power, constraint_power, damping_power, sigma = e.accounts.tolist()
        self.check_singularity(sigma)
        a = e.terms
        return MotionSolution(a.qdd, e.reactions, e.constraint_forces,
                              DynamicsTerms(a.M, a.h, a.forces, a.ee_position, a.ee_rotation, a.ee_jacobian, a.ee_bias,
                                            a.gravity_potential),
                              ConstraintTerms(e.residual, e.gradients, a.A, a.c, e.distance, e.velocity_residual),
                              a.velocity_map, sigma, kinetic, potential, torque,
                              np.array([drive_power, constraint_power, damping_power]))

    def projection(self, solution: MotionSolution) -> np.ndarray:
        """P of (8) at a solution: B (ideal constraints) or E_ic (servo-constraints)."""
        return projection_matrix(solution.velocity_map, self.independent, self.servo)

    def solve(self, t: float, q: np.ndarray, qd: np.ndarray, left_limit: bool = False) -> MotionSolution:
        """qdd from the programmed motion equations (8) and the multipliers lambda (drive taken just
        before t with ``left_limit``)."""
        return self.solution_from_evaluation(evaluate(
            np.ascontiguousarray(q, dtype=float), np.ascontiguousarray(qd, dtype=float),
            self.constraints.coefficients(t), self.dynamics.drive.kernel_parameters(t, left_limit), self.partition,
            self.dynamics.chain))

    def evaluated_rows(self, times: np.ndarray, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What the full evaluation of computed steps gives that a run without it left out
        (:meth:`~.integration.ExactFrequencyTrapezoidal.run` with ``every_row`` False): at each of ``times``
        (N,) [s], with the rows of q, qd and the integrator's qdd (N, n) there, the generalized force of the
        constraints (N, n), the drive torque (N,) [N m] and the constraint distances (N, m) [m]; by O(n)
        inverse dynamics, without M (:func:`~crane_reference.dynamics.runs.evaluated_rows`)."""
        times = np.asarray(times, dtype=float)
        return evaluated_rows(np.ascontiguousarray(q, dtype=float), np.ascontiguousarray(qd, dtype=float),
                                      np.ascontiguousarray(qdd, dtype=float), self.constraints.coefficients_at(times),
                                      self.dynamics.drive.kernel_parameters(times), self.partition,
                                      self.dynamics.chain)

"""Programmed (task) constraints on the end-effector E, eqs. (5.1)-(5.2) and (6.1)-(6.4).

A constraint is written on E's world position p = J T^(4) r_E (eq. (5)) and time.  Every constraint
here is a quadric in p with time-dependent coefficients,

    Phi(p, t) = p^T Q(t) p + g(t)^T p + c(t)        (Q symmetric),

which covers the paper's ellipse (5.1) and height (5.2) as well as planes, spheres, cylinders and
other surfaces.  With p' = C qd and p'' = C qdd + d (C, d from :mod:`crane_reference.kinematics`)

    dPhi/dt   = Phi_p C qd + Phi_t = 0                                     (6.1), (6.2)
    d2Phi/dt2 = Phi_p (C qdd + d) + convective = 0                         (6.3), (6.4)
    Phi_p = 2 Q p + g,   Phi_t = p^T Q' p + g'^T p + c',
    convective = p'^T 2Q p' + 2 (2 Q' p + g')^T p' + p^T Q'' p + g''^T p + c''.

A new task constraint is a new :class:`EndEffectorConstraint` that returns its coefficients and their
first two time derivatives (:class:`Quadric`); the solver (compiled, :mod:`crane_reference.kernels`)
does not change.  For the ellipse, the paper's u and v are Phi_p C / 2 and (Phi_p d + convective) / 2:
it divides (6.3) by two, which changes only the scale of the multiplier.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from .profiles import Profile


@dataclass(frozen=True)
class Quadric:
    """Coefficients of Phi = p^T Q p + g^T p + c and their time derivatives: index 0 value, 1 first,
    2 second derivative (Q: (3, 3, 3), g: (3, 3), c: (3,))."""

    Q: np.ndarray
    g: np.ndarray
    c: np.ndarray

    def residual(self, p: np.ndarray) -> float:
        return float(p @ self.Q[0] @ p + self.g[0] @ p + self.c[0])

    def gradient(self, p: np.ndarray) -> np.ndarray:
        return 2.0 * self.Q[0] @ p + self.g[0]

    def time_derivative(self, p: np.ndarray) -> float:
        return float(p @ self.Q[1] @ p + self.g[1] @ p + self.c[1])

    def convective(self, p: np.ndarray, v: np.ndarray) -> float:
        return float(2.0 * v @ self.Q[0] @ v + 2.0 * (2.0 * self.Q[1] @ p + self.g[1]) @ v
                     + p @ self.Q[2] @ p + self.g[2] @ p + self.c[2])


class EndEffectorConstraint(ABC):
    """One scalar holonomic constraint Phi(p, t) = 0, quadric in the end-effector position p [m]."""

    @abstractmethod
    def quadric(self, t: float) -> Quadric:
        """Coefficients of Phi at time t with their first and second time derivatives."""


@dataclass(frozen=True)
class EllipseXY(EndEffectorConstraint):
    """(5.1): Phi_1 = (x / a)^2 + (y / b)^2 - 1 with semi-axes a(t), b(t) [m] (constant in the paper,
    blended when re-targeted); the ellipse is centred on the world z axis."""

    a: Profile
    b: Profile

    @staticmethod
    def _inverse_square(profile: Profile, t: float) -> np.ndarray:
        """1/a^2 and its first two time derivatives."""
        a, da, dda = profile(t)
        return np.array([a**-2, -2.0 * da / a**3, -2.0 * dda / a**3 + 6.0 * da**2 / a**4])

    def quadric(self, t: float) -> Quadric:
        Q = np.zeros((3, 3, 3))
        Q[:, 0, 0] = self._inverse_square(self.a, t)
        Q[:, 1, 1] = self._inverse_square(self.b, t)
        return Quadric(Q, np.zeros((3, 3)), np.array([-1.0, 0.0, 0.0]))


@dataclass(frozen=True)
class HeightZ(EndEffectorConstraint):
    """(5.2): Phi_2 = z_E - z_E,a(t) [m]."""

    z: Profile

    def quadric(self, t: float) -> Quadric:
        g = np.zeros((3, 3))
        g[0, 2] = 1.0
        return Quadric(np.zeros((3, 3, 3)), g, -np.array(self.z(t)))


@dataclass(frozen=True)
class ConstraintCoefficients:
    """The quadrics of a constraint set at one time, stacked for the compiled solver:
    Q (m, 3, 3, 3), g (m, 3, 3), c (m, 3) (second axis: value, first, second time derivative)."""

    Q: np.ndarray
    g: np.ndarray
    c: np.ndarray


@dataclass(frozen=True)
class ConstraintTerms:
    """Stacked constraint quantities at one state, in generalized coordinates:
    residual Phi (m,), A = Phi_q = Phi_p C (m, n), velocity equation A qd = b, acceleration equation
    A qdd = c; ``gradients`` Phi_p (m, 3) for the distance of E from each constraint surface."""

    residual: np.ndarray
    gradients: np.ndarray
    A: np.ndarray
    b: np.ndarray
    c: np.ndarray

    @property
    def distance(self) -> np.ndarray:
        """First-order distance of E from each constraint surface, |Phi| / |Phi_p| [m]."""
        return np.abs(self.residual) / np.linalg.norm(self.gradients, axis=1)


@dataclass(frozen=True)
class ConstraintSet:
    """The programmed constraints imposed together (the paper: ellipse and height)."""

    constraints: tuple[EndEffectorConstraint, ...]

    @property
    def size(self) -> int:
        return len(self.constraints)

    def coefficients(self, t: float) -> ConstraintCoefficients:
        quadrics = [c.quadric(t) for c in self.constraints]
        return ConstraintCoefficients(np.array([q.Q for q in quadrics]), np.array([q.g for q in quadrics]),
                                      np.array([q.c for q in quadrics]))

    def residual(self, t: float, p: np.ndarray) -> np.ndarray:
        return np.array([c.quadric(t).residual(p) for c in self.constraints])

    def position_jacobian(self, t: float, p: np.ndarray) -> np.ndarray:
        """Phi_p stacked (m, 3)."""
        return np.array([c.quadric(t).gradient(p) for c in self.constraints])


def paper_constraints(a: Profile, b: Profile, z: Profile) -> ConstraintSet:
    """The paper's pair: ellipse (5.1) and height (5.2)."""
    return ConstraintSet((EllipseXY(a, b), HeightZ(z)))

"""Programmed (task) constraints on the end-effector E, eqs. (5.1)-(5.2) and (6.1)-(6.4).

A constraint is written on E's world position p = J T^(4) r_E (eq. (5)) and time, Phi(p, t) = 0.
With p' = C qd and p'' = C qdd + d (C, d from :mod:`crane_reference.kinematics`) its derivatives are

    dPhi/dt   = Phi_p C qd + Phi_t = 0                                    (6.1), (6.2)
    d2Phi/dt2 = Phi_p (C qdd + d) + p'^T Phi_pp p' + 2 Phi_pt p' + Phi_tt = 0    (6.3), (6.4)

so each constraint supplies its residual Phi, Jacobian Phi_p, explicit time term Phi_t and convective
term ``convective = p'^T Phi_pp p' + 2 Phi_pt p' + Phi_tt``.  The solver in
:mod:`crane_reference.programmed_motion` only sees these four quantities, so another task constraint
is a new subclass of :class:`EndEffectorConstraint`; nothing in the solver changes.

For the ellipse, the paper's u and v are Phi_p C / 2 and (Phi_p d + convective) / 2: it divides (6.3)
by two, which does not change the motion (only the scale of the multiplier).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from .profiles import Profile


class EndEffectorConstraint(ABC):
    """One scalar holonomic constraint Phi(p, t) = 0 on the end-effector position p [m]."""

    @abstractmethod
    def residual(self, t: float, p: np.ndarray) -> float:
        """Phi(p, t)."""

    @abstractmethod
    def gradient(self, t: float, p: np.ndarray) -> np.ndarray:
        """Phi_p (3,)."""

    @abstractmethod
    def time_derivative(self, t: float, p: np.ndarray) -> float:
        """Phi_t (the explicit time dependence)."""

    @abstractmethod
    def convective(self, t: float, p: np.ndarray, v: np.ndarray) -> float:
        """v^T Phi_pp v + 2 Phi_pt v + Phi_tt with v = p'."""


@dataclass(frozen=True)
class EllipseXY(EndEffectorConstraint):
    """(5.1): Phi_1 = (x / a)^2 + (y / b)^2 - 1 with semi-axes a(t), b(t) [m] (constant in the paper,
    blended when re-targeted); the ellipse is centred on the world z axis."""

    a: Profile
    b: Profile

    def residual(self, t: float, p: np.ndarray) -> float:
        a, b = self.a(t)[0], self.b(t)[0]
        return (p[0] / a) ** 2 + (p[1] / b) ** 2 - 1.0

    def gradient(self, t: float, p: np.ndarray) -> np.ndarray:
        a, b = self.a(t)[0], self.b(t)[0]
        return np.array([2.0 * p[0] / a**2, 2.0 * p[1] / b**2, 0.0])

    def time_derivative(self, t: float, p: np.ndarray) -> float:
        (a, da, _), (b, db, _) = self.a(t), self.b(t)
        return -2.0 * p[0] ** 2 * da / a**3 - 2.0 * p[1] ** 2 * db / b**3

    def convective(self, t: float, p: np.ndarray, v: np.ndarray) -> float:
        (a, da, dda), (b, db, ddb) = self.a(t), self.b(t)
        quadratic = 2.0 * v[0] ** 2 / a**2 + 2.0 * v[1] ** 2 / b**2
        mixed = -8.0 * p[0] * v[0] * da / a**3 - 8.0 * p[1] * v[1] * db / b**3
        explicit = (-2.0 * p[0] ** 2 * (dda / a**3 - 3.0 * da**2 / a**4)
                    - 2.0 * p[1] ** 2 * (ddb / b**3 - 3.0 * db**2 / b**4))
        return quadratic + mixed + explicit


@dataclass(frozen=True)
class HeightZ(EndEffectorConstraint):
    """(5.2): Phi_2 = z_E - z_E,a(t) [m]."""

    z: Profile

    def residual(self, t: float, p: np.ndarray) -> float:
        return p[2] - self.z(t)[0]

    def gradient(self, t: float, p: np.ndarray) -> np.ndarray:
        return np.array([0.0, 0.0, 1.0])

    def time_derivative(self, t: float, p: np.ndarray) -> float:
        return -self.z(t)[1]

    def convective(self, t: float, p: np.ndarray, v: np.ndarray) -> float:
        return -self.z(t)[2]


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

    def residual(self, t: float, p: np.ndarray) -> np.ndarray:
        return np.array([c.residual(t, p) for c in self.constraints])

    def position_jacobian(self, t: float, p: np.ndarray) -> np.ndarray:
        """Phi_p stacked (m, 3)."""
        return np.array([c.gradient(t, p) for c in self.constraints])

    def terms(self, t: float, p: np.ndarray, C: np.ndarray, d: np.ndarray, qd: np.ndarray) -> ConstraintTerms:
        """Phi, A = Phi_p C, b = -Phi_t and c = -(Phi_p d + convective) at one state."""
        v = C @ qd
        grads = self.position_jacobian(t, p)
        residual = self.residual(t, p)
        b = -np.array([c.time_derivative(t, p) for c in self.constraints])
        c = -(grads @ d) - np.array([con.convective(t, p, v) for con in self.constraints])
        return ConstraintTerms(residual, grads, grads @ C, b, c)


def paper_constraints(a: Profile, b: Profile, z: Profile) -> ConstraintSet:
    """The paper's pair: ellipse (5.1) and height (5.2)."""
    return ConstraintSet((EllipseXY(a, b), HeightZ(z)))

"""Programmed (task) constraints on the end-effector E, eqs. (5.1)-(5.2) and (6.1)-(6.4).

A constraint is written on E's world position p = J T^(4) r_E (eq. (5)) and time.  Every constraint
here is a quadric in p with time-dependent coefficients,

    Phi(p, t) = p^T Q(t) p + g(t)^T p + c(t)        (Q symmetric),

which covers the paper's ellipse (5.1) and height (5.2) as well as planes, spheres, cylinders and
other surfaces.  With p' = C qd and p'' = C qdd + d (C, d from :mod:`crane_reference.dynamics.kinematics`)

    dPhi/dt   = Phi_p C qd + Phi_t = 0                                     (6.1), (6.2)
    d2Phi/dt2 = Phi_p (C qdd + d) + convective = 0                         (6.3), (6.4)
    Phi_p = 2 Q p + g,   Phi_t = p^T Q' p + g'^T p + c',
    convective = p'^T 2Q p' + 2 (2 Q' p + g')^T p' + p^T Q'' p + g''^T p + c''.

First-order (velocity) task constraints are quadrics in z = (p, p') [m, m/s],

    Psi(p, p', t) = z^T Q(t) z + g(t)^T z + c(t)        (Q symmetric, 6 x 6),

e.g. a prescribed areal rate of E about the column axis, x y' - y x' = r(t) (:class:`ArealRate`).
Their velocity form is Psi = 0 itself, and their acceleration form

    dPsi/dt = Psi_v (C qdd + d) + Psi_p p' + Psi_t = 0,
    (Psi_p, Psi_v) = 2 Q z + g,   Psi_t = z^T Q' z + g'^T z + c'.

A new task constraint is a new :class:`EndEffectorConstraint` (holonomic: writes the coefficients of
a :class:`Quadric` with their first two time derivatives) or :class:`EndEffectorRateConstraint` (first
order: a :class:`RateQuadric` with its first time derivative); the solver (compiled,
:mod:`crane_reference.dynamics.evaluation` and :mod:`~crane_reference.dynamics.step`) does not change.  The
formulas above are implemented once, in
:mod:`crane_reference.dynamics.quadrics`; the methods here call them.
For the ellipse, the paper's u and v are Phi_p C / 2 and (Phi_p d + convective) / 2: it divides (6.3)
by two, which changes only the scale of the multiplier.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..dynamics import quadrics
from ..dynamics.structures import Coefficients
from ..model.profiles import Profile


def _vector(x: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=float)


@dataclass(frozen=True)
class Quadric:
    """Coefficients of Phi = p^T Q p + g^T p + c and their time derivatives: index 0 value, 1 first,
    2 second derivative (Q: (3, 3, 3), g: (3, 3), c: (3,))."""

    Q: np.ndarray
    g: np.ndarray
    c: np.ndarray

    def residual(self, p: np.ndarray) -> float:
        """Phi at p."""
        return float(quadrics.holonomic_value(self.Q, self.g, self.c, _vector(p))[0])

    def gradient(self, p: np.ndarray) -> np.ndarray:
        """Phi_p at p."""
        return quadrics.holonomic_value(self.Q, self.g, self.c, _vector(p))[1]

    def time_derivative(self, p: np.ndarray) -> float:
        """Phi_t at p (dPhi/dt at rest)."""
        return float(quadrics.holonomic_rate(self.Q, self.g, self.c, _vector(p), np.zeros(3))[0])

    def convective(self, p: np.ndarray, v: np.ndarray) -> float:
        """The convective part of d2Phi/dt2 at (p, v) (d2Phi/dt2 with zero acceleration)."""
        return -float(quadrics.holonomic_acceleration(self.Q, self.g, self.c, _vector(p), _vector(v),
                                                      np.zeros(3))[1])


@dataclass(frozen=True)
class RateQuadric:
    """Coefficients of Psi = z^T Q z + g^T z + c in z = (p, p') and their first time derivative: index 0
    value, 1 first derivative (Q: (2, 6, 6), g: (2, 6), c: (2,))."""

    Q: np.ndarray
    g: np.ndarray
    c: np.ndarray

    def residual(self, p: np.ndarray, v: np.ndarray) -> float:
        """Psi at (p, v)."""
        return float(quadrics.rate_value(self.Q, self.g, self.c, _vector(p), _vector(v))[0])


class EndEffectorConstraint(ABC):
    """One scalar holonomic constraint Phi(p, t) = 0, quadric in the end-effector position p [m]."""

    order = 0

    @abstractmethod
    def write(self, t: float | np.ndarray, Q: np.ndarray, g: np.ndarray, c: np.ndarray) -> None:
        """Write the coefficients of Phi at time t with their first and second time derivatives into
        zeroed arrays Q (..., 3, 3, 3), g (..., 3, 3), c (..., 3) (layout of :class:`Quadric`; the leading
        axes, if any, are those of an array of times t)."""

    def quadric(self, t: float) -> Quadric:
        Q, g, c = np.zeros((3, 3, 3)), np.zeros((3, 3)), np.zeros(3)
        self.write(t, Q, g, c)
        return Quadric(Q, g, c)


class EndEffectorRateConstraint(ABC):
    """One scalar first-order constraint Psi(p, p', t) = 0, quadric in E's position and velocity."""

    order = 1

    @abstractmethod
    def write(self, t: float | np.ndarray, Q: np.ndarray, g: np.ndarray, c: np.ndarray) -> None:
        """Write the coefficients of Psi at time t with their first time derivative into zeroed arrays
        Q (..., 2, 6, 6), g (..., 2, 6), c (..., 2) (layout of :class:`RateQuadric`; leading axes as in
        :meth:`EndEffectorConstraint.write`)."""

    def quadric(self, t: float) -> RateQuadric:
        Q, g, c = np.zeros((2, 6, 6)), np.zeros((2, 6)), np.zeros(2)
        self.write(t, Q, g, c)
        return RateQuadric(Q, g, c)


@dataclass(frozen=True)
class EllipseXY(EndEffectorConstraint):
    """(5.1): Phi_1 = (x / a)^2 + (y / b)^2 - 1 with semi-axes a(t), b(t) [m] (constant in the paper,
    blended when re-targeted); the ellipse is centred on the world z axis."""

    a: Profile
    b: Profile

    @staticmethod
    def _inverse_square(profile: Profile, t: float | np.ndarray) -> tuple:
        """1/a^2 and its first two time derivatives."""
        a, da, dda = profile(t)
        return a**-2, -2.0 * da / a**3, -2.0 * dda / a**3 + 6.0 * da**2 / a**4

    def write(self, t: float | np.ndarray, Q: np.ndarray, g: np.ndarray, c: np.ndarray) -> None:
        Q[..., 0, 0, 0], Q[..., 1, 0, 0], Q[..., 2, 0, 0] = self._inverse_square(self.a, t)
        Q[..., 0, 1, 1], Q[..., 1, 1, 1], Q[..., 2, 1, 1] = self._inverse_square(self.b, t)
        c[..., 0] = -1.0


@dataclass(frozen=True)
class HeightZ(EndEffectorConstraint):
    """(5.2): Phi_2 = z_E - z_E,a(t) [m]."""

    z: Profile

    def write(self, t: float | np.ndarray, Q: np.ndarray, g: np.ndarray, c: np.ndarray) -> None:
        g[..., 0, 2] = 1.0
        z, dz, ddz = self.z(t)
        c[..., 0], c[..., 1], c[..., 2] = -z, -dz, -ddz


@dataclass(frozen=True)
class ArealRate(EndEffectorRateConstraint):
    """Psi = x y' - y x' - r(t) [m^2/s]: twice the areal velocity of E's horizontal projection about
    the world z axis (the column axis) is prescribed.  On an ellipse x = a cos(theta), y = b sin(theta)
    with constant axes, x y' - y x' = a b theta', so r = a b omega(t) makes E run along the ellipse with
    the parametric angle rate omega(t) (a prescribed speed along the path)."""

    rate: Profile

    def write(self, t: float | np.ndarray, Q: np.ndarray, g: np.ndarray, c: np.ndarray) -> None:
        Q[..., 0, 0, 4] = Q[..., 0, 4, 0] = 0.5  # x y'
        Q[..., 0, 1, 3] = Q[..., 0, 3, 1] = -0.5  # -y x'
        r, dr, _ = self.rate(t)
        c[..., 0], c[..., 1] = -r, -dr


@dataclass(frozen=True)
class ConstraintTerms:
    """Stacked constraint quantities at one state, in generalized coordinates: ``residual`` Phi
    (holonomic rows) or Psi (first-order rows); ``gradients`` Phi_p or Psi_v (m, 3), the direction in
    which each row constrains E; the velocity-level Jacobian A = gradients C (m, n); the acceleration
    equation A qdd = c; ``distance`` |residual| / |gradients|, E's first-order distance from the
    constraint surface [m] (holonomic) or velocity error [m/s] (first order); ``velocity_residual``
    dPhi/dt (holonomic) or Psi (first order), zero on a consistent state."""

    residual: np.ndarray
    gradients: np.ndarray
    A: np.ndarray
    c: np.ndarray
    distance: np.ndarray
    velocity_residual: np.ndarray


@dataclass(frozen=True)
class ConstraintSet:
    """The programmed constraints imposed together (the paper: ellipse and height)."""

    constraints: tuple[EndEffectorConstraint | EndEffectorRateConstraint, ...]

    @property
    def size(self) -> int:
        return len(self.constraints)

    @cached_property
    def orders(self) -> np.ndarray:
        """0 for a holonomic, 1 for a first-order constraint, per row."""
        return np.array([c.order for c in self.constraints], dtype=np.int64)

    def coefficients_at(self, times: np.ndarray) -> Coefficients:
        """The coefficients (:class:`~crane_reference.dynamics.structures.Coefficients`) at each of ``times``,
        stacked on a leading axis: Q (N, m, 3, 6, 6) etc."""
        times = np.asarray(times, dtype=float)
        return self._coefficients(times, (times.size,))

    def coefficients(self, t: float) -> Coefficients:
        """The coefficients at time t (Q (m, 3, 6, 6) etc.)."""
        return self._coefficients(t, ())

    def _coefficients(self, t: float | np.ndarray, leading: tuple[int, ...]) -> Coefficients:
        m = self.size
        Q, g, c = np.zeros((*leading, m, 3, 6, 6)), np.zeros((*leading, m, 3, 6)), np.zeros((*leading, m, 3))
        for i, constraint in enumerate(self.constraints):
            if constraint.order == 0:
                constraint.write(t, Q[..., i, :, :3, :3], g[..., i, :, :3], c[..., i, :])
            else:
                constraint.write(t, Q[..., i, :2, :, :], g[..., i, :2, :], c[..., i, :2])
        return Coefficients(Q, g, c, self.orders)

    def _holonomic(self) -> tuple[EndEffectorConstraint, ...]:
        if any(c.order != 0 for c in self.constraints):
            raise TypeError("position residuals and Phi_p are defined for holonomic constraints only")
        return self.constraints

    def residual(self, t: float, p: np.ndarray) -> np.ndarray:
        """Phi(p, t) stacked (m,) (holonomic constraints)."""
        return np.array([c.quadric(t).residual(p) for c in self._holonomic()])

    def surface_offsets(self, times: np.ndarray, positions: np.ndarray) -> np.ndarray:
        """Phi / |Phi_p| (N, m) [m] at E's positions (N, 3) at ``times`` (N,) [s]: E's signed distance to each
        constraint's surface, to first order in Phi (holonomic constraints)."""
        self._holonomic()
        return quadrics.surface_offsets(np.ascontiguousarray(positions, dtype=float), self.coefficients_at(times))

    def position_jacobian(self, t: float, p: np.ndarray) -> np.ndarray:
        """Phi_p stacked (m, 3) (holonomic constraints)."""
        return np.array([c.quadric(t).gradient(p) for c in self._holonomic()])


def paper_constraints(a: Profile, b: Profile, z: Profile) -> ConstraintSet:
    """The paper's pair: ellipse (5.1) and height (5.2)."""
    return ConstraintSet((EllipseXY(a, b), HeightZ(z)))

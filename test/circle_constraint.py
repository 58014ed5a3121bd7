"""A constraint for tests: E on the circle x^2 + z^2 = R^2 (analytic linearisations are known)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from crane_reference.constraints import EndEffectorConstraint, Quadric


@dataclass(frozen=True)
class CircleXZ(EndEffectorConstraint):
    """x^2 + z^2 - R^2 = 0."""

    radius: float

    def quadric(self, t: float) -> Quadric:
        Q = np.zeros((3, 3, 3))
        Q[0] = np.diag([1.0, 0.0, 1.0])
        return Quadric(Q, np.zeros((3, 3)), np.array([-self.radius**2, 0.0, 0.0]))

"""A constraint for tests: E on the circle x^2 + z^2 = R^2 (analytic linearisations are known)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from crane_reference.motion.constraints import EndEffectorConstraint


@dataclass(frozen=True)
class CircleXZ(EndEffectorConstraint):
    """x^2 + z^2 - R^2 = 0."""

    radius: float

    def write(self, t: float | np.ndarray, Q: np.ndarray, g: np.ndarray, c: np.ndarray) -> None:
        Q[..., 0, :, :] = np.diag([1.0, 0.0, 1.0])
        c[..., 0] = -self.radius**2

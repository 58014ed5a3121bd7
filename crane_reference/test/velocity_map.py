"""A random velocity map B of eq. (7) (the kernels' tests of linear algebra against numpy)."""

from __future__ import annotations

import numpy as np


def random_velocity_map(rng: np.random.Generator, n: int, dependent: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """B of eq. (7) for a random Gamma: identity rows on ic, Gamma on dc; and the independent coordinates."""
    independent = np.array([k for k in range(n) if k not in dependent])
    B = np.zeros((n, independent.size))
    B[independent, np.arange(independent.size)] = 1.0
    B[dependent] = rng.normal(size=(dependent.size, independent.size))
    return B, independent

"""The kernels' small linear algebra against numpy's dense products and reductions."""

from __future__ import annotations

import numpy as np
from velocity_map import random_velocity_map

from crane_reference.dynamics.linalg import congruent, largest_magnitude, map_columns, project_rows


def test_congruent_is_the_dense_product_and_symmetric():
    """B^T X B without forming B equals numpy's dense B.T @ X @ B (dependent coordinates anywhere in q), and is
    exactly symmetric."""
    rng = np.random.default_rng(3)
    for n, dependent in ((24, np.array([7, 23])), (9, np.array([0, 4, 8])), (5, np.array([], dtype=np.int64))):
        X = rng.normal(size=(n, n))
        X = X + X.T
        B, independent = random_velocity_map(rng, n, dependent)
        reduced = congruent(X, B, independent, dependent)
        np.testing.assert_allclose(reduced, B.T @ X @ B, rtol=1e-12, atol=1e-12 * np.abs(X).max())
        np.testing.assert_array_equal(reduced, reduced.T)


def test_rows_and_columns_mapped_without_b_are_the_dense_products():
    """P^T X (P = B, or E_ic for servo-constraints) and Y B without forming B equal numpy's dense products."""
    rng = np.random.default_rng(4)
    n, dependent = 24, np.array([7, 23])
    B, independent = random_velocity_map(rng, n, dependent)
    X, Y = rng.normal(size=(n, 3)), rng.normal(size=(4, n))
    np.testing.assert_allclose(project_rows(X, B, independent, dependent, False), B.T @ X, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(project_rows(X, B, independent, dependent, True), X[independent])
    np.testing.assert_allclose(map_columns(Y, B, independent, dependent), Y @ B, rtol=1e-12, atol=1e-12)


def test_the_largest_magnitude_is_numpys_also_with_a_nan_anywhere():
    """max |x_i| as numpy's max gives it: NaN wherever a NaN stands (a NaN Newton correction or projection step
    must meet no tolerance), inf with an inf, 0 for no entries."""
    rng = np.random.default_rng(5)
    for special in (np.nan, np.inf, -np.inf):
        for where in range(4):
            x = rng.normal(size=4)
            x[where] = special
            np.testing.assert_array_equal(largest_magnitude(x), np.max(np.abs(x)))
    x = rng.normal(size=6)
    assert largest_magnitude(x) == np.max(np.abs(x)) and largest_magnitude(np.empty(0)) == 0.0

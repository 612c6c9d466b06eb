"""1D Haar wavelets (pipeline/math/haar.py): exact round trips, orthonormality, the
L2-optimal truncation and the sparse products the d2i renderer takes."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.math import haar


@pytest.mark.parametrize("n", [1, 2, 5, 64, 1000])
def test_round_trip_is_exact_without_truncation(n):
    rows = np.random.default_rng(n).normal(size=(3, n))
    coefficients = haar.forward(rows)
    assert coefficients.shape == (3, haar.padded_length(n))
    # float64 arithmetic: exact up to rounding of log2(N) butterfly levels
    np.testing.assert_allclose(haar.inverse(coefficients, n), rows, rtol=0, atol=1e-13)


def test_transform_is_orthonormal_so_dot_products_survive():
    rng = np.random.default_rng(1)
    t, light = rng.normal(size=(4, 300)), rng.normal(size=300)
    np.testing.assert_allclose(haar.forward(t) @ haar.forward(light), t @ light, rtol=1e-12)
    basis = haar.forward(np.eye(16))
    np.testing.assert_allclose(basis @ basis.T, np.eye(16), atol=1e-15)


def test_coefficient_layout_coarse_to_fine():
    # a constant row has only the scaling coefficient; a step at the middle only the
    # coarsest wavelet
    np.testing.assert_allclose(haar.forward(np.ones(8)), [np.sqrt(8), 0, 0, 0, 0, 0, 0, 0],
                               atol=1e-15)
    step = np.r_[np.ones(4), -np.ones(4)]
    np.testing.assert_allclose(haar.forward(step), [0, np.sqrt(8), 0, 0, 0, 0, 0, 0],
                               atol=1e-15)


def test_largest_keeps_the_biggest_and_the_error_is_the_dropped_energy():
    rng = np.random.default_rng(2)
    rows = np.cumsum(rng.normal(size=(5, 256)), axis=1)  # smooth-ish rows
    w = haar.forward(rows)
    idx, val = haar.largest(w, 20)
    assert idx.shape == val.shape == (5, 20)
    assert np.all(np.diff(idx, axis=1) > 0)
    kept = np.zeros_like(w)
    np.put_along_axis(kept, idx, val, axis=1)
    smallest_kept = np.min(np.abs(val), axis=1)
    dropped = np.abs(w - kept)
    assert np.all(dropped.max(axis=1) <= smallest_kept)
    error = np.linalg.norm(haar.inverse(kept, 256) - rows, axis=1)
    np.testing.assert_allclose(error, np.linalg.norm(w - kept, axis=1), rtol=1e-10)


def test_count_for_energy_meets_the_tolerance_with_the_fewest_coefficients():
    rows = np.cumsum(np.random.default_rng(3).normal(size=(6, 512)), axis=1)
    w = haar.forward(rows)
    for tolerance in (0.3, 0.05, 0.01):
        counts = haar.count_for_energy(w, tolerance)
        for row, count in zip(w, counts, strict=True):
            for c, should_pass in ((count, True), (count - 1, False)):
                idx, val = haar.largest(row[None], c)
                rest = np.linalg.norm(row) ** 2 - np.sum(val ** 2)
                assert (np.sqrt(max(rest, 0)) <= tolerance * np.linalg.norm(row)) == should_pass
    assert haar.count_for_energy(np.zeros((1, 8)), 0.1)[0] == 0


def test_sparse_dot_matches_the_dense_product_for_rgb_and_scalar_vectors():
    rng = np.random.default_rng(4)
    rows, light = rng.normal(size=(7, 100)), rng.normal(size=(100, 3))
    w, lw = haar.forward(rows), haar.forward(light.T).T
    idx, val = haar.largest(w, w.shape[1])
    np.testing.assert_allclose(haar.sparse_dot(idx, val, lw), rows @ light, rtol=1e-10)
    np.testing.assert_allclose(haar.sparse_dot(idx, val, lw[:, 0]), rows @ light[:, 0],
                               rtol=1e-10)

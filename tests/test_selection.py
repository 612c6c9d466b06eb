"""pipeline.math.selection: the k smallest keys per row by one partition are exactly the
first k of a stable sort (the rows that the bake's compression and the pooled cut keep)."""

from __future__ import annotations

import numpy as np

from pipeline.math import haar
from pipeline.math.selection import largest_magnitudes, order_by_magnitude, smallest_per_row


def test_smallest_per_row_is_the_head_of_a_stable_sort():
    """On keys with many ties (8 distinct values, as the pooled cut's ranks have at its
    boundary), at every kind of k: the same positions as a stable argsort's first k,
    ascending."""
    key = np.random.default_rng(5).integers(0, 8, size=(6, 1000)).astype(np.int64) << 31
    for k in (0, 1, 37, 500, 999, 1000, 1200):
        expected = np.sort(np.argsort(key, axis=1, kind="stable")[:, :k], axis=1)
        np.testing.assert_array_equal(smallest_per_row(key, k), expected)


def test_long_rows_select_through_candidates_exactly_also_when_the_sample_misleads():
    """Rows 16 k long and more take the sampled-threshold path; whatever the sample
    shows, the result is the stable sort's head: random keys, ties at the cut, rows of
    one value (too many candidates), the smallest keys all on sampled positions (too
    few) or all off them, and a row with a key equal to the padding value."""
    rng = np.random.default_rng(9)
    n, k = 4096, 100
    key = rng.integers(-1000, 1000, size=(7, n)).astype(np.int32)
    key[1] = 5
    key[2] = rng.integers(0, 1 << 20, n)
    key[2, ::16] = -rng.integers(1, 1 << 20, n // 16)   # the sample holds the smallest
    key[3] = rng.integers(0, 1 << 20, n)
    key[3, 1::16] = -rng.integers(1, 1 << 20, n // 16)  # the sample misses them
    key[4, :300] = -5000                                # ties across the cut
    key[5, -3:] = np.iinfo(np.int32).max
    key[6] = rng.integers(0, 3, n)
    for kk in (k, 256):
        expected = np.sort(np.argsort(key, axis=1, kind="stable")[:, :kk], axis=1)
        np.testing.assert_array_equal(smallest_per_row(key, kk), expected)


def test_largest_magnitudes_order_floats_by_value_through_their_bits():
    """Signs, +0 and −0, subnormals, equal magnitudes of both signs: the positions are
    those of a stable sort by descending |value|, in float32 and float64."""
    for dtype in (np.float32, np.float64):
        tiny = np.finfo(dtype).smallest_subnormal
        row = np.array([0.0, -0.0, 3.0, -3.0, tiny, -2 * tiny, 1e-3, -1e3, 3.0, 0.5],
                       dtype)
        rows = np.stack([row, row[::-1], np.zeros_like(row)])
        for k in range(len(row) + 1):
            expected = np.sort(np.argsort(-np.abs(rows), axis=1, kind="stable")[:, :k],
                               axis=1)
            np.testing.assert_array_equal(largest_magnitudes(rows, k), expected)
        assert rows[0, 1] == 0 and np.signbit(rows[0, 1])  # the input is not touched


def test_truncate_takes_equal_coefficients_by_index():
    """A row of equal magnitudes cut to a cap keeps its first ``cap`` coefficients (the
    choice among ties is defined, so a bake's rows do not depend on NumPy's
    partition)."""
    coefficients = np.tile(np.array([1.0, -1.0, 0.0, 1.0], np.float32), (2, 8))
    result = haar.truncate(coefficients, 0.0, 5)
    np.testing.assert_array_equal(result["index"].reshape(2, 5), [[0, 1, 3, 4, 5]] * 2)
    np.testing.assert_array_equal(result["value"].reshape(2, 5), [[1, -1, 1, 1, -1]] * 2)


def test_order_by_magnitude_is_a_stable_sort_of_the_magnitudes():
    """Rows with ties (rounded values, ± of one magnitude), zeros of both signs and
    subnormals: float32 (the int64-key sort) and float64 (the stable argsort) give the
    positions of a stable sort by descending |value|."""
    rng = np.random.default_rng(11)
    x = rng.standard_normal((40, 600)) * np.exp(3 * rng.standard_normal((40, 600)))
    x[:, ::5] = np.round(x[:, ::5])
    x[rng.random(x.shape) < 0.3] = -0.0
    x[3] = np.finfo(np.float32).smallest_subnormal * rng.integers(-2, 3, 600)
    for dtype in (np.float32, np.float64):
        values = x.astype(dtype)
        top = largest_magnitudes(values, 250)
        expected = np.take_along_axis(
            top, np.argsort(-np.abs(np.take_along_axis(values, top, 1)), axis=1,
                            kind="stable"), axis=1)
        got = order_by_magnitude(np.take_along_axis(values, top, 1), top)
        np.testing.assert_array_equal(got, expected)

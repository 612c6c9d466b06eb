"""pipeline.math.selection: the k smallest keys per row by one partition are exactly the
first k of a stable sort (the rows that the bake's compression and the pooled cut keep)."""

from __future__ import annotations

import numpy as np

from pipeline.math import haar
from pipeline.math.selection import largest_magnitudes, smallest_per_row


def test_smallest_per_row_is_the_head_of_a_stable_sort():
    """On keys with many ties (8 distinct values, as the pooled cut's ranks have at its
    boundary), at every kind of k: the same positions as a stable argsort's first k,
    ascending."""
    key = np.random.default_rng(5).integers(0, 8, size=(6, 1000)).astype(np.int64) << 31
    for k in (0, 1, 37, 500, 999, 1000, 1200):
        expected = np.sort(np.argsort(key, axis=1, kind="stable")[:, :k], axis=1)
        np.testing.assert_array_equal(smallest_per_row(key, k), expected)


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

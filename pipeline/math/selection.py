"""Selection of the k smallest keys per row in linear time — the first k of a stable
sort, without the sort.

A stable sort by key keeps equal keys in position order, so its first k entries are
every key below the k-th smallest key ``last`` and, of the keys equal to ``last``, the
first ones by position until k are taken. One partition finds ``last``; a comparison
and one pass over the row find the rest. NumPy's ``argpartition`` would find a set of k
smallest too, but it breaks ties arbitrarily and returns an index array as large as
the input (8 bytes per entry); the partition of the keys alone moves half the bytes.

Magnitudes select through their bit patterns: for floats ≥ 0 (+0, subnormals and
normals alike) the IEEE bit pattern read as a signed integer of the same width orders
exactly as the value, so ``−bits`` is a key whose smallest are the largest magnitudes.
"""

from __future__ import annotations

import numpy as np


def smallest_per_row(key: np.ndarray, k: int) -> np.ndarray:
    """Positions (rows, k), ascending within each row, of the ``k`` smallest entries of
    each row of ``key`` (rows, n) (integers; 0 ≤ k ≤ n), equal keys taken by position:
    the set a stable argsort's first ``k`` columns hold."""
    rows, n = key.shape
    if k >= n:
        return np.broadcast_to(np.arange(n), (rows, n)).copy()
    if k <= 0 or rows == 0:
        return np.zeros((rows, 0), np.int64)
    last = np.partition(key, k - 1, axis=1)[:, k - 1:k]
    keep = key <= last
    over = np.flatnonzero(np.count_nonzero(keep, axis=1) > k)  # rows with ties at last
    if len(over):
        tied = key[over] == last[over]
        room = k - np.count_nonzero(key[over] < last[over], axis=1)
        keep[over] &= ~tied | (np.cumsum(tied, axis=1) <= room[:, None])
    return (np.flatnonzero(keep) % n).reshape(rows, k)  # row-major: ascending per row


def largest_magnitudes(values: np.ndarray, k: int) -> np.ndarray:
    """Positions (rows, k), ascending within each row, of the ``k`` largest |values|
    (rows, n) of each row (float32 or float64, no NaN), equal magnitudes by position."""
    magnitude = np.abs(values)
    bits = magnitude.view(np.dtype(f"i{magnitude.itemsize}"))
    np.negative(bits, out=bits)
    return smallest_per_row(bits, k)

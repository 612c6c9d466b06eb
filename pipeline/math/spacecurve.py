"""Hilbert curves in 2D and 3D, for ordering points so that neighbours in order are
neighbours in space (gather samples: rows of T, D and Ms then vary smoothly
along the gather index and 1D Haar wavelets compress them well).

:func:`chart_order` orders points on surfaces: by group (an object), then by chart (the
axis and sign of the normal's largest component, the six faces of a cube map), then along
the 2D Hilbert curve of the position projected onto that chart's plane. On a planar
surface every run of 4^l consecutive points then fills a square, the footprint a
coarse Haar coefficient stands for; the 3D curve through the scene's box cuts a plane in
slices that it leaves and re-enters. Measured on the Cornell box (64², the same 4096
gathers in both orders, 128 coefficients per row): the median D row keeps a residual of
12.7 % instead of 14.5 %, the 90th percentile 23.8 % instead of 29.5 %.

:func:`hilbert_index` follows Skilling's transpose algorithm ("Programming the Hilbert
curve", AIP Conf. Proc. 707, 2004): consecutive indices always map to cells one step
apart (tested), which the Z-order (Morton) curve does not guarantee.
"""

from __future__ import annotations

import numpy as np


def hilbert_index(cells: np.ndarray, bits: int) -> np.ndarray:
    """Hilbert index (N,) uint64 of integer cells (N, d), d = 2 or 3, each coordinate in
    [0, 2^bits) (bits ≤ 21)."""
    if not 1 <= bits <= 21:
        raise ValueError("bits must lie in [1, 21]")
    x = np.asarray(cells, np.uint64).copy()
    n = x.shape[1]
    q = 1 << (bits - 1)
    while q > 1:  # undo excess work: rotate and reflect each level
        p = np.uint64(q - 1)
        for i in range(n):
            flip = (x[:, i] & np.uint64(q)) != 0
            x[flip, 0] ^= p
            keep = ~flip
            t = (x[keep, 0] ^ x[keep, i]) & p
            x[keep, 0] ^= t
            x[keep, i] ^= t
        q >>= 1
    for i in range(1, n):  # Gray encode
        x[:, i] ^= x[:, i - 1]
    t = np.zeros(len(x), np.uint64)
    q = 1 << (bits - 1)
    while q > 1:
        t[(x[:, n - 1] & np.uint64(q)) != 0] ^= np.uint64(q - 1)
        q >>= 1
    x ^= t[:, None]
    index = np.zeros(len(x), np.uint64)
    for b in range(bits - 1, -1, -1):  # interleave the transposed bits, x[0] first
        for i in range(n):
            index = (index << np.uint64(1)) | ((x[:, i] >> np.uint64(b)) & np.uint64(1))
    return index


def _cells(points: np.ndarray, lo: np.ndarray, extent: float, bits: int) -> np.ndarray:
    scaled = (np.asarray(points, np.float64) - lo) / max(extent, 1e-30) * (1 << bits)
    return np.clip(np.floor(scaled), 0, (1 << bits) - 1).astype(np.uint64)


def chart_order(points: np.ndarray, normals: np.ndarray, group: np.ndarray, lo: np.ndarray,
                hi: np.ndarray, bits: int = 10) -> np.ndarray:
    """Indices that sort surface ``points`` (N, 3) with ``normals`` (N, 3) by ``group``
    (N,), then by normal chart, then along the 2D Hilbert curve in the chart's plane
    (see the module docstring); the box [lo, hi] bounds the points."""
    normals = np.asarray(normals, np.float64)
    axis = np.argmax(np.abs(normals), axis=1)
    chart = 2 * axis + (normals[np.arange(len(axis)), axis] > 0)
    lo = np.asarray(lo, np.float64)
    extent = float(np.max(np.asarray(hi, np.float64) - lo))
    index = np.zeros(len(axis), np.uint64)
    for a in range(3):
        on = axis == a
        plane = np.delete(np.asarray(points, np.float64)[on], a, axis=1)
        index[on] = hilbert_index(_cells(plane, np.delete(lo, a), extent, bits), bits)
    return np.lexsort((index, chart, np.asarray(group)))

"""The 3D Hilbert curve, for ordering points so that neighbours in order are neighbours
in space (gather samples, DESIGN §7: rows of T, D and Ms then vary smoothly along the
gather index and 1D Haar wavelets compress them well).

:func:`hilbert_index` follows Skilling's transpose algorithm ("Programming the Hilbert
curve", AIP Conf. Proc. 707, 2004): consecutive indices always map to cells one step
apart (tested), which the Z-order (Morton) curve does not guarantee.
"""

from __future__ import annotations

import numpy as np


def hilbert_index(cells: np.ndarray, bits: int) -> np.ndarray:
    """Hilbert index (N,) uint64 of integer cells (N, 3), each coordinate in [0, 2^bits)
    (bits ≤ 21)."""
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


def hilbert_order(points: np.ndarray, lo: np.ndarray, hi: np.ndarray, bits: int = 10
                  ) -> np.ndarray:
    """Indices that sort ``points`` (N, 3) along the Hilbert curve through the box
    [lo, hi] (the box's longest side cut into 2^bits cells)."""
    lo = np.asarray(lo, np.float64)
    extent = max(float(np.max(np.asarray(hi, np.float64) - lo)), 1e-30)
    cells = np.clip(np.floor((np.asarray(points, np.float64) - lo) / extent * (1 << bits)),
                    0, (1 << bits) - 1)
    return np.argsort(hilbert_index(cells.astype(np.uint64), bits), kind="stable")

"""Functions on the sphere stored as truncated wavelet rows at bake time (method
triple): the leaf samples their leaf means are taken from, and the selection of the
coefficients each stored row keeps.

**Leaf samples.** A leaf mean of level L with refinement r is the solid-angle-weighted
mean of the function at the centroids of the 4^r leaves of level L + r inside the leaf
(:func:`pipeline.math.sphwavelet.leaf_means`); :func:`leaf_samples` gives those
centroids and their weights, normalised per leaf, for the OpenCL kernels.

**Selection.** A stored row holds the coefficients of C channels (RGB lighting: C = 3;
a BRDF table: C = 1) on one index set. With channel weights w_c (luminance for RGB)
a coefficient's energy is e_i = Σ_c w_c c_ic², and the row's energy E = Σ_i e_i: for
the orthonormal basis, E is the weighted squared L2 norm of the function, and dropping a
set D of coefficients leaves the relative error √(Σ_D e_i / E) (``residual``). A row
keeps

1. every coefficient i < ``keep_first`` with e_i > 0, so that run-time top-only budgets
   up to ``keep_first`` read exactly what the full row holds (320 = levels 0 and 1);
2. of the others, the largest e_i first, as few as leave a residual ≤ ``tolerance``,
   and at most ``budget`` − (the count of step 1) of them.

Ordering by e_i is the L2-optimal choice for the orthonormal basis (it keeps the
fewest coefficients for a tolerance); ties at the threshold are kept in depth-first
order while the row holds fewer than its budget (never more). Energies are
float32 (the stored precision), sorted per row, and the dropped energy is summed from
the smallest entry up, so that rounding stays small against the tolerance. Entries are
sorted by :func:`pipeline.math.sphwavelet.depth_first_keys`, what the triple-product
kernels merge.
"""

from __future__ import annotations

from functools import cache

import numpy as np

from pipeline.math.geodesic import geodesic_levels, locate
from pipeline.math.sphwavelet import depth_first_keys


@cache
def leaf_samples(leaf_level: int, refine: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit sample directions (N · 4^r, 3) and weights (N · 4^r,) of the leaves of level
    ``leaf_level``: the centroids of the level ``leaf_level + refine`` leaves, leaf n's
    at [n · 4^r, (n + 1) · 4^r), weighted by solid angle and normalised to sum to 1 per
    leaf (cached; treat as read-only)."""
    fine = geodesic_levels(leaf_level + refine)[-1]
    areas = fine.areas.reshape(-1, 4 ** refine)
    weights = (areas / areas.sum(axis=1, keepdims=True)).reshape(-1)
    return fine.centroids, weights


@cache
def leaf_permutation(leaf_level: int, signs: tuple[int, int, int]) -> np.ndarray:
    """The leaf (N,) that the reflection diag(``signs``) maps each leaf of level
    ``leaf_level`` to. Every sign change of the coordinates maps the icosahedron's
    vertices (±1, ±t, 0), (0, ±1, ±t), (±t, 0, ±1) onto themselves, and midpoints pushed
    onto the sphere onto midpoints, so it permutes the leaves of every level (and their
    centroids, exactly): a function's leaf means under the reflection are its leaf
    means permuted, f∘M at leaf n = f at leaf perm[n]."""
    centroids = geodesic_levels(leaf_level)[leaf_level].centroids
    perm = locate(centroids * np.asarray(signs, np.float64), leaf_level)
    if not np.array_equal(np.sort(perm), np.arange(len(perm))):
        raise AssertionError(f"reflection {signs} does not permute the leaves")
    return perm


@cache
def depth_first_order(leaf_level: int) -> np.ndarray:
    """Coefficient indices (N,) in depth-first order (cached; treat as read-only)."""
    return np.argsort(depth_first_keys(leaf_level), kind="stable")


def select_rows(coefficients: np.ndarray, leaf_level: int, budget: int, tolerance: float,
                keep_first: int, channel_weights: np.ndarray | None = None
                ) -> dict[str, np.ndarray]:
    """Stored rows of ``coefficients`` (R, C, N) (module docstring): ``count`` (R,)
    int32, ``residual`` (R,) float32 (relative weighted L2 error of what was dropped),
    flat ``index`` uint16 (depth-first order within each row) and ``value`` (nnz, C)
    float32. ``channel_weights`` (C,) default to 1."""
    c = np.asarray(coefficients, np.float32)
    rows, channels, size = c.shape
    w = np.ones(channels) if channel_weights is None else np.asarray(channel_weights)
    energy = np.zeros((rows, size), np.float32)
    for channel in range(channels):
        energy += np.float32(w[channel]) * np.square(c[:, channel])
    total = energy.sum(axis=1, dtype=np.float64)
    head = energy[:, :keep_first] > 0.0
    tail = energy[:, keep_first:]
    ascending = np.sort(tail, axis=1)
    # small[k - 1]: what dropping the k smallest tail entries loses (summed from the
    # smallest up, so float32 keeps its digits where the tolerance is decided)
    small = np.cumsum(ascending, axis=1)
    droppable = np.sum(small <= (tolerance ** 2 * total)[:, None], axis=1)
    need = np.minimum(tail.shape[1] - droppable, np.maximum(budget - head.sum(axis=1), 0))
    at = np.clip(tail.shape[1] - need, 0, max(tail.shape[1] - 1, 0))
    threshold = (np.where(need > 0, ascending[np.arange(rows), at], np.inf)
                 if tail.shape[1] else np.full(rows, np.inf))  # keep_first = N: no tail
    above = tail > threshold[:, None]
    tied = (tail == threshold[:, None]) & (tail > 0.0)
    cap = np.maximum(budget - head.sum(axis=1), 0)
    ties_kept = np.where(need > 0, np.minimum(tied.sum(axis=1), cap - above.sum(axis=1)), 0)
    order = depth_first_order(leaf_level)
    tied_full = np.concatenate([np.zeros_like(head), tied], axis=1)
    tie_rank = np.empty(tied_full.shape, np.int64)  # ties before it in depth-first order
    tie_rank[:, order] = np.cumsum(tied_full[:, order], axis=1) - tied_full[:, order]
    keep = np.concatenate([head, above], axis=1) | (tied_full & (tie_rank < ties_kept[:, None]))
    row_of, position = np.nonzero(keep[:, order])
    index = order[position]
    lost = np.where(keep, 0.0, energy).sum(axis=1, dtype=np.float64)
    residual = np.sqrt(np.divide(lost, total, out=np.zeros(rows), where=total > 0))
    return {"count": keep.sum(axis=1).astype(np.int32),
            "residual": residual.astype(np.float32),
            "index": index.astype(np.uint16),
            "value": np.ascontiguousarray(c[row_of, :, index])}


def rows_to_dense(count: np.ndarray, index: np.ndarray, value: np.ndarray,
                  size: int) -> np.ndarray:
    """The coefficient rows (R, C, N) that stored rows ``count`` (R,), ``index``
    (nnz,), ``value`` (nnz, C) hold (zeros elsewhere)."""
    value = np.asarray(value).reshape(len(index), -1)
    out = np.zeros((len(count), value.shape[1], size))
    row_of = np.repeat(np.arange(len(count)), count)
    out[row_of, :, index.astype(np.int64)] = value
    return out


def to_half(count: np.ndarray, value: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stored values for disk: ``value`` (nnz, C) float32 of rows with ``count`` (R,)
    entries as (value / scale of its row) float16 and ``scale`` (R,) float32, each row's
    largest |value| (1 for a row of zeros). Every stored value is in [−1, 1], so nothing
    overflows float16's 65504 whatever the map's range; rounding to float16's 11-bit
    significand changes a value by ≤ 2^-11 ≈ 4.9e-4 of itself (a row's relative L2
    error ≤ 4.9e-4, against the 1 % store tolerance), below 6.1e-5 of the row's
    largest (subnormals) by ≤ 2^-25 of the row's largest."""
    value = np.asarray(value, np.float32)
    count = np.asarray(count, np.int64)
    flat = np.abs(value).max(axis=tuple(range(1, value.ndim)), initial=0.0)  # (nnz,)
    scale = np.ones(len(count), np.float32)
    filled = count > 0
    starts = np.concatenate([[0], np.cumsum(count)[:-1]])[filled]
    if len(starts):
        peak = np.maximum.reduceat(flat, starts)
        scale[filled] = np.where(peak > 0.0, peak, 1.0)
    factor = np.repeat(scale, count).reshape((-1,) + (1,) * (value.ndim - 1))
    return (value / factor).astype(np.float16), scale


def from_half(count: np.ndarray, value: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """The float32 values (nnz, C) of :func:`to_half`'s ``value`` and ``scale``."""
    value = np.asarray(value)
    factor = np.repeat(np.asarray(scale, np.float32), count)
    return value.astype(np.float32) * factor.reshape((-1,) + (1,) * (value.ndim - 1))

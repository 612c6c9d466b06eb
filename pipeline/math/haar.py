"""1D orthonormal Haar wavelets on rows of transport matrices (paper 000 §3.4).

A row of length n is zero-padded to N = 2^⌈log2 n⌉ and transformed with the orthonormal
Haar filter pair (a, d) = ((x₀ + x₁)/√2, (x₀ − x₁)/√2), level by level, down to a single
scaling coefficient. Layout of the N coefficients (the usual "standard" order):
index 0 is the coarsest scaling coefficient, index 1 the coarsest wavelet, indices
[2^l, 2^(l+1)) the 2^l wavelets of level l, finest last.

Because the transform W is orthonormal, dot products survive it: (W t)·(W l) = t·l.
So the renderer's c(γ)ᵀ T^w L^w equals c(γ)ᵀ T L exactly when nothing is dropped, and
dropping coefficients of a row t errs in t·l by at most ‖t − t̃‖₂ ‖l‖₂, where
‖t − t̃‖₂ is the root of the dropped coefficients' energy: keeping the largest
coefficients is the L2-optimal truncation for every row.
"""

from __future__ import annotations

import numpy as np

_SQRT_HALF = np.sqrt(0.5)


def padded_length(n: int) -> int:
    """N = the smallest power of two ≥ n (n ≥ 1)."""
    return 1 << max(int(n) - 1, 0).bit_length()


def forward(rows: np.ndarray) -> np.ndarray:
    """Haar coefficients (..., N) of ``rows`` (..., n), zero-padded to N."""
    rows = np.asarray(rows)
    n = rows.shape[-1]
    size = padded_length(n)
    out = np.zeros((*rows.shape[:-1], size), np.result_type(rows.dtype, np.float32))
    out[..., :n] = rows
    length = size
    while length > 1:
        even, odd = out[..., 0:length:2], out[..., 1:length:2]
        average, detail = (even + odd) * _SQRT_HALF, (even - odd) * _SQRT_HALF
        half = length // 2
        out[..., :half], out[..., half:length] = average, detail
        length = half
    return out


def inverse(coefficients: np.ndarray, n: int | None = None) -> np.ndarray:
    """Rows (..., n) from Haar coefficients (..., N) (n defaults to N)."""
    out = np.array(coefficients, copy=True)
    size = out.shape[-1]
    if size != padded_length(size):
        raise ValueError(f"Haar coefficient rows must have a power-of-two length, not {size}")
    length = 1
    while length < size:
        average, detail = out[..., :length].copy(), out[..., length:2 * length].copy()
        out[..., 0:2 * length:2] = (average + detail) * _SQRT_HALF
        out[..., 1:2 * length:2] = (average - detail) * _SQRT_HALF
        length *= 2
    return out[..., :size if n is None else n]


def largest(coefficients: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``count`` largest-magnitude coefficients of each row of (rows, N): indices
    (rows, count) ascending within each row, and their values. Rows with fewer non-zero
    coefficients are padded with index 0 and value 0, which add nothing to a product."""
    coefficients = np.asarray(coefficients)
    rows, size = coefficients.shape
    count = min(int(count), size)
    if count == 0:
        return np.zeros((rows, 0), np.int64), np.zeros((rows, 0), coefficients.dtype)
    part = np.argpartition(-np.abs(coefficients), count - 1, axis=1)[:, :count]
    part.sort(axis=1)
    values = np.take_along_axis(coefficients, part, axis=1)
    return np.where(values != 0, part, 0), values


def count_for_energy(coefficients: np.ndarray, tolerance: float) -> np.ndarray:
    """Per row of (rows, N): the fewest largest coefficients whose dropped rest has a
    root energy ≤ ``tolerance`` × the row's norm (relative L2 truncation error)."""
    energy = np.sort(np.square(np.asarray(coefficients, np.float64)), axis=1)[:, ::-1]
    kept = np.cumsum(energy, axis=1)
    total = kept[:, -1:]
    dropped = total - kept  # after keeping 1, 2, ... coefficients
    enough = dropped <= (tolerance * tolerance) * total
    counts = np.argmax(enough, axis=1) + 1
    return np.where(total[:, 0] > 0, counts, 0)


def sparse_dot(indices: np.ndarray, values: np.ndarray, dense: np.ndarray) -> np.ndarray:
    """Σ_j values[..., j] · dense[indices[..., j]] over the last axis; ``dense`` (N,) or
    (N, C) gives (...,) or (..., C)."""
    gathered = np.asarray(dense)[indices]
    if gathered.ndim == values.ndim:
        return np.sum(values * gathered, axis=-1)
    return np.einsum("...j,...jc->...c", values, gathered)

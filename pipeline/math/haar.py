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

from functools import cache

import numpy as np

from pipeline.math.selection import largest_magnitudes, order_by_magnitude

_SQRT_HALF = np.sqrt(0.5)
BLOCK_LEVELS = 5  # levels per matrix product in forward (blocks of 32)


def padded_length(n: int) -> int:
    """N = the smallest power of two ≥ n (n ≥ 1)."""
    return 1 << max(int(n) - 1, 0).bit_length()


def forward(rows: np.ndarray) -> np.ndarray:
    """Haar coefficients (..., N) of ``rows`` (..., n), zero-padded to N.

    Computed ``BLOCK_LEVELS`` levels at a time: each block of 2^BLOCK_LEVELS scaling
    coefficients is transformed by one small matrix product (BLAS), its wavelets copied
    to their places in the standard layout, its scaling coefficient carried on; the last
    levels run one by one (``_forward_levels``). Same result as level by level, a few
    times fewer passes over the rows."""
    rows = np.asarray(rows)
    n = rows.shape[-1]
    size = padded_length(n)
    dtype = np.result_type(rows.dtype, np.float32)
    flat = rows.reshape(-1, n)
    out = np.empty((len(flat), size), dtype)  # every entry is written below
    scaling = flat.astype(dtype, copy=False)
    if n < size:
        scaling = np.zeros((len(flat), size), dtype)
        scaling[:, :n] = flat
    block = 1 << BLOCK_LEVELS
    matrix = _block_matrix(np.dtype(dtype))
    length = size
    while length >= block:
        count = length // block
        y = (scaling[:, :length].reshape(-1, block) @ matrix).reshape(len(flat), count, block)
        for level in range(BLOCK_LEVELS):  # in-block level k → global level, block order
            first = 1 << level
            out[:, count * first:count * 2 * first] = \
                y[:, :, first:2 * first].reshape(len(flat), -1)
        scaling = np.ascontiguousarray(y[:, :, 0])
        length = count
    out[:, :length] = _forward_levels(scaling[:, :length])
    return out.reshape(*rows.shape[:-1], size)


@cache
def _block_matrix(dtype: np.dtype) -> np.ndarray:
    """The 2^BLOCK_LEVELS-point transform as a matrix: row i transforms e_i."""
    matrix = _forward_levels(np.eye(1 << BLOCK_LEVELS, dtype=dtype))
    matrix.flags.writeable = False
    return matrix


def _forward_levels(rows: np.ndarray) -> np.ndarray:
    """The Haar transform of rows (..., N), N a power of two, one level at a time."""
    out = np.array(rows, copy=True)
    length = out.shape[-1]
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


def truncate(coefficients: np.ndarray, tolerance: float, cap: int) -> dict[str, np.ndarray]:
    """Keep each row's largest coefficients of (rows, N), largest first, until the dropped
    ones hold at most ``tolerance`` of the row's norm (relative L2), and never more than
    ``cap`` (of equal magnitudes, the lower index first). CSR result: ``count`` (rows,)
    int32, flat ``index`` int32 and ``value`` float32 (Σ count,), and ``residual``
    (rows,) float32, the dropped coefficients' norm over the row's norm (0 for an
    all-zero row, which keeps nothing)."""
    coefficients = np.asarray(coefficients)
    n, size = coefficients.shape
    cap = min(int(cap), size)
    if cap == 0 or n == 0:
        return {"count": np.zeros(n, np.int32), "index": np.zeros(0, np.int32),
                "value": np.zeros(0, np.float32), "residual": np.zeros(n, np.float32)}
    top = largest_magnitudes(coefficients, cap)  # by column, ties to the first
    top = order_by_magnitude(np.take_along_axis(coefficients, top, axis=1), top)
    values = np.take_along_axis(coefficients, top, axis=1)
    total = np.einsum("ij,ij->i", coefficients, coefficients, dtype=np.float64)
    dropped = total[:, None] - np.cumsum(np.square(values, dtype=np.float64), axis=1)
    enough = dropped <= (tolerance * tolerance) * total[:, None]
    count = np.where(enough.any(axis=1), np.argmax(enough, axis=1) + 1, cap)
    count = np.where(total > 0, count, 0)
    keep = np.arange(cap)[None, :] < count[:, None]
    last = np.take_along_axis(dropped, np.clip(count - 1, 0, cap - 1)[:, None], 1)[:, 0]
    residual = np.where(count > 0, np.sqrt(np.maximum(last, 0) / np.maximum(total, 1e-300)),
                        0.0)
    return {"count": count.astype(np.int32), "index": top[keep].astype(np.int32),
            "value": values[keep].astype(np.float32), "residual": residual.astype(np.float32)}


@cache
def matrix(n: int) -> np.ndarray:
    """The orthonormal Haar transform of length n (a power of two) as an (n, n) float64
    matrix W in the standard layout: W @ x == forward(x) (pipeline/methods/d2i/blocks.py applies
    it across blocks of neighbouring rows)."""
    return forward(np.eye(n)).T

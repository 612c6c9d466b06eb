"""Deterministic per-pixel random numbers, identical in NumPy and OpenCL (kernels/sampling.h).

A sample's number is a hash of (pixel, light, sample, dimension) with Wellons'
``lowbias32`` integer hash; all arithmetic is modulo 2^32. Uniform numbers are the top 24
bits of the hash divided by 2^24, so they lie in [0, 1) and are exact in float32.
"""

from __future__ import annotations

import numpy as np

_U32 = np.uint32


def lowbias32(x: np.ndarray) -> np.ndarray:
    """Wellons' lowbias32 hash of uint32 values."""
    x = np.asarray(x, dtype=_U32).copy()
    with np.errstate(over="ignore"):
        x ^= x >> _U32(16)
        x *= _U32(0x7FEB352D)
        x ^= x >> _U32(15)
        x *= _U32(0x846CA68B)
        x ^= x >> _U32(16)
    return x


def sample_uniform(pixel: np.ndarray, light: int, sample: np.ndarray, dim: int) -> np.ndarray:
    """Uniform float32 in [0, 1) for each (pixel, sample) pair (broadcast)."""
    with np.errstate(over="ignore"):
        inner = lowbias32(_U32(light) * _U32(0x85EBCA6B)
                          + np.asarray(sample, _U32) * _U32(0xC2B2AE35) + _U32(dim))
        h = lowbias32(np.asarray(pixel, _U32) * _U32(0x9E3779B1) + inner)
    return ((h >> _U32(8)).astype(np.float32) * np.float32(1.0 / 16777216.0))


def stratified_square(pixel: np.ndarray, light: int, count: int) -> np.ndarray:
    """``count`` (a square number m²) jittered points in [0, 1)², one per cell of an m×m
    grid, for each pixel: (len(pixel), count, 2) float32. Cell s is (s mod m, s div m)."""
    m = int(round(np.sqrt(count)))
    s = np.arange(count, dtype=_U32)[None, :]
    p = np.asarray(pixel, _U32)[:, None]
    ju, jv = sample_uniform(p, light, s, 0), sample_uniform(p, light, s, 1)
    cu = (s % _U32(m)).astype(np.float32)
    cv = (s // _U32(m)).astype(np.float32)
    inv = np.float32(1.0 / m)
    return np.stack([(cu + ju) * inv, (cv + jv) * inv], axis=-1)

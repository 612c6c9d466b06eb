"""Orthonormal frames around a normal."""

from __future__ import annotations

import numpy as np


def tangent_from_normal(n: np.ndarray) -> np.ndarray:
    """A unit tangent orthogonal to each unit normal in ``n`` (..., 3), continuous except
    at n_z = -1 (Duff et al. 2017, "Building an orthonormal basis, revisited")."""
    sign = np.where(n[..., 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[..., 2])
    b = n[..., 0] * n[..., 1] * a
    return np.stack([1.0 + sign * n[..., 0] ** 2 * a, sign * b, -sign * n[..., 0]], axis=-1)


def orthonormalize(t: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Gram-Schmidt: ``t`` made orthogonal to unit ``n`` and normalised; where that
    fails (t ∥ n or t = 0) the tangent from :func:`tangent_from_normal` is used."""
    t = t - np.sum(t * n, axis=-1, keepdims=True) * n
    length = np.linalg.norm(t, axis=-1, keepdims=True)
    fallback = tangent_from_normal(n)
    ok = length > 1e-8
    return np.where(ok, t / np.where(ok, length, 1.0), fallback)

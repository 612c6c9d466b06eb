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


def face_tangents(vertices: np.ndarray, uv: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Per-face dP/du (F, 3), zero where the face's uv mapping is degenerate."""
    p0, p1, p2 = (vertices[faces[:, i]].astype(np.float64) for i in range(3))
    t0, t1, t2 = (uv[faces[:, i]].astype(np.float64) for i in range(3))
    e1, e2 = p1 - p0, p2 - p0
    du1, dv1 = t1[:, 0] - t0[:, 0], t1[:, 1] - t0[:, 1]
    du2, dv2 = t2[:, 0] - t0[:, 0], t2[:, 1] - t0[:, 1]
    det = du1 * dv2 - du2 * dv1
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    return (e1 * dv2[:, None] - e2 * dv1[:, None]) * inv[:, None]

"""Environment lighting from a latitude-longitude radiance map.

Mapping (Mitsuba 3's, so that the two renderers agree; world +y is up). The map is
turned by ``rotation`` degrees about its unit ``axis`` (right-handed; default +y): the
map-to-world rotation R (:func:`rotation_about`). A unit world direction d, first taken
into the map by Rᵀ (d' = Rᵀd = (x, y, z)), looks up the map at

    u = atan2(x, −z) / 2π  (mod 1),  v = arccos(y) / π,

u across the columns (0 = left edge), v down the rows. So the centre column of the image
(u = ½) lies along +z, a quarter of the width (u = ¼) along +x. Radiance is interpolated
bilinearly between texels, column j centred at u = (j + ½)/W (wrapping), row i at
v = i/(H − 1) (row 0 the +y pole, row H − 1 the −y pole), as Mitsuba 3 does (measured
with its ``emitter.eval``; pipeline/evaluation/mitsuba.py), and multiplied by ``scale``.
Units: W/(m² sr).

Importance sampling picks a texel with probability ∝ its luminance × sin θ (the texel's
solid angle) and a point uniformly inside it, so the solid-angle density is
p(d) = P(texel) · W H / (2π² sin θ). A small uniform floor keeps p > 0 wherever
bilinear interpolation can make radiance non-zero.
"""

from __future__ import annotations

import numpy as np

LUMINANCE = np.array([0.2126, 0.7152, 0.0722])  # Rec. 709
UNIFORM_FLOOR = 1e-3  # fraction of the sampling mass spread evenly over all texels


def rotation_y(degrees: float) -> np.ndarray:
    """3×3 rotation by ``degrees`` about +y (right-handed)."""
    a = np.radians(degrees)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rotation_about(axis: tuple[float, float, float] | np.ndarray, degrees: float
                   ) -> np.ndarray:
    """3×3 rotation by ``degrees`` about the unit ``axis`` (right-handed, Rodrigues):
    R = cos a I + sin a [k]ₓ + (1 − cos a) k kᵀ. About +y it is :func:`rotation_y`."""
    k = np.asarray(axis, np.float64)
    k = k / np.linalg.norm(k)
    a = np.radians(degrees)
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.cos(a) * np.eye(3) + np.sin(a) * cross + (1.0 - np.cos(a)) * np.outer(k, k)


def direction_to_uv(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Map-space unit directions (..., 3) to (u, v) in [0, 1)."""
    u = np.mod(np.arctan2(d[..., 0], -d[..., 2]) / (2.0 * np.pi), 1.0)
    v = np.arccos(np.clip(d[..., 1], -1.0, 1.0)) / np.pi
    return u, v


def uv_to_direction(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Inverse of :func:`direction_to_uv`: (u, v) to map-space unit directions (..., 3)."""
    phi, theta = 2.0 * np.pi * u, np.pi * v
    st = np.sin(theta)
    return np.stack([st * np.sin(phi), np.cos(theta), -st * np.cos(phi)], axis=-1)


class EnvironmentMap:
    """A latitude-longitude map ``rgb`` (H, W, 3) of radiance, rotated by ``rotation``
    degrees about the unit ``axis`` (default +y) and multiplied by ``scale``."""

    def __init__(self, rgb: np.ndarray, rotation: float = 0.0, scale: float = 1.0,
                 axis: tuple[float, float, float] = (0.0, 1.0, 0.0)) -> None:
        self.rgb = np.asarray(rgb, np.float64) * scale
        self.height, self.width = self.rgb.shape[:2]
        self.to_world = rotation_about(axis, rotation)
        rows = (np.arange(self.height) + 0.5) / self.height
        weight = (self.rgb @ LUMINANCE).clip(0.0) * np.sin(np.pi * rows)[:, None]
        total = weight.sum()
        uniform = np.full(weight.shape, 1.0 / weight.size)
        self.texel_prob = (uniform if total <= 0 else
                           (1.0 - UNIFORM_FLOOR) * weight / total + UNIFORM_FLOOR * uniform)
        self.cdf = np.cumsum(self.texel_prob.ravel())
        self.cdf /= self.cdf[-1]

    def radiance(self, d: np.ndarray) -> np.ndarray:
        """Radiance (N, 3) arriving from world directions ``d`` (N, 3)."""
        u, v = direction_to_uv(d @ self.to_world)
        x = u * self.width - 0.5
        y = v * (self.height - 1)
        x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
        fx, fy = (x - x0)[:, None], (y - y0)[:, None]
        x0, x1 = x0 % self.width, (x0 + 1) % self.width
        y1 = np.minimum(y0 + 1, self.height - 1)
        m = self.rgb
        return ((1 - fy) * ((1 - fx) * m[y0, x0] + fx * m[y0, x1])
                + fy * ((1 - fx) * m[y1, x0] + fx * m[y1, x1]))

    def sample(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World directions (N, 3) and their solid-angle densities (N,) from uniform
        numbers ``u`` (N, 3)."""
        texel = np.minimum(np.searchsorted(self.cdf, u[:, 0], side="right"), self.cdf.size - 1)
        row, col = np.divmod(texel, self.width)
        mu = (col + u[:, 1]) / self.width
        mv = (row + u[:, 2]) / self.height
        d = uv_to_direction(mu, mv) @ self.to_world.T
        return d, self._density(self.texel_prob[row, col], mv)

    def pdf(self, d: np.ndarray) -> np.ndarray:
        """Solid-angle density (N,) with which :meth:`sample` returns world ``d`` (N, 3)."""
        u, v = direction_to_uv(d @ self.to_world)
        col = np.minimum((u * self.width).astype(np.int64), self.width - 1)
        row = np.minimum((v * self.height).astype(np.int64), self.height - 1)
        return self._density(self.texel_prob[row, col], v)

    def _density(self, texel_prob: np.ndarray, v: np.ndarray) -> np.ndarray:
        sin_theta = np.maximum(np.sin(np.pi * v), 1e-12)
        return texel_prob * self.width * self.height / (2.0 * np.pi ** 2 * sin_theta)

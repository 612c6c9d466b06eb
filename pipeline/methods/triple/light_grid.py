"""Environment lighting resampled in the local frames of a frame grid (method triple,
paper 004 §3.2): the NumPy side of kernels/triple/light_rotations.cl.

**What is stored.** For grid frame R (columns tangent, bitangent, normal in world
coordinates; :class:`pipeline.methods.triple.frame_grids.FrameGrid`) the local lighting is
L_local(ω) = L_world(R ω), ω in the local frame, and a stored row holds its leaf means
(:mod:`pipeline.methods.triple.wavelet_rows`) in the wavelet basis. The map's own ``rotation``
and ``scale`` are not applied: scale is linear, and a map rotated by ρ about +y lights
frame (φ, θ, ψ) as the unrotated map lights frame (φ − ρ, θ, ψ), because turning by φ
about +y is the grid's first Euler angle (frame_grids.py: M R_P(φ) Mᵀ = rotation_y(φ))
and EnvironmentMap looks world d up at rotation_y(−ρ) d.

**Turning about the pole is a column shift.** rotation_y(φ) changes a direction's map
coordinate u by −φ/2π (envmap.py: u = atan2(x, −z)/2π), so in a map whose width W is a
multiple of the grid's n_φ, grid step j moves every lookup by −j·W/n_φ whole columns:
the kernel maps each sample to texel coordinates once per (θ, ψ) and shifts.

**Prefiltering.** A leaf mean from 4^r point samples aliases when texels are much
smaller than the samples' spacing s ≈ √(4π / (20·4^(L+r))) rad: a small bright source
falls between samples or on one. Each sample stands for its level L + r leaf, about s
across, so :func:`prefilter` box-filters the map over s (rows over s, each row's
columns over s / sin θ, wrapping): the sample then reads the mean over its own small
leaf and the samples of a leaf tile it. The filtered map keeps its resolution and is
resampled bilinearly to W = n_φ·⌈W₀/n_φ⌉ columns, H = W/2 rows (the same row
convention, rows at v = i/(H − 1)) only when its width W₀ is not a multiple of n_φ.
(Resampling it to two texels per spacing, for the kernel's cache, raised the leaf
means' error on Grace from 3.6 % to 4.8 % at r = 1 and from 11 % to 15 % at r = 0.)
benchmarks/triple/tables.py measures the leaf
means' error against a finely sampled reference with and without it.
"""

from __future__ import annotations

import numpy as np

from pipeline.math.envmap import EnvironmentMap
from pipeline.math.geodesic import ROOTS
from pipeline.math.sphwavelet import leaf_means


def sample_spacing(leaf_level: int, refine: int) -> float:
    """Typical angle between neighbouring samples of level ``leaf_level + refine``
    (radians): the square root of a leaf's mean solid angle."""
    return float(np.sqrt(4.0 * np.pi / (ROOTS * 4 ** (leaf_level + refine))))


def prefiltered_width(width: int, n_phi: int) -> int:
    """Width of the prefiltered map of a map ``width`` texels wide: the next multiple
    of ``n_phi``."""
    return n_phi * -(-width // n_phi)


def _box_rows(rgb: np.ndarray, half: int) -> np.ndarray:
    """Mean over rows i − half .. i + half (clamped at the poles) of (H, W, 3)."""
    if half <= 0:
        return rgb
    padded = np.concatenate([np.repeat(rgb[:1], half, 0), rgb, np.repeat(rgb[-1:], half, 0)])
    sums = np.concatenate([np.zeros((1, *rgb.shape[1:])), np.cumsum(padded, axis=0)])
    return (sums[2 * half + 1:] - sums[:-2 * half - 1]) / (2 * half + 1)


def _box_columns(rgb: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Mean over columns j − half[i] .. j + half[i] (wrapping) of each row i of (H, W, 3);
    half[i] ≤ (W − 1)/2."""
    height, width = rgb.shape[:2]
    padded = np.concatenate([rgb, rgb, rgb], axis=1)
    sums = np.concatenate([np.zeros((height, 1, 3)), np.cumsum(padded, axis=1)], axis=1)
    j = np.arange(width)[None, :] + width
    hi = (j + half[:, None] + 1)[..., None]
    lo = (j - half[:, None])[..., None]
    rows = np.arange(height)[:, None, None]
    total = sums[rows, hi, np.arange(3)] - sums[rows, lo, np.arange(3)]
    return total / (2 * half + 1)[:, None, None]


def prefilter(rgb: np.ndarray, spacing: float, n_phi: int) -> np.ndarray:
    """The map (H, W, 3) box-filtered over ``spacing`` radians, (W'/2, W', 3) float32
    with W' = :func:`prefiltered_width` (module docstring)."""
    rgb = np.asarray(rgb, np.float64)
    height, width = rgb.shape[:2]
    row_step = np.pi / (height - 1)
    theta = np.arange(height) * row_step
    columns = spacing / (2.0 * np.pi / width) / np.maximum(np.sin(theta), 1e-6)
    half = np.minimum(np.round(0.5 * columns), (width - 1) // 2).astype(np.int64)
    out = _box_columns(_box_rows(rgb, int(round(0.5 * spacing / row_step))), half)
    new_width = prefiltered_width(width, n_phi)
    if new_width == width:
        return out.astype(np.float32)
    new_height = new_width // 2
    u = (np.arange(new_width) + 0.5) / new_width
    v = np.arange(new_height) / (new_height - 1)
    x = u * width - 0.5
    y = v * (height - 1)
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = (x - x0)[None, :, None], (y - y0)[:, None, None]
    x0, x1 = x0 % width, (x0 + 1) % width
    y1 = np.minimum(y0 + 1, height - 1)
    rows0, rows1 = out[y0], out[y1]
    return ((1 - fy) * ((1 - fx) * rows0[:, x0] + fx * rows0[:, x1])
            + fy * ((1 - fx) * rows1[:, x0] + fx * rows1[:, x1])).astype(np.float32)


def frame_leaf_means(rgb: np.ndarray, frames: np.ndarray, leaf_level: int,
                     refine: int) -> np.ndarray:
    """Leaf means (F, 3, N) of L_local(ω) = L(R ω) for frames ``frames`` (F, 3, 3) of the
    map ``rgb`` (H, W, 3) as it is (no prefilter, rotation or scale): the NumPy twin of
    kernels/triple/light_rotations.cl, through :func:`pipeline.math.sphwavelet.leaf_means`."""
    env = EnvironmentMap(rgb)
    return np.stack([leaf_means(lambda d, r=r: env.radiance(d @ r.T).T, leaf_level, refine)
                     for r in np.asarray(frames, np.float64)])

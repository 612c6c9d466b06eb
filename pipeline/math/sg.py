"""Spherical Gaussians (paper 003 §3.1, §5): evaluation, integral, inner product, product,
rotation, and the integral against an environment map prefiltered by SGs.

**The lobe.** Paper 003 writes a transport function as Σ_k w_k G(ω; μ_k, σ_k), "a 2D
spherical Gaussian centred around μ_k with standard deviation σ_k", without a formula.
Here

    G(ω; μ, λ) = exp(λ (μ·ω − 1)),      ω, μ unit vectors, λ ≥ 0 the sharpness,

peak 1 at ω = μ, so w is the lobe's peak value (RGB, the paper's "RGB color"). Near the
mean, with θ the angle between ω and μ, μ·ω − 1 = cos θ − 1 ≈ −θ²/2, so
G ≈ exp(−θ²/(2σ²)) with

    λ = 1/σ²,   σ = 1/√λ   (σ in radians).

That is the mapping used everywhere (storage keeps σ as the paper does; the formulas use λ).
It is a von Mises–Fisher density up to normalisation.

**Float32 forms.** For sharp lobes (λ up to 10⁴, σ ≈ 0.57°) the textbook forms fail in
float32: ∫G = (4π/λ) e^{−λ} sinh λ overflows (sinh 10⁴ = inf), and 1 − μ·ω loses all
digits within ~0.03° of the peak, where λ(1 − μ·ω) still matters. So:

- μ·ω − 1 = −‖ω − μ‖²/2 for unit vectors (no cancellation near the peak);
- ∫_S G dω = 2π (1 − e^{−2λ})/λ = −2π expm1(−2λ)/λ  (→ 4π as λ → 0);
- for two lobes, u = λa μa + λb μb, r = ‖u‖:
  G_a G_b = exp(u·ω − λa − λb) = e^{r − λa − λb} G(ω; u/r, r), and
  r − λa − λb = (r² − (λa + λb)²)/(r + λa + λb) = −λa λb ‖μa − μb‖² / (r + λa + λb),
  an exponent ≤ 0 computed without cancelling two numbers of size 2·10⁴;
- ⟨G_a, G_b⟩ = ∫ G_a G_b dω = e^{r − λa − λb} · 2π (1 − e^{−2r})/r.

**Environment lookups** (the renderer's integral of eq. 11). A lat-long map L (H, W, 3),
in pipeline/math/envmap.py's mapping (row i at polar angle π i/(H − 1), column j at
azimuth 2π(j + ½)/W, bilinear), is prefiltered into levels ℓ = 0 .. n − 1 of increasing
σ_ℓ = σ_0 q^ℓ, each the *normalised* convolution

    P_ℓ(d) = ∫ G(ω; d, 1/σ_ℓ²) L(ω) dω / ∫ G(ω; d, 1/σ_ℓ²) dω,

(a radiance, W/(m² sr)) stored at its own lat-long resolution (texel spacing ≤ σ_ℓ/3).
The integral of a lobe w G(·; μ, λ) against L is then looked up as

    ∫ w G L dω ≈ w · (∫G) · P(μ, σ),   σ = 1/√λ,

with P bilinear in direction within a level and linear between the two levels around
f = log(σ/σ_0)/log q (clamped to [0, n − 1]: lobes sharper than σ_0, the map's own
resolution, use level 0; broader than the last level use the last). Directions are in
the map's frame: for a map rotated by R the renderer looks up Rᵀμ (paper §5).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

TWO_PI = 2.0 * np.pi


def sharpness(sigma: np.ndarray | float) -> np.ndarray:
    """Sharpness λ = 1/σ² of standard deviations σ (radians)."""
    return 1.0 / np.square(sigma)


def sigma_of(lam: np.ndarray | float) -> np.ndarray:
    """Standard deviation σ = 1/√λ (radians) of sharpness λ."""
    return 1.0 / np.sqrt(lam)


def evaluate(omega: np.ndarray, mu: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """G(ω; μ, λ) = exp(−λ‖ω − μ‖²/2) for unit ω (..., 3), μ (..., 3) and λ (...),
    broadcast; shape (...)."""
    d = omega - mu
    return np.exp(-0.5 * lam * np.sum(d * d, axis=-1))


def _integral_factor(lam: np.ndarray) -> np.ndarray:
    """(1 − e^{−2λ})/λ = −expm1(−2λ)/λ, 2 at λ = 0."""
    lam = np.asarray(lam)
    safe = np.where(lam > 0, lam, 1)
    return np.where(lam > 0, -np.expm1(-2 * safe) / safe, 2 * np.ones_like(safe))


def integral(lam: np.ndarray) -> np.ndarray:
    """∫_S G(ω; μ, λ) dω = 2π(1 − e^{−2λ})/λ (sr), any μ; shape of ``lam``."""
    return TWO_PI * _integral_factor(lam)


@dataclass(frozen=True)
class Product:
    """G(ω; μa, λa) G(ω; μb, λb) = scale · G(ω; mu, lam): a lobe times a factor ≤ 1."""

    mu: np.ndarray     # (..., 3) unit
    lam: np.ndarray    # (...)
    scale: np.ndarray  # (...) e^{r − λa − λb}


def product(mu_a: np.ndarray, lam_a: np.ndarray, mu_b: np.ndarray,
            lam_b: np.ndarray) -> Product:
    """The product of two lobes as one lobe (module docstring). Where u = 0 (equal
    antipodal lobes) the product is the constant e^{−λa−λb}: mean μa, sharpness 0."""
    lam_a, lam_b = np.asarray(lam_a), np.asarray(lam_b)
    u = lam_a[..., None] * mu_a + lam_b[..., None] * mu_b
    r = np.linalg.norm(u, axis=-1)
    d = mu_a - mu_b
    exponent = -lam_a * lam_b * np.sum(d * d, axis=-1) / np.maximum(r + lam_a + lam_b, 1e-30)
    safe = np.where(r > 0, r, 1)[..., None]
    mu = np.where(r[..., None] > 0, u / safe, np.broadcast_to(mu_a, u.shape))
    return Product(mu=mu, lam=r, scale=np.exp(exponent))


def inner_product(mu_a: np.ndarray, lam_a: np.ndarray, mu_b: np.ndarray,
                  lam_b: np.ndarray) -> np.ndarray:
    """⟨G_a, G_b⟩ = ∫_S G(ω; μa, λa) G(ω; μb, λb) dω (sr), broadcast over (...)."""
    p = product(mu_a, lam_a, mu_b, lam_b)
    return p.scale * integral(p.lam)


def rotate(mu: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Means (..., 3) rotated by the 3×3 matrix ``rotation``: R μ. A lobe rotates with
    its mean (λ and w unchanged); to look a lobe up in a map rotated by R, use Rᵀ μ."""
    return mu @ np.asarray(rotation).T


# --- lat-long maps and their SG prefiltering -------------------------------------------


def latlong_directions(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """The sample directions (H, W, 3) of a lat-long map (envmap.py's mapping: row i at
    θ = π i/(H − 1) from +y, column j at u = (j + ½)/W) and their quadrature solid
    angles (H, W): row i stands for θ ∈ [θ_i − Δ/2, θ_i + Δ/2] ∩ [0, π], Δ = π/(H − 1),
    so Ω_ij = (2π/W)(cos θ_lo − cos θ_hi) and the Ω sum to 4π."""
    theta = np.pi * np.arange(height) / (height - 1)
    half = 0.5 * np.pi / (height - 1)
    lo, hi = np.clip(theta - half, 0, np.pi), np.clip(theta + half, 0, np.pi)
    u = (np.arange(width) + 0.5) / width
    phi = TWO_PI * u
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    d = np.stack(np.broadcast_arrays(st * np.sin(phi), ct, -st * np.cos(phi)), axis=-1)
    omega = (TWO_PI / width) * (np.cos(lo) - np.cos(hi))
    return d, np.broadcast_to(omega[:, None], (height, width)).copy()


@dataclass(frozen=True)
class PrefilterLevels:
    """The σ ladder of a prefiltered stack: σ_ℓ = sigma0 · ratio^ℓ (radians), level ℓ
    stored as a lat-long map of ``shapes[ℓ]`` = (H_ℓ, W_ℓ)."""

    sigma0: float
    ratio: float
    shapes: tuple[tuple[int, int], ...]

    @property
    def count(self) -> int:
        return len(self.shapes)

    @property
    def sigmas(self) -> np.ndarray:
        return self.sigma0 * self.ratio ** np.arange(self.count)


def prefilter_levels(height: int, width: int, ratio: float = 2.0 ** 0.25,
                     sigma_max: float = 4.0) -> PrefilterLevels:
    """Levels for an H × W map: σ_0 = π/(H − 1) (one row: the map holds nothing
    sharper), σ growing by ``ratio`` until it reaches ``sigma_max`` (4 rad, λ = 1/16:
    broader lobes see a nearly constant average). The ratio sets the error of the
    linear step between levels, which dominates the lookup's: on a 33 × 64 map of
    three SG lights (tests/test_sg.py), 400 random lobes are off the quadrature by at
    most 4.7 % (median 0.3 %) with ratio √2 and 2.5 % (median 0.24 %) with 2^¼, the
    default; a 512 × 1024 map then has 39 levels holding 9.7 base maps (7 at full
    resolution).
    Level ℓ has H_ℓ rows spaced ≤ σ_ℓ/3
    (bilinear error of a Gaussian-blurred map ≲ 1.4 % of its curvature scale), capped
    at H, and W_ℓ columns in the map's proportion (at least 8)."""
    sigma0 = math.pi / (height - 1)
    count = 1 + max(0, math.ceil(math.log(sigma_max / sigma0) / math.log(ratio)))
    shapes = []
    for level in range(count):
        sigma = sigma0 * ratio ** level
        rows = min(height, max(5, 1 + math.ceil(3.0 * math.pi / sigma)))
        cols = width if rows == height else max(8, round(width * (rows - 1) / (height - 1)))
        shapes.append((rows, cols))
    return PrefilterLevels(sigma0, ratio, tuple(shapes))


def prefilter_reference(rgb: np.ndarray, levels: PrefilterLevels,
                        chunk: int = 512) -> list[np.ndarray]:
    """The prefiltered stack by brute force (the NumPy reference; O(H W · H_ℓ W_ℓ) per
    level, for small maps): level ℓ at its sample directions d is
    Σ_j G(ω_j; d, λ_ℓ) L_j Ω_j / Σ_j G(ω_j; d, λ_ℓ) Ω_j over the map's samples j.
    Returns n arrays (H_ℓ, W_ℓ, 3)."""
    height, width = rgb.shape[:2]
    src, omega = latlong_directions(height, width)
    src, omega = src.reshape(-1, 3), omega.ravel()
    radiance = np.asarray(rgb, np.float64).reshape(-1, 3)
    out = []
    for (rows, cols), sigma in zip(levels.shapes, levels.sigmas, strict=True):
        lam = sharpness(sigma)
        dst = latlong_directions(rows, cols)[0].reshape(-1, 3)
        level = np.empty((len(dst), 3))
        for start in range(0, len(dst), chunk):
            # exp(λ(d·ω − 1)) Ω, the Gaussian of every destination over all sources
            g = np.exp(lam * (dst[start:start + chunk] @ src.T - 1.0)) * omega
            level[start:start + chunk] = (g @ radiance) / g.sum(axis=1, keepdims=True)
        out.append(level.reshape(rows, cols, 3))
    return out


def _bilinear(level: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Bilinear lookup (N, 3) of a lat-long level (H, W, 3) at map-space unit
    directions d (N, 3) (envmap.py's EnvironmentMap.radiance, without rotation)."""
    height, width = level.shape[:2]
    u = np.mod(np.arctan2(d[:, 0], -d[:, 2]) / TWO_PI, 1.0)
    v = np.arccos(np.clip(d[:, 1], -1.0, 1.0)) / np.pi
    x, y = u * width - 0.5, v * (height - 1)
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, x1 = x0 % width, (x0 + 1) % width
    y1 = np.minimum(y0 + 1, height - 1)
    m = level
    return ((1 - fy) * ((1 - fx) * m[y0, x0] + fx * m[y0, x1])
            + fy * ((1 - fx) * m[y1, x0] + fx * m[y1, x1]))


def level_coordinate(lam: np.ndarray, levels: PrefilterLevels) -> np.ndarray:
    """f = log(σ/σ_0)/log q, σ = 1/√λ, clamped to [0, n − 1] (fractional level)."""
    f = (-0.5 * np.log(np.maximum(lam, 1e-30)) - math.log(levels.sigma0)) / math.log(levels.ratio)
    return np.clip(f, 0.0, levels.count - 1)


def env_integral(stack: list[np.ndarray], levels: PrefilterLevels, mu: np.ndarray,
                 lam: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """∫ w G(ω; μ, λ) L(ω) dω ≈ w (∫G) P(μ, σ) (module docstring) for N lobes:
    map-space unit means μ (N, 3), sharpness λ (N,), RGB weights w (N, 3); (N, 3)."""
    f = level_coordinate(lam, levels)
    lo = np.minimum(np.floor(f).astype(np.int64), max(levels.count - 2, 0))
    t = (f - lo)[:, None]
    p = np.empty((len(mu), 3))
    for level in np.unique(lo):
        sel = lo == level
        a = _bilinear(stack[level], mu[sel])
        b = _bilinear(stack[min(level + 1, levels.count - 1)], mu[sel])
        p[sel] = (1 - t[sel]) * a + t[sel] * b
    return weight * integral(lam)[:, None] * p


def env_integral_reference(rgb: np.ndarray, mu: np.ndarray, lam: np.ndarray,
                           weight: np.ndarray) -> np.ndarray:
    """The same integral by quadrature over the map's samples (no prefiltering):
    Σ_j w G(ω_j; μ, λ) L_j Ω_j, (N, 3). Accurate while the lobe spans several texels."""
    src, omega = latlong_directions(*rgb.shape[:2])
    g = evaluate(src.reshape(1, -1, 3), mu[:, None, :], lam[:, None]) * omega.ravel()
    return weight * (g @ np.asarray(rgb, np.float64).reshape(-1, 3))


def pack_stack(stack: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The device layout of kernels/sg/sg.h: the levels' texels back to back (float32,
    Σ H_ℓ W_ℓ · 3) and per level (first texel, W_ℓ, H_ℓ) (int32, n × 3)."""
    sizes = [level.shape[0] * level.shape[1] for level in stack]
    first = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    info = np.array([(f, level.shape[1], level.shape[0]) for f, level in zip(first, stack,
                                                                            strict=True)])
    flat = np.concatenate([level.reshape(-1, 3) for level in stack]).astype(np.float32)
    return flat.ravel(), info.astype(np.int32)

"""Method sg's bright sources (decision 0048): the environment map split into the few
small bright regions that hold most of its light, each carried as one directional
source, and the residual map the prefiltered stack holds.

Under ``normal=visibility`` the glossy light of a pixel is the BRDF × cosine at its
normal held by 7 Gaussian nodes against the prefiltered map (pipeline/methods/sg/
visibility.py). A source much smaller than the BRDF's lobe (a studio light, a window)
then reflects as the nodes' sum *at one direction*, where a fit chosen for its L2 error
over the whole lobe (7–8 %) answers for that direction alone. A source's reflection
needs the BRDF at its direction only:

    glossy_s = ρs f(ω_s, ωo) max(0, n·ω_s) K_s P_s V(ω_s),

P_s = ∫ (L − t)+ dω over the region (radiance × sr, per channel), ω_s its direction
(the excess-weighted mean), λ_s its sharpness as a spherical Gaussian of the same
spread, 2 / E[‖ω − ω_s‖²] (excess-weighted), V the corners' visibility filtered over
σ_s = 1/√λ_s. Exact for a point source. For an extended one, K_s carries the source's
spread through the BRDF: the ratio (G_b ⊗ Ĝ_s)(ω_s) / G_b(ω_s) of the material's
one-Gaussian lobe G_b(μ, λ) (brdf_lobe.py) blurred by the normalised source to the lobe
itself at ω_s (1 where the lobe is much wider than the source), in closed form
(:func:`spread`), capped at e² where a sharp lobe's tail meets a wide source (the
Gaussian's tail is not the BRDF's). The studio map's two lights: σ_s = 0.03 and 0.08
rad, against dragon_sg's glossy lobes' σ = 1/√λ ≈ 0.15–0.3 rad.

**The split.** t is the ``quantile`` of the map's texels' luminance (channel mean); the
texels above it form connected regions (4-connected in the lat-long grid; a region
crossing the map's u = 0 seam counts as two); a region is a source if its excess power
(channel mean of P_s) is at least ``min_share`` of the map's power ∫ L̄ dω, the
``MAX_SOURCES`` strongest kept. In a source's texels the residual is min(L, t) per
channel and the source holds (L − t)+, so residual + sources = the map texel by texel;
elsewhere the residual is the map. A map with no such region (a sky, a blurred
interior) has no sources and its residual is the map.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from pipeline.math.sg import integral, latlong_directions

MAX_SOURCES = 8
FIELDS = 7  # direction (3, map frame), power (3, W/m²: radiance × sr), sharpness λ_s (rad⁻²)
SPREAD_CAP = 2.0  # log K_s at most (module docstring)


def split_sources(rgb: np.ndarray, quantile: float, min_share: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Sources (K, FIELDS) float64, strongest first (K ≤ MAX_SOURCES), and the residual
    map (H, W, 3) float64 of lat-long map ``rgb`` (H, W, 3) radiance (module
    docstring)."""
    rgb = np.asarray(rgb, np.float64)
    directions, omega = latlong_directions(*rgb.shape[:2])
    luminance = rgb.mean(axis=2)
    threshold = float(np.quantile(luminance, quantile))
    labels, _ = ndimage.label(luminance > threshold)
    power_total = float(np.sum(luminance * omega))
    excess = np.maximum(rgb - threshold, 0.0)
    found = []
    for label, region in enumerate(ndimage.find_objects(labels), start=1):
        inside = labels[region] == label
        e = excess[region][inside]
        w = omega[region][inside]
        power = (e * w[:, None]).sum(axis=0)
        if power.mean() < min_share * power_total or power.mean() <= 0.0:
            continue
        weight = e.mean(axis=1) * w
        mean = (directions[region][inside] * weight[:, None]).sum(axis=0)
        mean /= np.linalg.norm(mean)
        spread = np.sum(np.sum((directions[region][inside] - mean) ** 2, axis=1) * weight)
        sharpness = 2.0 * weight.sum() / max(spread, 1e-12)  # one texel: as sharp as 1e-12
        found.append((region, inside, power, mean, min(sharpness, 1e8)))
    found.sort(key=lambda s: -s[2].mean())
    residual = rgb.copy()
    sources = np.zeros((0, FIELDS))
    for region, inside, power, direction, sharpness in found[:MAX_SOURCES]:
        texels = residual[region]
        texels[inside] = np.minimum(texels[inside], threshold)
        sources = np.vstack([sources, [*direction, *power, sharpness]])
    return sources, residual


def spread(mu: np.ndarray, lam: np.ndarray, direction: np.ndarray, lam_s: np.ndarray
           ) -> np.ndarray:
    """K_s (module docstring) of lobes G_b(μ (..., 3), λ (...)) for sources at unit
    ``direction`` (..., 3) of sharpness λ_s (...): with d = μ − ω_s and r = ‖λ μ + λ_s
    ω_s‖ (the product lobe's sharpness, pipeline/math/sg.py ``product``),
    log K = (λ‖d‖²/2)(1 − 2λ_s/(r + λ + λ_s)) + log(∫G_r / ∫G_λs), at most SPREAD_CAP."""
    lam, lam_s = np.asarray(lam, np.float64), np.asarray(lam_s, np.float64)
    d2 = np.sum((mu - direction) ** 2, axis=-1)
    r = np.linalg.norm(lam[..., None] * mu + lam_s[..., None] * direction, axis=-1)
    log_k = 0.5 * lam * d2 * (1.0 - 2.0 * lam_s / (r + lam + lam_s)) \
        + np.log(integral(r) / integral(lam_s))
    return np.exp(np.minimum(log_k, SPREAD_CAP))


def to_world(sources: np.ndarray, rotation: np.ndarray | None) -> np.ndarray:
    """``sources`` (K, FIELDS) with their directions taken from the map frame to the
    world by the map-to-world ``rotation`` (3×3; None: unturned), float32."""
    out = np.array(sources, np.float32).reshape(-1, FIELDS)
    if rotation is not None and len(out):
        out[:, :3] = out[:, :3] @ np.asarray(rotation, np.float64).T
    return out

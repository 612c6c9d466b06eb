"""Importance sampling of the analytic BRDFs (pipeline/math/brdf.py), local frame.

Directions are unit vectors in the local shading frame (z the normal), ``wo`` towards
the viewer. Each BRDF is sampled from a two-lobe mixture:

* with probability 1 − q a cosine-weighted direction, p = cos θi / π;
* with probability q a glossy proposal, a cos^n lobe of exponent n:
    - for the half-vector models (Blinn-Phong, Ward, Ward-Dür, anisotropic Ward,
      Cook-Torrance, Ashikhmin-Shirley) the half vector h is drawn with density
      (n + 1)/2π · cos^n θh about the normal and ωi = 2(ωo·h)h − ωo, so
      p(ωi) = (n + 1)/2π · cos^n θh / (4 ωo·h);
    - for Lafortune, ωi is drawn with density (n + 1)/2π · (ωi·a)^n about the lobe axis
      a = (Cxy ωo,x, Cxy ωo,y, Cz ωo,z)/|·|.
  n = γ for the cos^γ models; for the Gaussian (Beckmann-type) ones, whose γ is the
  roughness α, n = 2/α² − 2 (the Phong exponent of equal lobe width; α of the
  anisotropic Ward: √(αx αy)), at least 1.

q = ρ̄s / (ρ̄s + k̄d) (channel means) clamped to [0.1, 0.9]; 0 for Lambertian materials.
The density of the mixture is returned with every sample, so an estimator dividing by it
is unbiased whatever the proposal's fit to the BRDF; a poor fit only costs variance.
Samples below the horizon (θi ≥ 90°) have BRDF 0; they are returned and carry no weight.
"""

from __future__ import annotations

import numpy as np

from pipeline.math.brdf import BrdfParams

_GAUSSIAN_MODELS = ("ward", "ward_duer", "ward_anisotropic", "cook_torrance")


def glossy_probability(p: BrdfParams) -> float:
    """q, the probability of drawing from the glossy proposal."""
    if p.model == "lambert":
        return 0.0
    s, d = float(np.mean(p.specular)), float(np.mean(p.albedo))
    return float(np.clip(s / max(s + d, 1e-30), 0.1, 0.9))


def lobe_exponent(p: BrdfParams) -> float:
    """n of the glossy proposal's cos^n lobe."""
    if p.model in _GAUSSIAN_MODELS:
        alpha2 = p.gamma * p.gamma * (p.alpha_ratio if p.model == "ward_anisotropic" else 1.0)
        return max(2.0 / alpha2 - 2.0, 1.0)
    return max(float(p.gamma), 1.0)


def cos_power_direction(u1: np.ndarray, u2: np.ndarray, n: float) -> np.ndarray:
    """Directions (N, 3) about +z with density (n + 1)/2π cos^n θ."""
    cos_t = u1 ** (1.0 / (n + 1.0))
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
    phi = 2.0 * np.pi * u2
    return np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=-1)


def frame_to_world(local: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Rotate directions given about +z onto unit ``axis`` (N, 3) (Duff et al. 2017)."""
    sign = np.where(axis[:, 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + axis[:, 2])
    b = axis[:, 0] * axis[:, 1] * a
    t = np.stack([1.0 + sign * axis[:, 0] ** 2 * a, sign * b, -sign * axis[:, 0]], axis=-1)
    bt = np.stack([b, sign + axis[:, 1] ** 2 * a, -axis[:, 1]], axis=-1)
    return local[:, :1] * t + local[:, 1:2] * bt + local[:, 2:] * axis


def _lafortune_axis(wo: np.ndarray, p: BrdfParams) -> np.ndarray:
    a = wo * np.array([p.cxy, p.cxy, p.cz])
    return a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-30)


def _glossy_pdf(wi: np.ndarray, wo: np.ndarray, p: BrdfParams) -> np.ndarray:
    n = lobe_exponent(p)
    if p.model == "lafortune":
        c = np.sum(wi * _lafortune_axis(wo, p), axis=-1)
        return np.where(c > 0.0, (n + 1.0) / (2.0 * np.pi) * np.maximum(c, 0.0) ** n, 0.0)
    h = wi + wo
    h /= np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-30)
    oh = np.sum(wo * h, axis=-1)
    ok = (oh > 0.0) & (h[:, 2] > 0.0)
    pdf_h = (n + 1.0) / (2.0 * np.pi) * np.maximum(h[:, 2], 0.0) ** n
    return np.where(ok, pdf_h / (4.0 * np.where(ok, oh, 1.0)), 0.0)


def pdf(wi: np.ndarray, wo: np.ndarray, p: BrdfParams) -> np.ndarray:
    """Solid-angle density (N,) of :func:`sample` returning ``wi`` given ``wo`` (N, 3)."""
    q = glossy_probability(p)
    cosine = np.maximum(wi[:, 2], 0.0) / np.pi
    if q == 0.0:
        return cosine
    return (1.0 - q) * cosine + q * _glossy_pdf(wi, wo, p)


def sample(wo: np.ndarray, u: np.ndarray, p: BrdfParams) -> np.ndarray:
    """Directions ωi (N, 3) for outgoing ``wo`` (N, 3) from uniform numbers ``u`` (N, 3):
    u[:, 0] picks the lobe, u[:, 1:] place the direction."""
    q = glossy_probability(p)
    r1, r2 = np.sqrt(u[:, 1]), 2.0 * np.pi * u[:, 2]
    wi = np.stack([r1 * np.cos(r2), r1 * np.sin(r2),
                   np.sqrt(np.maximum(0.0, 1.0 - u[:, 1]))], axis=-1)
    glossy = u[:, 0] < q
    if not glossy.any():
        return wi
    lobe = cos_power_direction(u[glossy, 1], u[glossy, 2], lobe_exponent(p))
    if p.model == "lafortune":
        wi[glossy] = frame_to_world(lobe, _lafortune_axis(wo[glossy], p))
    else:
        w, h = wo[glossy], lobe  # the half vector, about the normal
        wi[glossy] = 2.0 * np.sum(w * h, axis=-1, keepdims=True) * h - w
    return wi

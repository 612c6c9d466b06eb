"""A glossy BRDF times the cosine as one spherical Gaussian per view elevation: what method
sg's renderer needs to apply the BRDF at the pixel's own normal (decision 0042).

For an isotropic BRDF the glossy lobe ρs f(ωi, ωo) max(0, n·ωi) depends on ωo only
through c = n·ωo. Per c it is fitted (least squares over the sphere) by one Gaussian
a G(ωi; μ, λ), μ in the plane of n and ωo on the mirror side, at angle θ from n:

    μ = cos θ n − sin θ t,   t = (ωo − c n) / |ωo − c n|   (θ = θo: the mirror direction).

The table holds (θ, λ, a) at c_k = k / (K − 1), k = 0 … K − 1 (c_0 fitted at
c = 0.01); ρs is left out (it cancels in the renderer's ratio, where the face's 3
vertices share one material). θ moves the lobe above the horizon at grazing views, λ and
a keep its width and energy where the spherical warp of Wang et al. (2009) (λ = γ/(4c),
a = (γ + 2)/(2π) c for Blinn–Phong) is 24 % off the exact unshadowed radiance on
bunny_sg's pixels (the table: 9 %).
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np

from pipeline.math import sg
from pipeline.math.brdf import BrdfParams, glossy

TABLE = 32  # entries over c = cos θo ∈ [0, 1] (the kernel's SG_LOBE_TABLE)
GRID = (61, 120)  # the fit's lat-long grid over ωi (3° steps)
LOWEST = 0.01  # c_0 is fitted here: at c = 0 the view grazes the surface


@cache
def lobe_table(brdf: BrdfParams, size: int = TABLE) -> np.ndarray:
    """(size, 3) float64: per c_k = k/(size − 1) the fitted (θ rad, λ rad⁻², a 1/sr
    without ρs) of the module docstring; each fit starts from the next larger c's."""
    from scipy.optimize import least_squares

    directions, omega = sg.latlong_directions(*GRID)
    wi = directions.reshape(-1, 3)  # local frame: the normal is +z
    sw = np.sqrt(omega.ravel())
    cosine = np.maximum(wi[:, 2], 0.0)
    out = np.zeros((size, 3))
    start = None
    for k in range(size - 1, -1, -1):
        c = max(k / (size - 1), LOWEST)
        wo = np.array([math.sqrt(max(1.0 - c * c, 0.0)), 0.0, c])
        f = np.nan_to_num(glossy(wi, wo[None], brdf)) * cosine
        peak = float(f.max())
        if not peak > 0:
            out[k] = (math.acos(c), 1.0, 0.0)
            continue
        if start is None:
            start = [math.acos(c), math.log(2 * math.pi * peak / float(f @ omega.ravel())),
                     math.log(peak)]

        def residual(x: np.ndarray, f: np.ndarray = f) -> np.ndarray:
            mu = np.array([-math.sin(x[0]), 0.0, math.cos(x[0])])
            return sw * (math.exp(x[2]) * np.exp(math.exp(x[1]) * (wi @ mu - 1.0)) - f)

        start = least_squares(residual, start).x
        out[k] = (start[0], math.exp(start[1]), math.exp(start[2]))
    return out


def brdf_lobe(table: np.ndarray, normal: np.ndarray, wo: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The lobe of ``table`` (K, 3) (:func:`lobe_table`) at unit normals and directions
    to the eye (P, 3), world: means μ (P, 3) unit, λ (P,), a (P,) (0 where n·ωo ≤ 0),
    θ, λ and a linear in c between entries (the kernel's sg_brdf_lobe)."""
    n = np.asarray(normal, np.float64)
    wo = np.asarray(wo, np.float64)
    c = np.sum(n * wo, axis=-1)
    x = np.clip(c, 0.0, 1.0) * (len(table) - 1)
    k = np.minimum(np.floor(x).astype(np.int64), len(table) - 2)
    t = (x - k)[:, None]
    row = (1 - t) * table[k] + t * table[k + 1]
    side = wo - c[:, None] * n
    length = np.linalg.norm(side, axis=-1, keepdims=True)
    side = np.where(length > 1e-6, side / np.where(length > 1e-6, length, 1.0), 0.0)
    theta = row[:, 0:1]
    mu = np.cos(theta) * n - np.sin(theta) * side
    mu /= np.linalg.norm(mu, axis=-1, keepdims=True)
    return mu, row[:, 1], np.where(c > 0, row[:, 2], 0.0)

"""Real spherical harmonics in the world frame, +y up (method sg's diffuse light, paper
003 §3; Sloan et al. 2002).

**Basis.** With θ the angle from +y and φ = atan2(x, −z) the azimuth of the
environment map's mapping (pipeline/math/envmap.py: u = φ / 2π), the real orthonormal
harmonics are, for l ≥ 0 and −l ≤ m ≤ l,

    Y_l^0  = K_l^0 P_l^0(cos θ),
    Y_l^m  = √2 K_l^m cos(mφ) P_l^m(cos θ),       m > 0,
    Y_l^−m = √2 K_l^m sin(mφ) P_l^m(cos θ),       m > 0,
    K_l^m  = √((2l + 1)/(4π) · (l − m)!/(l + m)!),

P_l^m the associated Legendre functions without the Condon–Shortley phase. They are
orthonormal, ∫ Y_k Y_k' dω = δ_kk', and stored flat at k = l² + l + m, so order n
(l < n) has n² coefficients. Order 5 (25 coefficients) is paper 003's.

**Projection.** f ≈ Σ_k f_k Y_k with f_k = ∫ f Y_k dω; for a product of two band-limited
functions the integral is a dot product, ∫ f g dω = Σ_k f_k g_k, which is how a vertex's
diffuse transfer meets the lighting.

**Rotation about +y.** Turning a function by α about +y (``envmap.rotation_y``, which
takes φ to φ − α) mixes each pair (m, −m): the turned function f'(ω) = f(R^T ω) has
f'_{l,m} = cos(mα) f_{l,m} + sin(mα) f_{l,−m} and f'_{l,−m} = cos(mα) f_{l,−m} −
sin(mα) f_{l,m}; the m = 0 coefficients stay. So a light's rotation costs nothing.
"""

from __future__ import annotations

from math import factorial

import numpy as np
from scipy.special import lpmv

ORDER = 5  # bands l = 0..4, 25 coefficients (paper 003)


def index(l: int, m: int) -> int:  # noqa: E741 (l is the band, as in every SH text)
    """Flat index k = l² + l + m of Y_l^m."""
    return l * l + l + m


def _angles(directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cos θ (from +y) and φ = atan2(x, −z) of unit directions (..., 3)."""
    d = np.asarray(directions, np.float64)
    return np.clip(d[..., 1], -1.0, 1.0), np.arctan2(d[..., 0], -d[..., 2])


def basis(directions: np.ndarray, order: int = ORDER) -> np.ndarray:
    """Y_k (..., order²) at unit directions (..., 3), world frame."""
    cos_theta, phi = _angles(directions)
    out = np.empty(cos_theta.shape + (order * order,))
    for l in range(order):  # noqa: E741
        for m in range(l + 1):
            k = np.sqrt((2 * l + 1) / (4.0 * np.pi) * factorial(l - m) / factorial(l + m))
            # scipy's lpmv carries the Condon–Shortley phase (−1)^m: take it out
            legendre = (-1.0) ** m * lpmv(m, l, cos_theta)
            if m == 0:
                out[..., index(l, 0)] = k * legendre
            else:
                out[..., index(l, m)] = np.sqrt(2.0) * k * np.cos(m * phi) * legendre
                out[..., index(l, -m)] = np.sqrt(2.0) * k * np.sin(m * phi) * legendre
    return out


def project(directions: np.ndarray, solid_angles: np.ndarray, values: np.ndarray,
            order: int = ORDER) -> np.ndarray:
    """Coefficients (order², C) of a function sampled at unit ``directions`` (S, 3) with
    quadrature weights ``solid_angles`` (S,) (sr): Σ_s values[s] Y_k(ω_s) Ω_s for
    ``values`` (S, C)."""
    weighted = basis(directions, order) * np.asarray(solid_angles)[:, None]
    return weighted.T @ np.asarray(values, np.float64)


def rotate_y(coefficients: np.ndarray, degrees: float) -> np.ndarray:
    """Coefficients (order², ...) of the function turned by ``degrees`` about +y (the
    module docstring's rule; ``envmap.rotation_y``'s sense)."""
    c = np.asarray(coefficients, np.float64)
    order = int(round(np.sqrt(c.shape[0])))
    out = c.copy()
    alpha = np.radians(degrees)
    for l in range(1, order):  # noqa: E741
        for m in range(1, l + 1):
            cos, sin = np.cos(m * alpha), np.sin(m * alpha)
            plus, minus = c[index(l, m)], c[index(l, -m)]
            out[index(l, m)] = cos * plus + sin * minus
            out[index(l, -m)] = cos * minus - sin * plus
    return out


def rotation_matrix(to_world: np.ndarray, order: int = ORDER) -> np.ndarray:
    """M (order², order²) turning coefficients by the rotation ``to_world`` (3×3, any
    axis): the turned function f'(ω) = f(Rᵀω) has f' = M f, M_kj = ∫ Y_k(ω) Y_j(Rᵀω) dω.
    Rotation keeps each band, so the product Y_k (Y_j ∘ Rᵀ) is a polynomial of band
    ≤ 2(order − 1) and the quadrature is exact: Gauss–Legendre in cos θ with ``order``
    nodes (exact to degree 2·order − 1) times 2·order equally spaced φ (exact to
    frequency 2·order − 1). About +y it is :func:`rotate_y`'s rule."""
    nodes, weights = np.polynomial.legendre.leggauss(order)
    n_phi = 2 * order
    phi = 2.0 * np.pi * (np.arange(n_phi) + 0.5) / n_phi
    sin_theta = np.sqrt(1.0 - nodes ** 2)[:, None]
    directions = np.stack([sin_theta * np.sin(phi), np.broadcast_to(nodes[:, None],
                           (order, n_phi)), -sin_theta * np.cos(phi)], axis=-1).reshape(-1, 3)
    solid = np.repeat(weights * (2.0 * np.pi / n_phi), n_phi)
    here = basis(directions, order) * solid[:, None]
    turned = basis(directions @ np.asarray(to_world, np.float64), order)  # Y_j(Rᵀω)
    return here.T @ turned


def rotate(coefficients: np.ndarray, to_world: np.ndarray) -> np.ndarray:
    """Coefficients (order², ...) of the function turned by the 3×3 rotation
    ``to_world`` (any axis; :func:`rotation_matrix`)."""
    c = np.asarray(coefficients, np.float64)
    order = int(round(np.sqrt(c.shape[0])))
    return np.tensordot(rotation_matrix(to_world, order), c, axes=1)


def latlong_quadrature(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Directions (H, W, 3) and solid angles (H, 1) (sr) of a lat-long map's samples as
    ``envmap.EnvironmentMap.radiance`` reads them: row i at θ = πi/(H − 1) (the poles
    are rows), column j at φ = 2π(j + ½)/W. Each sample owns the band θ_i ± Δ/2 (half
    a band at the poles) times 2π/W: the trapezoid rule in θ, summing to 4π."""
    theta = np.pi * np.arange(height) / (height - 1)
    half = 0.5 * np.pi / (height - 1)
    top, bottom = np.clip(theta - half, 0.0, np.pi), np.clip(theta + half, 0.0, np.pi)
    solid = (2.0 * np.pi / width) * (np.cos(top) - np.cos(bottom))
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width
    st = np.sin(theta)[:, None]
    directions = np.stack([st * np.sin(phi), np.broadcast_to(np.cos(theta)[:, None],
                           (height, width)), -st * np.cos(phi)], axis=-1)
    return directions, solid[:, None]


def project_latlong(rgb: np.ndarray, degrees: float = 0.0, order: int = ORDER
                    ) -> np.ndarray:
    """Coefficients (order², C) of a lat-long map (H, W, C) as lit in the world when
    turned by ``degrees`` about +y (radiance from world ω = map(R^T ω), as
    ``EnvironmentMap``), by :func:`latlong_quadrature`. Separable: θ is constant along
    a row and φ along a column, so each row is first reduced to its Fourier sums
    Σ_j rgb cos(mφ_j), Σ_j rgb sin(mφ_j) (m < order), then weighted by K P_l^m(cos θ_i)
    and the row's solid angle: O(H W order) instead of O(H W order²)."""
    rgb = np.asarray(rgb, np.float64)
    height, width = rgb.shape[:2]
    _, solid = latlong_quadrature(height, width)
    theta = np.pi * np.arange(height) / (height - 1)
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width
    m = np.arange(order)
    cos_sums = np.einsum("hwc,wm->hmc", rgb, np.cos(np.outer(phi, m)))
    sin_sums = np.einsum("hwc,wm->hmc", rgb, np.sin(np.outer(phi, m)))
    out = np.zeros((order * order, rgb.shape[2]))
    row_weight = solid[:, 0]
    for l in range(order):  # noqa: E741
        for mm in range(l + 1):
            k = np.sqrt((2 * l + 1) / (4.0 * np.pi) * factorial(l - mm) / factorial(l + mm))
            radial = row_weight * k * (-1.0) ** mm * lpmv(mm, l, np.cos(theta))  # (H,)
            if mm == 0:
                out[index(l, 0)] = radial @ cos_sums[:, 0]
            else:
                out[index(l, mm)] = np.sqrt(2.0) * (radial @ cos_sums[:, mm])
                out[index(l, -mm)] = np.sqrt(2.0) * (radial @ sin_sums[:, mm])
    return rotate_y(out, degrees)

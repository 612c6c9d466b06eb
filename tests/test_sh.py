"""Real spherical harmonics (pipeline/math/sh.py): orthonormality, projection of a known
function, rotation about +y against re-projection, and the lat-long projection against
the map as ``EnvironmentMap`` reads it."""

from __future__ import annotations

import numpy as np

from pipeline.math import sh
from pipeline.math.envmap import EnvironmentMap, rotation_y


def gauss_legendre_sphere(n_theta: int, n_phi: int) -> tuple[np.ndarray, np.ndarray]:
    """Directions (S, 3) and weights (S,) of a product rule exact for band-limited
    functions of degree < min(2 n_theta, n_phi): Gauss–Legendre in cos θ (θ from +y),
    uniform in φ."""
    x, w = np.polynomial.legendre.leggauss(n_theta)
    phi = 2.0 * np.pi * (np.arange(n_phi) + 0.5) / n_phi
    st = np.sqrt(1.0 - x * x)[:, None]
    d = np.stack([st * np.sin(phi), np.broadcast_to(x[:, None], (n_theta, n_phi)),
                  -st * np.cos(phi)], axis=-1).reshape(-1, 3)
    weights = np.repeat(w * 2.0 * np.pi / n_phi, n_phi)
    return d, weights


def test_orthonormal() -> None:
    # products of two order-5 harmonics have degree ≤ 8: the 16×32 rule integrates
    # them exactly, so the Gram matrix is the identity to rounding (1e-12)
    d, w = gauss_legendre_sphere(16, 32)
    y = sh.basis(d)
    gram = (y * w[:, None]).T @ y
    assert np.abs(gram - np.eye(25)).max() < 1e-12


def test_low_bands_closed_form() -> None:
    # Y_0^0 = 1/(2√π); Y_1^0 = √(3/4π) cos θ (θ from +y); Y_1^1 = √(3/4π) sin θ cos φ
    # with φ = atan2(x, −z), i.e. √(3/4π)·(−z)
    d = np.random.default_rng(1).normal(size=(50, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    y = sh.basis(d)
    c = np.sqrt(3.0 / (4.0 * np.pi))
    assert np.allclose(y[:, 0], 0.5 / np.sqrt(np.pi))
    assert np.allclose(y[:, sh.index(1, 0)], c * d[:, 1])
    assert np.allclose(y[:, sh.index(1, 1)], c * -d[:, 2])
    assert np.allclose(y[:, sh.index(1, -1)], c * d[:, 0])


def test_projection_recovers_a_band_limited_function() -> None:
    coefficients = np.random.default_rng(2).normal(size=(25, 3))
    d, w = gauss_legendre_sphere(16, 32)
    values = sh.basis(d) @ coefficients
    assert np.allclose(sh.project(d, w, values), coefficients, atol=1e-12)


def test_rotation_about_y_equals_reprojection() -> None:
    coefficients = np.random.default_rng(3).normal(size=(25, 2))
    d, w = gauss_legendre_sphere(16, 32)
    rot = rotation_y(37.0)
    # turned function f'(ω) = f(Rᵀω); rows of d are ω, so Rᵀω = d @ rot
    turned = sh.basis(d @ rot) @ coefficients
    assert np.allclose(sh.project(d, w, turned), sh.rotate_y(coefficients, 37.0),
                       atol=1e-12)


def test_latlong_projection_matches_the_map_as_read() -> None:
    # A smooth map (degree ≤ 4 in direction) sampled as a lat-long image: the separable
    # trapezoid projection must match a fine Gauss–Legendre projection of the map as
    # EnvironmentMap reads it (bilinear between samples), turned by the same angle.
    # Tolerance 2e-3 of the largest coefficient: the trapezoid rule in θ and the
    # bilinear interpolation both err by O(Δθ²) with Δθ = π/63.
    truth = np.random.default_rng(4).normal(size=(25, 3))
    truth[0] += 6.0  # positive radiance
    height, width = 64, 128
    directions, _ = sh.latlong_quadrature(height, width)
    rgb = sh.basis(directions) @ truth
    degrees = 70.0
    coefficients = sh.project_latlong(rgb, degrees)
    d, w = gauss_legendre_sphere(40, 80)
    as_read = EnvironmentMap(rgb, rotation=degrees).radiance(d)
    expected = sh.project(d, w, as_read)
    assert np.abs(coefficients - expected).max() < 2e-3 * np.abs(expected).max()
    assert np.abs(coefficients - sh.rotate_y(truth, degrees)).max() < 2e-3 * np.abs(truth).max()


def test_constant_map() -> None:
    # L(ω) = c everywhere: L_00 = c √(4π) exactly (the trapezoid weights sum to 4π);
    # every m ≠ 0 band is 0 to rounding (the φ sums of cos mφ, sin mφ vanish); the m = 0
    # bands l = 2, 4 are 0 only up to the trapezoid rule's O(Δθ²) error in θ:
    # Δθ = π/32 here, so ≤ 2e-3 of L_00
    rgb = np.full((33, 64, 3), 2.5)
    coefficients = sh.project_latlong(rgb, 15.0)
    assert np.allclose(coefficients[0], 2.5 * np.sqrt(4.0 * np.pi), rtol=1e-12)
    m_zero = [sh.index(band, 0) for band in range(1, sh.ORDER)]
    others = np.setdiff1d(np.arange(1, 25), m_zero)
    assert np.abs(coefficients[others]).max() < 1e-12
    assert np.abs(coefficients[m_zero]).max() < 2e-3 * coefficients[0].max()


def test_rotation_about_any_axis():
    """sh.rotate by a rotation about any axis: orthogonal, about +y the closed-form
    rotate_y, and the turned coefficients evaluate to the function at Rᵀω (to float64
    rounding: the quadrature is exact for band-limited functions)."""
    from pipeline.math.envmap import rotation_about

    c = np.random.default_rng(0).normal(size=(64, 3))
    np.testing.assert_allclose(sh.rotate(c, rotation_y(37.0)), sh.rotate_y(c, 37.0),
                               atol=1e-12)
    turn = rotation_about((1.0, 2.0, 3.0), 50.0)
    m = sh.rotation_matrix(turn, 8)
    np.testing.assert_allclose(m @ m.T, np.eye(64), atol=1e-12)
    d = np.random.default_rng(1).normal(size=(100, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(sh.basis(d, 8) @ sh.rotate(c, turn),
                               sh.basis(d @ turn, 8) @ c, atol=1e-12)

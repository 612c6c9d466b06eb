"""The pieces of studies/sg_fig5.py (paper 003 Fig. 5) at tiny size: each
representation reproduces a function it can represent exactly (error 0) and not one it
cannot; Haar's error is the dropped coefficients' norm; welded normals ignore how a mesh
file split its vertices."""

from __future__ import annotations

import importlib.util
import sys

import numpy as np
from helpers import PROJECT

from pipeline.math import sg, sh
from pipeline.math.sphwavelet import wavelet_basis

_SPEC = importlib.util.spec_from_file_location("sg_fig5", PROJECT / "studies" / "sg_fig5.py")
fig5 = importlib.util.module_from_spec(_SPEC)
sys.modules["sg_fig5"] = fig5  # dataclasses look their module up there
_SPEC.loader.exec_module(fig5)

LEVEL = 3  # 1280 leaves, 6.3° apart


def test_relative_l2_is_the_weighted_norm_ratio():
    """‖a − d‖/‖d‖ with Σ Ω weights: 0 for a = d, |s − 1| for a = s·d, 1 for a = 0."""
    d, omega = fig5.sphere_grid(2)
    data = np.random.default_rng(1).random((len(d), 3))
    assert fig5.relative_l2(data, data, omega) == 0.0
    assert abs(fig5.relative_l2(1.3 * data, data, omega) - 0.3) < 1e-12
    assert abs(fig5.relative_l2(0 * data, data, omega) - 1.0) < 1e-12


def test_haar_keeps_an_exactly_sparse_function_and_its_error_is_the_dropped_norm():
    """A function made of 9 basis functions (scaling and wavelets at every level) is
    rebuilt to rounding (1e-12) from its 9 largest coefficients; keeping 8 leaves the
    smallest one out, and the basis being orthonormal in the solid-angle norm, the
    error is exactly |c_min| / ‖c‖ (to 1e-12)."""
    basis = wavelet_basis(LEVEL)
    rng = np.random.default_rng(2)
    coefficients = np.zeros((3, basis.size))
    chosen = rng.choice(basis.size, 9, replace=False)
    chosen[0] = 3  # a root scaling coefficient among them
    coefficients[:, chosen] = rng.uniform(0.5, 2.0, 9) * np.array([[1.0], [0.7], [0.4]])
    data = basis.inverse(coefficients).T                                   # (S, 3)
    _, omega = fig5.sphere_grid(LEVEL)
    assert fig5.relative_l2(fig5.haar_truncation(data, LEVEL, 9), data, omega) < 1e-12
    norms = np.linalg.norm(coefficients[:, chosen], axis=0)
    expected = norms.min() / np.linalg.norm(norms)
    assert abs(fig5.relative_l2(fig5.haar_truncation(data, LEVEL, 8), data, omega)
               - expected) < 1e-12


def test_sh_least_squares_is_exact_within_its_bands_only():
    """A random combination of the bands l < 3 is reproduced by order 3 to 1e-10 (the
    least squares is exact on its span); order 2 drops band 2, which holds half of the
    function's squared norm here, so the error is far from 0 (> 0.5 with the
    quadrature's coupling of the bands small on 1280 leaves)."""
    d, omega = fig5.sphere_grid(LEVEL)
    c = np.random.default_rng(3).normal(size=(9, 2))
    c[4:] *= np.sqrt(np.sum(c[:4] ** 2, 0) / np.sum(c[4:] ** 2, 0))  # band 2: half
    data = sh.basis(d, 3) @ c
    assert fig5.relative_l2(fig5.sh_least_squares(d, omega, data, 3), data, omega) < 1e-10
    assert fig5.relative_l2(fig5.sh_least_squares(d, omega, data, 2), data, omega) > 0.5


def test_gaussians_recover_a_sum_of_two_gaussians():
    """Two lobes (σ 15° and 20°, 80° apart, RGB weights) are fitted with error below
    1e-3 by N = 2 (the fit's stopping tolerance, 1e-8 relative energy, allows ≈ 1e-4),
    and N = 1 cannot hold both (error > 0.3)."""
    d, omega = fig5.sphere_grid(LEVEL)
    mu = np.array([[0.0, 1.0, 0.0], [np.sin(np.radians(80)), np.cos(np.radians(80)), 0.0]])
    lam = sg.sharpness(np.radians([15.0, 20.0]))
    w = np.array([[1.0, 0.8, 0.6], [0.7, 0.7, 0.9]])
    data = sg.evaluate(d[:, None], mu[None], lam[None]) @ w
    results = fig5.fit_gaussians(d, omega, data, 2)
    errors = [fig5.relative_l2(fig5.sg_values(d, r["fit"]), data, omega) for r in results]
    assert errors[1] < 1e-3 and errors[0] > 0.3
    assert set(results[1]["starts"]) == {"moments", "continuation"}

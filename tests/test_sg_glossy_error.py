"""The pieces of studies/sg_glossy_error.py (decision 0037) that need no bake: the
sub-triangle lookup behind its refinement rows, and the quadrature truth's lobe
integral against the lookup's reference."""

from __future__ import annotations

import importlib.util
import sys
from types import SimpleNamespace

import numpy as np
from helpers import PROJECT

from pipeline.math import sg

_SPEC = importlib.util.spec_from_file_location(
    "sg_glossy_error", PROJECT / "studies" / "sg_glossy_error.py")
study = importlib.util.module_from_spec(_SPEC)
sys.modules["sg_glossy_error"] = study
_SPEC.loader.exec_module(study)


def test_sub_triangle_holds_the_point():
    """Corners on the s-lattice, weights ≥ 0 summing to 1 that rebuild the barycentrics,
    at random points, vertices and edge midpoints."""
    rng = np.random.default_rng(3)
    points = [*rng.dirichlet([1, 1, 1], 200), np.array([1.0, 0, 0]), np.array([0.5, 0.5, 0]),
              np.array([0.25, 0.25, 0.5])]
    for s in (2, 4):
        for b in points:
            corners, weights = study.sub_triangle(b, s)
            assert np.allclose(corners.sum(axis=1), s)
            assert np.all(corners >= 0) and np.all(weights >= -1e-12)
            assert abs(weights.sum() - 1) < 1e-12
            assert np.allclose(weights @ corners / s, b)


def test_truth_lobe_integral_matches_the_map_quadrature():
    """Truth.lobes on a lat-long grid equals sg.env_integral_reference on a map sampled
    at that grid (a smooth map: the same quadrature)."""
    rows, cols = 33, 64
    d, omega = sg.latlong_directions(rows, cols)
    rgb = 1.0 + 0.5 * d[..., [0, 1, 2]]
    truth = study.Truth(None, SimpleNamespace(specular=(0.1, 0.1, 0.1)), rgb.reshape(-1, 3),
                        d.reshape(-1, 3), omega.ravel(), None)
    mu = np.array([[0.0, 1.0, 0.0], [0.6, 0.0, 0.8]])
    lam = np.array([20.0, 5.0])
    w = np.array([[1.0, 2.0, 3.0], [0.5, 0.5, 0.5]])
    got = truth.lobes(mu[:, None], lam[:, None], w[:, None])
    assert np.allclose(got, sg.env_integral_reference(rgb, mu, lam, w), rtol=1e-10)


def test_the_hybrid_is_the_ratio_below_the_unshadowed_light_and_additive_above():
    """studies/sg_glossy_error.py ``corrected`` (decision 0042): per channel, where the
    corners hold less than their unshadowed light (F ≤ U) the hybrid is U_p F/U, where
    more it is F + U_p − U; U = 0 leaves v = 1."""
    rng = np.random.default_rng(5)
    bary = rng.dirichlet([1, 1, 1], 400)
    u = rng.uniform(0.1, 2.0, (400, 3, 3))
    f = u * rng.uniform(0.0, 2.0, (400, 3, 1))
    up = rng.uniform(0.1, 3.0, (400, 3))
    fs, us = np.einsum("pa,pac->pc", bary, f), np.einsum("pa,pac->pc", bary, u)
    ratio = study.corrected(up, f, u, bary, "ratio")
    additive = study.corrected(up, f, u, bary, "additive")
    hybrid = study.corrected(up, f, u, bary, "hybrid")
    below = fs <= us
    assert 0 < below.mean() < 1
    assert np.allclose(hybrid[below], ratio[below]) and np.allclose(ratio, fs * up / us)
    assert np.allclose(hybrid[~below], additive[~below])
    assert np.allclose(study.corrected(up, f, 0 * u, bary, "hybrid"), fs + up)

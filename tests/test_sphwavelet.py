"""Spherical Haar wavelets on the geodesic sphere (pipeline/math/geodesic.py,
pipeline/math/sphwavelet.py): the hierarchy, the basis, transforms and triple products."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from pipeline.math.geodesic import geodesic_levels, locate, solid_angles
from pipeline.math.sphwavelet import (
    PATTERNS,
    basis_functions,
    depth_first_keys,
    equal_area_basis,
    kernel_tables,
    leaf_means,
    sparse_triple_product,
    tripling_by_quadrature,
    tripling_coefficients,
    wavelet_basis,
)

FLOAT64 = 1e-12  # rounding of a few hundred float64 operations on values of order 1


def random_directions(n: int, seed: int = 0) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_hierarchy_areas_and_nesting():
    levels = geodesic_levels(4)
    assert [len(level.faces) for level in levels] == [20, 80, 320, 1280, 5120]
    for coarse, fine in zip(levels, levels[1:], strict=False):
        assert np.allclose(fine.areas.reshape(-1, 4).sum(axis=1), coarse.areas, atol=FLOAT64)
        assert fine.areas.sum() == pytest.approx(4 * np.pi, abs=FLOAT64)
        # the children's corners are the parent's corners and edge midpoints (sphere)
        parent = coarse.corners
        child = fine.corners.reshape(-1, 4, 3, 3)
        for corner in range(3):
            assert np.allclose(child[:, corner, corner], parent[:, corner])
    # The geodesic grid's figures: unequal children, 1.30 between extreme leaves.
    first = levels[1].areas.reshape(-1, 4)
    assert first[:, 3] / first[:, 0] == pytest.approx(1.2031, abs=1e-4)
    assert levels[4].areas.max() / levels[4].areas.min() == pytest.approx(1.2989, abs=1e-4)


def test_solid_angle_of_an_octant():
    e = np.eye(3)
    assert solid_angles(e[0], e[1], e[2]) == pytest.approx(np.pi / 2, rel=FLOAT64)


def test_locate_finds_the_leaf_that_holds_the_direction():
    level = geodesic_levels(3)[3]
    d = random_directions(20000)
    leaf = locate(d, 3)
    corners = level.corners[leaf]
    for p, q in ((0, 1), (1, 2), (2, 0)):
        assert np.all(np.einsum("ni,ni->n", np.cross(corners[:, p], corners[:, q]), d) > -FLOAT64)
    assert np.array_equal(locate(level.centroids, 3), np.arange(len(level.faces)))
    # a direction's leaf at level 3 lies inside its triangle at level 1
    assert np.array_equal(locate(d, 1), leaf >> 4)


@pytest.mark.parametrize("leaf_level", [1, 2, 4])
def test_perfect_reconstruction_and_parseval(leaf_level):
    basis = wavelet_basis(leaf_level)
    x = np.random.default_rng(leaf_level).normal(size=(3, basis.size))
    c = basis.forward(x)
    assert np.abs(basis.inverse(c) - x).max() < FLOAT64
    assert np.sum(c ** 2, axis=1) == pytest.approx(np.sum(basis.leaf_areas() * x ** 2, axis=1),
                                                    rel=FLOAT64)


def test_basis_is_orthonormal_with_solid_angle_weights():
    basis = wavelet_basis(3)
    psi = basis_functions(basis, np.arange(basis.size))
    gram = (psi * basis.leaf_areas()) @ psi.T
    assert np.abs(gram - np.eye(basis.size)).max() < 1e-6  # the bound; found ~1e-14


def test_equal_area_patterns_are_not_orthogonal_here():
    """Why the basis is corrected: the paper's ±1 patterns on the real (unequal) children
    are off orthogonality by several per cent."""
    areas = geodesic_levels(1)[1].areas.reshape(-1, 4)
    p = np.array([[1, -1, -1, 1], [1, -1, 1, -1], [1, 1, -1, -1]], float)
    gram = np.einsum("ac,nc,bc->nab", p, areas, p)
    off = np.abs(gram[:, 0, 1]) / gram[:, 0, 0]
    assert off.max() > 0.02


def test_tripling_coefficients_of_the_first_two_levels_match_quadrature():
    """Every tripling coefficient among the 320 functions of levels 0 and 1 (a basis of
    leaf level 2), sparse list against the dense leaf-by-leaf integral."""
    basis = wavelet_basis(2)
    psi = basis_functions(basis, np.arange(basis.size))
    pairs = (psi[:, None, :] * psi[None, :, :] * basis.leaf_areas()).reshape(-1, basis.size)
    dense = (pairs @ psi.T).reshape(basis.size, basis.size, basis.size)
    listed = np.zeros_like(dense)
    indices, values = tripling_coefficients(basis)
    for (i, j, k), v in zip(indices, values, strict=True):
        for p in set(itertools.permutations((i, j, k))):
            listed[p] = v
    assert np.abs(listed - dense).max() < FLOAT64 * np.abs(dense).max()
    assert np.count_nonzero(np.abs(dense) > FLOAT64) == np.count_nonzero(listed)
    assert tripling_by_quadrature(basis, *indices[-1]) == pytest.approx(values[-1], rel=1e-12)


def test_tree_triple_product_equals_the_sparse_tripling_sum():
    basis = wavelet_basis(3)
    f, g, h = np.random.default_rng(7).normal(size=(3, basis.size))
    indices, values = tripling_coefficients(basis)
    total = 0.0
    for (i, j, k), v in zip(indices, values, strict=True):
        orders = set(itertools.permutations((i, j, k)))
        total += v * sum(f[a] * g[b] * h[c] for a, b, c in orders)
    assert basis.triple_product(f, g, h) == pytest.approx(total, rel=1e-10)


def smooth_lobes(seed: int):
    """A random smooth positive spherical function: a few spherical Gaussians."""
    rng = np.random.default_rng(seed)
    axes = random_directions(4, seed)
    sharpness = rng.uniform(2, 20, 4)
    weights = rng.uniform(0.2, 1.0, 4)

    def f(d: np.ndarray) -> np.ndarray:
        return np.sum(weights * np.exp(sharpness * (d @ axes.T - 1.0)), axis=-1) + 0.1
    return f


def test_triple_product_of_smooth_functions_against_brute_force_quadrature():
    """∫ f g h over the sphere: the wavelet triple product of the level-4 projections
    against a 327 680-cell quadrature of the functions themselves. The projections
    differ from the functions by O(leaf size · gradient); with lobes of sharpness ≤ 20
    on leaves of ~3° that is ≲ 1 % of the integral, halving per level."""
    functions = [smooth_lobes(s) for s in (1, 2, 3)]
    fine = geodesic_levels(7)[7]
    exact = np.sum(fine.areas * np.prod([f(fine.centroids) for f in functions], axis=0))
    errors = []
    for level in (3, 4):
        basis = wavelet_basis(level)
        coefficients = [basis.forward(leaf_means(f, level)) for f in functions]
        errors.append(abs(basis.triple_product(*coefficients) / exact - 1))
    assert errors[1] < 0.01
    assert errors[1] < 0.5 * errors[0]


def test_equal_area_basis_is_the_papers_rules():
    """The paper's basis: normalised sign patterns, and its triple product is the
    equal-weight leaf sum (what the paper's tripling theorem computes)."""
    basis = equal_area_basis(3)
    assert np.allclose(basis.wavelets[0][0] * np.sqrt(4 * np.pi / 80), PATTERNS / 2)
    x = np.random.default_rng(3).normal(size=(3, basis.size))
    c = basis.forward(x)
    assert np.abs(basis.inverse(c) - x).max() < FLOAT64
    equal_weight = np.sum(4 * np.pi / basis.size * x[0] * x[1] * x[2])
    assert basis.triple_product(*c) == pytest.approx(equal_weight, rel=1e-10)


def test_depth_first_sparse_triple_product_equals_the_dense_one():
    """Ng et al.'s sparse algorithm on this hierarchy: random sparse lists (5–90 % of the
    coefficients kept, different per function) give the dense tree sum."""
    basis = wavelet_basis(3)
    keys = depth_first_keys(3)
    assert len(np.unique(keys)) == basis.size
    rng = np.random.default_rng(0)
    for _ in range(10):
        dense = rng.normal(size=(3, basis.size))
        lists = []
        for f in dense:
            kept = rng.random(basis.size) < rng.uniform(0.05, 0.9)
            f[~kept] = 0.0
            order = np.flatnonzero(kept)[np.argsort(keys[kept])]
            lists.append((order, f[order]))
        assert sparse_triple_product(basis, tuple(lists)) == pytest.approx(
            basis.triple_product(*dense), rel=1e-9, abs=1e-9)


def csr_table(rng: np.random.Generator, rows: int, basis, keys: np.ndarray,
              fraction: float, channels: int
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A random sparse table: start (rows + 1,), index (ushort, depth-first sorted per
    row), value (entries, channels) float32, and the dense rows (rows, N, 3) it stands
    for (a grey table's value in all three channels)."""
    dense = np.zeros((rows, basis.size, 3), np.float32)
    start, index, value = [0], [], []
    for r in range(rows):
        kept = np.flatnonzero(rng.random(basis.size) < fraction)
        kept = kept[np.argsort(keys[kept])]
        v = rng.normal(size=(len(kept), channels)).astype(np.float32)
        dense[r, kept] = v
        index.append(kept)
        value.append(v)
        start.append(start[-1] + len(kept))
    return (np.array(start, np.uint32), np.concatenate(index).astype(np.uint16),
            np.concatenate(value), dense)


def test_triple_product_kernel_matches_numpy():
    """kernels/sphwavelet.h: RGB triple products of RGB-weighted sums of up to 8 sparse
    rows per function (tables of RGB, grey and RGB values) against the dense float64
    tree sum per channel. Tolerance: float32 sums of ~10³ terms of order 1: ~10² ulp,
    relative 1e-5 of the sum of the terms' magnitudes (found 4e-7)."""
    cl = pytest.importorskip("pipeline.device.cl")
    level, n, rows_max = 3, 64, 8
    basis = wavelet_basis(level)
    keys = depth_first_keys(level)
    rng = np.random.default_rng(11)
    channels = (3, 1, 3)
    tables = [csr_table(rng, 12, basis, keys, fraction, ch)
              for fraction, ch in zip((0.6, 0.1, 0.3), channels, strict=True)]
    rows = rng.integers(0, 12, size=(n, 3, rows_max)).astype(np.uint32)
    weight = rng.uniform(0, 1, size=(n, 3, rows_max, 3)).astype(np.float32)
    count = rng.integers(1, rows_max + 1, size=(n, 3)).astype(np.int32)
    dense = np.zeros((3, n, 3, basis.size))  # function, item, channel, coefficient
    for f in range(3):
        for i in range(n):
            k = count[i, f]
            dense[f, i] = np.einsum("rc,rnc->cn", weight[i, f, :k], tables[f][3][rows[i, f, :k]])
    expected = basis.triple_product(*dense)
    scale = basis.triple_product(*np.abs(dense))  # ≥ every partial sum's magnitude
    tables32 = kernel_tables(basis)
    buffers = [cl.read_only_buffer(a) for t in tables for a in t[:3]]
    buffers.append(np.array([*channels, 0], np.int32))
    buffers += [cl.read_only_buffer(a) for a in (rows, weight, count)]
    buffers += [cl.read_only_buffer(tables32[k]) for k in ("root_area", "wavelet", "tensor")]
    out = np.empty((n, 3), np.float32)
    kernel = cl.kernel("triple_product.cl", "triple_products",
                       {"SW_LEVELS": level, "SW_ROWS": rows_max})
    cl.run(kernel, n, *buffers, np.int32(n), out=out)
    assert np.all(np.abs(out - expected) <= 1e-5 * scale), np.max(np.abs(out - expected) / scale)
    assert np.abs(expected).max() > 1e-3 * scale.max()  # the sums are not trivially zero

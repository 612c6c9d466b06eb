"""Method triple's per-pixel shading (pipeline/methods/triple/render.py,
kernels/triple/triple.cl)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.math.sphwavelet import depth_first_keys, wavelet_basis
from pipeline.methods.triple.frame_grids import FrameGrid, ViewGrid
from pipeline.methods.triple.render import shade, shade_numpy
from pipeline.methods.triple.tables import (
    PixelLookups,
    TripleTables,
    WaveletRows,
    brdf_lookups,
    read_rows,
    texel_lookups,
)
from pipeline.methods.triple.wavelet_rows import select_rows, to_half

LEVEL = 2


def random_rows(rng, count: int, channels: int, budget: int,
                mask: np.ndarray | None = None) -> WaveletRows:
    """``count`` random smooth-ish functions, transformed and truncated to ``budget``;
    zero on the leaves where ``mask`` (leaves,) is False."""
    basis = wavelet_basis(LEVEL)
    leaf = rng.normal(size=(count, channels, basis.size)) + 2.0
    if mask is not None:
        leaf *= mask
    coefficients = basis.forward(leaf)
    rows = select_rows(coefficients, LEVEL, budget, 0.0, 0)
    value = rows["value"][:, 0] if channels == 1 else rows["value"]
    return WaveletRows.from_counts(rows["count"], rows["index"], value)


def synthetic_tables(rng) -> TripleTables:
    """Two materials: 0 glossy (view rows 0 .. V − 1, diffuse row V), 1 Lambertian
    (diffuse row V + 1)."""
    frames, views = FrameGrid(4, 3, 4), ViewGrid(4, 3)
    brdf = random_rows(rng, views.size + 2, 1, 120)
    return TripleTables(wavelet_basis(LEVEL), frames, views,
                        random_rows(rng, frames.size, 3, 150), random_rows(rng, 30, 1, 100),
                        brdf, np.array([0, -1]), np.array([views.size, views.size + 1]))


def random_lookups(rng, tables: TripleTables, n: int) -> PixelLookups:
    normal = rng.normal(size=(n, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    tangent = np.cross(normal, rng.normal(size=(n, 3)))
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    light_rows, light_weight = tables.frames.weights(normal, tangent, turn=0.3)
    vis_rows = rng.integers(0, tables.visibility.rows, size=(n, 4))
    vis_weight = rng.dirichlet(np.ones(4), size=n)
    wo = rng.normal(size=(n, 3))
    wo[:, 2] = np.abs(wo[:, 2])
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    material = rng.integers(0, 2, size=n)
    kd = np.array([[0.3, 0.2, 0.1], [0.5, 0.5, 0.5]])
    rho_s = np.array([[0.1, 0.2, 0.3], [0.0, 0.0, 0.0]])
    brdf_rows, brdf_weight = brdf_lookups(tables, material, wo, kd, rho_s)
    return PixelLookups(light_rows, light_weight, vis_rows, vis_weight, brdf_rows, brdf_weight)


def test_shading_kernel_matches_numpy():
    """kernels/triple/triple.cl against the float64 sparse triple products of the interpolated
    rows. Tolerance: float32 sums of a few hundred terms: relative 1e-4."""
    rng = np.random.default_rng(2)
    tables = synthetic_tables(rng)
    lookups = random_lookups(rng, tables, 64)
    rgb, _, moved = shade(tables, lookups)
    pixels = np.arange(0, 64, 4)
    expected = shade_numpy(tables, lookups, pixels)
    assert moved > 0
    assert np.allclose(rgb[pixels], expected, rtol=1e-4, atol=1e-4 * np.abs(expected).max())
    assert np.abs(expected).max() > 1.0  # not trivially zero


def test_texel_lookups_are_bilinear_and_skip_empty_texels():
    size = np.array([[4, 8]])
    filled = np.ones(32, bool)
    rows, weight = texel_lookups(np.array([[2.0, 1.5]]), size, np.array([0]), filled)
    # x = 2.0 lies halfway between texel columns 1 and 2 of row 1
    assert set(rows[0][weight[0] > 0]) == {9, 10} and np.allclose(weight[0][weight[0] > 0], 0.5)
    filled[10] = False
    rows, weight = texel_lookups(np.array([[2.0, 1.5]]), size, np.array([0]), filled)
    assert np.allclose(weight[0][rows[0] == 9], 1.0) and weight.sum() == pytest.approx(1.0)


@pytest.mark.parametrize("selection", ["top-only", "adaptive"])
def test_run_time_truncation_keeps_the_budget_in_depth_first_order(selection):
    rng = np.random.default_rng(4)
    rows = random_rows(rng, 10, 3, 200)
    basis = wavelet_basis(LEVEL)
    cut = rows.truncated(basis, selection, 40)
    keys = depth_first_keys(LEVEL)
    for r in range(cut.rows):
        index = cut.index[cut.start[r]:cut.start[r + 1]].astype(np.int64)
        assert len(index) <= 40 and np.all(np.diff(keys[index]) > 0)
        full = rows.dense(r, basis.size)
        kept = cut.dense(r, basis.size)
        assert np.array_equal(kept[index], full[index])
        if selection == "top-only":
            assert index.max() < 40
        else:  # no dropped coefficient outweighs a kept one
            weight = np.linalg.norm(full, axis=1) * np.sqrt(basis.support_areas())
            dropped = np.setdiff1d(np.flatnonzero(weight), index)
            if len(dropped):
                assert weight[dropped].max() <= weight[index].min() + 1e-6


class StoredRows:
    """An artifact as ``read_rows`` reads it: count, index, float16 value and row scale."""

    def __init__(self, rows: WaveletRows) -> None:
        count = np.diff(rows.start.astype(np.int64))
        value, scale = to_half(count, rows.value)
        self.arrays = {"count": count, "index": rows.index, "value": value, "scale": scale}
        self.names = list(self.arrays)

    def read(self, name: str) -> np.ndarray:
        return self.arrays[name]


@pytest.mark.parametrize("channels", [1, 3])
def test_rows_cut_while_reading_equal_the_cut_of_all_rows(channels):
    """The renderer's top-only cut made while reading (before the float16 expansion)
    gives the same rows, bit for bit, as reading everything and cutting after; empty
    rows and rows with nothing below the budget included."""
    rng = np.random.default_rng(11)
    rows = random_rows(rng, 12, channels, 150)
    count = np.diff(rows.start.astype(np.int64))
    count[3] = 0  # an empty row
    keep = np.ones(len(rows.index), bool)
    keep[rows.start[5]:rows.start[6]] = rows.index[rows.start[5]:rows.start[6]] >= 80
    count[5] = keep[rows.start[5]:rows.start[6]].sum()
    keep[rows.start[3]:rows.start[4]] = False
    rows = WaveletRows.from_counts(count, rows.index[keep], rows.value[keep])
    stored = StoredRows(rows)
    for budget in (20, 80, 320):
        cut = read_rows(stored, budget)
        expected = read_rows(stored).truncated(wavelet_basis(LEVEL), "top-only", budget)
        for name in ("start", "index", "value"):
            np.testing.assert_array_equal(getattr(cut, name), getattr(expected, name))
    assert len(read_rows(stored, 80).index) < len(rows.index)

"""Method triple's dense top-only path: triple products of functions constant on the
triangles of one level (kernels/triple.cl ``triple_shade_dense``).

The first B = 20·4^k coefficients of the layout (the 20 scaling functions and the
wavelets of levels 0 .. k−1) span exactly the functions constant on the 20·4^k
triangles of level k, so a row cut top-only to a budget ≤ B is such a function, and
the triple product of three of them is

    ∫ L V ρ̃ dω = Σ_t A_t L_t V_t ρ̃_t,     A_t the solid angle of triangle t (sr),

with L_t, V_t, ρ̃_t their values on triangle t. Interpolation between rows is linear, so
it commutes with the inverse transform: every row is turned into its T = 20·4^k
triangle values once, when the tables are cut (:func:`triangle_values`), and a pixel
sums its weighted rows triangle by triangle — no merge, no tree walk. A budget that is
not 20·4^k uses the next level (the coefficients it dropped stay zero: still exact).

The path is used for top-only budgets ≤ :data:`DENSE_MAX` (the 320 triangles of level
2): at level 3 the dense tables would take 1280 floats per row (Grace's 16 384 lighting
rows alone 250 MB, the bunny's 54 k visibility rows 276 MB); ``adaptive`` selections
and the stored rows (budget 0) keep the general sparse path.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache, cached_property
from typing import TYPE_CHECKING, Any

import numpy as np

from pipeline import cl
from pipeline.math.geodesic import ROOTS, geodesic_levels
from pipeline.math.sphwavelet import WaveletBasis, wavelet_basis

if TYPE_CHECKING:
    from pipeline.render.triple import PixelLookups, TripleTables, WaveletRows

DENSE_MAX = 320  # 20·4^2: the largest top-only budget the dense path serves


def dense_level(selection: str, budget: int) -> int | None:
    """The level k whose 20·4^k triangles carry a top-only ``budget`` exactly (the
    smallest with 20·4^k ≥ budget), or None where the sparse path applies (adaptive,
    budget 0 = as stored, budget > :data:`DENSE_MAX`)."""
    if selection != "top-only" or budget <= 0 or budget > DENSE_MAX:
        return None
    level = 0
    while ROOTS * 4 ** level < budget:
        level += 1
    return level


@cache
def _level_matrix(leaf_level: int, level: int) -> tuple[np.ndarray, np.ndarray]:
    """M (T, T) with M[c, t] = basis function c's value on level-``level`` triangle t
    (c < T = 20·4^level), and the triangles' solid angles (T,) sr. Triangle t of level k
    is the union of leaves t·4^(L−k) .. (t + 1)·4^(L−k) − 1 (children 4i .. 4i + 3)."""
    basis = wavelet_basis(leaf_level)
    count = ROOTS * 4 ** level
    unit = np.zeros((count, basis.size))
    unit[:, :count] = np.eye(count)
    leaves = basis.inverse(unit)  # (T, N): constant over each level-k triangle's leaves
    per = 4 ** (basis.leaf_level - level)
    areas = geodesic_levels(basis.leaf_level)[basis.leaf_level].areas.reshape(count, per)
    return leaves[:, ::per], areas.sum(axis=1)


def triangle_values(rows: WaveletRows, basis: WaveletBasis, level: int) -> np.ndarray:
    """Every row's values on the 20·4^level triangles, (rows, T) for grey rows or
    (rows, T, 3) for RGB, float32; ``rows`` must hold no index ≥ T (top-only cut)."""
    matrix, _ = _level_matrix(basis.leaf_level, level)
    count = len(matrix)
    counts = np.diff(rows.start.astype(np.int64))
    row = np.repeat(np.arange(rows.rows), counts)
    index = rows.index.astype(np.int64)
    if len(index) and index.max() >= count:
        raise ValueError(f"triangle_values: an index ≥ {count}: rows not cut top-only")
    channels = rows.channels
    coefficients = np.zeros((rows.rows, channels, count), np.float64)
    coefficients[row, :, index] = rows.value.reshape(len(index), channels)
    values = (coefficients.reshape(-1, count) @ matrix).reshape(rows.rows, channels, count)
    return np.ascontiguousarray(values.transpose(0, 2, 1) if channels > 1 else values[:, 0],
                                np.float32)


@dataclass
class DenseTables:
    """Per-triangle tables of one level, float32: ``light`` (rows, 3, T) × the
    triangles' solid angles (channels planar: the kernel loads W triangles of a channel
    at once), ``visibility`` (rows, T), ``brdf`` (rows, T)."""

    level: int
    light: np.ndarray
    visibility: np.ndarray
    brdf: np.ndarray

    @property
    def triangles(self) -> int:
        return self.light.shape[2]

    @property
    def vector_width(self) -> int:
        """Triangles the kernel sums at a time (TRIPLE_W): 8 where T allows (20: 4)."""
        return 8 if self.triangles % 8 == 0 else 4

    @cached_property
    def device(self) -> list[Any]:
        """The three tables as read-only device buffers (uploaded once)."""
        return [cl.read_only_buffer(a) for a in (self.light, self.visibility, self.brdf)]

    @classmethod
    def from_tables(cls, tables: TripleTables, level: int) -> DenseTables:
        """The per-triangle values of ``tables`` (rows cut top-only to ≤ 20·4^level)."""
        _, area = _level_matrix(tables.basis.leaf_level, level)
        light = triangle_values(tables.light, tables.basis, level) * area[:, None]
        return cls(level, np.ascontiguousarray(light.transpose(0, 2, 1), np.float32),
                   triangle_values(tables.visibility, tables.basis, level),
                   triangle_values(tables.brdf, tables.basis, level))

    def with_brdf(self, brdf: WaveletRows, basis: WaveletBasis) -> DenseTables:
        """These tables with the BRDF rows replaced (a run-time γ edit)."""
        return DenseTables(self.level, self.light, self.visibility,
                           triangle_values(brdf, basis, self.level))


def shade_dense_numpy(dense: DenseTables, lookups: PixelLookups) -> np.ndarray:
    """The dense kernel's sums Σ_t (A_t L_t) V_t ρ̃_t (P, 3) in float64 for host lookups
    (:class:`~pipeline.render.triple.PixelLookups`): the NumPy twin."""
    light = np.einsum("pr,prct->ptc", lookups.light_weight,
                      dense.light[lookups.light_rows].astype(np.float64))
    vis = np.einsum("pr,prt->pt", lookups.vis_weight,
                    dense.visibility[lookups.vis_rows].astype(np.float64))
    brdf = np.einsum("prc,prt->ptc", lookups.brdf_weight,
                     dense.brdf[lookups.brdf_rows].astype(np.float64))
    return np.einsum("ptc,pt,ptc->pc", light, vis, brdf)

"""Method triple's dense top-only path: triple products of functions constant on the
triangles of one level (kernels/triple/triple.cl ``triple_shade_dense``).

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

**Only the triangles above the horizon.** ρ̃ = BRDF × cos θ_i is zero below the local
horizon (every BRDF of pipeline/math/brdf.py is), so a triangle lying wholly in z ≤ 0 of
the local frame adds nothing to the sum: those (36 of level 1's 80, 152 of level 2's 320)
are left out of all three tables (:func:`kept_triangles`), which cuts the kernel's loop
and the tables' bytes by ≈ 40 %. The BRDF rows' values there are the float16 rounding of
zero (≤ 2·10⁻⁴ of the row's largest on bunny_grace); :meth:`DenseTables.from_tables`
checks it and keeps every triangle where a table says otherwise.

The path is used for top-only budgets ≤ :data:`DENSE_MAX` (the 320 triangles of level
2): at level 3 the dense tables would take 1280 floats per row (Grace's 16 384 lighting
rows alone 250 MB, the bunny's 54 k visibility rows 276 MB); ``adaptive`` selections
and the stored rows (budget 0) keep the general sparse path.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache, cached_property
from typing import Any

import numpy as np

from pipeline.device import cl
from pipeline.math.geodesic import ROOTS, geodesic_levels
from pipeline.math.sphwavelet import WaveletBasis, wavelet_basis
from pipeline.methods.triple.tables import PixelLookups, TripleTables, WaveletRows

DENSE_MAX = 320  # 20·4^2: the largest top-only budget the dense path serves
BELOW_HORIZON_TOLERANCE = 1e-3  # BRDF value on a left-out triangle / the row's largest


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


@cache
def kept_triangles(leaf_level: int, level: int) -> np.ndarray:
    """Indices (K,) of the level-``level`` triangles with a corner above the local
    horizon (z > 0): a geodesic triangle whose three corners lie in z ≤ 0 lies there
    whole (its edges are great-circle arcs, which stay in a closed hemisphere)."""
    geo = geodesic_levels(leaf_level)[level]
    below = (geo.vertices[geo.faces][..., 2] <= 0.0).all(axis=1)
    return np.flatnonzero(~below)


def _padded(values: np.ndarray, kept: np.ndarray, width: int) -> np.ndarray:
    """``values`` (rows, T, ...) at the ``kept`` triangles, zero-padded to a multiple of
    ``width`` triangles (the kernel sums ``width`` at a time), float32."""
    count = -(-len(kept) // width) * width
    out = np.zeros((len(values), count, *values.shape[2:]), np.float32)
    out[:, :len(kept)] = values[:, kept]
    return out


def _halved(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows (rows, ...) as float16 over a float32 scale per row (the row's largest
    magnitude, 1 for a zero row): values/scale lie in [−1, 1], where float16 keeps 11
    significant bits (a relative rounding ≤ 2⁻¹¹) and no map's radiance overflows it."""
    flat = values.reshape(len(values), -1)
    scale = np.abs(flat).max(axis=1, initial=0.0).astype(np.float32)
    scale[scale == 0] = 1.0
    shape = (-1,) + (1,) * (values.ndim - 1)
    return (values / scale.reshape(shape)).astype(np.float16), scale


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
    """Per-triangle tables of one level on its ``kept`` triangles (zero-padded to T, a
    multiple of the kernel's vector width), float16 (the kernel converts as it loads:
    half the bytes of float32; a prototype without the row scales, bunny_grace at 320
    and 1024×768 on two loaded CPU cores: shading median 139 against 164 ms, frames equal
    to 4·10⁻⁵ of the largest pixel):
    ``light`` (rows, 3, T) × the
    triangles' solid angles over ``light_scale`` (rows,) float32 (channels planar: the
    kernel loads W triangles of a channel at once), ``visibility`` (rows, T) (values in
    [0, 1]), ``brdf`` (rows, T) over ``brdf_scale`` (rows,). :meth:`values` gives them
    scaled back, float64."""

    level: int
    kept: np.ndarray  # (K,) the level's triangles the tables hold (kept_triangles)
    light: np.ndarray
    light_scale: np.ndarray
    visibility: np.ndarray
    brdf: np.ndarray
    brdf_scale: np.ndarray

    @classmethod
    def of(cls, level: int, kept: np.ndarray, light: np.ndarray, visibility: np.ndarray,
           brdf: np.ndarray) -> DenseTables:
        """The tables of float32 ``light`` (rows, 3, T), ``visibility`` and ``brdf``
        (rows, T), stored as the class says."""
        return cls(level, kept, *_halved(light), visibility.astype(np.float16),
                   *_halved(brdf))

    def values(self, name: str) -> np.ndarray:
        """Table ``name`` (light, visibility or brdf) scaled back, float64."""
        table = getattr(self, name).astype(np.float64)
        scale = {"light": self.light_scale, "brdf": self.brdf_scale}.get(name)
        return table if scale is None else \
            table * scale.reshape((-1,) + (1,) * (table.ndim - 1))

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in (self.light, self.light_scale, self.visibility,
                                      self.brdf, self.brdf_scale))

    @property
    def triangles(self) -> int:
        """Triangles per row the kernel sums (TRIPLE_T): those kept, padded."""
        return self.light.shape[2]

    @property
    def vector_width(self) -> int:
        """Triangles the kernel sums at a time (TRIPLE_W): 8 where T allows, else 4."""
        return 8 if self.triangles % 8 == 0 else 4

    @cached_property
    def device(self) -> list[Any]:
        """The tables as read-only device buffers in the kernel's order (uploaded once):
        light, light_scale, visibility, brdf, brdf_scale."""
        return [cl.read_only_buffer(a) for a in (self.light, self.light_scale,
                                                 self.visibility, self.brdf, self.brdf_scale)]

    @classmethod
    def from_tables(cls, tables: TripleTables, level: int) -> DenseTables:
        """The per-triangle values of ``tables`` (rows cut top-only to ≤ 20·4^level) on
        the triangles that can be above the horizon (module docstring), or on all of
        them where the BRDF rows are not zero below it."""
        leaf_level = tables.basis.leaf_level
        _, area = _level_matrix(leaf_level, level)
        brdf = triangle_values(tables.brdf, tables.basis, level)
        kept = _kept_for(brdf, leaf_level, level)
        width = 4 if level == 0 else 8  # level 0 holds 12 (or 20) triangles
        light = triangle_values(tables.light, tables.basis, level) * area[:, None]
        return cls.of(level, kept, np.ascontiguousarray(
            _padded(light, kept, width).transpose(0, 2, 1)),
            _padded(triangle_values(tables.visibility, tables.basis, level), kept, width),
            _padded(brdf, kept, width))

    def with_brdf(self, brdf: WaveletRows, basis: WaveletBasis) -> DenseTables:
        """These tables with the BRDF rows replaced (a run-time γ edit); the triangles
        kept stay (an edited BRDF is zero below the horizon too: checked)."""
        values = triangle_values(brdf, basis, self.level)
        if not np.array_equal(_kept_for(values, basis.leaf_level, self.level), self.kept):
            raise ValueError("with_brdf: the edited BRDF is not zero below the horizon")
        return DenseTables(self.level, self.kept, self.light, self.light_scale,
                           self.visibility, *_halved(_padded(values, self.kept,
                                                             self.vector_width)))


def _kept_for(brdf: np.ndarray, leaf_level: int, level: int) -> np.ndarray:
    """:func:`kept_triangles`, or every triangle where some BRDF row (rows, T) is not
    zero (to :data:`BELOW_HORIZON_TOLERANCE` of its largest value) on the others."""
    kept = kept_triangles(leaf_level, level)
    dropped = np.ones(brdf.shape[1], bool)
    dropped[kept] = False
    largest = np.abs(brdf).max(axis=1)
    if np.any(np.abs(brdf[:, dropped]).max(axis=1, initial=0.0)
              > BELOW_HORIZON_TOLERANCE * largest):
        return np.arange(brdf.shape[1])
    return kept


def shade_dense_numpy(dense: DenseTables, lookups: PixelLookups) -> np.ndarray:
    """The dense kernel's sums Σ_t (A_t L_t) V_t ρ̃_t (P, 3) in float64 for host lookups
    (:class:`~pipeline.methods.triple.tables.PixelLookups`): the NumPy twin."""
    light = np.einsum("pr,prct->ptc", lookups.light_weight,
                      dense.values("light")[lookups.light_rows])
    vis = np.einsum("pr,prt->pt", lookups.vis_weight,
                    dense.values("visibility")[lookups.vis_rows])
    brdf = np.einsum("prc,prt->ptc", lookups.brdf_weight,
                     dense.values("brdf")[lookups.brdf_rows])
    return np.einsum("ptc,pt,ptc->pc", light, vis, brdf)

"""What method triple's frames read, as held in memory: the wavelet rows of the three
tables (:class:`WaveletRows`, :class:`TripleTables`, read from the artifacts by
:func:`read_rows`), the atlas that finds a surface point's visibility texels
(:class:`Atlas`), and per shaded pixel the rows and weights of its three functions
(:class:`PixelLookups`; the NumPy twins :func:`texel_lookups`, :func:`brdf_lookups` of
kernels/triple/triple_lookup.h). The renderer (render.py), its G-buffer (gbuffer.py) and
the dense path (dense.py) share them.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from pipeline.device import cl
from pipeline.device.raytrace import Surface
from pipeline.engine.store import Artifact
from pipeline.math.sphwavelet import WaveletBasis
from pipeline.methods.triple.frame_grids import FrameGrid, ViewGrid
from pipeline.methods.triple.wavelet_rows import from_half

LIGHT_ROWS, VIS_ROWS, BRDF_ROWS = 8, 4, 9  # as kernels/triple/triple_lookup.h
SELECTIONS = ("top-only", "adaptive")  # run-time cuts of the stored rows (WaveletRows.truncated)


@dataclass(frozen=True)
class WaveletRows:
    """CSR rows of wavelet coefficients: row r holds entries ``start[r]`` ..
    ``start[r + 1] − 1``; ``index`` (E,) uint16 coefficient indices sorted depth first
    within each row, ``value`` (E,) or (E, 3) float32 (grey or RGB)."""

    start: np.ndarray
    index: np.ndarray
    value: np.ndarray

    @classmethod
    def from_counts(cls, count: np.ndarray, index: np.ndarray, value: np.ndarray
                    ) -> WaveletRows:
        """From per-row entry counts and the flat entries."""
        start = np.concatenate([[0], np.cumsum(count, dtype=np.int64)]).astype(np.uint32)
        return cls(start, np.ascontiguousarray(index, np.uint16),
                   np.ascontiguousarray(value, np.float32))

    @property
    def rows(self) -> int:
        return len(self.start) - 1

    @property
    def channels(self) -> int:
        return 1 if self.value.ndim == 1 else self.value.shape[1]

    @property
    def nbytes(self) -> int:
        return self.start.nbytes + self.index.nbytes + self.value.nbytes

    def truncated(self, basis: WaveletBasis, selection: str, budget: int) -> WaveletRows:
        """Each row cut to ``budget`` entries: ``top-only`` keeps those with index <
        budget (the first ``budget`` of the layout), ``adaptive`` the ``budget`` largest
        by area-weighted magnitude (|c|·√support, channels summed in quadrature); the
        kept entries stay sorted depth first."""
        count = np.diff(self.start.astype(np.int64))
        row = np.repeat(np.arange(self.rows), count)
        if selection == "top-only":
            keep = self.index < budget
        else:
            magnitude = self.value if self.value.ndim == 1 else \
                np.linalg.norm(self.value, axis=1)
            weight = np.abs(magnitude) * np.sqrt(basis.support_areas())[self.index]
            order = np.lexsort((-weight, row))  # by row, largest first
            rank = np.empty(len(order), np.int64)
            rank[order] = np.arange(len(order)) - np.repeat(self.start[:-1].astype(np.int64),
                                                            count)
            keep = rank < budget
        kept_count = np.bincount(row[keep], minlength=self.rows)
        return WaveletRows.from_counts(kept_count, self.index[keep], self.value[keep])

    def with_rows(self, first: int, rows: WaveletRows) -> WaveletRows:
        """These rows with rows ``first`` .. ``first + rows.rows − 1`` replaced."""
        count = np.diff(self.start.astype(np.int64))
        count[first:first + rows.rows] = np.diff(rows.start.astype(np.int64))
        a, b = int(self.start[first]), int(self.start[first + rows.rows])
        return WaveletRows.from_counts(count,
                                       np.concatenate([self.index[:a], rows.index,
                                                       self.index[b:]]),
                                       np.concatenate([self.value[:a], rows.value,
                                                       self.value[b:]]))

    @cached_property
    def device(self) -> list[Any]:
        """``start``, ``index`` and ``value`` as read-only device buffers, uploaded once
        per set of rows (not once per frame)."""
        return [cl.read_only_buffer(a) for a in (self.start, self.index, self.value)]

    def dense(self, row: int, size: int) -> np.ndarray:
        """Row ``row`` as dense coefficients (size, channels) float64."""
        out = np.zeros((size, self.channels))
        s, e = int(self.start[row]), int(self.start[row + 1])
        out[self.index[s:e]] = self.value[s:e].reshape(e - s, -1)
        return out


@dataclass
class TripleTables:
    """What a frame reads: ``light`` rows (one per ``frames`` grid entry, RGB),
    ``visibility`` rows (one per texel, grey), ``brdf`` rows (grey; per material
    ``glossy_base[m]`` + view-grid entry for its glossy rows, ``diffuse_row[m]`` its
    diffuse row; −1 where a Lambertian material has no glossy rows), the grids and the
    basis."""

    basis: WaveletBasis
    frames: FrameGrid
    views: ViewGrid
    light: WaveletRows
    visibility: WaveletRows
    brdf: WaveletRows
    glossy_base: np.ndarray
    diffuse_row: np.ndarray

    @property
    def nbytes(self) -> int:
        """Bytes of the three tables' rows as held (what a frame reads of them)."""
        return self.light.nbytes + self.visibility.nbytes + self.brdf.nbytes

    def truncated(self, selection: str, budget: int) -> TripleTables:
        """The tables with every row cut to the run-time budget."""
        cut = [t.truncated(self.basis, selection, budget)
               for t in (self.light, self.visibility, self.brdf)]
        return TripleTables(self.basis, self.frames, self.views, *cut, self.glossy_base,
                            self.diffuse_row)


@dataclass
class PixelLookups:
    """Per shaded pixel (P of them): the rows and weights of its three functions, as
    kernels/triple/triple.cl reads them: ``light_rows``/``light_weight`` (P, 8),
    ``vis_rows``/``vis_weight`` (P, 4), ``brdf_rows`` (P, 9) and ``brdf_weight``
    (P, 9, 3) (:func:`brdf_lookups`: the diffuse row, 4 glossy rows of the material, 4
    of the material it blends with)."""

    light_rows: np.ndarray
    light_weight: np.ndarray
    vis_rows: np.ndarray
    vis_weight: np.ndarray
    brdf_rows: np.ndarray
    brdf_weight: np.ndarray

    def arrays(self) -> list[np.ndarray]:
        return [np.ascontiguousarray(a, dt) for a, dt in (
            (self.light_rows, np.uint32), (self.light_weight, np.float32),
            (self.vis_rows, np.uint32), (self.vis_weight, np.float32),
            (self.brdf_rows, np.uint32), (self.brdf_weight, np.float32))]


def texel_lookups(texel_xy: np.ndarray, size: np.ndarray, offset: np.ndarray,
                  filled: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear texel rows and weights (P, 4) at continuous texel coordinates
    ``texel_xy`` (P, 2) (x right, y down, texel (i, j) centred at (j + ½, i + ½)) in
    textures of ``size`` (P, 2) = (height, width) whose texel (i, j) is row
    ``offset`` + i·width + j; texels not ``filled`` (a flag per row) get weight 0 and
    the others are renormalised."""
    x = np.clip(texel_xy[:, 0] - 0.5, 0.0, size[:, 1] - 1.0)
    y = np.clip(texel_xy[:, 1] - 0.5, 0.0, size[:, 0] - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), np.maximum(size[:, 1] - 2, 0))
    y0 = np.minimum(np.floor(y).astype(np.int64), np.maximum(size[:, 0] - 2, 0))
    fx, fy = x - x0, y - y0
    x1 = np.minimum(x0 + 1, size[:, 1] - 1)
    y1 = np.minimum(y0 + 1, size[:, 0] - 1)
    rows = np.stack([offset + yy * size[:, 1] + xx
                     for yy, xx in ((y0, x0), (y0, x1), (y1, x0), (y1, x1))], 1)
    weight = np.stack([(1 - fy) * (1 - fx), (1 - fy) * fx, fy * (1 - fx), fy * fx], 1)
    weight = weight * filled[rows]
    total = weight.sum(1, keepdims=True)
    return rows, np.divide(weight, total, out=np.zeros_like(weight), where=total > 0)


def brdf_lookups(tables: TripleTables, material: np.ndarray, wo_local: np.ndarray,
                 kd: np.ndarray, rho_s: np.ndarray, material_b: np.ndarray | None = None,
                 blend: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """BRDF rows (P, 9) and RGB weights (P, 9, 3) for materials ``material`` (P,)
    blended with ``material_b`` (P,) by ``blend`` t (P,) (absent: no blend), seen from
    local ``wo_local`` (P, 3), with per-material diffuse albedo ``kd`` and ``rho_s``
    (materials, 3). The blended BRDF (1 − t) ρ̃_a + t ρ̃_b is

        diffuse row × ((1 − t) kd_a + t kd_b)                 (row 0: every diffuse row
                                                              holds the same cos⁺θ/π)
        + Σ 4 glossy view rows of a × bilinear × (1 − t) ρs_a  (rows 1–4)
        + Σ 4 glossy view rows of b × bilinear × t ρs_b        (rows 5–8);

    rows of weight 0 (no blend, a Lambertian material) are skipped by the kernel. A view
    at or below the horizon (``wo_local`` z ≤ 0, e.g. a smooth normal at a silhouette)
    gets weight 0 on every row: every BRDF is zero there (pipeline/math/brdf.py)."""
    if material_b is None or blend is None:
        material_b, blend = material, np.zeros(len(material))
    t = np.asarray(blend, np.float64)[:, None]
    entries, weights = tables.views.weights(wo_local)
    parts_rows = [tables.diffuse_row[material][:, None]]
    parts_weight = [((1 - t) * kd[material] + t * kd[material_b])[:, None, :]]
    for m, share in ((material, 1 - t), (material_b, t)):
        base = tables.glossy_base[m]
        glossy = base >= 0
        parts_rows.append(np.where(glossy[:, None], base[:, None] + entries, 0))
        parts_weight.append((weights * glossy[:, None] * share)[:, :, None]
                            * rho_s[m][:, None, :])
    above = (np.asarray(wo_local)[:, 2] > 0.0)[:, None, None]
    return np.concatenate(parts_rows, 1), np.concatenate(parts_weight, 1) * above


def read_rows(artifact: Artifact, below: int = 0) -> WaveletRows:
    """The CSR rows of a triple artifact (``count``, ``index``, ``value``; rows stored
    back to back); float16 values with a per-row ``scale`` (triple_lighting and
    triple_brdf v2) are expanded to float32. With ``below`` > 0 only the entries of
    index < ``below`` are kept (a top-only cut), before the expansion: a renderer of 80
    coefficients expands 1/16 of a 1,280-coefficient table."""
    count, index, value = artifact.read("count"), artifact.read("index"), artifact.read("value")
    if below > 0:
        kept = np.flatnonzero(index < below)  # ~budget/stored of the entries
        row = np.searchsorted(np.cumsum(count, dtype=np.int64), kept, side="right")
        count = np.bincount(row, minlength=len(count))
        index, value = index[kept], value[kept]
    if "scale" in artifact.names:
        value = from_half(count, value, artifact.read("scale"))
    return WaveletRows.from_counts(count, index, value)


@dataclass
class Atlas:
    """Where a surface point's visibility lives: per face its atlas corners ``face_uv``
    (F, 3, 2) in texel units, per object its texture ``size`` (objects, 2) = (height,
    width) and flat ``offset``, per flat texel whether it is ``filled`` and its
    visibility ``row``."""

    face_uv: np.ndarray
    size: np.ndarray
    offset: np.ndarray
    filled: np.ndarray
    row: np.ndarray

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in (self.face_uv, self.size, self.offset, self.filled,
                                      self.row))

    def texel_xy(self, surface: Surface) -> np.ndarray:
        """Continuous texel coordinates (P, 2) of surface hits in their object's texture:
        the barycentric blend of the face's atlas corners."""
        u, v = surface.hits.u.astype(np.float64), surface.hits.v.astype(np.float64)
        corners = self.face_uv[surface.face].astype(np.float64)
        return (1.0 - u - v)[:, None] * corners[:, 0] + u[:, None] * corners[:, 1] \
            + v[:, None] * corners[:, 2]

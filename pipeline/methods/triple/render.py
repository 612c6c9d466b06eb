"""Method ``triple`` (paper 004): per-pixel triple products of lighting, visibility and
BRDF in the pixel's local frame (kernels/triple/triple.cl, kernels/sphwavelet.h).

For a pixel that sees the surface point x with shading frame F = (t, n × t, n) and view
direction ω_o (local), the reflected radiance of the environment map L is

    B = ∫ L(F ω) V_x(ω) ρ̃(ω, ω_o) dω,   ρ̃ = kd cos θ/π + ρs f_g(ω, ω_o) cos θ,

with every factor a spherical Haar wavelet expansion over local directions ω
(pipeline/math/sphwavelet.py):

* L(F ·) interpolated trilinearly between the nearest frames of the rotation grid
  (pipeline/methods/triple/frame_grids.py ``FrameGrid``); an environment rotation α about +y at
  run time is a shift of the lookup's φ (``FrameGrid.weights``' ``turn``), its ``scale``
  a factor on the result;
* V_x interpolated bilinearly between the nearest texels of the object's visibility
  texture (texels that hold nothing are left out and the weights renormalised);
* ρ̃ the material's diffuse row weighted by kd and its glossy rows at the nearest
  local views (``ViewGrid``) weighted by ρs × the bilinear weights: kd and ρs edits cost
  nothing; a γ (or other shape) edit at run time re-samples that material's glossy rows
  as the ``triple.brdf_tables`` stage does (``resample_ms``, once per edited value).
  A spatially varying BRDF (a blend by a texture, t the weight of the second material)
  adds the second material's glossy rows weighted by t (:func:`brdf_lookups`).

Bump maps (paper 004 §4.2, pipeline/render/surface_detail.py): the lighting lookup (the frame
F) and ω_o use the bumped shading frame, the visibility stays in the texel's geometric
frame — "not physically correct", the paper's approximation.

Camera rays are traced once per camera (any camera; pipeline/raytrace.py) into a
G-buffer (pipeline/methods/triple/gbuffer.py) that frames reuse while the camera stays:
pixels that miss see the environment map itself (kernel ``triple_background``). This
module keeps the tables as :class:`WaveletRows`; the kernels compute every pixel's rows
and weights from the G-buffer (kernels/triple/triple_lookup.h; twins :func:`texel_lookups`,
:func:`brdf_lookups`, FrameGrid/ViewGrid.weights) and sum the triple products: top-only
budgets ≤ 320 by the dense path (pipeline/methods/triple/dense.py), the rest by the
sparse merge; :func:`shade_numpy` is the sums' NumPy twin.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from pipeline import cl
from pipeline.errors import PrtError
from pipeline.images import read_environment
from pipeline.math.brdf import scene_brdfs
from pipeline.math.camera import camera_rays
from pipeline.math.sphwavelet import (
    WaveletBasis,
    depth_first_keys,
    kernel_tables,
    sparse_triple_product,
    wavelet_basis,
)
from pipeline.methods.triple.dense import DenseTables, dense_level
from pipeline.methods.triple.frame_grids import FrameGrid, ViewGrid
from pipeline.methods.triple.gbuffer import (
    GBuffer,
    LookupTables,
    device_lookups,
    kernel_arguments,
    surface_attributes,
)
from pipeline.methods.triple.stages.brdf_tables import SHAPE_KEYS, glossy_rows
from pipeline.methods.triple.wavelet_rows import from_half
from pipeline.raytrace import Mesh, RayTracer, Surface, surface_at
from pipeline.render import (
    WORK_GROUP,
    DeviceImage,
    Frame,
    back_face_notes,
    camera_key,
    sees_back,
)
from pipeline.render.surface_detail import SceneDetail
from pipeline.scene import Light, Scene
from pipeline.store import Artifact

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


def shade(tables: TripleTables, lookups: PixelLookups) -> tuple[np.ndarray, float, int]:
    """Radiance (P, 3) float32 of the pixels' triple products on the OpenCL device, the
    kernel's milliseconds and the bytes it read and wrote (tables once, lookups)."""
    n = len(lookups.light_rows)
    out = np.empty((max(n, 1), 3), np.float32)
    basis = kernel_tables(tables.basis)
    table_arrays = [a for t in (tables.light, tables.visibility, tables.brdf)
                    for a in (t.start, t.index, t.value)]
    args = [b for t in (tables.light, tables.visibility, tables.brdf) for b in t.device]
    args += [cl.read_only_buffer(a) for a in (*lookups.arrays(), basis["root_area"],
                                              basis["wavelet"], basis["tensor"])]
    kernel = cl.kernel("triple.cl", "triple_shade", {"SW_LEVELS": tables.basis.leaf_level,
                                                     "SW_ROWS": max(LIGHT_ROWS, BRDF_ROWS)})
    ms = cl.run(kernel, max(n, 1), *args, np.int32(n), out=out, writes=12 * n)
    moved = sum(a.nbytes for a in (*table_arrays, *lookups.arrays(), out))
    return out[:n], ms, moved


def shade_gbuffer(tables: TripleTables, dense: DenseTables | None, gbuffer: GBuffer,
                  lookup: LookupTables, turn: float, static: dict[str, Any],
                  out_buffer: Any | None = None
                  ) -> tuple[np.ndarray | None, dict[str, float], int]:
    """Radiance (P, 3) float32 of the G-buffer's pixels, with the lookups on the device:
    the dense top-only kernel (lookups fused) where ``dense`` is given, else
    ``triple_lookups`` then the sparse ``triple_shade``. Also the kernels' milliseconds
    (``lookup_ms``: 0 when fused, ``kernel_ms``) and the bytes they read and wrote (the
    tables once, the G-buffer, the lookups where they go through memory, the output).
    With ``out_buffer`` (a device buffer of ≥ P · 12 bytes) the radiance stays there
    and None is returned in its place."""
    n = gbuffer.count
    out = None if out_buffer is not None else np.empty((max(n, 1), 3), np.float32)
    result = None if out is None else out[:n]
    out_bytes = 12 * max(n, 1)
    args = kernel_arguments(gbuffer, tables, lookup, turn, static)
    gbuffer_bytes = sum(getattr(gbuffer, a).nbytes for a in (
        "normal", "tangent", "view", "texel_xy", "object", "material_a", "material_b",
        "blend"))
    if dense is not None:
        kernel = cl.kernel("triple.cl", "triple_shade_dense",
                           {"SW_LEVELS": tables.basis.leaf_level,
                            "TRIPLE_T": dense.triangles, "TRIPLE_W": dense.vector_width})
        ms = cl.run(kernel, max(n, 1), *dense.device, *args, np.int32(n), out=out,
                    writes=12 * n, out_buffer=out_buffer, local=WORK_GROUP)
        moved = sum(a.nbytes for a in (dense.light, dense.visibility, dense.brdf)) + out_bytes
        return result, {"lookup_ms": 0.0, "kernel_ms": ms}, moved + gbuffer_bytes
    buffers, lookup_ms = device_lookups(gbuffer, tables, lookup, turn, static)
    basis = kernel_tables(tables.basis)
    kernel = cl.kernel("triple.cl", "triple_shade", {"SW_LEVELS": tables.basis.leaf_level})
    table_args = [b for t in (tables.light, tables.visibility, tables.brdf) for b in t.device]
    ms = cl.run(kernel, max(n, 1), *table_args, *buffers,
                *(cl.read_only_buffer(basis[k]) for k in ("root_area", "wavelet", "tensor")),
                np.int32(n), out=out, writes=12 * n, out_buffer=out_buffer,
                local=WORK_GROUP)
    lookup_bytes = n * 4 * (2 * LIGHT_ROWS + 2 * VIS_ROWS + 4 * BRDF_ROWS)
    moved = sum(a.nbytes for t in (tables.light, tables.visibility, tables.brdf)
                for a in (t.start, t.index, t.value))
    return result, {"lookup_ms": lookup_ms, "kernel_ms": ms}, \
        moved + gbuffer_bytes + 2 * lookup_bytes + out_bytes


def shade_numpy(tables: TripleTables, lookups: PixelLookups, pixels: np.ndarray
                ) -> np.ndarray:
    """The kernel's sums for the lookups' rows ``pixels`` (K,), in float64 with
    :func:`~pipeline.math.sphwavelet.sparse_triple_product` on the interpolated rows
    (slow: for tests)."""
    size = tables.basis.size
    keys = depth_first_keys(tables.basis.leaf_level)
    out = np.zeros((len(pixels), 3))
    for k, p in enumerate(pixels):
        light = sum(w * tables.light.dense(r, size) for r, w in
                    zip(lookups.light_rows[p], lookups.light_weight[p], strict=True) if w)
        vis = sum(w * tables.visibility.dense(r, size) for r, w in
                  zip(lookups.vis_rows[p], lookups.vis_weight[p], strict=True) if w)
        brdf = sum(w * tables.brdf.dense(r, size) for r, w in
                   zip(lookups.brdf_rows[p], lookups.brdf_weight[p], strict=True) if np.any(w))
        functions = [np.broadcast_to(np.asarray(f, float) + np.zeros((size, 3)), (size, 3))
                     for f in (light, vis, brdf)]
        for c in range(3):
            lists = []
            for f in functions:
                nonzero = np.flatnonzero(f[:, c])
                nonzero = nonzero[np.argsort(keys[nonzero])]
                lists.append((nonzero, f[nonzero, c]))
            out[k, c] = sparse_triple_product(tables.basis, tuple(lists))
    return out


# ------------------------------------------------------------------------- artifacts


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


def camera_gbuffer(tracer: RayTracer, mesh: Mesh, atlas: Atlas, detail: SceneDetail,
                   cam: Any) -> GBuffer:
    """The G-buffer of camera ``cam`` (pipeline/methods/triple/gbuffer.py): camera rays
    traced, surface attributes at the hits on the device (``surface_attributes``: the
    interpolated normal, the uv tangent, the texel coordinates); where a material has a
    blend or a bump, ``detail`` (pipeline/render/surface_detail.py) turns the shading frame and
    blends the materials on the host. The texel coordinates stay with the geometric hit
    (the visibility is the unbumped texel's, paper 004 §4.2). NumPy twin:
    :func:`camera_gbuffer_numpy`."""
    origins, directions = camera_rays(cam.position, cam.look_at, cam.up, cam.fov,
                                      cam.width, cam.height)
    origins, directions = origins.reshape(-1, 3), directions.reshape(-1, 3)
    hits = tracer.intersect(origins, directions)
    hit = hits.prim >= 0
    pixel = np.flatnonzero(hit)
    s = surface_attributes(mesh, atlas.face_uv, hits, directions, pixel)
    material = np.asarray(mesh.object_material, np.int32)[s["object"]]
    material_b, blend = material.copy(), np.zeros(len(pixel), np.float32)
    which = np.flatnonzero(np.isin(material, [*detail.blend, *detail.bump]))
    if len(which):  # the host's SceneDetail on the pixels of detailed materials
        at = pixel[which]
        shading = detail.at(surface_at(mesh, hits.select(at), origins[at], directions[at],
                                       normal_dtype=np.float32))
        s["normal"][which], s["tangent"][which] = shading.normal, shading.tangent
        material_b[which], blend[which] = shading.material_b, shading.blend
    back = sees_back(directions[pixel], mesh.face_normal[hits.prim[pixel]])
    return GBuffer(cam.width, cam.height, pixel, s["normal"], s["tangent"], s["view"],
                   s["texel_xy"], s["object"], material, material_b, blend,
                   np.flatnonzero(~hit), directions[~hit], back)


def camera_gbuffer_numpy(tracer: RayTracer, mesh: Mesh, atlas: Atlas, detail: SceneDetail,
                         cam: Any) -> GBuffer:
    """:func:`camera_gbuffer` on the host: every attribute from
    pipeline.raytrace.Surface, ``detail`` and :meth:`Atlas.texel_xy` (the device
    kernel's twin, tests and benchmarks)."""
    origins, directions = camera_rays(cam.position, cam.look_at, cam.up, cam.fov,
                                      cam.width, cam.height)
    origins, directions = origins.reshape(-1, 3), directions.reshape(-1, 3)
    hits = tracer.intersect(origins, directions)
    hit = hits.prim >= 0
    d = directions[hit]  # float32, as the G-buffer keeps it (normals blended in float32)
    surface = surface_at(mesh, hits.select(hit), origins[hit], d, normal_dtype=np.float32)
    shading = detail.at(surface)
    return GBuffer(cam.width, cam.height, np.flatnonzero(hit),
                   shading.normal.astype(np.float32), shading.tangent.astype(np.float32), -d,
                   atlas.texel_xy(surface), surface.object_id, shading.material_a,
                   shading.material_b, shading.blend, np.flatnonzero(~hit), directions[~hit])


def load_tables(artifacts: Mapping[str, Artifact], material_names: list[str],
                below: int = 0) -> tuple[TripleTables, Atlas]:
    """The baked tables and the atlas, from the artifacts of ``triple.atlas``,
    ``triple.visibility``, ``triple.light_rotations`` and ``triple.brdf_tables``; with
    ``below`` > 0 every row already cut top-only to that budget (:func:`_rows`)."""
    light, brdf = artifacts["triple.light_rotations"], artifacts["triple.brdf_tables"]
    atlas, visibility = artifacts["triple.atlas"], artifacts["triple.visibility"]
    names = brdf.attrs["material_names"]
    row_start = np.asarray(brdf.attrs["row_start"])
    views = ViewGrid(*brdf.attrs["view_grid"])
    order = [names.index(n) for n in material_names]
    diffuse = row_start[order]
    glossy = np.where(np.diff(row_start)[order] > 1, row_start[order] + 1, -1)
    tables = TripleTables(wavelet_basis(int(light.attrs["leaf_level"])),
                          FrameGrid(*light.attrs["frame_grid"]), views,
                          *(read_rows(a, below) for a in (light, visibility, brdf)), glossy,
                          diffuse)
    sizes = atlas.attrs["texture_sizes"]
    objects = list(sizes)
    return tables, Atlas(atlas.read("face_uv"),
                         np.array([sizes[o] for o in objects], np.int64),
                         np.asarray(atlas.read("texture_offsets"), np.int64),
                         atlas.read("texel_state") > 0,
                         np.asarray(visibility.read("texel_row"), np.int64))


# -------------------------------------------------------------------------- frames


def _shape(scene: Scene, name: str) -> dict[str, Any]:
    """What shapes material ``name``'s glossy table (γ, alpha_ratio, ...; absent: None)."""
    params = scene.materials[name].params
    return {k: params.get(k) for k in SHAPE_KEYS}


def environment_of(scene: Scene) -> Light:
    """The scene's environment light (method triple renders exactly one)."""
    return next(light for light in scene.lights if light.type == "environment")


def triple_renderer(scene: Scene, artifacts: Mapping[str, Artifact], budget: int = 0,
                    selection: str = "top-only") -> Callable[[Scene], Frame]:
    """Frames from the baked tables, loaded once (cut to ``budget`` coefficients per
    function by ``selection`` when ``budget`` > 0; else as stored): each call traces
    its scene's camera, looks up every pixel's rows and shades them (timings: trace,
    lookups, kernel). Materials' kd and ρs and the environment's rotation and scale are
    read from the scene of each call."""
    if selection not in SELECTIONS:
        raise PrtError("--option", f"selection={selection!r}: expected one of "
                       f"{', '.join(SELECTIONS)}")
    if budget < 0:
        raise PrtError("--option", f"budget={budget}: expected 0 (as stored) or a positive "
                       "number of coefficients")
    geo = artifacts["geometry"]
    material_names = geo.attrs["material_names"]
    # a top-only budget is cut while reading (the expansion to float32 is most of the
    # load); an adaptive one needs every stored entry's magnitude first
    tables, atlas = load_tables(artifacts, material_names,
                                budget if selection == "top-only" else 0)
    if budget > 0 and selection != "top-only":
        tables = tables.truncated(selection, budget)
    brdf_attrs = artifacts["triple.brdf_tables"].attrs
    baked_shapes = {n: _shape(scene, n) for n in material_names}
    resampled: dict[tuple, WaveletRows] = {}

    spliced: dict[tuple, WaveletRows] = {}  # the last edited table, reused while unchanged

    def current_brdf(scene: Scene) -> WaveletRows:
        """The BRDF rows, with the glossy rows of every material whose shape (γ, ...)
        differs from the bake re-sampled as the stage samples them."""
        edits = []
        for m, name in enumerate(material_names):
            shape = _shape(scene, name)
            if tables.glossy_base[m] < 0 or shape == baked_shapes[name]:
                continue
            key = (name, tuple(sorted(shape.items())))
            if key not in resampled:
                a = brdf_attrs
                fresh = glossy_rows(scene.materials[name].model, shape, tables.views,
                                    int(a["leaf_level"]), int(a["refine"]),
                                    int(a["store_budget"]), float(a["store_tolerance"]),
                                    int(a["store_top"]))
                new = WaveletRows.from_counts(fresh["count"], fresh["index"],
                                              fresh["value"][:, 0])
                resampled[key] = new.truncated(tables.basis, selection, budget) \
                    if budget > 0 else new
            edits.append((m, key))
        if not edits:
            return tables.brdf
        if tuple(edits) not in spliced:
            rows = tables.brdf
            for m, key in edits:
                rows = rows.with_rows(int(tables.glossy_base[m]), resampled[key])
            spliced.clear()
            spliced[tuple(edits)] = rows
        return spliced[tuple(edits)]

    arrays = {n: geo.read(n) for n in
              ("vertices", "normals", "uv", "faces", "face_object", "object_material")}
    tracer = RayTracer(arrays["vertices"], arrays["faces"])
    mesh = Mesh.from_arrays(arrays)
    detail = SceneDetail(scene, material_names)
    env_map = np.ascontiguousarray(read_environment(environment_of(scene).params["file"]),
                                   np.float32)
    level = dense_level(selection, budget)
    base_dense = None if level is None else DenseTables.from_tables(tables, level)
    edited: list[tuple[WaveletRows, DenseTables]] = []  # the last edited BRDF table's
    static: dict[str, Any] = {}  # device buffers kept across frames (atlas, map)
    cached: dict[tuple, GBuffer] = {}  # the last camera's G-buffer
    images: dict[int, DeviceImage] = {}  # the last image size's device image

    def dense_of(brdf: WaveletRows) -> DenseTables | None:
        """The dense tables for these BRDF rows (converted once per edited table)."""
        if base_dense is None or brdf is tables.brdf:
            return base_dense
        if not edited or edited[0][0] is not brdf:
            edited[:] = [(brdf, base_dense.with_brdf(brdf, tables.basis))]
        return edited[0][1]

    def frame(scene: Scene) -> Frame:
        t0 = time.perf_counter()
        cam = scene.camera
        key = camera_key(cam)
        was_cached = key in cached
        if not was_cached:  # a new camera: trace it (the previous one is dropped)
            cached.clear()
            cached[key] = camera_gbuffer(tracer, mesh, atlas, detail, cam)
        gbuffer = cached[key]
        _, angles_ms = gbuffer.angles(tables.frames, tables.views)  # 0 ms once cached
        t1 = time.perf_counter()
        frame_tables = dataclasses.replace(tables, brdf=current_brdf(scene))
        frame_dense = dense_of(frame_tables.brdf)
        t_resample = time.perf_counter()
        light = environment_of(scene).params
        turn = float(np.radians(light.get("rotation", 0.0)))
        brdfs = scene_brdfs(scene, material_names)
        lookup = LookupTables.of(frame_tables, atlas, np.array([b.albedo for b in brdfs]),
                                 np.array([b.specular for b in brdfs]))
        # shading, background and their scatter into the image stay on the device; the
        # frame comes back in one copy
        image = DeviceImage.of_size(images, cam.width * cam.height)
        shaded = cl.scratch_buffer(image.buffers, "shaded", 12 * gbuffer.count)
        _, kernel_times, moved = shade_gbuffer(frame_tables, frame_dense, gbuffer,
                                               lookup, turn, static, out_buffer=shaded)
        scale = float(light.get("scale", 1.0))
        pixel, miss_pixel = gbuffer.pixel_device
        scatter_ms = image.scatter(shaded, pixel, gbuffer.count, scale)
        background_ms = 0.0
        if len(gbuffer.miss_pixel):
            if "map" not in static:
                static["map"] = cl.read_only_buffer(env_map)
            miss = cl.scratch_buffer(image.buffers, "miss", 12 * len(gbuffer.miss_pixel))
            kernel = cl.kernel("triple.cl", "triple_background",
                               {"SW_LEVELS": tables.basis.leaf_level})
            background_ms = cl.run(kernel, len(gbuffer.miss_pixel), static["map"],
                                   np.int32(env_map.shape[1]), np.int32(env_map.shape[0]),
                                   gbuffer.miss_uv_device, np.float32(turn), np.float32(scale),
                                   np.int32(len(gbuffer.miss_pixel)), out=None,
                                   writes=12 * len(gbuffer.miss_pixel), out_buffer=miss,
                                   local=WORK_GROUP)
            scatter_ms += image.scatter(miss, miss_pixel, len(gbuffer.miss_pixel))
        rgb = image.read()
        t3 = time.perf_counter()
        shading_ms = kernel_times["lookup_ms"] + kernel_times["kernel_ms"]
        timings = {"gbuffer_ms": (t1 - t0) * 1e3, "gbuffer_cached": float(was_cached),
                   "angles_ms": angles_ms,
                   "resample_ms": (t_resample - t1) * 1e3,
                   "lookup_ms": kernel_times["lookup_ms"],
                   "shade_ms": kernel_times["kernel_ms"], "background_ms": background_ms,
                   "scatter_ms": scatter_ms,
                   "kernel_ms": shading_ms + background_ms + scatter_ms,
                   "counted_kernel_ms": shading_ms,
                   "setup_ms": (t_resample - t0) * 1e3, "total_ms": (t3 - t0) * 1e3}
        notes = back_face_notes("triple", gbuffer.back, gbuffer.object, list(scene.objects))
        return Frame("triple", rgb.reshape(cam.height, cam.width, 3), timings, notes, moved,
                     read_bytes=frame_tables.nbytes + atlas.nbytes)

    return frame

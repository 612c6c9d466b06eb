"""Method ``triple`` (paper 004): per-pixel triple products of lighting, visibility and
BRDF in the pixel's local frame (kernels/triple/triple.cl, kernels/sphwavelet.h).

For a pixel that sees the surface point x with shading frame F = (t, n × t, n) and view
direction ω_o (local), the reflected radiance of the environment map L is

    B = ∫ L(F ω) V_x(ω) ρ̃(ω, ω_o) dω,   ρ̃ = kd cos θ/π + ρs f_g(ω, ω_o) cos θ,

with every factor a spherical Haar wavelet expansion over local directions ω
(pipeline/math/sphwavelet.py):

* L(F ·) interpolated trilinearly between the nearest frames of the rotation grid
  (pipeline/methods/triple/frame_grids.py ``FrameGrid``); an environment rotation α about +y at
  run time is a shift of the lookup's φ (``FrameGrid.weights``' ``turn``), a rotation R
  about any other axis looks up the frame RᵀF instead (``GBuffer.turned``: one pass over
  the pixels per turn), its ``scale`` a factor on the result;
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

Camera rays are traced once per camera (any camera; pipeline/device/raytrace.py) into a
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
from typing import Any

import numpy as np

from pipeline.device import cl
from pipeline.device.bvh import DeviceRayTracer
from pipeline.device.raytrace import Hits, Mesh, RayTracer, surface_at
from pipeline.engine.store import Artifact
from pipeline.errors import PrtError
from pipeline.images import read_environment
from pipeline.math.brdf import scene_brdfs
from pipeline.math.sphwavelet import (
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
    aligned,
    device_lookups,
    kernel_arguments,
    surface_attributes,
)
from pipeline.methods.triple.stages.brdf_tables import SHAPE_KEYS, glossy_rows
from pipeline.methods.triple.tables import (
    BRDF_ROWS,
    LIGHT_ROWS,
    SELECTIONS,
    VIS_ROWS,
    Atlas,
    PixelLookups,
    TripleTables,
    WaveletRows,
    read_rows,
)
from pipeline.render import (
    WORK_GROUP,
    DeviceImage,
    Frame,
    back_face_notes,
    camera_key,
    sees_back,
)
from pipeline.render.rays import aligned_image_rays
from pipeline.render.surface_detail import SceneDetail
from pipeline.scene.model import Scene

TRACERS = ("auto", "device", "embree")  # camera rays: the device's BVH (auto: on a GPU) or Embree


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
        moved = dense.nbytes + out_bytes
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


def camera_gbuffer(tracer: RayTracer, mesh: Mesh, atlas: Atlas, detail: SceneDetail,
                   cam: Any, static: dict[str, Any] | None = None) -> GBuffer:
    """The G-buffer of camera ``cam`` (pipeline/methods/triple/gbuffer.py): camera rays
    traced, surface attributes at the hits on the device (``surface_attributes``: the
    interpolated normal, the uv tangent, the texel coordinates); where a material has a
    blend or a bump, ``detail`` (pipeline/render/surface_detail.py) turns the shading frame and
    blends the materials on the host. The texel coordinates stay with the geometric hit
    (the visibility is the unbumped texel's, paper 004 §4.2). NumPy twin:
    :func:`camera_gbuffer_numpy`. ``static``: the renderer's cache of device buffers
    (the mesh's are uploaded once)."""
    origins, directions = aligned_image_rays(cam)
    hits = tracer.intersect(origins, directions)
    hit = hits.prim >= 0
    # page-aligned arrays from here on: a CPU device's kernels read them in place
    hits = Hits(hits.t, *(aligned(a, a.dtype) for a in (hits.prim, hits.u, hits.v)))
    pixel = aligned(np.flatnonzero(hit), np.int32)
    s = surface_attributes(mesh, atlas.face_uv, hits, directions, pixel, static)
    material = cl.aligned_empty(len(pixel), np.int32)
    np.take(np.asarray(mesh.object_material, np.int32), s["object"], out=material)
    material_b = cl.aligned_empty(len(pixel), np.int32)
    blend = cl.aligned_empty(len(pixel), np.float32)
    material_b[...], blend[...] = material, 0.0
    which = np.zeros(0, np.int64) if detail.empty else \
        np.flatnonzero(np.isin(material, [*detail.blend, *detail.bump]))
    if len(which):  # the host's SceneDetail on the pixels of detailed materials
        at = pixel[which]
        shading = detail.at(surface_at(mesh, hits.select(at), origins[at], directions[at],
                                       normal_dtype=np.float32))
        s["normal"][which], s["tangent"][which] = shading.normal, shading.tangent
        material_b[which], blend[which] = shading.material_b, shading.blend
    miss = aligned(np.flatnonzero(~hit), np.int32)
    miss_direction = aligned(directions[miss], np.float32)
    return GBuffer(cam.width, cam.height, pixel, s["normal"], s["tangent"], s["view"],
                   s["texel_xy"], s["object"], material, material_b, blend,
                   miss, miss_direction, s["back"].view(bool))


def camera_gbuffer_numpy(tracer: RayTracer, mesh: Mesh, atlas: Atlas, detail: SceneDetail,
                         cam: Any, static: dict[str, Any] | None = None) -> GBuffer:
    """:func:`camera_gbuffer` on the host: every attribute from
    pipeline.device.raytrace.Surface, ``detail`` and :meth:`Atlas.texel_xy` (the device
    kernel's twin, tests and benchmarks; it uploads nothing, so ``static`` is unused)."""
    origins, directions = aligned_image_rays(cam)
    hits = tracer.intersect(origins, directions)
    hit = hits.prim >= 0
    d = directions[hit]  # float32, as the G-buffer keeps it (normals blended in float32)
    surface = surface_at(mesh, hits.select(hit), origins[hit], d, normal_dtype=np.float32)
    shading = detail.at(surface)
    back = sees_back(d, mesh.face_normal[hits.prim[hit]])
    return GBuffer(cam.width, cam.height, np.flatnonzero(hit),
                   shading.normal.astype(np.float32), shading.tangent.astype(np.float32), -d,
                   atlas.texel_xy(surface), surface.object_id, shading.material_a,
                   shading.material_b, shading.blend, np.flatnonzero(~hit), directions[~hit],
                   back)


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


class TripleRenderer:
    """Method triple's renderer (pipeline/render/__init__.py ``Renderer``): the tables of
    ``triple.light_rotations``, ``triple.visibility``, ``triple.brdf_tables`` and the
    atlas of ``triple.atlas`` loaded once (cut to ``budget`` coefficients per function by
    ``selection`` when ``budget`` > 0; else as stored), the Embree scene of ``geometry``,
    the environment map. Each frame traces its scene's camera, looks up every pixel's
    rows and shades them (timings: trace, lookups, kernel); materials' kd and ρs, their
    γ (or other shape: the glossy rows re-sampled) and the environment's rotation and
    scale are read from the scene of each frame.

    Caches (each dropped when its key changes): ``resampled`` the re-sampled glossy rows
    per (material, shape); ``spliced`` the BRDF table with the last edits spliced in;
    ``edited_dense`` its dense tables; ``gbuffers`` the last camera's G-buffer;
    ``images`` the last image size's device image; ``device`` the buffers kept on the
    device across frames (the atlas's, the map)."""

    def __init__(self, scene: Scene, artifacts: Mapping[str, Artifact], budget: int = 0,
                 selection: str = "top-only", trace: str = "auto") -> None:
        if selection not in SELECTIONS:
            raise PrtError("--option", f"selection={selection!r}: expected one of "
                           f"{', '.join(SELECTIONS)}")
        if trace not in TRACERS:
            raise PrtError("--option", f"trace={trace!r}: expected one of "
                           f"{', '.join(TRACERS)}")
        if budget < 0:
            raise PrtError("--option", f"budget={budget}: expected 0 (as stored) or a "
                           "positive number of coefficients")
        self.budget, self.selection = budget, selection
        geo = artifacts["geometry"]
        self.material_names = geo.attrs["material_names"]
        # a top-only budget is cut while reading (the expansion to float32 is most of the
        # load); an adaptive one needs every stored entry's magnitude first
        self.tables, self.atlas = load_tables(artifacts, self.material_names,
                                              budget if selection == "top-only" else 0)
        if budget > 0 and selection != "top-only":
            self.tables = self.tables.truncated(selection, budget)
        self.brdf_attrs = artifacts["triple.brdf_tables"].attrs
        self.baked_shapes = {n: _shape(scene, n) for n in self.material_names}
        arrays = {n: geo.read(n) for n in
                  ("vertices", "normals", "uv", "faces", "face_object", "object_material")}
        import pyopencl as pcl

        on_gpu = bool(cl.device().type & pcl.device_type.GPU)
        self.tracer = DeviceRayTracer(arrays["vertices"], arrays["faces"]) \
            if trace == "device" or (trace == "auto" and on_gpu) \
            else RayTracer(arrays["vertices"], arrays["faces"])
        self.mesh = Mesh.from_arrays(arrays)
        self.detail = SceneDetail(scene, self.material_names)
        self.env_map = np.ascontiguousarray(
            read_environment(scene.environment.file), np.float32)
        level = dense_level(selection, budget)
        self.base_dense = None if level is None else DenseTables.from_tables(self.tables,
                                                                            level)
        self.resampled: dict[tuple, WaveletRows] = {}
        self.spliced: dict[tuple, WaveletRows] = {}
        self.edited_dense: list[tuple[WaveletRows, DenseTables]] = []
        self.gbuffers: dict[tuple, GBuffer] = {}
        self.turned: dict[tuple, GBuffer] = {}  # the last camera's, for the last turn
        self.images: dict[int, DeviceImage] = {}
        self.device: dict[str, Any] = {}

    def current_brdf(self, scene: Scene) -> WaveletRows:
        """The BRDF rows, with the glossy rows of every material whose shape (γ, ...)
        differs from the bake re-sampled as the stage samples them."""
        tables, edits = self.tables, []
        for m, name in enumerate(self.material_names):
            shape = _shape(scene, name)
            if tables.glossy_base[m] < 0 or shape == self.baked_shapes[name]:
                continue
            key = (name, tuple(sorted(shape.items())))
            if key not in self.resampled:
                a = self.brdf_attrs
                fresh = glossy_rows(scene.materials[name].model, shape, tables.views,
                                    int(a["leaf_level"]), int(a["refine"]),
                                    int(a["store_budget"]), float(a["store_tolerance"]),
                                    int(a["store_top"]))
                new = WaveletRows.from_counts(fresh["count"], fresh["index"],
                                              fresh["value"][:, 0])
                self.resampled[key] = new.truncated(tables.basis, self.selection,
                                                    self.budget) if self.budget > 0 else new
            edits.append((m, key))
        if not edits:
            return tables.brdf
        if tuple(edits) not in self.spliced:
            rows = tables.brdf
            for m, key in edits:
                rows = rows.with_rows(int(tables.glossy_base[m]), self.resampled[key])
            self.spliced.clear()
            self.spliced[tuple(edits)] = rows
        return self.spliced[tuple(edits)]

    def turned_gbuffer(self, camera: tuple, gbuffer: GBuffer, to_world: np.ndarray
                       ) -> GBuffer:
        """The camera's G-buffer taken into a map turned by ``to_world`` about an axis
        other than ±y (GBuffer.turned), kept for the next frame with the same turn."""
        key = (camera, np.asarray(to_world, np.float64).tobytes())
        if key not in self.turned:
            self.turned.clear()
            self.turned[key] = gbuffer.turned(to_world)
        return self.turned[key]

    def dense_of(self, brdf: WaveletRows) -> DenseTables | None:
        """The dense tables for these BRDF rows (converted once per edited table)."""
        if self.base_dense is None or brdf is self.tables.brdf:
            return self.base_dense
        if not self.edited_dense or self.edited_dense[0][0] is not brdf:
            self.edited_dense[:] = [(brdf, self.base_dense.with_brdf(brdf, self.tables.basis))]
        return self.edited_dense[0][1]

    def edit_mode(self, kind: str, scene: Scene) -> Callable[[Scene], Frame]:
        """Every edit takes the one frame path (its caches keep what an edit leaves)."""
        return self.frame

    def frame(self, scene: Scene) -> Frame:
        tables, atlas, static = self.tables, self.atlas, self.device
        t0 = time.perf_counter()
        cam = scene.camera
        key = camera_key(cam)
        was_cached = key in self.gbuffers
        if not was_cached:  # a new camera: trace it (the previous one is dropped)
            self.gbuffers.clear()
            self.gbuffers[key] = camera_gbuffer(self.tracer, self.mesh, atlas, self.detail,
                                                cam, static)
        gbuffer = self.gbuffers[key]
        env = scene.environment
        about_y = env.turn_about_y
        if about_y is None:  # a turn about another axis: the frames taken into the map
            gbuffer = self.turned_gbuffer(key, gbuffer, env.to_world)
        _, angles_ms = gbuffer.angles(tables.frames, tables.views)  # 0 ms once cached
        t1 = time.perf_counter()
        frame_tables = dataclasses.replace(tables, brdf=self.current_brdf(scene))
        frame_dense = self.dense_of(frame_tables.brdf)
        t_resample = time.perf_counter()
        turn = float(np.radians(about_y or 0.0))
        brdfs = scene_brdfs(scene, self.material_names)
        lookup = LookupTables.of(frame_tables, atlas, np.array([b.albedo for b in brdfs]),
                                 np.array([b.specular for b in brdfs]))
        # shading, background and their scatter into the image stay on the device; the
        # frame comes back in one copy
        image = DeviceImage.of_size(self.images, cam.width * cam.height)
        shaded = cl.scratch_buffer(image.buffers, "shaded", 12 * gbuffer.count)
        _, kernel_times, moved = shade_gbuffer(frame_tables, frame_dense, gbuffer,
                                               lookup, turn, static, out_buffer=shaded)
        scale = env.scale
        pixel, miss_pixel = gbuffer.pixel_device
        scatter_ms = image.scatter(shaded, pixel, gbuffer.count, scale)
        background_ms = 0.0
        env_map = self.env_map
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

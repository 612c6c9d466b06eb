"""Stage ``transfer``: per pixel, the diffuse transfer D of method d2i (paper 000 §3,
§5.2) and, for the pixels of glossy materials, the visibility the glossy transfer T is
computed from; one chunk per pixel tile. Schema ``transfer``.

For each view sample x (a G-buffer pixel) and gather disk g: the visibility V_g(x) of
g's centre through Embree or the device's BVH kernel (``bake.device``: only pairs that
face each other at the centres are traced), then the sub-area estimator of
pipeline/methods/d2i/transfer.py on the OpenCL device (kernels/d2i/transfer.cl) for D.
A glossy pixel's V_g(x) is stored too, a bit per gather sample: stage ``d2i.transfer_t``
(pipeline/methods/d2i/stages/transfer_glossy.py) computes T (k + 1 rows: b0 and the k
PCA bases of the pixel's material) from it, one chunk per tile and material, so that an
edit of one material's γ range re-runs that material's T and traces no ray.

Rows are stored per unit area: entry g is divided by |A_g| (the renderer multiplies the
gather radiance by |A_g| instead: D L = Σ_g (D_g/|A_g|)(|A_g| L_g)). Each entry is
proportional to its sample's area, and the areas of neighbouring gather samples scatter
like Voronoi cells (about ±50 %): with the area in them, rows are noise to a wavelet and
keep a residual of ≈ 20 % of their norm at 512 Haar coefficients (measured on the Cornell
box, 256², 16k gathers); per unit area they are the smooth geometry term, cut only by
visibility.

Rows are stored in the Haar domain (pipeline/math/haar.py, gather index padded to a power
of two), truncated losslessly in practice: each row keeps its largest coefficients until
the dropped ones hold at most ``transfer.keep_tolerance`` of the row's norm (relative L2),
and never more than ``transfer.d_max_coefficients`` (D; T's rows
``transfer.max_coefficients``); ``*_residual`` records what each row lost. Rows are
variable-length (CSR: per-row counts, flat indices and values, largest coefficient
first within a row). Dense rows would not fit (400² pixels × 16k gathers ×
4 bytes is 10 GB for D alone); the ``truncate`` stages then cut these rows down to the
renderer's budgets without recomputing transport, so budget sweeps re-run only them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pipeline.device import cl
from pipeline.device.bake_tracer import PARAM, bake_tracer
from pipeline.device.raytrace import RAY_EPSILON
from pipeline.device.threads import map_slices
from pipeline.engine.rows import ROW_CHUNKS, ROW_FIELDS, join_arrays, sort_rows
from pipeline.engine.stage import AssembleContext, Chunk, ChunkContext, Layout, Output
from pipeline.math import haar
from pipeline.math.brdf import MODEL_CODES, BrdfParams, pack_materials
from pipeline.methods.d2i.transfer import (
    FIRST_CHECK,
    PLANE_MARGIN,
    Disks,
    GlossyTable,
    Receivers,
    disk_polygons,
    fill_sourceless,
    split_near,
    subarea_points,
)

# The work-group size of both kernels, fixed: PoCL compiles a kernel once per
# work-group size, and left to choose, it picks one that divides each launch's pair
# count — a new compile (0.1-1 s) for most batches. That was the first re-bake's extra
# 2-9 s after a full bake (a basis of a new size: new kernels;
# decision 0016).
LAUNCH_GROUP = 64
PIXEL_BATCH = 128    # receivers per kernel launch (memory: batch × |G| × rows floats)
COMPRESS_BLOCK = 128  # rows per compression task: its temporaries stay in cache


def gather_disks(gather: Any) -> Disks:
    """The gather artifact's disks: centres and normals in float64; areas (as stored),
    sub-area points and polygons in float32, as the kernel reads them."""
    center = gather.read("position").astype(np.float64)
    normal = gather.read("normal").astype(np.float64)
    area = gather.read("area").astype(np.float64)
    tangent = gather.read("disk_tangent").astype(np.float64)
    points = subarea_points(center, normal, tangent, gather.read("radius").astype(np.float64),
                            gather.read("disk_rotation").astype(np.float64),
                            gather.read("disk_pattern").astype(np.float64))
    polygon = disk_polygons(center, normal, tangent, area)
    return Disks(center, normal, area.astype(np.float32),
                 np.ascontiguousarray(points, np.float32),
                 np.ascontiguousarray(polygon, np.float32))


def center_visibility(tracer: Any, position: np.ndarray, normal: np.ndarray,
                      disks: Disks, epsilon: float) -> np.ndarray:
    """V (P, G) uint8: 1 where receiver p and disk centre g face each other
    (n_p·ω > 0, n_g·ω < 0) and nothing lies between them for ``tracer``
    (pipeline/device/bake_tracer.py). The facing tests are two
    matrix products; rays run from p to g, both offset by ``epsilon`` along their
    normals, with the unnormalised direction (end − start) and t_far = 1 − 1e-4 (Embree's
    t is in units of the direction's length: no square roots). Points that coincide
    fail the strict facing test, so no ray has zero length. Groups of receivers run on
    all cores (NumPy and Embree release the GIL), each building its rays and tracing
    them (the device's tracer takes one group's rays at a time)."""
    x, n = position.astype(np.float32), normal.astype(np.float32)
    c, ng = disks.center.astype(np.float32), disks.normal.astype(np.float32)
    start_of = x + np.float32(epsilon) * n
    end_of = c + np.float32(epsilon) * ng
    c_side = np.sum(ng * c, axis=1)[None, :]
    vis = np.zeros((len(x), len(c)), np.uint8)

    def group(rows: slice) -> None:
        facing = n[rows] @ c.T > np.sum(n[rows] * x[rows], axis=1)[:, None]
        facing &= x[rows] @ ng.T > c_side
        pair = np.flatnonzero(facing)  # p · G + g (a flat search: 2-D nonzero is slower)
        start = np.repeat(start_of[rows], np.count_nonzero(facing, axis=1), axis=0)
        ray = np.take(end_of, pair % len(c), axis=0)
        ray -= start
        t_far = np.full(len(pair), 1 - 1e-4, np.float32)
        blocked = tracer.occluded(start, ray, t_far, threads=1)
        facing.reshape(-1)[pair[blocked]] = False  # most rays are free: clear the rest
        vis[rows] = facing

    map_slices(group, len(x), max(1, -(-len(x) // (4 * tracer.threads))), tracer.threads)
    return vis


class TransferKernel:
    """kernels/d2i/transfer.cl over one set of gather disks (uploaded once)."""

    def __init__(self, disks: Disks, solid_angle: float, tolerance: float) -> None:
        self.count, self.subarea = len(disks.area), disks.points.shape[1]
        self.disks = cl.read_only_buffer(disks.packed)
        self.points = cl.read_only_buffer(np.asarray(disks.points, np.float32))
        self.polygons = cl.read_only_buffer(np.asarray(disks.polygon, np.float32))
        self.sides = disks.polygon.shape[1]
        self.solid_angle, self.tolerance = np.float32(solid_angle), np.float32(tolerance)

    def __call__(self, receivers: Receivers, visibility: np.ndarray,
                 table: GlossyTable | None) -> tuple[np.ndarray, np.ndarray | None]:
        """D (P, G) and T (P, R, G) float32, as pipeline.methods.d2i.transfer.transfer."""
        n = len(receivers.position)
        packed = np.concatenate([receivers.position, receivers.normal, receivers.tangent,
                                 receivers.wo], axis=1).astype(np.float32)
        rows = 0 if table is None else len(table.rows)
        if n == 0 or self.count == 0:
            return (np.zeros((n, self.count), np.float32),
                    np.zeros((n, rows, self.count), np.float32) if rows else None)
        defines = {"ROWS": rows, "SUBAREA": self.subarea, "FIRST_CHECK": FIRST_CHECK,
                   "POLYGON_SIDES": self.sides, "PLANE_MARGIN": f"{PLANE_MARGIN}f"}
        if table is None:
            material = np.zeros((1, 16), np.float32)
            grid = np.zeros(2, np.float32)
            values = np.zeros(2, np.float32)
            angle_lo, angle_scale = 0.0, 1.0
        else:
            material = pack_materials([table.params])
            grid = table.grid.astype(np.float32)
            values = table.rows.astype(np.float32)
            angle_lo, angle_scale = _grid_angles(table.params, table.grid)
            defines["BRDF_MODEL"] = MODEL_CODES[table.params.model]
            if table.params.model == "lafortune":
                defines["REVERSED_GRID"] = 1
        pairs = np.flatnonzero(visibility).astype(np.uint32)
        d = np.zeros((n, self.count), np.float32)
        t = np.zeros((n, rows, self.count) if rows else 1, np.float32)  # 1: an unused stand-in
        d_buf, t_buf = cl.shared_output_buffer(d), cl.shared_output_buffer(t)
        if len(pairs):
            common = (cl.read_only_buffer(material), cl.read_only_buffer(grid),
                      cl.read_only_buffer(values), np.int32(len(grid)),
                      np.float32(angle_lo), np.float32(angle_scale), self.solid_angle)
            receivers_buf = cl.read_only_buffer(packed)
            deferred = np.zeros(len(pairs), np.uint8)
            deferred_buf = cl.shared_output_buffer(deferred)
            # each pair p · count + g writes d and t at that index: all inside the buffers
            if int(pairs.max()) >= n * self.count:
                raise RuntimeError(f"transfer pair {int(pairs.max())} is past the {n} × "
                                   f"{self.count} outputs: refusing to launch")
            # transfer_points reads its pair unguarded: the list is padded to the groups
            padded = np.zeros(-(-len(pairs) // LAUNCH_GROUP) * LAUNCH_GROUP, np.uint32)
            padded[:len(pairs)] = pairs
            cl.enqueue(cl.kernel("transfer.cl", "transfer_points", defines), len(padded),
                       receivers_buf, self.disks, np.int32(self.count),
                       cl.read_only_buffer(padded), np.int32(len(pairs)), *common,
                       deferred_buf, d_buf, t_buf, local=LAUNCH_GROUP)
            cl.read_output_buffer(deferred, deferred_buf)
            near = pairs[deferred.view(bool)]
            if len(near):
                cl.enqueue(cl.kernel("transfer.cl", "transfer_pairs", defines), len(near),
                           receivers_buf, self.disks, np.int32(self.count), self.points,
                           self.polygons, cl.read_only_buffer(near), np.int32(len(near)),
                           *common, self.tolerance, d_buf, t_buf, local=LAUNCH_GROUP)
            cl.read_output_buffer(d, d_buf)
            if rows:
                cl.read_output_buffer(t, t_buf)
        return d, (t if rows else None)


def _grid_angles(params: BrdfParams, grid: np.ndarray) -> tuple[float, float]:
    """(angle_lo, angle_scale) so that (angle − lo) · scale is the fractional index of an
    angle in the basis grid's angle sequence (Lafortune: arccos of its x grid, reversed)."""
    if params.model == "lafortune":
        lo, hi = float(np.arccos(grid[-1])), float(np.arccos(grid[0]))
    else:
        lo, hi = float(grid[0]), float(grid[-1])
    return lo, (len(grid) - 1) / (hi - lo)


def compress_rows(rows: np.ndarray, area: np.ndarray, keep_tolerance: float,
                  max_coefficients: int) -> dict[str, np.ndarray]:
    """Dense rows (n, G) per unit source area as CSR rows over the renderer's radiance
    vector (Haar coefficients, then gather-domain values): each row's near entries
    (pipeline.methods.d2i.transfer.split_near) first, as index haar_length + g, then its far
    part's Haar coefficients — its columns of sources without area and the padding filled
    smoothly first (fill_sourceless: the product never reads them) — truncated by
    pipeline.math.haar.truncate (largest first; ``residual`` is relative to the far
    part). Row blocks run on all cores (NumPy's loops, partitions and sorts release the
    GIL)."""
    if len(rows) <= COMPRESS_BLOCK:
        return _compress_block(rows, area, keep_tolerance, max_coefficients)
    parts = map_slices(lambda block: _compress_block(rows[block], area, keep_tolerance,
                                                     max_coefficients),
                       len(rows), COMPRESS_BLOCK)
    return {k: np.concatenate([part[k] for part in parts]) for k in parts[0]}


def _compress_block(rows: np.ndarray, area: np.ndarray, keep_tolerance: float,
                    max_coefficients: int) -> dict[str, np.ndarray]:
    offset = haar.padded_length(rows.shape[1])
    far, (near_row, near_column, near_value) = split_near(rows, area)
    far = fill_sourceless(far, area, offset)  # after the split: no spike spreads into it
    haar_rows = haar.truncate(haar.forward(far), keep_tolerance, max_coefficients)
    near_count = np.bincount(near_row, minlength=len(rows))
    return merge_rows({"count": near_count, "index": near_column + offset,
                       "value": near_value}, haar_rows)


def merge_rows(first: dict[str, np.ndarray], second: dict[str, np.ndarray]
               ) -> dict[str, np.ndarray]:
    """CSR rows whose entries are ``first``'s, then ``second``'s (same row count);
    ``residual`` from ``second``. Each entry goes straight to its place (row start, plus
    first's count for second's entries, plus its rank within its row): no sort."""
    count = first["count"] + second["count"]
    start = np.cumsum(count) - count
    out = {"count": count.astype(np.int32),
           "index": np.empty(int(count.sum()), np.int32),
           "value": np.empty(int(count.sum()), np.float32),
           "residual": second["residual"]}
    for part, offset in ((first, start), (second, start + first["count"])):
        own_start = np.cumsum(part["count"]) - part["count"]
        place = np.arange(len(part["index"])) + np.repeat(offset - own_start, part["count"])
        out["index"][place] = part["index"]
        out["value"][place] = part["value"]
    return out


# ---------------------------------------------------------------------------- the stage

_CACHE: dict[str, tuple[str, Any]] = {}


def _cached(kind: str, key: str, build) -> Any:
    """The object of ``kind`` for input ``key`` (the ray tracer, the uploaded disks, the
    kernel), built once per process; a new key replaces the old object, so that a process
    baking many variants (`prt evaluate` sweeps) holds one of each."""
    if kind not in _CACHE or _CACHE[kind][0] != key:
        _CACHE.pop(kind, None)
        _CACHE[kind] = (key, build())
    return _CACHE[kind][1]


def scene_tools(ctx: AssembleContext) -> tuple[Any, Disks, TransferKernel, float]:
    """The tracer of ``bake.device`` (pipeline/device/bake_tracer.py), the gather disks,
    the transfer kernel over them (each built once per process and input key) and the
    ray offset (scene units)."""
    geometry = ctx.inputs["geometry"]
    tracer = _cached("tracer", f"{geometry.record['key']}:{ctx.params[PARAM]}",
                     lambda: bake_tracer(ctx.params[PARAM], geometry.record["key"],
                                         geometry.read("vertices"), geometry.read("faces")))
    disks, kernel = gather_tools(ctx)
    bbox = np.subtract(geometry.attrs["bbox_max"], geometry.attrs["bbox_min"])
    return tracer, disks, kernel, RAY_EPSILON * float(np.linalg.norm(bbox))


def gather_tools(ctx: AssembleContext) -> tuple[Disks, TransferKernel]:
    """The gather disks and the transfer kernel over them, without the ray tracer (a
    stage that reads stored visibility traces no ray)."""
    gather = ctx.inputs["d2i.gather"]
    disks = _cached("disks", gather.record["key"], lambda: gather_disks(gather))
    solid_angle = ctx.params["transfer.subarea_solid_angle"]
    tolerance = ctx.params["transfer.subarea_tolerance"]
    kernel = _cached("kernel", f"{gather.record['key']}{solid_angle}{tolerance}",
                     lambda: TransferKernel(disks, solid_angle, tolerance))
    return disks, kernel


def tile_pixels(ctx: ChunkContext) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The chunk's pixel tile from the G-buffer: position, normal, tangent (P, 3)
    float64, the unit direction to the eye ``wo`` and ``material`` (P,) per pixel in
    raster order within the tile; and each pixel's global id (y · width + x)."""
    gbuf = ctx.inputs["gbuffer"]
    y0, y1, x0, x1 = ctx.chunk.region
    region = (slice(y0, y1), slice(x0, x1))
    out = {name: gbuf.read(name, region).reshape(-1, 3).astype(np.float64)
           for name in ("position", "normal", "tangent")}
    out["material"] = gbuf.read("material_id", region).reshape(-1)
    rows_y, cols_x = np.divmod(np.arange(len(out["material"])), x1 - x0)
    pixel = (rows_y + y0) * ctx.scene["camera"]["width"] + cols_x + x0
    eye = np.asarray(ctx.scene["camera"]["position"], np.float64)
    wo = eye - out["position"]
    out["wo"] = wo / np.maximum(np.linalg.norm(wo, axis=1, keepdims=True), 1e-30)
    return out, pixel


def glossy_material_ids(ctx: AssembleContext) -> np.ndarray:
    """Material indices (geometry order) of the glossy materials (model not lambert)
    among those whose sections the chunk sees."""
    names = ctx.inputs["geometry"].attrs["material_names"]
    return np.array([i for i, name in enumerate(names)
                     if ctx.scene.get(f"materials.{name}.model") not in (None, "lambert")],
                    np.int64)


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    tile, pixel = tile_pixels(ctx)
    tracer, disks, kernel, epsilon = scene_tools(ctx)
    keep = float(ctx.params["transfer.keep_tolerance"])
    cap = int(ctx.params["transfer.d_max_coefficients"])
    glossy = np.isin(tile["material"], glossy_material_ids(ctx))

    d_parts: list[tuple[np.ndarray, dict, int]] = []
    v_parts: list[tuple[np.ndarray, np.ndarray]] = []
    seen = np.flatnonzero(tile["material"] >= 0)
    for start in range(0, len(seen), PIXEL_BATCH):
        batch = seen[start:start + PIXEL_BATCH]
        vis = center_visibility(tracer, tile["position"][batch], tile["normal"][batch],
                                disks, epsilon)
        receivers = Receivers(tile["position"][batch], tile["normal"][batch],
                              tile["tangent"][batch], tile["wo"][batch])
        d, _ = kernel(receivers, vis, None)
        d *= disks.inverse_area  # in place: the kernel's fresh array
        d_parts.append((batch, compress_rows(d, disks.area, keep, cap), 1))
        own = glossy[batch]
        v_parts.append((batch[own], np.packbits(vis[own].astype(bool), axis=1)))
    unseen = np.flatnonzero(tile["material"] < 0)
    d_parts.append((unseen, {"count": np.zeros(len(unseen), np.int32),
                             "residual": np.zeros(len(unseen), np.float32),
                             "index": np.zeros(0, np.int32), "value": np.zeros(0, np.float32)},
                    1))
    out = {f"d_{k}": v for k, v in rows_by_pixel(pixel, d_parts).items()}
    local = join_arrays([sel for sel, _ in v_parts], np.int64)
    order = np.argsort(local, kind="stable")
    out["v_pixel"] = pixel[local[order]].astype(np.int32)
    out["v_bits"] = (np.concatenate([bits for _, bits in v_parts])[order] if v_parts else
                     np.zeros((0, (len(disks.area) + 7) // 8), np.uint8))
    return out  # the tile's rows: pieces of the artifact's segmented arrays


def rows_by_pixel(pixel: np.ndarray, parts: list[tuple[np.ndarray, dict, int]]
                   ) -> dict[str, np.ndarray]:
    """CSR rows of ``parts`` [(local pixels, their rows, rows per pixel)] ordered by
    pixel (a pixel's rows stay together, in order), with ``pixel`` the global id of
    each row's pixel."""
    rows = {k: join_arrays([part[k] for _, part, _ in parts], dt) for k, dt in ROW_FIELDS.items()}
    local = join_arrays([np.repeat(sel, n) for sel, _, n in parts], np.int64)
    out = sort_rows(local, rows)
    out["pixel"] = pixel[np.sort(local, kind="stable")].astype(np.int32)
    return out


def layout(ctx: AssembleContext) -> Layout:
    return Layout(sizes=ROW_CHUNKS)


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    """The rows are the tiles' pieces in tile order; ``d_pixel`` and ``v_pixel`` name
    each row's pixel (the truncate stage orders them by pixel)."""
    return Output(row_attrs(ctx, "transfer.d_max_coefficients"))


def row_attrs(ctx: AssembleContext, cap: str) -> dict[str, Any]:
    """The attributes of an artifact of per-pixel rows: the image and gather counts,
    the Haar length and the near-lossless cut (``cap``: the parameter that capped it)."""
    cam = ctx.scene["camera"]
    gather_count = int(ctx.inputs["d2i.gather"].attrs["count"])
    return {"width": cam["width"], "height": cam["height"], "gather_count": gather_count,
            "haar_length": haar.padded_length(gather_count),
            "keep_tolerance": float(ctx.params["transfer.keep_tolerance"]),
            "max_coefficients": int(ctx.params[cap])}

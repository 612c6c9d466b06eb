"""Stage ``triple.visibility``: per texel, binary visibility in its local frame as wavelet
rows (paper 004 §4: the visibility textures).

Per texel tile of ``triple.atlas`` (one chunk each), for every covered or dilated texel
with surface point p, shading normal n, tangent t and its face's geometric normal g
(all world, outward):

* the local frame is (t, n × t, n) (as ``pipeline.math.brdf.to_local``); ω_i runs over
  the centroids of the leaves of level L + r of the geodesic sphere (L =
  ``triple.leaf_level``, r = ``triple.visibility_refine``: 4^r rays per leaf of level L),
  taken in that frame to the world direction d = x t + y (n × t) + z n;
* V(ω_i) = 1 when ω_i lies above both horizons, z > 0 (the shading normal's) and
  d · g > 0 (the face's), and an occlusion ray from p + ε g along d meets nothing
  (Embree's or the device's BVH kernel's: ``bake.device``, pipeline/device/bake_tracer.py)
  (ε = 1e-4 of the scene's bounding-box diagonal, as the other stages offset rays);
  else 0. No ray is cast below either horizon: below the shading horizon the BRDF table
  ρ̃ (which holds max(cos θ_i, 0)) is zero anyway, and below the geometric one the face
  itself is in the way, so V is zero on the lower hemisphere and the rows are sparser;
* V's leaf means over level L (the solid-angle-weighted mean of the 4^r fine values
  in each leaf, as ``pipeline.math.sphwavelet.leaf_means``) go through
  ``wavelet_basis(L).forward`` and are stored with ``pipeline.methods.triple.wavelet_rows.
  select_rows`` (as the lighting and BRDF tables are): every non-zero coefficient of
  indices < ``triple.store_top`` (320: levels 0 and 1, so run-time top-only budgets ≤
  320 are exact), and beyond them the largest first, as few as leave a relative L2
  error ≤ ``triple.store_tolerance``, at most ``triple.store_budget`` per row.

Rows (schema ``triple_visibility``): one per texel of the tile, in raster order within
the tile, tiles in the chunk order (objects in scene order, tiles in raster order over
each texture); empty texels have empty rows. ``texel_row`` maps the atlas's flat texel
order to rows, and ``start`` (read back global through ``offset_by``) gives each row's
first entry in ``index`` / ``value``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from pipeline.device.bake_tracer import PARAM, bake_tracer
from pipeline.device.raytrace import RAY_EPSILON
from pipeline.device.threads import map_slices
from pipeline.engine.chunkwrite import segment_name
from pipeline.engine.rows import ROW_CHUNKS, join_arrays
from pipeline.engine.stage import (
    AssembleContext,
    Chunk,
    ChunkContext,
    Layout,
    Output,
    ToleranceResult,
)
from pipeline.math.geodesic import geodesic_levels
from pipeline.math.sphwavelet import wavelet_basis
from pipeline.methods.triple.texels import EMPTY
from pipeline.methods.triple.wavelet_rows import select_rows
from pipeline.stages.geometry import traced_geometry

TEXEL_BATCH = 64     # texels whose rays are cast together (× 10·4^(L+r) directions)



def fine_directions(leaf_level: int, refine: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit centroids (20·4^(L+r), 3) of the leaves of level L + r, grouped 4^r per
    leaf of level L, and their solid angles (same length, sr)."""
    fine = geodesic_levels(leaf_level + refine)[-1]
    return fine.centroids, fine.areas


def visibility_batches(tracer: Any, position: np.ndarray, normal: np.ndarray,
                       tangent: np.ndarray, geometric_normal: np.ndarray, epsilon: float,
                       leaf_level: int, refine: int, then: Callable[[np.ndarray], Any]
                       ) -> tuple[list[Any], int]:
    """``then`` applied to the leaf means (B, 20·4^L) of V (module docstring, ``tracer``
    one of pipeline/device/bake_tracer.py's) of each batch of TEXEL_BATCH of the T
    texels (all (T, 3), world, float64), in texel order, and the number of rays cast.
    The batches run on this task's threads, each tracing on its own thread, so that one
    batch's NumPy work (and ``then``) overlaps another's rays. Only the fine directions
    above the shading horizon (z > 0 in the local frame) are taken to the world, in
    float32."""
    local, areas = fine_directions(leaf_level, refine)
    group = 4 ** refine
    weights = areas.reshape(-1, group)
    upper = np.flatnonzero(local[:, 2] > 0)
    local_up = local[upper].astype(np.float32)
    frames = np.stack([tangent, np.cross(normal, tangent), normal], axis=1).astype(np.float32)
    g = geometric_normal.astype(np.float32)
    origins = (position + epsilon * geometric_normal).astype(np.float32)

    def batch(b: slice) -> tuple[np.ndarray, int]:
        world = np.matmul(local_up, frames[b])                      # (T, M_up, 3)
        above = np.matmul(world, g[b, :, None])[..., 0] > 0         # the face's horizon
        # Rays below the face's horizon get a negative length: Embree skips them
        # (cheaper than compacting the others).
        length = np.where(above, np.float32(np.inf), np.float32(-1.0)).reshape(-1)
        blocked = tracer.occluded(np.repeat(origins[b], world.shape[1], axis=0),
                                  world.reshape(-1, 3), length, threads=1)
        visible = np.zeros((len(world), len(local)), np.float32)
        visible[:, upper] = above & ~blocked.reshape(above.shape)
        means = np.einsum("tnk,nk->tn", visible.reshape(len(world), -1, group),
                          weights) / weights.sum(axis=1)
        return then(means), int(above.sum())

    parts = map_slices(batch, len(position), TEXEL_BATCH)
    return [p for p, _ in parts], sum(n for _, n in parts)


def visibility_leaf_means(tracer: Any, position: np.ndarray, normal: np.ndarray,
                          tangent: np.ndarray, geometric_normal: np.ndarray,
                          epsilon: float, leaf_level: int, refine: int
                          ) -> tuple[np.ndarray, int]:
    """Leaf means (T, 20·4^L) of V at T texels (:func:`visibility_batches`), and the
    number of rays cast."""
    parts, rays = visibility_batches(tracer, position, normal, tangent, geometric_normal,
                                     epsilon, leaf_level, refine, lambda means: means)
    empty = np.zeros((0, wavelet_basis(leaf_level).size))
    return np.concatenate([empty, *parts]), rays


def _tile_texels(atlas, obj: str, region: tuple[int, int, int, int]) -> dict[str, np.ndarray]:
    """The atlas's per-texel arrays of the tile ``region`` of object ``obj``'s texture,
    flattened in raster order within the tile."""
    y0, y1, x0, x1 = region
    width = int(atlas.attrs["texture_sizes"][obj][1])
    out = {}
    for name in ("texel_state", "texel_face", "texel_position", "texel_normal",
                 "texel_tangent"):
        rows = np.asarray(atlas.group[name][segment_name(obj)][y0 * width:y1 * width])
        rows = rows.reshape(y1 - y0, width, *rows.shape[1:])[:, x0:x1]
        out[name] = rows.reshape(-1, *rows.shape[2:])
    return out


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    obj, region = ctx.chunk.object, ctx.chunk.region
    level = int(ctx.params["triple.leaf_level"])
    refine = int(ctx.params["triple.visibility_refine"])
    geometry, atlas = ctx.inputs["geometry"], ctx.inputs["triple.atlas"]
    traced = traced_geometry(geometry)
    face_normal, epsilon = traced.mesh.face_normal, traced.epsilon
    tracer = bake_tracer(ctx.params[PARAM], geometry.record["key"], traced.mesh.vertices,
                         traced.mesh.faces, traced.tracer)
    texel = _tile_texels(atlas, obj, region)
    filled = texel["texel_state"] != EMPTY
    first_face = geometry.read("object_ranges")[geometry.attrs["object_names"].index(obj), 2]
    basis = wavelet_basis(level)

    def rows(means: np.ndarray) -> dict[str, np.ndarray]:
        selected = select_rows(basis.forward(means)[:, None, :], level,
                               int(ctx.params["triple.store_budget"]),
                               float(ctx.params["triple.store_tolerance"]),
                               min(int(ctx.params["triple.store_top"]), basis.size))
        return {**selected, "value": selected["value"][:, 0]}

    parts, rays = visibility_batches(
        tracer, texel["texel_position"][filled].astype(np.float64),
        texel["texel_normal"][filled].astype(np.float64),
        texel["texel_tangent"][filled].astype(np.float64),
        face_normal[first_face + texel["texel_face"][filled]], epsilon, level, refine, rows)
    stored = {name: join_arrays([p[name] for p in parts], dtype)
              for name, dtype in (("count", np.int32), ("residual", np.float32),
                                  ("index", np.uint16), ("value", np.float32))}
    count = np.zeros(len(filled), np.int32)
    residual = np.zeros(len(filled), np.float32)
    count[filled], residual[filled] = stored["count"], stored["residual"]
    ctx.meta.update({"rays": rays, "texels": int(filled.sum()), "rows": len(filled),
                     "coefficients": int(count.sum()),
                     "worst_residual": float(residual.max(initial=0.0))})
    return {"count": count, "residual": residual,
            "start": (np.cumsum(count, dtype=np.int64) - count),
            "index": stored["index"], "value": stored["value"]}


def layout(ctx: AssembleContext) -> Layout:
    return Layout(sizes={**ROW_CHUNKS, "texel_chunk": 1 << 16})


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    """``texel_row`` from the chunk order, the totals, and per object the worst relative
    L2 error a stored row kept."""
    atlas = ctx.inputs["triple.atlas"]
    sizes = atlas.attrs["texture_sizes"]
    offsets = dict(zip(sizes, atlas.read("texture_offsets").tolist(), strict=True))
    texel_row = np.full(sum(h * w for h, w in sizes.values()), -1, np.int64)
    row = 0
    worst: dict[str, float] = {}
    for chunk, meta in metas:
        y0, y1, x0, x1 = chunk.region
        width = sizes[chunk.object][1]
        flat = offsets[chunk.object] + (np.arange(y0, y1)[:, None] * width
                                        + np.arange(x0, x1)[None, :]).reshape(-1)
        texel_row[flat] = row + np.arange(len(flat))
        row += len(flat)
        worst[chunk.object] = max(worst.get(chunk.object, 0.0), meta["worst_residual"])
    tolerance = float(ctx.params["triple.store_tolerance"])
    budget = int(ctx.params["triple.store_budget"])
    level = int(ctx.params["triple.leaf_level"])
    results = [ToleranceResult(
        f"object {obj}", "worst relative L2 error of a texel's visibility row", tolerance,
        value, {"store_budget": budget}, "" if value <= tolerance else f"store_budget {budget}",
        "" if value <= tolerance else "raise triple.store_budget") for obj, value in worst.items()]
    return Output(
        attrs={"leaf_level": level, "coefficients": wavelet_basis(level).size,
               "visibility_refine": int(ctx.params["triple.visibility_refine"]),
               "selection": "largest",
               "keep_first": min(int(ctx.params["triple.store_top"]), wavelet_basis(level).size),
               "store_tolerance": tolerance, "store_budget": budget,
               "texel_tile": int(ctx.params["triple.texel_tile"]),
               "texture_sizes": sizes, "ray_epsilon": RAY_EPSILON,
               "rays": int(sum(m["rays"] for _, m in metas)),
               "texels": int(sum(m["texels"] for _, m in metas)),
               "stored_coefficients": int(sum(m["coefficients"] for _, m in metas))},
        arrays={"texel_row": texel_row}, tolerances=results)

"""Stage ``gbuffer``: one camera ray per pixel centre, first hit through Embree.

Per pixel tile (one chunk each) it stores the hit position, the shading normal
(barycentric blend of vertex normals, turned to face the camera), a tangent (along +u of
the mesh's uv where that is well defined, else a frame from the normal), object and
material ids, interpolated uv (all from ``pipeline.device.raytrace.surface_at``; the normal
normalised in float32) and camera-space depth. Schema ``gbuffer``.
"""

from __future__ import annotations

import numpy as np

from pipeline.device.raytrace import surface_at
from pipeline.engine.stage import (
    AssembleContext,
    Block,
    Chunk,
    ChunkContext,
    Layout,
    Output,
    tile_blocks,
)
from pipeline.math.camera import camera_frame, camera_rays
from pipeline.stages.geometry import traced_geometry


def layout(ctx: AssembleContext) -> Layout:
    """Full images, zarr chunks of the stage's tile."""
    cam = ctx.scene["camera"]
    h, w = cam["height"], cam["width"]
    shapes = {"position": (h, w, 3), "normal": (h, w, 3), "tangent": (h, w, 3),
              "object_id": (h, w), "material_id": (h, w), "uv": (h, w, 2), "depth": (h, w)}
    return Layout(shapes, {"tile": int(ctx.params["gbuffer.tile"])})


def run_chunk(ctx: ChunkContext) -> dict[str, Block]:
    cam = ctx.scene["camera"]
    y0, y1, x0, x1 = ctx.chunk.region
    shape = (y1 - y0, x1 - x0)
    origins, dirs = camera_rays(cam["position"], cam["look_at"], cam["up"], cam["fov"],
                                cam["width"], cam["height"], ctx.chunk.region)
    traced = traced_geometry(ctx.inputs["geometry"])
    mesh = traced.mesh
    hits = traced.tracer.intersect(origins, dirs)
    hit = hits.prim >= 0
    d = dirs.reshape(-1, 3).astype(np.float64)
    surface = surface_at(mesh, hits.select(hit), origins.reshape(-1, 3)[hit], d[hit],
                         normal_dtype=np.float32)
    forward = camera_frame(cam["position"], cam["look_at"], cam["up"])[2]
    depth = hits.t * (d @ forward)

    def image(a: np.ndarray, dtype, fill=0) -> np.ndarray:
        """Per-hit values ``a`` as a tile (``fill`` where the ray missed)."""
        out = np.full((len(hit), *a.shape[1:]), fill, dtype)
        out[hit] = a
        return out.reshape(*shape, *a.shape[1:])

    return tile_blocks(ctx.chunk, {
        "position": image(surface.position, np.float32),
        "normal": image(surface.normal, np.float32),
        "tangent": image(surface.tangent, np.float32),
        "object_id": image(surface.object_id, np.int32, -1),
        "material_id": image(surface.material_id, np.int32, -1),
        "uv": image(surface.uv, np.float32),
        "depth": image(depth[hit], np.float32),
    })


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    cam = ctx.scene["camera"]
    return Output({"width": cam["width"], "height": cam["height"],
                   "tile": int(ctx.params["gbuffer.tile"]), "camera": cam})

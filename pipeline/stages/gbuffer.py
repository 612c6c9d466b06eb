"""Stage ``gbuffer``: one camera ray per pixel centre, first hit through Embree.

Per pixel tile (one chunk each) it stores the hit position, the shading normal
(barycentric blend of vertex normals, turned to face the camera), a tangent (along +u of
the mesh's uv where that is well defined, else a frame from the normal), object and
material ids, interpolated uv and camera-space depth. Schema ``gbuffer``.
"""

from __future__ import annotations

import numpy as np

from pipeline.math.camera import camera_frame, camera_rays
from pipeline.math.frames import face_tangents, orthonormalize
from pipeline.raytrace import RayTracer
from pipeline.stages import AssembleContext, Chunk, ChunkContext, Output, stitch_tiles

_TRACERS: dict[str, tuple[RayTracer, dict[str, np.ndarray]]] = {}


def _scene_tracer(ctx: ChunkContext) -> tuple[RayTracer, dict[str, np.ndarray]]:
    """The Embree scene of the geometry input, built once per process and input key."""
    geometry = ctx.inputs["geometry"]
    key = geometry.record["key"]
    if key not in _TRACERS:
        arrays = {n: geometry.read(n) for n in
                  ("vertices", "normals", "uv", "faces", "face_object", "object_material")}
        _TRACERS.clear()
        _TRACERS[key] = (RayTracer(arrays["vertices"], arrays["faces"]), arrays)
    return _TRACERS[key]


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    cam = ctx.scene["camera"]
    y0, y1, x0, x1 = ctx.chunk.region
    shape = (y1 - y0, x1 - x0)
    origins, dirs = camera_rays(cam["position"], cam["look_at"], cam["up"], cam["fov"],
                                cam["width"], cam["height"], ctx.chunk.region)
    tracer, geo = _scene_tracer(ctx)
    hits = tracer.intersect(origins, dirs)
    hit = hits.prim >= 0
    prim = np.where(hit, hits.prim, 0)
    tri = geo["faces"][prim]
    w = np.stack([1.0 - hits.u - hits.v, hits.u, hits.v], axis=1)[:, :, None]
    d = dirs.reshape(-1, 3).astype(np.float64)

    position = origins.reshape(-1, 3) + hits.t[:, None] * d
    normal = np.sum(w * geo["normals"][tri], axis=1)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-30)
    normal = np.where(np.sum(normal * d, axis=1, keepdims=True) > 0, -normal, normal)
    uv = np.sum(w * geo["uv"][tri], axis=1)
    tangent = orthonormalize(face_tangents(geo["vertices"], geo["uv"], geo["faces"][prim]),
                             normal)
    forward = camera_frame(cam["position"], cam["look_at"], cam["up"])[2]
    depth = hits.t * (d @ forward)

    obj = np.where(hit, geo["face_object"][prim], -1)
    mask = hit[:, None]

    def image(a: np.ndarray, dtype) -> np.ndarray:
        a = np.where(mask, a, 0) if a.ndim == 2 else np.where(hit, a, 0)
        return a.astype(dtype).reshape(*shape, *a.shape[1:])

    return {
        "position": image(position, np.float32),
        "normal": image(normal, np.float32),
        "tangent": image(tangent, np.float32),
        "object_id": obj.astype(np.int32).reshape(shape),
        "material_id": np.where(hit, geo["object_material"][np.maximum(obj, 0)], -1)
        .astype(np.int32).reshape(shape),
        "uv": image(uv, np.float32),
        "depth": image(depth, np.float32),
    }


def assemble(ctx: AssembleContext, pieces: list[tuple[Chunk, dict]]) -> Output:
    cam = ctx.scene["camera"]
    tile = int(ctx.params["gbuffer.tile"])
    return Output(stitch_tiles(pieces, cam["height"], cam["width"]),
                  attrs={"width": cam["width"], "height": cam["height"], "tile": tile,
                         "camera": cam},
                  sizes={"tile": tile})

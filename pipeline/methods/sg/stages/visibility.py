"""Stage ``sg.visibility``: per vertex, its visibility as an octahedral mip pyramid and
its occluder transfer, what ``--option normal=visibility`` renders from
(pipeline/methods/sg/visibility.py, decision 0046). Schema ``sg_visibility``; one chunk,
the whole scene, traced ``BATCH`` vertices at a time (a few seconds per 10k vertices
at the default 32² texels × 2² rays: 4096 rays a vertex).

The key holds the geometry, sg.diffuse (the occluders' radiance) and the params — not
the materials' glossy parameters: ρs and γ are applied at render time.
"""

from __future__ import annotations

import numpy as np

from pipeline.engine.stage import AssembleContext, Chunk, ChunkContext, Output
from pipeline.errors import PrtError
from pipeline.methods.sg import visibility
from pipeline.methods.sg.stages.diffuse import integer_param, vertex_scene

BATCH = 256  # vertices per tracing batch: 256 × R² S² rays


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    """``maps`` (V, total) uint8 packed pyramids and ``occluder`` (V, 3, n²) float32."""
    resolution = integer_param(ctx, "sg.visibility_resolution", 1)
    if resolution & (resolution - 1):
        raise PrtError("sg.visibility_resolution", f"{resolution}: expected a power of two")
    supersample = integer_param(ctx, "sg.visibility_supersample", 1)
    samples = integer_param(ctx, "sg.visibility_occluder_samples", 1)
    scene = vertex_scene(ctx)
    transfer = np.asarray(ctx.inputs["sg.diffuse"].read("transfer"), np.float64)
    count = len(scene.positions)
    maps = np.zeros((count, visibility.level_offsets(resolution)[-1]), np.uint8)
    occluder = np.zeros((count,) + transfer.shape[1:], np.float32)
    for start in range(0, count, BATCH):
        batch = np.arange(start, min(start + BATCH, count))
        maps[batch] = visibility.pyramid(visibility.visibility_maps(scene, batch, resolution,
                                                                    supersample))
        occluder[batch] = visibility.occluder_transfer(scene, batch, transfer, samples,
                                                       ctx.rng)
    return {"maps": maps, "occluder": occluder}


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    return Output({"resolution": int(ctx.params["sg.visibility_resolution"]),
                   "supersample": int(ctx.params["sg.visibility_supersample"]),
                   "occluder_samples": int(ctx.params["sg.visibility_occluder_samples"])})

"""Stage ``sg.source_visibility``: per vertex and bright source of the map, what the
vertex sees of the source at each turn of the map about +y (pipeline/methods/sg/
source_rings.py, decision 0049): what ``normal=visibility`` lights the sources' glossy
and diffuse light by. Schema ``sg_source_visibility``; one chunk, the whole scene,
traced ``BATCH`` vertices at a time (a map without sources stores an empty table).

The key holds the geometry, sg.env_prefilter (the sources' directions and sharpness)
and the params; no material: the table is visibility only.
"""

from __future__ import annotations

import numpy as np

from pipeline.engine.stage import AssembleContext, Chunk, ChunkContext, Output
from pipeline.errors import PrtError
from pipeline.methods.sg import source_rings
from pipeline.methods.sg.sources import FIELDS
from pipeline.methods.sg.stages.diffuse import vertex_scene

BATCH = 64  # vertices per tracing batch of 64 × R × N rays (studio lights: 4.3k, 2.0k a vertex)


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    """``table`` (V, Σ N_s) uint8 and ``offsets`` (K + 1,) int32: source s's columns."""
    step = float(ctx.params["sg.source_visibility_step"])
    if not step > 0.0:
        raise PrtError("sg.source_visibility_step", f"{step}: must be > 0")
    sources = np.asarray(ctx.inputs["sg.env_prefilter"].read("sources"),
                         np.float64).reshape(-1, FIELDS)
    scene = vertex_scene(ctx, albedo=False)
    count = len(scene.positions)
    rings = [source_rings.ring_rows(s[:3], float(s[6]), step) for s in sources]
    offsets = np.cumsum([0] + [n for _, _, n in rings]).astype(np.int32)
    table = np.zeros((count, int(offsets[-1])), np.uint8)
    for (rows, weights, n), first in zip(rings, offsets, strict=False):
        for start in range(0, count, BATCH):
            batch = np.arange(start, min(start + BATCH, count))
            table[batch, first:first + n] = source_rings.seen_by(scene, batch, rows, weights)
    return {"table": table, "offsets": offsets}


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    return Output({"step": float(ctx.params["sg.source_visibility_step"])})

"""Stage ``sg.diffuse``: per vertex, the diffuse transfer of method sg in order-5
spherical harmonics, shadows and ``sg.diffuse_bounces`` diffuse interreflections
included (pipeline/math/sg_diffuse.py). Schema ``sg_diffuse``; one chunk, the whole
scene.

**Why one chunk.** Bounce b at a vertex gathers bounce b − 1 at the hits of its rays,
which may be any vertex of the scene; so the bounces need every vertex's direct
transfer first. The rays that give the direct transfer also give the gather matrix G
(sparse, V × V, ≈ 3 × the blocked rays' entries), after which each bounce is one sparse
product with a (V, 75) array: milliseconds. So the whole stage is one pass of
``sg.diffuse_samples`` rays per vertex (traced ``BATCH`` vertices at a time, Embree on
all of the task's threads) plus the products, in one chunk; splitting it into a
vertex-batch direct stage and a bounce stage would have to store G (12 bytes per ray:
≈ 50 MB for bunny_sg) to save nothing but progress granularity. NOTES.md (issue 17,
third session) has the cost on bunny_sg.

The key holds the geometry, the materials' albedos kd (the glossy part of the light
leaving a surface is not part of this transfer) and the params: editing a model, ρs or
γ re-bakes nothing here.
"""

from __future__ import annotations

import numpy as np

from pipeline.errors import PrtError
from pipeline.math import sg_diffuse, sh
from pipeline.math.brdf import BrdfParams
from pipeline.math.sg_scene import VertexScene
from pipeline.stages import AssembleContext, Chunk, ChunkContext, Output

BATCH = 1024  # vertices per tracing batch: 1024 × samples rays


def vertex_scene(ctx: AssembleContext) -> VertexScene:
    """The geometry as a VertexScene whose materials carry only their albedo kd (as
    Lambert: all this stage reads of them)."""
    geometry = ctx.inputs["geometry"]
    arrays = {name: geometry.read(name) for name in
              ("vertices", "normals", "faces", "object_ranges", "object_material")}
    materials = [BrdfParams("lambert", tuple(ctx.scene[f"materials.{name}.albedo"]))
                 for name in geometry.attrs["material_names"]]
    return VertexScene.from_arrays(arrays, materials)


def _count(ctx: AssembleContext, name: str, low: int) -> int:
    value = ctx.params[name]
    if not isinstance(value, int) or isinstance(value, bool) or value < low:
        raise PrtError(name, f"{value!r}: expected an integer ≥ {low}")
    return value


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    """``transfer`` (V, 3, 25) float32 of every vertex."""
    samples = _count(ctx, "sg.diffuse_samples", 1)
    bounces = _count(ctx, "sg.diffuse_bounces", 0)
    transfer = sg_diffuse.transfer(vertex_scene(ctx), samples, bounces, ctx.rng, BATCH)
    return {"transfer": transfer.astype(np.float32)}


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    return Output({"order": sh.ORDER, "bounces": int(ctx.params["sg.diffuse_bounces"]),
                   "samples": int(ctx.params["sg.diffuse_samples"])})

"""Stage ``sg.diffuse``: per vertex, the diffuse transfer of method sg in spherical
harmonics of order ``sg.diffuse_order`` (8; paper 003's 5: 25 coefficients), shadows and
``sg.diffuse_bounces`` diffuse interreflections included (pipeline/methods/sg/diffuse.py).
Schema ``sg_diffuse``; one chunk, the whole scene.

**Order.** Under a map with small bright sources (Grace's windows) order 5 misses much
of the shadowed diffuse light: on bunny_sg's bunny the blue channel, which Grace keeps
mostly in its windows, comes out ≈ 0 at order 5 (per-vertex relative RMS 96 %; red 11 %),
8 gives 42 % / 5.5 %, 12 gives 20 % / 3 %, against ray-traced direct light
(decision 0028). The renderer takes the order from the artifact's ``order``
attribute, so raising the param needs no other change.

**Why one chunk.** Bounce b at a vertex gathers bounce b − 1 at the hits of its rays,
which may be any vertex of the scene; so the bounces need every vertex's direct
transfer first. The rays that give the direct transfer also give the gather matrix G
(sparse, V × V, ≈ 3 × the blocked rays' entries), after which each bounce is one sparse
product with a (V, 75) array: milliseconds. So the whole stage is one pass of
``sg.diffuse_samples`` rays per vertex (traced ``BATCH`` vertices at a time, Embree on
all of the task's threads) plus the products, in one chunk; splitting it into a
vertex-batch direct stage and a bounce stage would have to store G (12 bytes per ray:
≈ 50 MB for bunny_sg) to save nothing but progress granularity. Its cost on bunny_sg:
decision 0028.

The key holds the geometry, the materials' albedos kd (the glossy part of the light
leaving a surface is not part of this transfer) and the params: editing a model, ρs or
γ re-bakes nothing here.
"""

from __future__ import annotations

import numpy as np

from pipeline.device.bake_tracer import PARAM, bake_tracer
from pipeline.engine.stage import AssembleContext, Chunk, ChunkContext, Output
from pipeline.errors import PrtError
from pipeline.math.brdf import BrdfParams
from pipeline.methods.sg import diffuse as sg_diffuse
from pipeline.methods.sg.vertex_scene import VertexScene

BATCH = 1024  # vertices per tracing batch: 1024 × samples rays


def vertex_scene(ctx: AssembleContext, albedo: bool = True) -> VertexScene:
    """The geometry as a VertexScene whose materials carry only their albedo kd (as
    Lambert: all this stage reads of them; ``albedo`` False: no materials, for a stage
    that traces visibility alone), its rays traced as ``bake.device`` says
    (pipeline/device/bake_tracer.py)."""
    geometry = ctx.inputs["geometry"]
    arrays = {name: geometry.read(name) for name in
              ("vertices", "normals", "faces", "object_ranges", "object_material")}
    materials = [BrdfParams("lambert", tuple(ctx.scene[f"materials.{name}.albedo"]))
                 for name in geometry.attrs["material_names"]] if albedo else []
    tracer = bake_tracer(ctx.params[PARAM], geometry.record["key"], arrays["vertices"],
                         arrays["faces"])
    return VertexScene.from_arrays(arrays, materials, tracer)


def integer_param(ctx: AssembleContext, name: str, low: int) -> int:
    """Stage parameter ``name``, an integer ≥ ``low`` (PrtError naming it otherwise)."""
    value = ctx.params[name]
    if not isinstance(value, int) or isinstance(value, bool) or value < low:
        raise PrtError(name, f"{value!r}: expected an integer ≥ {low}")
    return value


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    """``transfer`` (V, 3, order²) float32 of every vertex, and its ``direct`` part (the
    bright sources' direct light is taken from what each vertex sees of them instead,
    decisions 0048 and 0049)."""
    samples = integer_param(ctx, "sg.diffuse_samples", 1)
    bounces = integer_param(ctx, "sg.diffuse_bounces", 0)
    order = integer_param(ctx, "sg.diffuse_order", 1)
    transfer, direct = sg_diffuse.transfers(vertex_scene(ctx), samples, bounces, ctx.rng,
                                            BATCH, order)
    return {"transfer": transfer.astype(np.float32), "direct": direct.astype(np.float32)}


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    return Output({"order": int(ctx.params["sg.diffuse_order"]),
                   "bounces": int(ctx.params["sg.diffuse_bounces"]),
                   "samples": int(ctx.params["sg.diffuse_samples"])})

"""Toy stand-in for a UV atlas stage: per object a texture of side
⌈√(vertices × toy.texels_per_vertex)⌉ texels, recorded as the attribute texture_sizes."""

from __future__ import annotations

import math

import numpy as np

from pipeline.engine.stage import Output


def run_chunk(ctx):
    counts = ctx.inputs["geometry"].attrs["vertex_counts"]
    sides = [math.ceil(math.sqrt(n * ctx.params["toy.texels_per_vertex"]))
             for n in counts.values()]
    ctx.meta["texture_sizes"] = {obj: [side, side + 1] for obj, side in zip(counts, sides,
                                                                            strict=True)}
    return {"side": np.asarray(sides, np.int32)}


def finalize(ctx, metas):
    return Output({"texture_sizes": metas[0][1]["texture_sizes"]})

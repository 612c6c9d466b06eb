"""Toy stage chunked by tile and material: per pixel of the chunk's material in its tile,
the parent tile's value times the material's red albedo (a piece of segmented arrays)."""

from __future__ import annotations

import numpy as np

from pipeline.engine.stage import Output


def run_chunk(ctx):
    y0, y1, x0, x1 = ctx.chunk.region
    name = ctx.chunk.materials[0]
    index = list(ctx.inputs["geometry"].attrs["material_names"]).index(name)
    material = ctx.inputs["gbuffer"].read("material_id", (slice(y0, y1), slice(x0, x1)))
    ys, xs = np.nonzero(material == index)
    value = ctx.inputs["tiles"].read("value", (slice(y0, y1), slice(x0, x1)))[ys, xs]
    albedo = float(ctx.scene[f"materials.{name}.albedo"][0])
    width = ctx.scene["camera"]["width"]
    return {"pixel": ((ys + y0) * width + xs + x0).astype(np.int32),
            "value": (value * albedo).astype(np.float32)}


def finalize(ctx, metas):
    return Output({})

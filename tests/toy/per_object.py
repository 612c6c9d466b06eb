"""Toy stage chunked by object: each chunk holds its material's albedo times toy.scale
(a row of a region array), plus one seeded random number (a piece of a segmented one)."""

from __future__ import annotations

import numpy as np

from pipeline.engine.stage import Block, Layout, Output


def layout(ctx):
    objects = {key.split(".")[1] for key in ctx.scene if key.startswith("objects.")}
    return Layout({"value": (len(objects), 3)})


def run_chunk(ctx):
    material = ctx.scene[f"objects.{ctx.chunk.object}.material"]
    albedo = np.asarray(ctx.scene[f"materials.{material}"]["albedo"], np.float64)
    return {"value": Block((ctx.chunk.index,),
                           (albedo * ctx.params["toy.scale"]).astype(np.float32)[None]),
            "noise": ctx.rng.random(1).astype(np.float32)}


def finalize(ctx, metas):
    return Output({})

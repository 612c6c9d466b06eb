"""Toy stage chunked by object: each chunk holds its material's albedo times toy.scale,
plus one seeded random number."""

from __future__ import annotations

import numpy as np

from pipeline.stages import Output


def run_chunk(ctx):
    material = ctx.scene[f"objects.{ctx.chunk.object}.material"]
    albedo = np.asarray(ctx.scene[f"materials.{material}"]["albedo"], np.float64)
    return {"value": (albedo * ctx.params["toy.scale"]).astype(np.float32),
            "noise": ctx.rng.random(1).astype(np.float32)}


def assemble(ctx, pieces):
    return Output({"value": np.stack([p["value"] for _, p in pieces]),
                   "noise": np.concatenate([p["noise"] for _, p in pieces])}, {})

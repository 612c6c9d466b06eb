"""Toy stage chunked by pixel tile: seeded noise per pixel, after sleeping toy.sleep
seconds (so that tests can kill a run in the middle of the stage)."""

from __future__ import annotations

import time

from pipeline.engine.stage import Layout, Output, tile_blocks


def layout(ctx):
    cam = ctx.scene["camera"]
    return Layout({"value": (cam["height"], cam["width"])}, {"tile": ctx.params["toy.tile"]})


def run_chunk(ctx):
    time.sleep(ctx.params["toy.sleep"])
    y0, y1, x0, x1 = ctx.chunk.region
    return tile_blocks(ctx.chunk, {"value": ctx.rng.random((y1 - y0, x1 - x0)).astype("float32")})


def finalize(ctx, metas):
    return Output({})

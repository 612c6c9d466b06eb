"""Toy stage chunked by pixel tile: seeded noise per pixel, after sleeping toy.sleep
seconds (so that tests can kill a run in the middle of the stage)."""

from __future__ import annotations

import time

from pipeline.stages import Output, stitch_tiles


def run_chunk(ctx):
    time.sleep(ctx.params["toy.sleep"])
    y0, y1, x0, x1 = ctx.chunk.region
    return {"value": ctx.rng.random((y1 - y0, x1 - x0)).astype("float32")}


def assemble(ctx, pieces):
    cam = ctx.scene["camera"]
    return Output(stitch_tiles(pieces, cam["height"], cam["width"]), {},
                  {"tile": ctx.params["toy.tile"]})

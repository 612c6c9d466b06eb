"""Toy stage chunked by texel tiles: each tile's texel count, as its own segment."""

from __future__ import annotations

import numpy as np

from pipeline.engine.stage import Output


def run_chunk(ctx):
    y0, y1, x0, x1 = ctx.chunk.region
    return {"texels": np.array([(y1 - y0) * (x1 - x0)], np.int64)}


def finalize(ctx, metas):
    return Output({})

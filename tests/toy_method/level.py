"""Stage toy.level: the mean of toy.shade."""

from __future__ import annotations

import numpy as np

from pipeline.engine.stage import Output


def run_chunk(ctx):
    return {"level": np.array([ctx.inputs["toy.shade"].read("shade").mean()], np.float32)}


def finalize(ctx, metas):
    return Output({})

"""Toy stage, unchunked: sums the per_object values, plus toy.offset."""

from __future__ import annotations

import numpy as np

from pipeline.engine.stage import Output


def run_chunk(ctx):
    values = ctx.inputs["per_object"].read("value")
    return {"value": (values.sum(axis=0) + ctx.params["toy.offset"]).astype(np.float32),
            "noise": ctx.inputs["per_object"].read("noise")}


def finalize(ctx, metas):
    return Output({})

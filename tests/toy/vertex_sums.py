"""Toy stage chunked by vertex batches: the batch's vertices, read from the geometry."""

from __future__ import annotations

from pipeline.engine.stage import Output


def run_chunk(ctx):
    geometry = ctx.inputs["geometry"]
    names = geometry.attrs["object_names"]
    first = int(geometry.read("object_ranges")[names.index(ctx.chunk.object), 0])
    start, end = ctx.chunk.span
    return {"vertices": geometry.read("vertices")[first + start:first + end]}


def finalize(ctx, metas):
    return Output({})

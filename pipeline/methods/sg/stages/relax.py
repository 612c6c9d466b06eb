"""Stage ``sg.relax``: the relaxation pass of method sg over every mesh edge (paper 003
§7: "an additional relaxation step" against lobe flips). Schema ``sg_lobes``, the
lobes the renderer reads; one chunk per object.

``sg.fit`` fits vertex batches apart (in parallel, each its own chunk), so it counts and
relaxes flips only over the edges inside a batch. The edges between batches were left
with far more flips: on the coarse bunny (scenes/bunny_sg_coarse.yaml, batches of 256,
the default then) 19 % of the edges cross a batch boundary, and 41–46 % of the vertex
pairs there were flipped by more than 5° against 13–15 % inside batches; after this
stage 17–18 % (decision 0027).

This stage runs ``sg.fit_relaxation_sweeps`` sweeps of pipeline/methods/sg/coherence.py
``relax`` over each object's whole mesh in its breadth-first order, starting from the
batches' labels: slots are relabelled per vertex and view, nothing else changes (each
lobe's weights, mean and sharpness, the counts and the errors are sg.fit's). Flips are
counted over every edge and view pair of the object before and after (attrs
``flips_before_relaxation`` / ``flips_after_relaxation``; the batches' own counts stay
in sg.fit's attrs).
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from pipeline.engine.stage import AssembleContext, Chunk, ChunkContext, Layout, Output
from pipeline.methods.sg import coherence as sg_coherence
from pipeline.methods.sg.stages.fit import (
    VERTEX_CHUNK,
    batch_edges,
    flood_order,
    pack_slots,
    slot_counts,
    unpack_slots,
)


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    """The chunk's object: sg.fit's arrays of its vertices, slots relabelled."""
    geometry, fit = ctx.inputs["geometry"], ctx.inputs["sg.fit"]
    obj = geometry.attrs["object_names"].index(ctx.chunk.object)
    start, end = (int(x) for x in geometry.read("object_ranges")[obj, :2])
    count, error = (fit.read(name, (slice(start, end),)) for name in ("count", "error"))
    rows, first = fit.read("lobes"), fit.read("first")
    slots = slot_counts(first, len(rows))[start:end]
    lo = int(first[start]) if end > start else 0
    rows, first = rows[lo:lo + int(slots.sum())], first[start:end] - lo
    if (count >= 2).any():
        lobes = unpack_slots(rows, first, slots)
        edges = batch_edges(geometry.read("faces"), start, end)
        order, vertex_nbs = flood_order(end - start, edges)
        view_nbs = sg_coherence.view_neighbours(fit.read("views"))
        active = error >= 0
        before = sg_coherence.count_flips(lobes[..., 3:6], active, count, edges, view_nbs)
        perm, sweeps = sg_coherence.relax(lobes[..., 3:6].astype(np.float64), active, count,
                                          vertex_nbs, view_nbs, order,
                                          int(ctx.params["sg.fit_relaxation_sweeps"]))
        lobes = np.take_along_axis(lobes, perm[..., None], axis=2)
        after = sg_coherence.count_flips(lobes[..., 3:6], active, count, edges, view_nbs)
        ctx.meta.update(flips_before=before, flips_after=after, sweeps=sweeps)
        rows, first = pack_slots(lobes, slots)
    return {"lobes": rows, "first": first, "count": count, "error": error}


def layout(ctx: AssembleContext) -> Layout:
    return Layout(sizes={"vertex_chunk": VERTEX_CHUNK, "slot_chunk": VERTEX_CHUNK})


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    """sg.fit's attrs, with the flips counted here over every edge (summed over the
    objects) in place of the batches' counts."""
    fit = ctx.inputs["sg.fit"]
    before, after = Counter(), Counter()
    for _, meta in metas:
        before.update(meta.get("flips_before", {}))
        after.update(meta.get("flips_after", {}))
    return Output(attrs={**fit.attrs, "flips_before_relaxation": dict(before),
                         "flips_after_relaxation": dict(after),
                         "batch_flips_before_relaxation": fit.attrs["flips_before_relaxation"],
                         "batch_flips_after_relaxation": fit.attrs["flips_after_relaxation"],
                         "relaxed_over": "every mesh edge of each object"},
                  arrays={"views": fit.read("views")})

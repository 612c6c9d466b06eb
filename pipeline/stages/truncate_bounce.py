"""Stage ``d2i.truncate_ms``: cut the stored Haar rows of the bounce matrix Ms down to the
renderer's budgets, by the rules of ``d2i.truncate`` (pipeline/stages/truncate.py:
``truncate.budget``, ``truncate.tolerance``, and ``truncate.ms_coefficients`` per row
for the proportional rule; near entries always kept). One chunk per block of gather
rows of the bounce stage, each reading only its twin block. Schema ``compressed_bounce``.
"""

from __future__ import annotations

import numpy as np

from pipeline.math import haar
from pipeline.rows import ROW_CHUNKS
from pipeline.stages import AssembleContext, Chunk, ChunkContext, Layout, Output
from pipeline.stages.truncate import cut_to_budget


def _haar_length(ctx: ChunkContext | AssembleContext) -> int:
    """The Haar length of the rows' far part (the gather count padded, as the transfer
    and bounce stages pad it): indices from there on are near entries."""
    return haar.padded_length(int(ctx.inputs["d2i.bounce"].attrs["gather_count"]))


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    """The block's Ms rows, cut."""
    bounce = ctx.inputs["d2i.bounce"]
    arrays = {n: bounce.read_piece(n, ctx.chunk.id) for n in bounce.names}
    budget = np.full(len(arrays["ms_count"]), int(ctx.params["truncate.ms_coefficients"]))
    return cut_to_budget(ctx.params, "ms", arrays, _haar_length(ctx), budget)


def layout(ctx: AssembleContext) -> Layout:
    return Layout(sizes=ROW_CHUNKS)


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    return Output({
        "gather_count": int(ctx.inputs["d2i.bounce"].attrs["gather_count"]),
        "haar_length": _haar_length(ctx),
        "budget": ctx.params["truncate.budget"],
        "tolerance": float(ctx.params["truncate.tolerance"]),
        "coefficients": int(ctx.params["truncate.ms_coefficients"])})

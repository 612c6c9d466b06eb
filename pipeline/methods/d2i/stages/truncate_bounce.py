"""Stage ``d2i.truncate_ms``: cut the stored Haar rows of the bounce matrix Ms down to the
renderer's budgets, by the rules of ``d2i.truncate`` (pipeline/methods/d2i/stages/truncate.py:
``truncate.budget``, ``truncate.tolerance``, and ``truncate.ms_coefficients`` per row
for the proportional rule; near entries always kept), after a Haar transform across
blocks of ``truncate.ms_block`` consecutive rows, as D's rows are cut across pixel blocks:
on the Cornell box (16k gathers) blocks of 16 at 125 coefficients per row erred 1.1 % in
the bounce product Ms L with its mean kept to 0.04 %, single rows 4.2 % and 2.6 % low
(decision 0012). One chunk per block of gather rows of the bounce
stage, each reading only its twin block. Schema ``compressed_bounce``.
"""

from __future__ import annotations

import numpy as np

from pipeline.engine.rows import ROW_CHUNKS
from pipeline.engine.stage import AssembleContext, Chunk, ChunkContext, Layout, Output
from pipeline.math import haar
from pipeline.methods.d2i.stages.truncate import block_size, cut_blocks, pooled_budget


def _haar_length(ctx: ChunkContext | AssembleContext) -> int:
    """The Haar length of the rows' far part (the gather count padded, as the transfer
    and bounce stages pad it): indices from there on are near entries."""
    return haar.padded_length(int(ctx.inputs["d2i.bounce"].attrs["gather_count"]))


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    """The chunk's Ms rows transformed across blocks of ``truncate.ms_block`` consecutive
    gather samples (neighbours: the gather stage orders them along a space-filling curve)
    and cut per block (pipeline/methods/d2i/stages/truncate.py cut_blocks)."""
    bounce = ctx.inputs["d2i.bounce"]
    rows = {k: bounce.read_piece(f"ms_{k}", ctx.chunk.id)
            for k in ("count", "index", "value", "residual")}
    size = block_size(ctx.params, "truncate.ms_block", "bounce.block")
    gather = ctx.chunk.span[0] + np.arange(len(rows["count"]))
    haar_length = _haar_length(ctx)
    columns = haar_length + int(bounce.attrs["gather_count"])
    cut = cut_blocks(ctx.params, rows, gather // size, gather % size, haar.matrix(size),
                     haar_length, columns, int(ctx.params["truncate.ms_coefficients"]),
                     pooled_budget(ctx.params))
    return {f"ms_{k}": v for k, v in cut.items()}


def layout(ctx: AssembleContext) -> Layout:
    return Layout(sizes=ROW_CHUNKS)


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    return Output({
        "gather_count": int(ctx.inputs["d2i.bounce"].attrs["gather_count"]),
        "haar_length": _haar_length(ctx),
        "budget": ctx.params["truncate.budget"],
        "tolerance": float(ctx.params["truncate.tolerance"]),
        "coefficients": int(ctx.params["truncate.ms_coefficients"]),
        "block": int(ctx.params["truncate.ms_block"])})

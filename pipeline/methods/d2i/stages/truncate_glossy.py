"""Stage ``truncate_glossy`` (``d2i.truncate_t``): cut the stored Haar rows of T down to
the renderer's budgets (paper 000 §3.4, §7.2) by the rules of
pipeline/methods/d2i/stages/truncate.py,
one chunk per chunk of ``d2i.transfer_t`` (a pixel tile's pixels of one material), each
reading only its twin and its material's basis. Schema ``compressed_glossy``.

With the proportional rule, row 0 (b0) of each pixel keeps ``truncate.coefficients``
and row j ≥ 1 that × σ_j/σ_1 (the PCA singular values of the material's basis), at
least a quarter of it.
"""

from __future__ import annotations

import numpy as np

from pipeline.engine.rows import place_in_runs
from pipeline.engine.stage import AssembleContext, Chunk, ChunkContext, Layout, Output
from pipeline.methods.d2i.stages.truncate import cut_attrs, cut_to_budget
from pipeline.methods.d2i.stages.truncate import layout as truncate_layout

MIN_RATIO = 0.25  # a basis row keeps at least this share of b0's budget


def proportional_budgets(pixel: np.ndarray, singular_values: np.ndarray, coefficients: int
                         ) -> np.ndarray:
    """Per T row (``pixel``: each row's pixel, a pixel's rows b0..bk consecutive): the
    proportional rule's coefficient budget, ``coefficients`` × σ_j/σ_1 for row j ≥ 1 of
    its pixel (``singular_values``: the material's σ_1..σ_k), ``coefficients`` for b0."""
    row = place_in_runs(pixel)
    ratio = np.ones(len(pixel))
    later = row > 0
    s = singular_values[row[later] - 1] / max(float(singular_values[0]), 1e-300)
    ratio[later] = np.maximum(s, MIN_RATIO)
    return np.maximum(np.round(coefficients * ratio), 1).astype(np.int64)


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    """The chunk's T rows, cut (in the glossy transfer chunk's row order)."""
    transfer = ctx.inputs["d2i.transfer_t"]
    arrays = {n: transfer.read_piece(n, ctx.chunk.id) for n in transfer.names}
    basis = ctx.inputs["brdf_basis"]
    index = list(basis.attrs["material_names"]).index(ctx.chunk.materials[0])
    budgets = proportional_budgets(arrays["t_pixel"],
                                   basis.read("singular_values", (index,)),
                                   int(ctx.params["truncate.coefficients"]))
    out = cut_to_budget(ctx.params, "t", arrays, int(transfer.attrs["haar_length"]), budgets)
    out["t_pixel"] = arrays["t_pixel"]
    return out


def layout(ctx: AssembleContext) -> Layout:
    return truncate_layout(ctx)


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    return Output({**cut_attrs(ctx, "d2i.transfer_t"),
                   "coefficients": int(ctx.params["truncate.coefficients"])})

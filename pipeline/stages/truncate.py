"""Stage ``d2i.truncate``: cut the stored Haar rows of T and D down to the renderer's
budgets (paper 000 §3.4, §7.2), one chunk per pixel tile of the transfer stage, each
reading only its twin transfer tile and the bases of the materials it sees (so an edit
of one material re-cuts only the tiles that see it). Schema ``compressed_transport``.
Ms is cut by ``d2i.truncate_ms`` (pipeline/stages/truncate_bounce.py) by the same rules.

The ``transfer`` and ``bounce`` stages keep each row near-losslessly (its near entries
in the gather domain, then Haar coefficients largest first, to
``transfer.keep_tolerance``); this stage keeps a prefix of each row, near entries always.
Because the Haar transform is orthonormal, a row that keeps the coefficients of energy
E_kept of its full energy E errs in any product t·l by at most √(E − E_kept)·‖l‖
(pipeline/math/haar.py). Budgets:

Every row also keeps its ``COARSE_KEPT`` coarsest Haar coefficients (the far part's
mean and its means over the 16 largest blocks of gather samples), moved right after its
near entries. A row beside a contact (a wall pixel 1 mm above the floor) keeps, after its
near entries, a spike of floor samples just below the near bar; that spike's chain of
coefficients holds nearly all the row's energy, and a tolerance met by it alone dropped
the mean: the pixel's D L fell from 1.27 to 0.006 (a black pixel; Tableau, 128²).

``tolerance``: each row keeps the fewest coefficients whose dropped energy,
    including what the transfer stage already dropped, is at most
    ``truncate.tolerance``² of the row's full energy: no row keeps more than its own
    accuracy needs (a dark or smooth row keeps few), and a pixel on a diffuse material
    has no T rows at all.
``proportional`` (the paper's rule; the default): row 0 (b0) of T and every Ms row
    keep ``truncate.coefficients``, every D row ``truncate.d_coefficients``; T row j ≥ 1
    keeps
    ``truncate.coefficients`` × σ_j/σ_1 (the PCA singular values of the pixel's
    material), at least a quarter of it. Paper 000 used (250, 150, 150, 100, 100, 100,
    100) for its Cornell floor. At equal storage this rule erred about half as much as
    the tolerance on the Cornell box, and at 500 beat the tolerance 0.02 in error and
    storage on the Cornell box, the Tableau and the Still-life (NOTES.md, issue 19).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pipeline.errors import PrtError
from pipeline.rows import ROW_CHUNKS, cut_rows, quantise_values
from pipeline.stages import AssembleContext, Chunk, ChunkContext, Layout, Output

BUDGETS = ("tolerance", "proportional")
COARSE_KEPT = 16  # Haar coefficients 0..15 (scaling and 4 coarsest levels) always kept


def kept_counts(count: np.ndarray, residual: np.ndarray, value: np.ndarray,
                tolerance: float, near: np.ndarray | None = None,
                always: np.ndarray | None = None) -> np.ndarray:
    """Per CSR row (largest coefficient first): the fewest leading entries whose dropped
    energy (the rest of the row plus the residual already dropped) is ≤ tolerance² of
    the row's full energy. Entries flagged ``near`` (a row's leading gather-domain
    entries, pipeline/stages/transfer.py) are always kept and count for no energy;
    entries flagged ``always`` (leading too, after the near ones) are always kept.

    The energy kept up to each entry grows along a row, so the entries still short of
    the energy a row must keep are a prefix of it: one binary search per row in the
    running energy of all entries, rather than a comparison per entry."""
    count = count.astype(np.int64)
    end = np.cumsum(count)
    start = end - count
    near = np.zeros(len(value), bool) if near is None else near
    energy = np.square(value, dtype=np.float64)
    energy[near] = 0.0
    running = np.concatenate([[0.0], np.cumsum(energy)])  # energy of the entries before i
    kept_total = running[end] - running[start]
    residual2 = np.square(residual.astype(np.float64))
    full = kept_total / np.maximum(1.0 - residual2, 1e-12)
    allowed = full * (1.0 - tolerance * tolerance)  # energy a row must keep
    # entries i of the row with running[i + 1] − running[start] < allowed
    short = np.searchsorted(running[1:], running[start] + allowed * (1 - 1e-12)) - start
    leading = near if always is None else near | always
    leading_before = np.concatenate([[0], np.cumsum(leading, dtype=np.int64)])
    needed = np.maximum(np.clip(short, 0, count), leading_before[end] - leading_before[start])
    return np.minimum(needed + 1, count)


def cut_to_budget(params: dict[str, Any], prefix: str, arrays: dict[str, np.ndarray],
                  haar_length: int, proportional: np.ndarray | None = None
                  ) -> dict[str, np.ndarray]:
    """The rows ``{prefix}_count/_index/_value`` (and ``_residual``) cut by
    ``truncate.budget``: to ``truncate.tolerance``, or to ``proportional`` (else
    ``truncate.coefficients``) entries besides their near ones (index ≥ haar_length);
    values stored as float16 over a float32 scale per row (pipeline.rows.quantise_values)."""
    if params["truncate.budget"] not in BUDGETS:
        raise PrtError(None, f"truncate.budget = {params['truncate.budget']!r}: "
                       f"expected one of {', '.join(BUDGETS)}")
    count = arrays[f"{prefix}_count"]
    index, value = coarse_first(count, arrays[f"{prefix}_index"], arrays[f"{prefix}_value"],
                                haar_length)
    near = index >= haar_length
    if params["truncate.budget"] == "tolerance":
        keep = kept_counts(count, arrays[f"{prefix}_residual"], value,
                           float(params["truncate.tolerance"]), near, index < COARSE_KEPT)
    else:
        near_count = np.bincount(np.repeat(np.arange(len(count)), count), weights=near,
                                 minlength=len(count)).astype(np.int64)
        keep = near_count + (proportional if proportional is not None else
                             np.full(len(count), int(params["truncate.coefficients"])))
    out = cut_rows(count, index, value, keep)
    out["scale"], out["value"] = quantise_values(out["count"], out["value"])
    return {f"{prefix}_{k}": v for k, v in out.items()}


def coarse_first(count: np.ndarray, index: np.ndarray, value: np.ndarray, haar_length: int
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The entries (index, value) of CSR rows (near entries first, then Haar coefficients
    largest first) with each row's coefficients below ``COARSE_KEPT`` moved right after
    its near entries; the order is otherwise kept (the counts do not change)."""
    row = np.repeat(np.arange(len(count)), count)
    group = np.where(index >= haar_length, 0, np.where(index < COARSE_KEPT, 1, 2))
    order = np.lexsort((np.arange(len(index)), group, row))
    return index[order], value[order]


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    """The tile's D and T rows, cut (in the transfer tile's row order)."""
    transfer = ctx.inputs["d2i.transfer"]
    arrays = {n: transfer.read_piece(n, ctx.chunk.id) for n in transfer.names}
    haar = int(transfer.attrs["haar_length"])
    d_budget = np.full(len(arrays["d_count"]), int(ctx.params["truncate.d_coefficients"]))
    out = cut_to_budget(ctx.params, "d", arrays, haar, d_budget)
    out.update(cut_to_budget(ctx.params, "t", arrays, haar, _proportional_t(ctx, arrays)))
    out.update(d_pixel=arrays["d_pixel"], t_pixel=arrays["t_pixel"])
    return out


def _proportional_t(ctx: ChunkContext, arrays: dict[str, np.ndarray]) -> np.ndarray:
    """Per T row: truncate.coefficients × σ_j/σ_1 of the pixel's material (row 0: all)."""
    coefficients = int(ctx.params["truncate.coefficients"])
    pixel = arrays["t_pixel"]
    if len(pixel) == 0:
        return np.zeros(0, np.int64)
    material = ctx.inputs["gbuffer"].read("material_id").reshape(-1)[pixel]
    sv = ctx.inputs["brdf_basis"].read("singular_values")
    first = np.r_[True, pixel[1:] != pixel[:-1]]
    row = np.arange(len(pixel)) - np.maximum.accumulate(np.where(first, np.arange(len(pixel)),
                                                                 0))
    ratio = np.ones(len(pixel))
    later = row > 0
    s = sv[material[later], row[later] - 1] / np.maximum(sv[material[later], 0], 1e-300)
    ratio[later] = np.maximum(s, 0.25)
    return np.maximum(np.round(coefficients * ratio), 1).astype(np.int64)


def layout(ctx: AssembleContext) -> Layout:
    return Layout(sizes=ROW_CHUNKS)


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    transfer = ctx.inputs["d2i.transfer"].attrs
    return Output({
        "width": transfer["width"], "height": transfer["height"],
        "gather_count": transfer["gather_count"], "haar_length": transfer["haar_length"],
        "budget": ctx.params["truncate.budget"],
        "tolerance": float(ctx.params["truncate.tolerance"]),
        "coefficients": int(ctx.params["truncate.coefficients"]),
        "d_coefficients": int(ctx.params["truncate.d_coefficients"])})

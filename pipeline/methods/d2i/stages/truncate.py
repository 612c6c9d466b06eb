"""Stage ``d2i.truncate``: cut the stored Haar rows of D down to the renderer's budgets
(paper 000 §3.4, §7.2), one chunk per pixel tile of the transfer stage, each reading
only its twin transfer tile. Schema ``compressed_transport``. T is cut by
``d2i.truncate_t`` (pipeline/methods/d2i/stages/truncate_glossy.py) and Ms by ``d2i.truncate_ms``
(pipeline/methods/d2i/stages/truncate_bounce.py), by the rules of this module.

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
``proportional`` (the paper's rule; the default): row 0 (b0) of T keeps
    ``truncate.coefficients``, D ``truncate.d_coefficients`` per pixel, every Ms row
    ``truncate.ms_coefficients`` (d2i.truncate_ms); T row j ≥ 1
    keeps
    ``truncate.coefficients`` × σ_j/σ_1 (the PCA singular values of the pixel's
    material), at least a quarter of it. Paper 000 used (250, 150, 150, 100, 100, 100,
    100) for its Cornell floor. At equal storage this rule erred about half as much as
    the tolerance on the Cornell box, and at 500 beat the tolerance 0.02 in error and
    storage on the Cornell box, the Tableau and the Still-life
    (decision 0019).

D is cut per block of ``truncate.d_block``² pixels rather than per row
(:func:`cut_pixel_blocks`): the block's rows are first transformed across its pixels (2D
Haar, pipeline/methods/d2i/blocks.py) into a mean row and difference rows, and the rules above
apply to all the block's entries together (budget: per pixel × the pixels that have a
row). Neighbouring pixels' rows are nearly equal, so the difference rows are small and
the shared budget buys the mean row many more coefficients than a pixel's row alone
keeps. ``truncate.shared_budget``: ``chunk`` (the default) pools the budget of all the
blocks of the tile — the tile keeps its largest entries —, ``block`` gives each block
its own. On the Cornell box at 128², 125 coefficients per pixel, D L against the
transfer stage's rows: per row 4.9 % (3.3 % dark), per block 1.4 %, pooled over the
tile 0.85 % (the mean kept to 0.02 %) (decision 0012).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from pipeline.engine.rows import ROW_CHUNKS, cut_rows, quantise_values
from pipeline.engine.stage import AssembleContext, Chunk, ChunkContext, Layout, Output
from pipeline.errors import PrtError
from pipeline.math.selection import smallest_per_row
from pipeline.methods.d2i.blocks import block_transform, pixel_blocks

BUDGETS = ("tolerance", "proportional")
COARSE_KEPT = 16  # Haar coefficients 0..15 (scaling and 4 coarsest levels) always kept


def kept_counts(count: np.ndarray, residual: np.ndarray, value: np.ndarray,
                tolerance: float, near: np.ndarray | None = None,
                always: np.ndarray | None = None) -> np.ndarray:
    """Per CSR row (largest coefficient first): the fewest leading entries whose dropped
    energy (the rest of the row plus the residual already dropped) is ≤ tolerance² of
    the row's full energy. Entries flagged ``near`` (a row's leading gather-domain
    entries, pipeline/methods/d2i/stages/transfer.py) are always kept and count for no energy;
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


def budget_rule(params: dict[str, Any]) -> str:
    """``truncate.budget``, checked."""
    if params["truncate.budget"] not in BUDGETS:
        raise PrtError(None, f"truncate.budget = {params['truncate.budget']!r}: "
                       f"expected one of {', '.join(BUDGETS)}")
    return params["truncate.budget"]


def block_size(params: dict[str, Any], name: str, chunk: str) -> int:
    """Parameter ``name``, the edge or length of a block of neighbours, checked: a power
    of two that divides parameter ``chunk`` (so that no block straddles two chunks)."""
    size, of = int(params[name]), int(params[chunk])
    if size < 1 or size & (size - 1) or of % size:
        raise PrtError(None, f"{name} = {size}: expected a power of two that divides "
                       f"{chunk} = {of}")
    return size


SHARED_BUDGETS = ("chunk", "block")


def pooled_budget(params: dict[str, Any]) -> bool:
    """Whether ``truncate.shared_budget`` pools a chunk's blocks (``chunk``) rather than
    giving each block its own budget (``block``), checked."""
    if params["truncate.shared_budget"] not in SHARED_BUDGETS:
        raise PrtError(None, f"truncate.shared_budget = {params['truncate.shared_budget']!r}"
                       f": expected one of {', '.join(SHARED_BUDGETS)}")
    return params["truncate.shared_budget"] == "chunk"


def cut_to_budget(params: dict[str, Any], prefix: str, arrays: dict[str, np.ndarray],
                  haar_length: int, proportional: np.ndarray | None = None
                  ) -> dict[str, np.ndarray]:
    """The rows ``{prefix}_count/_index/_value`` (and ``_residual``) cut by
    ``truncate.budget``: to ``truncate.tolerance``, or to ``proportional`` (else
    ``truncate.coefficients``) entries besides their near ones (index ≥ haar_length);
    values stored as float16 over a float32 scale per row (pipeline.engine.rows.quantise_values),
    each row's kept entries by ascending index (:func:`by_index`)."""
    rule = budget_rule(params)
    count = arrays[f"{prefix}_count"]
    index, value = coarse_first(count, arrays[f"{prefix}_index"], arrays[f"{prefix}_value"],
                                haar_length)
    near = index >= haar_length
    if rule == "tolerance":
        keep = kept_counts(count, arrays[f"{prefix}_residual"], value,
                           float(params["truncate.tolerance"]), near, index < COARSE_KEPT)
    else:
        near_count = np.bincount(np.repeat(np.arange(len(count)), count), weights=near,
                                 minlength=len(count)).astype(np.int64)
        keep = near_count + (proportional if proportional is not None else
                             np.full(len(count), int(params["truncate.coefficients"])))
    out = cut_rows(count, index, value, keep)
    out["index"], out["value"] = by_index(out["count"], out["index"], out["value"])
    out["scale"], out["value"] = quantise_values(out["count"], out["value"])
    return {f"{prefix}_{k}": v for k, v in out.items()}


def coarse_first(count: np.ndarray, index: np.ndarray, value: np.ndarray, haar_length: int
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The entries (index, value) of CSR rows (near entries first, then Haar coefficients
    largest first) with each row's coefficients below ``COARSE_KEPT`` moved right after
    its near entries; the order is otherwise kept (the counts do not change)."""
    row = np.repeat(np.arange(len(count), dtype=np.int64), count)
    group = np.where(index >= haar_length, 0, np.where(index < COARSE_KEPT, 1, 2))
    # a stable sort by (row, group): the rows are in order already, so NumPy's stable
    # sort runs through them (2.5x faster than np.lexsort with the position as a key)
    order = np.argsort(3 * row + group, kind="stable")
    return index[order], value[order]


def by_index(count: np.ndarray, index: np.ndarray, value: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
    """CSR rows' entries (index, value) reordered to ascending ``index`` within each row
    (the counts do not change): the stored order of every cut row. A row's indices then
    rise in small steps, which zstd packs 3.5× tighter than in the order kept (D of the
    Cornell box at 400²: 27.1 → 7.8 MB, T 44.9 → 12.8 MB;
    decision 0014), and the products read the radiance vector in order."""
    order = _row_index_order(np.repeat(np.arange(len(count)), np.asarray(count, np.int64)),
                             index)
    return index[order], value[order]


def _row_index_order(row: np.ndarray, index: np.ndarray) -> np.ndarray:
    """The order of entries (row, index) by row, then index (pairs unique): one sort of
    a combined int64 key (2.3× faster than np.lexsort of the two), stable — the keys
    are unique, so any sort gives this order, but the rows come in order and NumPy's
    stable sort exploits that (2.7× faster than its default at 360k entries)."""
    return np.argsort((row.astype(np.int64) << 32) | index.astype(np.int64), kind="stable")


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    """The tile's D rows over pixel blocks, cut."""
    transfer = ctx.inputs["d2i.transfer"]
    arrays = {n: transfer.read_piece(n, ctx.chunk.id) for n in transfer.names
              if n.startswith("d_")}
    haar_length = int(transfer.attrs["haar_length"])
    block = block_size(ctx.params, "truncate.d_block", "transfer.tile")
    return cut_pixel_blocks(ctx.params, arrays, haar_length,
                            haar_length + int(transfer.attrs["gather_count"]),
                            int(ctx.scene["camera"]["width"]), block)


def cut_pixel_blocks(params: dict[str, Any], arrays: dict[str, np.ndarray], haar_length: int,
                     columns: int, width: int, block: int) -> dict[str, np.ndarray]:
    """D's rows ``d_pixel/_count/_index/_value/_residual`` (one per pixel) transformed
    over ``block`` × ``block`` pixel blocks (pipeline/methods/d2i/blocks.py block_transform) and
    cut by :func:`cut_blocks` to ``truncate.d_coefficients`` per pixel, the budget shared
    as ``truncate.shared_budget`` says. Returns rows ``d_row`` (block id · b² + row),
    ``d_count``, ``d_index``, ``d_value`` (float16) and ``d_scale``."""
    ids, slot = pixel_blocks(arrays["d_pixel"], width, block)
    cut = cut_blocks(params, {k: arrays[f"d_{k}"] for k in ("count", "index", "value",
                                                             "residual")},
                     ids, slot, block_transform(block), haar_length, columns,
                     int(params["truncate.d_coefficients"]), pooled_budget(params))
    return {f"d_{k}": v for k, v in cut.items()}


def cut_blocks(params: dict[str, Any], rows: dict[str, np.ndarray], block_of: np.ndarray,
               slot: np.ndarray, transform: np.ndarray, haar_length: int, columns: int,
               budget: int, pooled: bool = False) -> dict[str, np.ndarray]:
    """CSR ``rows`` (``count``, ``index``, ``value``, ``residual``; ``columns``: the
    radiance vector's length) grouped into blocks — row r is slot ``slot[r]`` of block
    ``block_of[r]`` —, each block's rows replaced by ``transform`` (n × n, orthonormal:
    pipeline/methods/d2i/blocks.py) applied across them, and cut per block by the rules of
    :func:`cut_to_budget` applied to all the block's entries at once: its near entries
    (index ≥ haar_length), then its row 0's ``COARSE_KEPT`` coarsest coefficients (row 0
    is the block's mean), then the rest largest first, to the tolerance (of the block's
    energy) or to ``budget`` per row of the block that has entries; with ``pooled``, the
    same over all the blocks at once (the largest entries of all of them, to the budget
    of all their rows: a block that straddles an edge takes what smooth blocks do not
    need). Returns ``row``
    (block · n + transformed row: every row of the blocks present, ascending),
    ``count``, ``index`` (ascending within a row), ``value`` (float16 over ``scale``, per
    row) and ``scale``. A
    block of one row cuts exactly as :func:`cut_to_budget` cuts it."""
    count = rows["count"].astype(np.int64)
    n = len(transform)
    blocks, local = np.unique(block_of, return_inverse=True)
    offsets = np.concatenate([[0], np.cumsum(count)])
    matrix = sp.csr_matrix((rows["value"].astype(np.float64), rows["index"], offsets),
                           shape=(len(count), columns))
    weight = transform[:, slot]  # (n, rows)
    q, i = np.nonzero(weight)
    across = sp.csr_matrix((weight[q, i], (local[i] * n + q, i)),
                           shape=(len(blocks) * n, len(count)))
    product = (across @ matrix).tocoo()
    nonzero = product.data != 0
    row, index = product.row[nonzero].astype(np.int64), product.col[nonzero].astype(np.int64)
    value = product.data[nonzero]
    owner = np.zeros_like(row) if pooled else row // n
    group = np.where(index >= haar_length, 0,
                     np.where((index < COARSE_KEPT) & (row % n == 0), 1, 2))
    # an owner's entries in the order they are kept: by group, then largest first
    # (magnitudes as float32 bit patterns, which order as the magnitudes do), then as
    # they come
    magnitude = np.abs(value).astype(np.float32).view(np.int32).astype(np.int64)
    rank = (group << 31) | (0x7FFFFFFF - magnitude)
    owners = 1 if pooled else len(blocks)
    owner_of_row = np.zeros_like(local) if pooled else local
    per_owner = np.bincount(owner, minlength=owners)
    order = None  # the entries by owner, then rank: not needed for one owner's budget
    if budget_rule(params) == "tolerance":
        order = np.argsort((owner << 34) | rank, kind="stable")
        keep = kept_counts(per_owner, _block_residual(rows, owner_of_row, owners),
                           value[order], float(params["truncate.tolerance"]),
                           group[order] == 0, group[order] == 1)
    else:
        rows_with_entries = np.bincount(owner_of_row, weights=count > 0, minlength=owners)
        near_count = np.bincount(owner, weights=group == 0, minlength=owners)
        keep = (near_count + budget * rows_with_entries).astype(np.int64)
        if not pooled:
            order = np.argsort((owner << 34) | rank, kind="stable")
    kept = (smallest_per_row(rank[None], int(keep[0]))[0] if order is None  # no sort
            else order[_leading(per_owner, keep)])
    kept = kept[_row_index_order(row[kept], index[kept])]  # as by_index stores rows
    row, index, value = row[kept], index[kept], value[kept]
    counts = np.bincount(row, minlength=len(blocks) * n).astype(np.int32)
    scale, half = quantise_values(counts, value)
    all_rows = np.arange(len(blocks) * n)
    return {"row": (blocks[all_rows // n] * n + all_rows % n).astype(np.int32),
            "count": counts, "index": index.astype(np.int32), "value": half, "scale": scale}


def _leading(per_owner: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Positions, in a list of entries grouped by owner (``per_owner`` entries each, in
    order), of each owner's first ``keep`` entries."""
    start = np.concatenate([[0], np.cumsum(per_owner)[:-1]])
    place = np.arange(int(per_owner.sum())) - np.repeat(start, per_owner)
    return np.flatnonzero(place < np.repeat(keep, per_owner))


def _block_residual(rows: dict[str, np.ndarray], local: np.ndarray, blocks: int
                    ) -> np.ndarray:
    """Per block, the energy the transfer stage dropped from its rows over their full
    energy, rooted (as each row's ``residual``; the transform across a block keeps
    energy)."""
    count = rows["count"].astype(np.int64)
    row = np.repeat(np.arange(len(count)), count)
    kept = np.bincount(row, weights=np.square(rows["value"].astype(np.float64)),
                       minlength=len(count))
    residual2 = np.square(rows["residual"].astype(np.float64))
    full = kept / np.maximum(1.0 - residual2, 1e-12)
    dropped = np.bincount(local, weights=full * residual2, minlength=blocks)
    total = np.bincount(local, weights=full, minlength=blocks)
    return np.sqrt(dropped / np.maximum(total, 1e-300)).astype(np.float32)


def layout(ctx: AssembleContext) -> Layout:
    return Layout(sizes=ROW_CHUNKS)


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    return Output({**cut_attrs(ctx, "d2i.transfer"),
                   "d_coefficients": int(ctx.params["truncate.d_coefficients"]),
                   "d_block": int(ctx.params["truncate.d_block"])})


def cut_attrs(ctx: AssembleContext, source: str) -> dict[str, Any]:
    """The attributes every cut artifact carries: the image, gather count and Haar
    length of the rows it cut (input ``source``) and the budget rule."""
    rows = ctx.inputs[source].attrs
    return {"width": rows["width"], "height": rows["height"],
            "gather_count": rows["gather_count"], "haar_length": rows["haar_length"],
            "budget": ctx.params["truncate.budget"],
            "tolerance": float(ctx.params["truncate.tolerance"])}

"""Transport rows across blocks of neighbours (pipeline/methods/d2i/blocks.py) and their cut
(pipeline/methods/d2i/stages/truncate.py cut_pixel_blocks): the block transform, its
inverse, and the
budgets and tolerances of the cut."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from pipeline.math import haar
from pipeline.methods.d2i import blocks


def _dense(rows, columns):
    """CSR rows (count, index, value) as a dense float64 matrix."""
    offsets = np.concatenate([[0], np.cumsum(rows["count"])]).astype(np.int64)
    return sp.csr_matrix((np.asarray(rows["value"], np.float64), rows["index"], offsets),
                         shape=(len(rows["count"]), columns)).toarray()


def _pixel_rows(rng, width, height, length, near_from):
    """Smooth random D-like rows of a width × height image in pixel order: each pixel's
    row is a shared far field plus a small per-pixel change, as CSR (largest first, near
    entries first) the way the transfer stage stores them; a few pixels see nothing."""
    base = np.abs(rng.normal(size=length))
    pixel, count, index, value, residual = [], [], [], [], []
    for p in range(width * height):
        if p % 11 == 5:  # sees no surface
            pixel.append(p), count.append(0), residual.append(0.0)
            continue
        row = base * (1 + 0.1 * rng.normal(size=length))
        far = haar.truncate(haar.forward(row[None, :near_from]), 0.0, 512)
        near = np.flatnonzero(rng.random(4) < 0.5) + near_from
        pixel.append(p), count.append(len(near) + int(far["count"][0]))
        index.append(np.r_[near + (haar.padded_length(near_from) - near_from), far["index"]])
        value.append(np.r_[rng.uniform(5, 10, len(near)), far["value"]])
        residual.append(float(far["residual"][0]))
    return {"d_pixel": np.array(pixel, np.int32), "d_count": np.array(count, np.int32),
            "d_index": np.concatenate(index).astype(np.int32),
            "d_value": np.concatenate(value).astype(np.float32),
            "d_residual": np.array(residual, np.float32)}


def _stored(cut, columns):
    """Dense rows of a cut (d_count, d_index, float16 d_value over d_scale)."""
    from pipeline.engine.rows import expand_values

    value = expand_values(cut["d_count"], cut["d_value"], cut["d_scale"])
    return _dense({"count": cut["d_count"], "index": cut["d_index"], "value": value}, columns)


def _unblock_pixels(products, width, height, block=4):
    """Each pixel's product from the products of its block's rows."""
    ids, slot = blocks.pixel_blocks(np.arange(width * height), width, block)
    return blocks.unblock(products, ids, slot, blocks.block_transform(block))


def _exact(rows, columns):
    return _dense({k: rows[f"d_{k}"] for k in ("count", "index", "value")}, columns)


@pytest.mark.parametrize("block", [1, 2, 4, 8])
def test_block_transform_is_orthonormal_and_unblock_inverts_it(block):
    """B (b² × b²) is orthonormal (exact to float64 rounding), row 0 the block's mean × b;
    unblock(B-transformed products) gives back each pixel's own product, on an image
    whose edges cut blocks (10 × 6 pixels)."""
    b = blocks.block_transform(block)
    np.testing.assert_allclose(b @ b.T, np.eye(block * block), atol=1e-14)
    np.testing.assert_allclose(b[0], 1.0 / block)
    width, height = 10, 6
    products = np.random.default_rng(block).normal(size=(width * height, 3))
    ids, slot = blocks.pixel_blocks(np.arange(width * height), width, block)
    count = -(-width // block) * -(-height // block)
    grouped = np.zeros((count, block * block, 3))
    grouped[ids, slot] = products
    transformed = np.einsum("qs,bsc->bqc", b, grouped).reshape(-1, 3)
    np.testing.assert_allclose(blocks.unblock(transformed, ids, slot, b), products, atol=1e-13)


def test_cut_pixel_blocks_of_one_pixel_cut_as_rows_do_and_wide_budgets_keep_everything():
    """pipeline/methods/d2i/stages/truncate.py cut_pixel_blocks: with blocks of one pixel
    it keeps exactly
    what cut_to_budget keeps per row (same counts, same entries); with blocks of 4 × 4
    and a budget above every block's entry count, the stored block rows unblock to the
    pixels' rows within float16 rounding (2^-11 of the largest value)."""
    from pipeline.methods.d2i.stages.truncate import cut_pixel_blocks, cut_to_budget

    width, height, length = 12, 8, 64
    rows = _pixel_rows(np.random.default_rng(7), width, height, length, 60)
    columns = length + 60
    params = {"truncate.budget": "proportional", "truncate.d_coefficients": 20,
              "truncate.tolerance": 0.0, "truncate.shared_budget": "block"}
    single = cut_pixel_blocks(params, rows, length, columns, width, 1)
    per_row = cut_to_budget(params, "d", rows, length,
                            np.full(len(rows["d_count"]), 20))
    np.testing.assert_array_equal(single["d_row"], rows["d_pixel"])
    np.testing.assert_array_equal(single["d_count"], per_row["d_count"])
    np.testing.assert_array_equal(_stored(single, columns), _stored(per_row, columns))

    params["truncate.d_coefficients"] = 10 ** 6
    wide = cut_pixel_blocks(params, rows, length, columns, width, 4)
    exact = _exact(rows, columns)
    back = _unblock_pixels(_stored(wide, columns), width, height)
    np.testing.assert_allclose(back, exact, rtol=0, atol=2.0 ** -11 * np.abs(exact).max())


@pytest.mark.parametrize("shared", ["block", "chunk"])
def test_cut_pixel_blocks_keeps_near_entries_and_the_budget(shared):
    """Blocks of 4 × 4: every near entry of the block's pixels is kept (its transform
    spreads it over the block's rows; all of them stay); the far coefficients kept are
    min(available, budget × pixels with a row) per block (``block``) or over all the
    blocks (``chunk``: then not per block); the tolerance rule keeps the dropped energy
    within tolerance² of the energy, per block or over the blocks."""
    from pipeline.methods.d2i.stages.truncate import cut_pixel_blocks

    width, height, length = 8, 8, 64
    rows = _pixel_rows(np.random.default_rng(3), width, height, length, 60)
    columns = length + 60
    ids, _ = blocks.pixel_blocks(rows["d_pixel"], width, 4)
    with_rows = np.bincount(ids, weights=rows["d_count"] > 0)
    params = {"truncate.budget": "proportional", "truncate.d_coefficients": 6,
              "truncate.tolerance": 0.0, "truncate.shared_budget": shared}
    cut = cut_pixel_blocks(params, rows, length, columns, width, 4)
    row_block = np.repeat(cut["d_row"] // 16, cut["d_count"])
    far = np.bincount(row_block, weights=cut["d_index"] < length, minlength=4)
    if shared == "block":
        np.testing.assert_array_equal(far, 6 * with_rows)
    else:
        assert far.sum() == 6 * with_rows.sum() and not np.array_equal(far, 6 * with_rows)
    exact = _exact(rows, columns)
    near_columns = set(np.flatnonzero(np.abs(exact[:, length:]).sum(0)) + length)
    assert near_columns == set(cut["d_index"][cut["d_index"] >= length].tolist())

    params.update({"truncate.budget": "tolerance", "truncate.tolerance": 0.1})
    cut = cut_pixel_blocks(params, rows, length, columns, width, 4)
    back = _unblock_pixels(_stored(cut, columns), width, height)
    groups = [ids == block for block in range(4)] if shared == "block" else [ids >= 0]
    for mine in groups:
        dropped = np.sum((back[mine] - exact[mine])[:, :length] ** 2)
        # 0.1² of the far energy, plus float16 rounding of what is kept
        assert dropped <= (0.1 ** 2 + 1e-5) * np.sum(exact[mine][:, :length] ** 2)


def test_block_sizes_must_be_powers_of_two_within_a_chunk():
    """truncate.d_block and truncate.ms_block: a power of two dividing the chunk's edge or
    length (no block may straddle two chunks), else a one-line refusal naming both."""
    from pipeline.errors import PrtError
    from pipeline.methods.d2i.stages.truncate import block_size

    params = {"truncate.d_block": 4, "transfer.tile": 32}
    assert block_size(params, "truncate.d_block", "transfer.tile") == 4
    for bad in (3, 64, 0):
        params["truncate.d_block"] = bad
        with pytest.raises(PrtError, match=r"truncate.d_block = .*transfer.tile = 32"):
            block_size(params, "truncate.d_block", "transfer.tile")


def test_cut_rows_are_stored_by_ascending_index():
    """Every cut row (per row: cut_to_budget; per block: cut_pixel_blocks, both budget
    rules) stores its entries by strictly ascending index — the order zstd packs best
    (truncate.by_index) — and keeps the same entries as the order they were chosen in."""
    from pipeline.methods.d2i.stages.truncate import cut_pixel_blocks, cut_to_budget

    width, height, length = 8, 8, 64
    rows = _pixel_rows(np.random.default_rng(11), width, height, length, 60)
    columns = length + 60
    for rule in ("proportional", "tolerance"):
        params = {"truncate.budget": rule, "truncate.d_coefficients": 6,
                  "truncate.coefficients": 6, "truncate.tolerance": 0.1,
                  "truncate.shared_budget": "chunk"}
        for cut in (cut_pixel_blocks(params, rows, length, columns, width, 4),
                    cut_to_budget(params, "d", rows, length)):
            row = np.repeat(np.arange(len(cut["d_count"])), cut["d_count"])
            same_row = row[1:] == row[:-1]
            assert np.all(np.diff(cut["d_index"])[same_row] > 0)
            assert same_row.any()

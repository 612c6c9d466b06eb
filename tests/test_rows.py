"""pipeline.engine.rows: the CSR row helpers the d2i stages and renderer share."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.engine import rows as rows_module
from pipeline.engine.rows import sort_rows


@pytest.mark.parametrize("piece", [3, 1 << 22])
def test_sort_rows_moves_whole_rows_in_key_order(monkeypatch, piece):
    """Rows reordered by their key (stable: equal keys keep their order) carry their
    entries and per-row fields with them — also when the entries move in pieces smaller
    than one row (``SORT_PIECE`` 3 against rows of up to 6 entries) — and no rows."""
    monkeypatch.setattr(rows_module, "SORT_PIECE", piece)
    rng = np.random.default_rng(7)
    count = rng.integers(0, 7, size=40).astype(np.int32)
    key = rng.integers(0, 5, size=40)
    start = np.concatenate([[0], np.cumsum(count)])
    index = rng.integers(0, 1000, size=start[-1]).astype(np.int32)
    value = rng.normal(size=start[-1]).astype(np.float16)
    scale = rng.uniform(size=40).astype(np.float32)
    out = sort_rows(key, {"count": count, "index": index, "value": value, "scale": scale})
    order = sorted(range(40), key=lambda r: key[r])  # Python's sort is stable
    np.testing.assert_array_equal(out["count"], count[order])
    np.testing.assert_array_equal(out["scale"], scale[order])
    np.testing.assert_array_equal(out["index"], np.concatenate(
        [index[start[r]:start[r + 1]] for r in order]))
    np.testing.assert_array_equal(out["value"], np.concatenate(
        [value[start[r]:start[r + 1]] for r in order]))
    empty = sort_rows(np.zeros(0), {"count": np.zeros(0, np.int32),
                                    "index": np.zeros(0, np.int32),
                                    "value": np.zeros(0, np.float32)})
    assert len(empty["count"]) == 0 and len(empty["index"]) == 0


def test_merge_rows_puts_first_entries_before_seconds_in_each_row():
    """pipeline.methods.d2i.stages.transfer.merge_rows against the definition: row by row, the
    first CSR's entries then the second's, with empty rows on either side."""
    from pipeline.methods.d2i.stages.transfer import merge_rows

    rng = np.random.default_rng(3)
    first_count, second_count = rng.integers(0, 4, 30), rng.integers(0, 6, 30)
    first = {"count": first_count, "index": rng.integers(0, 99, first_count.sum()),
             "value": rng.standard_normal(first_count.sum())}
    second = {"count": second_count, "index": rng.integers(0, 99, second_count.sum()),
              "value": rng.standard_normal(second_count.sum()), "residual": rng.random(30)}
    merged = merge_rows(first, second)
    ends = [np.cumsum(np.concatenate([[0], part["count"]])) for part in (first, second)]
    for name in ("index", "value"):
        expected = np.concatenate([
            np.concatenate([part[name][end[r]:end[r + 1]] for part, end in
                            zip((first, second), ends, strict=True)]) for r in range(30)])
        np.testing.assert_array_equal(merged[name], expected.astype(merged[name].dtype))
    np.testing.assert_array_equal(merged["count"], first_count + second_count)
    assert merged["residual"] is second["residual"]

"""pipeline.rows: the CSR row helpers the d2i stages and renderer share."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline import rows as rows_module
from pipeline.rows import sort_rows


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

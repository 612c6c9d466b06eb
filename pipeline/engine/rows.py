"""Transport rows in CSR form: the packed row format shared by the d2i stages that write
rows (transfer, bounce), the stage that cuts them (truncate) and the renderer.

A set of rows is stored as per-row arrays (``count``: entries in the row, ``residual``:
the norm the row's compression dropped over the row's norm) and flat entry arrays
(``index``, ``value``): row r's entries are the next ``count[r]`` entries. Within a row,
entries come in the order the writer chose (near entries first, then Haar coefficients
largest first: pipeline/methods/d2i/stages/transfer.py). On the device the same rows are
``offsets`` (rows + 1), ``index`` and ``value`` (:class:`Rows`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

# zarr chunk lengths of stored rows' arrays: entries (index, value), rows (count, ...)
ROW_CHUNKS = {"coefficient_chunk": 1 << 20, "row_chunk": 1 << 16}
SORT_PIECE = 1 << 22  # entries moved at a time by sort_rows
ROW_FIELDS = {"count": np.int32, "residual": np.float32, "index": np.int32,
               "value": np.float32}


def join_arrays(parts: list[np.ndarray], dtype: Any) -> np.ndarray:
    return np.concatenate(parts).astype(dtype) if parts else np.zeros(0, dtype)


def place_in_runs(key: np.ndarray) -> np.ndarray:
    """Each entry's place (0, 1, ...) in its run of equal consecutive ``key`` values: a
    T row's basis index b_j from the pixel of each row (a pixel's rows consecutive)."""
    if len(key) == 0:
        return np.zeros(0, np.int64)
    first = np.r_[True, key[1:] != key[:-1]]
    index = np.arange(len(key))
    return index - np.maximum.accumulate(np.where(first, index, 0))


def sort_rows(key: np.ndarray, rows: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """CSR rows (``count`` and, if present, ``residual`` and ``scale`` per row; flat
    ``index``, ``value``) reordered by ``key`` (one per row; stable, so rows with equal keys keep
    their order). The entries move in pieces of about ``SORT_PIECE`` (the gather's
    positions of all entries at once would take 8 bytes per entry)."""
    order = np.argsort(key, kind="stable")
    count = rows["count"].astype(np.int64)
    start = np.concatenate([[0], np.cumsum(count)[:-1]])[order]
    new_count = count[order]
    new_end = np.cumsum(new_count)
    out = {"count": rows["count"][order], "index": np.empty_like(rows["index"]),
           "value": np.empty_like(rows["value"])}
    cuts = np.searchsorted(new_end, np.arange(SORT_PIECE, int(new_end[-1]) if len(new_end)
                                              else 0, SORT_PIECE), side="right")
    for first, last in zip(np.r_[0, cuts], np.r_[cuts, len(order)], strict=True):
        e0 = int(new_end[first - 1]) if first else 0
        e1 = int(new_end[last - 1]) if last else 0
        entry = np.repeat(start[first:last] - (new_end[first:last] - new_count[first:last]),
                          new_count[first:last]) + np.arange(e0, e1)
        out["index"][e0:e1] = rows["index"][entry]
        out["value"][e0:e1] = rows["value"][entry]
    for per_row in ("residual", "scale"):
        if per_row in rows:
            out[per_row] = rows[per_row][order]
    return out


def cut_rows(count: np.ndarray, index: np.ndarray, value: np.ndarray, keep: np.ndarray
             ) -> dict[str, np.ndarray]:
    """CSR rows cut to their first ``keep`` entries (≤ count)."""
    count = count.astype(np.int64)
    keep = np.minimum(keep.astype(np.int64), count)
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    row_of = np.repeat(np.arange(len(count)), count)
    position = np.arange(len(index)) - start[row_of]
    mask = position < keep[row_of]
    return {"count": keep.astype(np.int32), "index": index[mask].astype(np.int32),
            "value": value[mask].astype(np.float32)}


def quantise_values(count: np.ndarray, value: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CSR values as the cut stages store them: per row a float32 ``scale`` (the RMS of
    its entries; 1 for a row without entries or only zeros) and the values over it as
    float16. No entry can overflow (|v| / RMS ≤ √count ≤ 2^9 for rows of up to 2^18
    entries); rounding is ≤ 2^-11 relative down to 2^-14 × the RMS, then absolute
    (float16 subnormals, steps of 2^-24 × the RMS). The RMS rather than the largest
    entry: a row's near entries can be 10^3 × its far coefficients."""
    count = count.astype(np.int64)
    row = np.repeat(np.arange(len(count)), count)
    energy = np.bincount(row, weights=np.square(value.astype(np.float64)), minlength=len(count))
    scale = np.sqrt(energy / np.maximum(count, 1))
    scale[scale == 0] = 1.0
    scale = scale.astype(np.float32)
    return scale, (value / scale[row]).astype(np.float16)


def expand_values(count: np.ndarray, value: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """float32 values of rows stored by :func:`quantise_values` (each value times its
    row's scale, the scales repeated per entry: 4 bytes of temporary per entry)."""
    out = value.astype(np.float32)
    out *= np.repeat(scale.astype(np.float32, copy=False), count.astype(np.int64))
    return out


@dataclass
class Rows:
    """CSR rows on the host: ``offsets`` (rows + 1,) int32, ``index`` uint16 where the
    radiance vector has at most 2^16 entries (a quarter fewer bytes for the products to
    stream), else int32, ``value`` float32 — or, with a per-row ``scale`` (rows,)
    float32, ``value`` float16 as :func:`quantise_values` stores them (the entry is
    value × scale): the products stream 4 bytes per entry instead of 6 and apply the
    scale once per row (kernels/d2i/sparse_rows.cl, VALUE_HALF)."""

    offsets: np.ndarray
    index: np.ndarray
    value: np.ndarray
    scale: np.ndarray | None = None

    @classmethod
    def from_counts(cls, count: np.ndarray, index: np.ndarray, value: np.ndarray,
                    size: int, scale: np.ndarray | None = None) -> Rows:
        """Rows over a radiance vector of ``size`` entries (float16 ``value`` over a
        per-row ``scale`` when one is given)."""
        offsets = np.concatenate([[0], np.cumsum(count, dtype=np.int64)]).astype(np.int32)
        if scale is None:
            return cls(offsets, np.ascontiguousarray(index, index_dtype(size)),
                       np.ascontiguousarray(value, np.float32))
        return cls(offsets, np.ascontiguousarray(index, index_dtype(size)),
                   np.ascontiguousarray(value, np.float16),
                   np.ascontiguousarray(scale, np.float32))

    @property
    def count(self) -> int:
        return len(self.offsets) - 1

    @property
    def nbytes(self) -> int:
        extra = 0 if self.scale is None else self.scale.nbytes
        return self.offsets.nbytes + self.index.nbytes + self.value.nbytes + extra

    def expanded(self) -> Rows:
        """The same rows with float32 values (no scale)."""
        return self if self.scale is None else Rows(self.offsets, self.index, self.values())

    def values(self) -> np.ndarray:
        """The entries' values as float32 (scaled back where stored as float16)."""
        if self.scale is None:
            return self.value
        return expand_values(np.diff(self.offsets), self.value, self.scale)


def index_dtype(size: int) -> type:
    """The narrowest index type of rows over a radiance vector of ``size`` entries."""
    return np.uint16 if size <= 1 << 16 else np.int32

"""OpenCL launchers of the stored-row selection (kernels/triple/wavelet_select.cl), the device
twin of :func:`pipeline.methods.triple.wavelet_rows.select_rows`, for the stages that select many
rows at once (method triple's lighting and BRDF tables): the coefficients stay on the
device, and only the stored rows come back.

The rule is select_rows' (its docstring); the kernel finds each row's energy threshold
by a radix select on the float bit patterns (four 256-bin histogram passes) with float32
per-bin sums instead of a sorted float32 prefix sum, so a coefficient within float32
rounding of the tolerance may be kept by one and dropped by the other
(tests/test_wavelet_select.py)."""

from __future__ import annotations

from typing import Any

import numpy as np

from pipeline.device import cl
from pipeline.methods.triple.wavelet_rows import depth_first_order


def select_rows_buffer(coefficients: Any, first_row: int, rows: int, channels: int,
                       leaf_level: int, budget: int, tolerance: float, keep_first: int,
                       channel_weights: np.ndarray | None = None,
                       half: bool = False) -> dict[str, np.ndarray]:
    """Stored rows (``count``, ``residual``, ``index``, ``value`` as select_rows) of rows
    ``first_row`` .. ``first_row + rows − 1`` of the device buffer ``coefficients``
    (rows, ``channels``, N) float32. With ``half``, ``value`` and ``scale`` as
    :func:`pipeline.methods.triple.wavelet_rows.to_half` makes them (float16 over a float32 scale
    per row), converted on the device."""
    import pyopencl as cl_

    size = 20 * 4 ** leaf_level
    weights = np.ones(channels) if channel_weights is None else channel_weights
    defines = {"CHANNELS": channels}
    write_defines = {**defines, "HALF": 1} if half else defines
    ctx, queue = cl.context(), cl.queue()
    flags = cl_.mem_flags.READ_WRITE
    energy = cl_.Buffer(ctx, flags, max(rows * size, 1) * 4)
    candidates = cl_.Buffer(ctx, flags, max(rows * size, 1) * 4)  # its scratch
    threshold = cl_.Buffer(ctx, flags, max(rows, 1) * 4)
    ties = cl_.Buffer(ctx, flags, max(rows, 1) * 4)
    count_buf = cl_.Buffer(ctx, flags, max(rows, 1) * 4)
    residual_buf = cl_.Buffer(ctx, flags, max(rows, 1) * 4)
    count = np.zeros(rows, np.int32)
    residual = np.zeros(rows, np.float32)
    if rows:
        cl.kernel("wavelet_select.cl", "select_threshold", defines)(
            queue, (rows,), None, coefficients,
            cl.read_only_buffer(np.asarray(weights, np.float32)), np.int32(first_row),
            np.int32(rows), np.int32(size), np.int32(min(keep_first, size)), np.int32(budget),
            np.float32(tolerance ** 2), energy, candidates, threshold, ties, count_buf,
            residual_buf)
        cl_.enqueue_copy(queue, count, count_buf)
        cl_.enqueue_copy(queue, residual, residual_buf)
    most = max(budget, min(keep_first, size))  # the head's entries, then the budget
    if rows and not 0 <= count.min() <= count.max() <= most:
        raise RuntimeError(f"select_threshold counted {count.min()}..{count.max()} entries "
                           f"in a row of {size} with a budget of {most}: refusing to write")
    offset = np.concatenate([[0], np.cumsum(count, dtype=np.int64)])
    entries = int(offset[-1])
    index = np.empty(entries, np.uint16)
    value = np.empty((entries, channels), np.float16 if half else np.float32)
    scale = np.ones(rows, np.float32)
    if entries:
        index_buf = cl_.Buffer(ctx, flags, entries * 2)
        value_buf = cl_.Buffer(ctx, flags, value.nbytes)
        outputs = [index_buf, value_buf]
        if half:
            outputs.append(cl_.Buffer(ctx, flags, rows * 4))
        cl.kernel("wavelet_select.cl", "select_write", write_defines)(
            queue, (rows,), None, coefficients, np.int32(first_row),
            np.int32(rows), np.int32(size), np.int32(min(keep_first, size)), energy,
            threshold, ties,
            cl.read_only_buffer(offset[:-1].astype(np.uint32)),
            cl.read_only_buffer(depth_first_order(leaf_level).astype(np.int32)), *outputs)
        cl_.enqueue_copy(queue, index, index_buf)
        cl_.enqueue_copy(queue, value, value_buf)
        if half:
            cl_.enqueue_copy(queue, scale, outputs[2])
    rows_out = {"count": count, "residual": residual, "index": index, "value": value}
    return {**rows_out, "scale": scale} if half else rows_out


def select_rows(coefficients: np.ndarray, leaf_level: int, budget: int, tolerance: float,
                keep_first: int, channel_weights: np.ndarray | None = None
                ) -> dict[str, np.ndarray]:
    """:func:`pipeline.methods.triple.wavelet_rows.select_rows` of host ``coefficients`` (R, C, N)
    on the device."""
    c = np.ascontiguousarray(coefficients, np.float32)
    return select_rows_buffer(cl.read_only_buffer(c), 0, c.shape[0], c.shape[1], leaf_level,
                              budget, tolerance, keep_first, channel_weights)

"""OpenCL launchers of the spherical wavelet transform (kernels/wavelet_forward.cl), the
device twin of :meth:`pipeline.math.sphwavelet.WaveletBasis.forward`, for the stages
that transform many functions at once (method triple's lighting and BRDF tables)."""

from __future__ import annotations

from functools import cache
from typing import Any

import numpy as np

from pipeline.device import cl
from pipeline.math.sphwavelet import coefficient_count, level_start, wavelet_basis


@cache
def _tables(leaf_level: int) -> tuple[tuple[Any, Any], ...]:
    """Per level: device copies of the child solid angles (T, 4) and wavelets (T, 3, 4)."""
    basis = wavelet_basis(leaf_level)
    return tuple((cl.read_only_buffer(basis.child_areas[lv].astype(np.float32)),
                  cl.read_only_buffer(basis.wavelets[lv].astype(np.float32)))
                 for lv in range(leaf_level))


@cache
def _root_areas(leaf_level: int) -> Any:
    return cl.read_only_buffer(wavelet_basis(leaf_level).root_areas.astype(np.float32))


def forward_device(leaf_values: Any, rows: int, leaf_level: int) -> Any:
    """A device buffer of the coefficients (rows, N) float32 of the ``rows`` functions
    whose leaf values (rows, N) float32 are in the device buffer ``leaf_values`` (the
    buffer is reused)."""
    import pyopencl as cl_

    size = coefficient_count(leaf_level)
    flags = cl_.mem_flags.READ_WRITE
    coeffs = cl_.Buffer(cl.context(), flags, rows * size * 4)
    scratch = [cl_.Buffer(cl.context(), flags, max(rows * size // 4, 1) * 4) for _ in range(2)]
    level_kernel = cl.kernel("wavelet_forward.cl", "wavelet_forward_level")
    cl.check_writes("wavelet_forward", coeffs, rows * size * 4)  # every coefficient
    fine = leaf_values
    for level in reversed(range(leaf_level)):
        triangles = 20 * 4 ** level
        areas, wavelets = _tables(leaf_level)[level]
        coarse = scratch[level % 2]
        cl.check_writes("wavelet_forward_level", coarse, rows * triangles * 4)  # its means
        level_kernel(cl.queue(), (triangles, rows), None, fine, areas, wavelets,
                     np.int32(triangles), np.int32(level_start(level)), np.int32(size),
                     coarse, coeffs)
        fine = coarse
    cl.kernel("wavelet_forward.cl", "wavelet_forward_roots")(
        cl.queue(), (20, rows), None, fine, _root_areas(leaf_level), np.int32(size), coeffs)
    return coeffs


def forward_buffer(leaf_values: Any, rows: int, leaf_level: int) -> np.ndarray:
    """The coefficients of :func:`forward_device` on the host."""
    import pyopencl as cl_

    out = np.empty((rows, coefficient_count(leaf_level)), np.float32)
    cl_.enqueue_copy(cl.queue(), out, forward_device(leaf_values, rows, leaf_level))
    return out


def forward(leaf_values: np.ndarray | Any, leaf_level: int) -> np.ndarray:
    """Coefficients (..., N) float32 of leaf values (..., N) on the device."""
    values = np.ascontiguousarray(leaf_values, np.float32)
    out = forward_buffer(cl.read_only_buffer(values), int(np.prod(values.shape[:-1])),
                         leaf_level)
    return out.reshape(values.shape)

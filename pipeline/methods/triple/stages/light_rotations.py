"""Stage ``triple.light_rotations``: the scene's environment map resampled in every local
frame of the frame grid, as stored wavelet rows (method triple, paper 004 §3.2).
Schema ``triple_lighting``; one chunk per block of ``triple.light_block`` grid entries.

Per grid entry (row = FrameGrid entry index, pipeline/methods/triple/frame_grids.py) the leaf
means of L_local(ω) = L(R ω) over the level-L leaves (``triple.leaf_level``), from
4^r samples per leaf (``triple.light_refine``) of the map prefiltered to their spacing
(pipeline/methods/triple/light_grid.py), computed in OpenCL (kernels/triple/light_rotations.cl),
transformed there too (kernels/wavelet_forward.cl, pipeline/device/sphwavelet_cl.py) and
truncated there with one index set for the three channels (luminance-weighted energy,
pipeline/methods/triple/wavelet_rows.py, kernels/triple/wavelet_select.cl), values stored as float16
with a float32 scale per row (wavelet_rows.to_half, on the device). The map's
rotation and scale are applied by the renderer: the key holds the map file's bytes
(scene section ``environment.file``) and the params only.
"""

from __future__ import annotations

import hashlib
from functools import lru_cache
from typing import Any

import numpy as np

from pipeline.device import cl
from pipeline.device.sphwavelet_cl import forward_device
from pipeline.engine.rows import ROW_CHUNKS
from pipeline.engine.stage import (
    AssembleContext,
    Chunk,
    ChunkContext,
    Layout,
    Output,
    ToleranceResult,
)
from pipeline.errors import PrtError
from pipeline.math.envmap import LUMINANCE
from pipeline.methods.triple.frame_grids import FrameGrid, euler_frame
from pipeline.methods.triple.light_grid import prefilter, prefiltered_width, sample_spacing
from pipeline.methods.triple.wavelet_rows import leaf_permutation, leaf_samples
from pipeline.methods.triple.wavelet_select_cl import select_rows_buffer


def frame_grid(params: dict[str, Any]) -> FrameGrid:
    """The grid of ``triple.frame_grid`` ([n_phi, n_theta, n_psi])."""
    return FrameGrid(*(int(n) for n in params["triple.frame_grid"]))


def _phi_major(rgb: np.ndarray, n_phi: int) -> np.ndarray:
    """(H, W, 3) as the kernel's float4 texels (RGB and an unused fourth), phi-major:
    (H, W / n_phi, n_phi, 4), texel (y, k · W / n_phi + m) at [y, m, k]."""
    height, width = rgb.shape[:2]
    out = np.zeros((height, n_phi, width // n_phi, 4), np.float32)
    out[..., :3] = rgb.reshape(height, n_phi, width // n_phi, 3)
    return np.ascontiguousarray(out.transpose(0, 2, 1, 3))


def _defines(refine: int, width: int, n_phi: int) -> dict[str, int]:
    """kernels/triple/light_rotations.cl's build constants: samples per leaf, map columns per
    φ step."""
    return {"SAMPLES": 4 ** refine, "COLUMNS": width // n_phi}


@lru_cache(maxsize=1)
def _sample_coords(grid: FrameGrid, leaf_level: int, refine: int, width: int,
                   height: int) -> tuple[Any, int]:
    """A device buffer of the texel coordinates (frames, N · 4^r) float2 of every leaf
    sample in the grid's frames at φ = 0 that the kernel is given (ψ < π for an even
    n_ψ), and that count of frames; kept for the next chunk (the trigonometry costs
    as much as several φ steps of lookups)."""
    import pyopencl as cl_

    psi_given = grid.n_psi // 2 if grid.n_psi % 2 == 0 else grid.n_psi  # the kernel's
    theta = np.pi * np.arange(grid.n_theta) / (grid.n_theta - 1)        # half turns
    psi = 2 * np.pi * np.arange(psi_given) / grid.n_psi
    t, p = (g.reshape(-1) for g in np.meshgrid(theta, psi, indexing="ij"))
    frames = euler_frame(np.zeros_like(t), t, p)  # (n_theta · psi_given, 3, 3)
    fine, _ = leaf_samples(leaf_level, refine)
    coords = cl_.Buffer(cl.context(), cl_.mem_flags.READ_WRITE, len(frames) * len(fine) * 8)
    cl.check_writes("light_sample_coords", coords, len(frames) * len(fine) * 8)  # float2
    cl.kernel("light_rotations.cl", "light_sample_coords",
              _defines(refine, width, grid.n_phi))(
        cl.queue(), (len(fine), len(frames)), None,
        cl.read_only_buffer(frames.reshape(-1, 9).astype(np.float32)),
        cl.read_only_buffer(fine.astype(np.float32)), np.int32(width), np.int32(height),
        np.int32(len(frames)), np.int32(len(fine)), coords)
    return coords, len(frames)


def leaf_means_buffer(rgb: np.ndarray, grid: FrameGrid, start: int, end: int,
                      leaf_level: int, refine: int) -> Any:
    """A device buffer of the leaf means (end − start, 3, N) float32 of map ``rgb``
    (H, W, 3), W a multiple of ``grid.n_phi``, in the frames of grid entries
    ``start`` .. ``end`` − 1 (kernels/triple/light_rotations.cl: the φ planes the span touches,
    only the entries inside it)."""
    import pyopencl as cl_

    height, width = rgb.shape[:2]
    if width % grid.n_phi:
        raise ValueError(f"map width {width} is not a multiple of n_phi {grid.n_phi}")
    per_phi = grid.n_theta * grid.n_psi
    phi_first, phi_end = start // per_phi, -(-end // per_phi)
    psi_given = grid.n_psi // 2 if grid.n_psi % 2 == 0 else grid.n_psi
    coords, frames = _sample_coords(grid, leaf_level, refine, width, height)
    _, weights = leaf_samples(leaf_level, refine)
    leaves = 20 * 4 ** leaf_level
    kernel = cl.kernel("light_rotations.cl", "light_leaf_means",
                       _defines(refine, width, grid.n_phi))
    partner = cl.read_only_buffer(leaf_permutation(leaf_level, (-1, -1, 1)).astype(np.int32))
    result = cl_.Buffer(cl.context(), cl_.mem_flags.READ_WRITE,
                        (end - start) * 3 * leaves * 4)
    cl.check_writes("light_leaf_means", result, (end - start) * 3 * leaves * 4)  # the span's
    kernel(cl.queue(), (leaves, frames), None, coords,
           cl.read_only_buffer(weights.astype(np.float32)),
           cl.read_only_buffer(_phi_major(rgb, grid.n_phi)), np.int32(width),
           np.int32(height), np.int32(frames), np.int32(leaves), np.int32(phi_first),
           np.int32(phi_end - phi_first), np.int32(grid.n_phi), np.int32(psi_given),
           np.int32(grid.n_psi), np.int32(start - phi_first * per_phi),
           np.int32(end - start), partner, result)
    return result


def kernel_leaf_means(rgb: np.ndarray, grid: FrameGrid, start: int, end: int,
                      leaf_level: int, refine: int) -> np.ndarray:
    """The leaf means of :func:`leaf_means_buffer` on the host."""
    import pyopencl as cl_

    leaves = 20 * 4 ** leaf_level
    out = np.empty((end - start, 3, leaves), np.float32)
    cl_.enqueue_copy(cl.queue(), out, leaf_means_buffer(rgb, grid, start, end, leaf_level,
                                                        refine))
    return out


def prefiltered_map(rgb: np.ndarray, params: dict[str, Any]) -> np.ndarray:
    """The map as the kernel samples it: prefiltered to the samples' spacing. The last
    one is kept, keyed by a digest of the map's bytes and the settings: the chunks of a
    grid that a process runs share it (0.13–0.2 s of NumPy per chunk otherwise). A
    read-only map seen last time (the runner's cached read, a renderer's map) is not
    hashed again (7 ms per chunk for a 1024×512 map)."""
    spacing = sample_spacing(int(params["triple.leaf_level"]), int(params["triple.light_refine"]))
    n_phi = frame_grid(params).n_phi
    if _PREFILTERED.get("source") is rgb and not rgb.flags.writeable \
            and _PREFILTERED["settings"] == (spacing, n_phi):
        return _PREFILTERED["map"]
    contiguous = np.ascontiguousarray(rgb)
    key = (hashlib.blake2b(contiguous.view(np.uint8)).digest(), rgb.shape, str(rgb.dtype),
           spacing, n_phi)
    if _PREFILTERED.get("key") != key:
        filtered = prefilter(contiguous, spacing, n_phi)
        filtered.setflags(write=False)
        _PREFILTERED.update(key=key, map=filtered)
    _PREFILTERED.update(source=rgb, settings=(spacing, n_phi))
    return _PREFILTERED["map"]


_PREFILTERED: dict[str, Any] = {}  # prefiltered_map's last key and (read-only) map


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    """The stored rows of grid entries [start, end) of the chunk's span."""
    if ctx.environment is None:
        raise PrtError(None, "method triple needs an environment light (lights: "
                       "[{type: environment, file: ...}])")
    grid = frame_grid(ctx.params)
    level, refine = int(ctx.params["triple.leaf_level"]), int(ctx.params["triple.light_refine"])
    start, end = ctx.chunk.span
    rgb = prefiltered_map(ctx.environment, ctx.params)
    means = leaf_means_buffer(rgb, grid, start, end, level, refine)
    coefficients = forward_device(means, (end - start) * 3, level)  # (rows, 3, N)
    rows = select_rows_buffer(coefficients, 0, end - start, 3,
                              level, int(ctx.params["triple.light_budget"]),
                              float(ctx.params["triple.light_tolerance"]),
                              int(ctx.params["triple.store_top"]), LUMINANCE, half=True)
    ctx.meta.update(map_width=int(ctx.environment.shape[1]),
                    worst_residual=float(rows["residual"].max()),
                    most_coefficients=int(rows["count"].max()), entries=len(rows["index"]))
    return rows


def layout(ctx: AssembleContext) -> Layout:
    return Layout(sizes=ROW_CHUNKS)


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    """Attributes, and whether every row met ``triple.light_tolerance``."""
    tolerance = float(ctx.params["triple.light_tolerance"])
    budget = int(ctx.params["triple.light_budget"])
    worst = max(m["worst_residual"] for _, m in metas)
    most = max(m["most_coefficients"] for _, m in metas)
    short = worst > tolerance
    grid = frame_grid(ctx.params)
    level, refine = int(ctx.params["triple.leaf_level"]), int(ctx.params["triple.light_refine"])
    width = prefiltered_width(metas[0][1]["map_width"], grid.n_phi)
    return Output({
        "frame_grid": [grid.n_phi, grid.n_theta, grid.n_psi],
        "leaf_level": level,
        "refine": refine,
        "prefiltered_width": int(width),
        "store_tolerance": tolerance,
        "store_budget": budget,
        "store_top": int(ctx.params["triple.store_top"]),
        "entries": int(sum(m["entries"] for _, m in metas)),
    }, tolerances=[ToleranceResult(
        "environment lighting", "worst relative L2 error of a stored row (luminance-weighted)",
        tolerance, worst, {"coefficients": most},
        f"triple.light_budget {budget}" if short else "",
        "raise triple.light_budget" if short else "")])

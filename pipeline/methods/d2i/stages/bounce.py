"""Stage ``bounce``: the single-bounce gather matrix Ms of method d2i (paper 000 §5.2),
one chunk per block of gather samples (receivers). Schema ``bounce``.

Ms[g, h] is D with gather sample g as the receiver and disk h as the source
(pipeline/methods/d2i/transfer.py): V_h(g) (1/π) |A_h|/n Σ G(g, q_i), geometry and visibility
only, every surface taken as Lambertian (paper 000: "we assume that all the surfaces of
scene are Lambertian"); L_{n+1} = kd ⊙ Ms L_n applies the receivers' albedos at run
time. A sample does not light itself (its own disk does not face it). Rows are stored as
the ``transfer`` stage stores D: per unit source area, as Haar CSR rows to
``transfer.keep_tolerance``.
"""

from __future__ import annotations

import numpy as np

from pipeline.engine.rows import ROW_CHUNKS, ROW_FIELDS, join_arrays
from pipeline.engine.stage import AssembleContext, Chunk, ChunkContext, Layout, Output
from pipeline.math.frames import tangent_from_normal
from pipeline.methods.d2i.stages.transfer import (
    PIXEL_BATCH,
    center_visibility,
    compress_rows,
    scene_tools,
)
from pipeline.methods.d2i.transfer import Receivers


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    tracer, disks, kernel, epsilon = scene_tools(ctx)
    start, end = ctx.chunk.span
    end = min(end, len(disks.center))
    keep = float(ctx.params["transfer.keep_tolerance"])
    cap = int(ctx.params["bounce.max_coefficients"])
    parts = []
    for s in range(start, end, PIXEL_BATCH):
        rows = slice(s, min(s + PIXEL_BATCH, end))
        position, normal = disks.center[rows], disks.normal[rows]
        receivers = Receivers(position, normal, tangent_from_normal(normal), normal)
        vis = center_visibility(tracer, position, normal, disks, epsilon)
        ms, _ = kernel(receivers, vis, None)
        ms *= disks.inverse_area  # in place: the kernel's fresh array
        parts.append(compress_rows(ms, disks.area, keep, cap))
    return {f"ms_{k}": join_arrays([p[k] for p in parts], dt) for k, dt in ROW_FIELDS.items()}


def layout(ctx: AssembleContext) -> Layout:
    return Layout(sizes=ROW_CHUNKS)


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    return Output({
        "gather_count": int(ctx.inputs["d2i.gather"].attrs["count"]),
        "keep_tolerance": float(ctx.params["transfer.keep_tolerance"]),
        "max_coefficients": int(ctx.params["bounce.max_coefficients"])})

"""Stage toy.shade: max(0, n · up) per pixel of a tile, by the kernel toy_shade.cl, plus
a little seeded noise (so that tests see a code edit draw the same random numbers)."""

from __future__ import annotations

import numpy as np

from pipeline.device import cl
from pipeline.engine.stage import Layout, Output, tile_blocks


def run_chunk(ctx):
    import pyopencl as pcl

    y0, y1, x0, x1 = ctx.chunk.region
    normal = np.ascontiguousarray(ctx.inputs["gbuffer"].read(
        "normal", (slice(y0, y1), slice(x0, x1))).reshape(-1, 3), np.float32)
    out = np.empty(len(normal), np.float32)
    buf = pcl.Buffer(cl.context(), pcl.mem_flags.WRITE_ONLY, max(out.nbytes, 4))
    event = cl.kernel("toy_shade.cl", "toy_shade")(
        cl.queue(), (len(out),), None, cl.read_only_buffer(normal), buf, np.int32(len(out)))
    pcl.enqueue_copy(cl.queue(), out, buf, wait_for=[event]).wait()
    out += np.float32(1e-3) * ctx.rng.random(len(out), dtype=np.float32)
    return tile_blocks(ctx.chunk, {"shade": out.reshape(y1 - y0, x1 - x0)})


def layout(ctx):
    cam = ctx.scene["camera"]
    return Layout({"shade": (cam["height"], cam["width"])},
                  {"tile": ctx.params["toy.shade_tile"]})


def finalize(ctx, metas):
    return Output({})

"""The toy method's renderer: gain × shade + 0.1 × level per pixel (kernel toy_gain.cl)."""

from __future__ import annotations

import time

import numpy as np

from pipeline.device import cl
from pipeline.render import Frame


class ToyRenderer:
    """Reads ``toy.shade`` and ``toy.level`` once; no cache between frames."""

    def __init__(self, scene, artifacts, gain=1.0):
        self.shade = artifacts["toy.shade"].read("shade")
        self.level = float(artifacts["toy.level"].read("level")[0])
        self.gain = gain

    def edit_mode(self, kind, scene):
        return self.frame

    def frame(self, scene):
        import pyopencl as pcl

        t0 = time.perf_counter()
        flat = np.ascontiguousarray(self.shade.reshape(-1), np.float32)
        rgb = np.empty((len(flat), 3), np.float32)
        buf = pcl.Buffer(cl.context(), pcl.mem_flags.WRITE_ONLY, rgb.nbytes)
        event = cl.kernel("toy_gain.cl", "toy_gain")(
            cl.queue(), (len(flat),), None, cl.read_only_buffer(flat), np.float32(self.gain),
            np.float32(0.1 * self.level), buf, np.int32(len(flat)))
        pcl.enqueue_copy(cl.queue(), rgb, buf, wait_for=[event])
        ms = cl.event_ms(event)
        total = (time.perf_counter() - t0) * 1e3
        return Frame("toy", rgb.reshape(*self.shade.shape, 3), {
            "setup_ms": total - ms, "kernel_ms": ms, "total_ms": total})


def sequence(scene, artifacts, spec):
    """``gain:N``: the same scene N times (the renderer's gain is an option, so the
    sequence shows the frame path, not an edit)."""
    kind, _, count = spec.partition(":")
    return kind, [scene] * int(count), [f"frame {i}" for i in range(int(count))]

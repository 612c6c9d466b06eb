"""A bounding-volume hierarchy for shadow rays and closest hits on the OpenCL device
(kernels/bvh.h).

Embree traces the bake's rays and the CPU renderer's; on a GPU the renderer's shadow rays
would cross the bus twice per frame (points out, visibility back), so they are traced
where the frame is shaded. The hierarchy is built once per scene, in NumPy:

* **Order.** Triangles are sorted by the Morton code of their centroid (10 bits per
  axis over the scene's bounds), so that triangles close in the order are close in
  space (Lauterbach et al. 2009, "Fast BVH construction on GPUs").
* **Tree.** Leaves hold ``LEAF`` consecutive triangles of that order; the tree over the
  leaves is complete and implicit: node k (k ≥ 1) has children 2k and 2k + 1, the P
  leaves (P a power of two) are nodes P … 2P − 1. No child pointers, no build-time
  recursion: each level's boxes are the element-wise min/max of the level below. The
  split is at the middle of the Morton range rather than at a surface-area optimum:
  simpler, and for occlusion rays (any hit ends the walk) good enough — the benchmark
  (benchmarks/d2i/frames.py) compares its ray rate with Embree's.
* **Boxes** are float32 min/max of the float32 vertices (exact), so a triangle never
  pokes out of its leaf's box. Leaves past the last triangle get inverted boxes, which
  the slab test of kernels/bvh.h never enters.

Triangles are stored as (v0, e1 = v1 − v0, e2 = v2 − v0) float4 triples for the
Möller–Trumbore test, both sides counted as Embree counts them.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

LEAF = 4  # triangles per leaf
MORTON_BITS = 10  # per axis


def _spread_bits(x: np.ndarray) -> np.ndarray:
    """Bits b of 10-bit integers moved to bit 3b (uint64)."""
    x = x.astype(np.uint64) & np.uint64(0x3FF)
    for shift, mask in ((16, 0xFF0000FF), (8, 0x0300F00F), (4, 0x030C30C3), (2, 0x09249249)):
        x = (x | (x << np.uint64(shift))) & np.uint64(mask)
    return x


def morton_codes(points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """30-bit Morton codes (N,) uint64 of ``points`` (N, 3) in the box [lo, hi]."""
    scale = (1 << MORTON_BITS) - 1
    cell = np.clip((points - lo) / np.maximum(hi - lo, 1e-30) * scale, 0, scale)
    q = cell.astype(np.uint64)
    return (_spread_bits(q[:, 0]) << np.uint64(2)) | (_spread_bits(q[:, 1]) << np.uint64(1)) \
        | _spread_bits(q[:, 2])


@dataclass(frozen=True)
class Bvh:
    """The implicit tree: ``lo``, ``hi`` (2P, 4) float32 node boxes (row 0 unused),
    ``triangles`` (P·LEAF, 3, 4) float32 (v0, e1, e2; zero rows past the last
    triangle), ``order`` (T,) the original face of each stored triangle, ``leaves`` P."""

    lo: np.ndarray
    hi: np.ndarray
    triangles: np.ndarray
    order: np.ndarray
    leaves: int

    @classmethod
    def build(cls, vertices: np.ndarray, faces: np.ndarray) -> Bvh:
        """The hierarchy of the triangles ``faces`` (T, 3) over ``vertices`` (V, 3)."""
        v = np.asarray(vertices, np.float32)[np.asarray(faces, np.int64)]  # (T, 3, 3)
        tri_lo, tri_hi = v.min(axis=1), v.max(axis=1)
        if len(v):
            centroid = v.astype(np.float64).mean(axis=1)
            order = np.argsort(morton_codes(centroid, centroid.min(0), centroid.max(0)),
                               kind="stable")
        else:
            order = np.zeros(0, np.int64)
        leaves = 1 << max(int(np.ceil(max(len(v), 1) / LEAF)) - 1, 0).bit_length()
        slots = leaves * LEAF
        lo = np.full((slots, 3), np.inf, np.float32)
        hi = np.full((slots, 3), -np.inf, np.float32)
        lo[:len(v)], hi[:len(v)] = tri_lo[order], tri_hi[order]
        node_lo = np.zeros((2 * leaves, 4), np.float32)
        node_hi = np.zeros((2 * leaves, 4), np.float32)
        node_lo[leaves:, :3] = lo.reshape(leaves, LEAF, 3).min(axis=1)
        node_hi[leaves:, :3] = hi.reshape(leaves, LEAF, 3).max(axis=1)
        level = leaves // 2
        while level >= 1:  # parents k in [level, 2·level): children 2k, 2k + 1
            kids = slice(2 * level, 4 * level)
            node_lo[level:2 * level] = np.minimum(node_lo[kids][0::2], node_lo[kids][1::2])
            node_hi[level:2 * level] = np.maximum(node_hi[kids][0::2], node_hi[kids][1::2])
            level //= 2
        triangles = np.zeros((slots, 3, 4), np.float32)
        s = v[order]
        triangles[:len(v), 0, :3] = s[:, 0]
        triangles[:len(v), 1, :3] = s[:, 1] - s[:, 0]
        triangles[:len(v), 2, :3] = s[:, 2] - s[:, 0]
        return cls(node_lo, node_hi, triangles, order, leaves)

    @cached_property
    def device(self) -> list[Any]:
        """Device buffers in kernels/bvh.h's argument order (lo, hi, triangles)."""
        from pipeline.device import cl

        return [cl.read_only_buffer(a) for a in (self.lo, self.hi, self.triangles)]

    @property
    def nbytes(self) -> int:
        return self.lo.nbytes + self.hi.nbytes + self.triangles.nbytes


def occluded(bvh: Bvh, origins: np.ndarray, directions: np.ndarray,
             distances: np.ndarray) -> tuple[np.ndarray, float]:
    """True where a triangle lies on the ray o + t d, 0 < t < ``distances`` (N,) (t in
    units of |d|, as Embree's ``occluded``), traced on the device (kernel
    ``occluded_rays``); and the kernel's milliseconds."""
    from pipeline.device import cl
    from pipeline.math.lights import light_defines

    n = len(origins)
    if n == 0:
        return np.zeros(0, bool), 0.0
    rays = np.zeros((n, 2, 4), np.float32)
    rays[:, 0, :3], rays[:, 1, :3] = origins, directions
    rays[:, 0, 3] = distances
    out = np.empty(n, np.uint8)
    # the file's other kernel shades lights: it is built with their row layout
    defines = {**light_defines(), "BVH_LEAF": LEAF}
    ms = cl.run(cl.kernel("shadow_rays.cl", "occluded_rays", defines), n,
                *bvh.device, np.int32(bvh.leaves), cl.read_only_buffer(rays), np.int32(n),
                out=out, writes=n, local=64)  # a byte per ray
    return out.astype(bool), ms


def closest(bvh: Bvh, origins: np.ndarray, directions: np.ndarray,
            distances: np.ndarray | None = None) -> tuple[Any, float]:
    """The closest hits of rays (N, 3) float32, 0 < t < ``distances`` (None: unbounded),
    traced on the device (kernel ``closest_rays``) as pipeline.device.raytrace.Hits
    (Embree's: ``t`` (inf where none), the original face ``prim`` (-1 where none) and the
    barycentrics ``u``, ``v``), and the kernel's milliseconds."""
    from pipeline.device import cl
    from pipeline.device.raytrace import Hits
    from pipeline.math.lights import light_defines

    n = len(origins)
    rays = np.zeros((n, 2, 4), np.float32)
    rays[:, 0, :3], rays[:, 1, :3] = origins, directions
    rays[:, 0, 3] = np.inf if distances is None else distances
    t, u, v = (np.empty(n, np.float32) for _ in range(3))
    stored = np.empty(n, np.int32)
    if n == 0:
        return Hits(t, stored, u, v), 0.0
    import pyopencl as pcl

    defines = {**light_defines(), "BVH_LEAF": LEAF}
    outs = [pcl.Buffer(cl.context(), pcl.mem_flags.WRITE_ONLY, 4 * n) for _ in range(4)]
    kernel = cl.kernel("shadow_rays.cl", "closest_rays", defines)
    event = kernel(cl.queue(), (-(-n // 64) * 64,), (64,), *bvh.device,
                   np.int32(bvh.leaves), cl.read_only_buffer(rays), np.int32(n), *outs)
    for array, buffer in zip((t, stored, u, v), outs, strict=True):
        pcl.enqueue_copy(cl.queue(), array, buffer, wait_for=[event])
    prim = np.full(n, -1, np.int32)
    prim[stored >= 0] = bvh.order[stored[stored >= 0]]
    t[stored < 0] = np.inf
    return Hits(t, prim, u, v), cl.event_ms(event)


class DeviceRayTracer:
    """Rays on the device, as pipeline.device.raytrace.RayTracer traces them on the host
    (Embree): closest hits (``intersect``, kernel ``closest_rays``) and any-hit
    occlusion (``occluded``, kernel ``occluded_rays``), the hierarchy built once, each
    call one kernel. On a GPU a camera's rays then never wait on the host's cores, and a
    bake's visibility rays run there (pipeline/device/bake_tracer.py). Callers on several
    threads take turns (a lock: the kernels' arguments are set per call)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        self.bvh = Bvh.build(vertices, faces)
        self.kernel_ms = 0.0  # the last call's
        self._lock = threading.Lock()

    @property
    def threads(self) -> int:
        """Threads a caller splits its host work over (this task's share of the cores);
        the rays themselves run on the device."""
        from pipeline.device.threads import task_threads

        return task_threads()

    def intersect(self, origins: np.ndarray, directions: np.ndarray) -> Any:
        """Closest hits of rays (N, 3) float32 (pipeline.device.raytrace.Hits)."""
        with self._lock:
            hits, self.kernel_ms = closest(self.bvh, np.asarray(origins, np.float32),
                                           np.asarray(directions, np.float32))
        return hits

    def occluded(self, origins: np.ndarray, directions: np.ndarray, distances: np.ndarray,
                 threads: int | None = None) -> np.ndarray:
        """True where something lies on the ray before ``distances`` (N,), in units of
        |d| (a negative distance: no ray, False), as RayTracer.occluded; ``threads`` is
        RayTracer's argument, unused here."""
        with self._lock:
            blocked, self.kernel_ms = occluded(
                self.bvh, np.asarray(origins, np.float32).reshape(-1, 3),
                np.asarray(directions, np.float32).reshape(-1, 3),
                np.asarray(distances, np.float32).reshape(-1))
        return blocked

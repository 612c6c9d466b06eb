"""Shadow rays toward every light sample, traced each frame: with Embree on the host
(:func:`light_visibility`), or on the OpenCL device against pipeline/device/bvh.py's hierarchy
(:class:`DeviceShadows`, kernel ``light_visibility`` of kernels/shadow_rays.cl: the same
rays, so that a GPU frame's visibility never crosses the bus)."""

from __future__ import annotations

from typing import Any

import numpy as np

from pipeline.device import cl
from pipeline.device.bvh import LEAF, Bvh
from pipeline.device.raytrace import RayTracer
from pipeline.device.threads import map_slices
from pipeline.math.lights import (
    TYPE_CODES,
    LightRow,
    light_defines,
    light_sample_points,
    total_samples,
)

SHADOW_EPSILON = 1e-4  # ray origin offset along the normal, relative to the scene diagonal
POINT_BATCH = 16384  # points per thread: ray set-up in NumPy and Embree both release the GIL


def light_visibility(tracer: RayTracer, position: np.ndarray, normal: np.ndarray,
                     pixel: np.ndarray, packed: np.ndarray, scene_diagonal: float) -> np.ndarray:
    """(N, total_samples) uint8: 1 where light sample s of each point is unoccluded.

    Only samples in front of the point (n·l > 0) are traced; the others are left 0, as
    they contribute nothing. Rays stop just short of the sample point so that an
    emitter's own surface does not shadow it. Batches of points run on a thread pool,
    set-up and tracing together (the set-up costs about as much as Embree's rays)."""
    vis = np.zeros((len(position), total_samples(packed)), np.uint8)
    eps = SHADOW_EPSILON * scene_diagonal

    def batch(rows: slice) -> None:
        vis[rows] = _batch_visibility(tracer, position[rows], normal[rows], pixel[rows],
                                      packed, eps, 4.0 * scene_diagonal)

    map_slices(batch, len(position), POINT_BATCH)
    return vis


def _batch_visibility(tracer: RayTracer, position: np.ndarray, normal: np.ndarray,
                      pixel: np.ndarray, packed: np.ndarray, eps: float,
                      far: float) -> np.ndarray:
    """light_visibility of one batch of points, traced on the calling thread; ``eps`` the
    origin offset and ``far`` the length of rays towards directional lights."""
    vis = np.zeros((len(position), total_samples(packed)), np.uint8)
    origin = np.asarray(position + eps * normal, np.float32)
    for i, row in enumerate(packed):
        off = int(row[LightRow.SAMPLE_OFFSET])
        if int(row[LightRow.TYPE]) == TYPE_CODES["directional"]:
            point = np.flatnonzero(normal @ -row[LightRow.DIRECTION] > 0)
            sample = np.zeros(len(point), np.int64)
            dirs = np.broadcast_to(-row[LightRow.DIRECTION], (len(point), 3))
            dists = np.full(len(point), far, np.float32)
        else:
            samples = light_sample_points(packed, i, pixel)
            delta = samples - origin[:, None, :]
            # n·(q − p) > 0: the sample is in front of the point (judged from p, not the
            # moved origin: an eps as large as the near geometry would put o past it)
            facing = np.einsum("nk,nsk->ns", normal, samples - position[:, None, :])
            point, sample = np.nonzero(facing > 0)
            # direction q − o unnormalised: Embree's t is in its lengths, so t_far just
            # short of 1 stops the ray just short of the sample (no square roots)
            dirs = delta[point, sample]
            dists = np.full(len(point), 1.0 - 1e-4, np.float32)
        blocked = tracer.occluded(origin[point], dirs, dists, threads=1)
        vis[point, off + sample] = ~blocked
    return vis


class DeviceShadows:
    """Shadow rays on the OpenCL device against the scene's BVH (built once)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        self.bvh = Bvh.build(vertices, faces)

    def visibility(self, position: Any, normal: Any, pixel: Any, count: int,
                   packed: np.ndarray, scene_diagonal: float, out: Any | None = None
                   ) -> tuple[Any, float]:
        """Device buffer (count, max(total_samples, 1)) uint8, as :func:`light_visibility`
        of the ``count`` points in device buffers ``position``, ``normal`` (float32 ×3)
        and ``pixel`` (uint32 ids); written into ``out`` when given; and kernel ms."""
        import pyopencl as pcl

        stride = max(total_samples(packed), 1)
        if out is None:
            out = pcl.Buffer(cl.context(), pcl.mem_flags.READ_WRITE, max(count * stride, 1))
        if count == 0 or not len(packed):
            if count:
                pcl.enqueue_fill_buffer(cl.queue(), out, np.uint8(0), 0, count * stride)
            return out, 0.0
        kernel = cl.kernel("shadow_rays.cl", "light_visibility",
                           {**light_defines(), "BVH_LEAF": LEAF})
        ms = cl.run(kernel, count, *self.bvh.device, np.int32(self.bvh.leaves), position,
                    normal, pixel, cl.read_only_buffer(np.asarray(packed, np.float32)),
                    np.int32(len(packed)), np.int32(stride),
                    np.float32(SHADOW_EPSILON * scene_diagonal),
                    np.float32(4.0 * scene_diagonal), np.int32(count), out=None,
                    writes=count * stride, out_buffer=out, local=64)  # a byte per sample
        return out, ms

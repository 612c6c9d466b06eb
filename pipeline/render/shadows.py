"""Shadow rays toward every light sample, traced with Embree each frame."""

from __future__ import annotations

import numpy as np

from pipeline.math.lights import TYPE_CODES, light_sample_points, total_samples
from pipeline.raytrace import RayTracer

SHADOW_EPSILON = 1e-4  # ray origin offset along the normal, relative to the scene diagonal


def light_visibility(tracer: RayTracer, position: np.ndarray, normal: np.ndarray,
                     pixel: np.ndarray, packed: np.ndarray, scene_diagonal: float) -> np.ndarray:
    """(N, total_samples) uint8: 1 where light sample s of each point is unoccluded.

    Only samples in front of the point (n·l > 0) are traced; the others are left 0, as
    they contribute nothing. Rays stop just short of the sample point so that an
    emitter's own surface does not shadow it."""
    eps = SHADOW_EPSILON * scene_diagonal
    vis = np.zeros((len(position), total_samples(packed)), np.uint8)
    origin = (position + eps * normal).astype(np.float32)
    for i, row in enumerate(packed):
        off, count = int(row[17]), int(row[15])
        if int(row[0]) == TYPE_CODES["directional"]:
            d = np.broadcast_to(-row[4:7], origin.shape).astype(np.float32)
            dist = np.full(len(origin), 4.0 * scene_diagonal, np.float32)
            front = (normal @ -row[4:7]) > 0
            dirs, dists, rays_front = d[:, None], dist[:, None], front[:, None]
            src = origin[:, None]
        else:
            q = light_sample_points(packed, i, pixel)
            delta = q - origin[:, None, :]
            dists = np.linalg.norm(delta, axis=-1)
            dirs = delta / np.maximum(dists[..., None], 1e-30)
            rays_front = np.einsum("nk,nsk->ns", normal, dirs) > 0
            dists = dists * (1.0 - 1e-4)
            src = np.broadcast_to(origin[:, None, :], dirs.shape)
        todo = rays_front & (dists > 0)
        blocked = tracer.occluded(src[todo], dirs[todo], dists[todo])
        block = np.zeros(todo.shape, bool)
        block[todo] = blocked
        vis[:, off:off + count] = (todo & ~block).reshape(len(origin), count)
    return vis

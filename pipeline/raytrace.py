"""Ray casting with Embree (through embreex), batched across a thread pool.

embreex releases the GIL inside ``EmbreeScene.run``, so batches of a few tens of
thousands of rays run concurrently on all cores. Rays start at their origin (there is no
t_near): callers offset shadow-ray origins off the surface themselves.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from pipeline.executors import map_slices

BATCH = 32768


@dataclass
class Hits:
    """First hits: ``t`` distance along the (unit) ray, ``prim`` global face index or
    -1, ``u``, ``v`` barycentrics of vertices 1 and 2 of the face. All (N,)."""

    t: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray


class RayTracer:
    """An Embree scene over one triangle soup: ``vertices`` (V, 3), ``faces`` (F, 3)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, threads: int | None = None):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self.scene = rtcore_scene.EmbreeScene()
        triangles = np.ascontiguousarray(np.asarray(vertices, np.float32)[faces])
        TriangleMesh(self.scene, triangles)
        self.threads = threads or os.cpu_count() or 1

    def _batched(self, fn, n: int, threads: int | None = None) -> list:
        return map_slices(fn, n, BATCH, threads or self.threads)

    def intersect(self, origins: np.ndarray, directions: np.ndarray) -> Hits:
        """Closest hits of rays (N, 3) float32."""
        o = np.ascontiguousarray(origins.reshape(-1, 3), np.float32)
        d = np.ascontiguousarray(directions.reshape(-1, 3), np.float32)

        def run(s: slice):
            return self.scene.run(o[s], d[s], output=1)

        parts = self._batched(run, len(o))
        if not parts:
            empty = np.zeros(0, np.float32)
            return Hits(empty, np.zeros(0, np.int32), empty, empty)
        return Hits(np.concatenate([p["tfar"] for p in parts]),
                    np.concatenate([p["primID"] for p in parts]),
                    np.concatenate([p["u"] for p in parts]),
                    np.concatenate([p["v"] for p in parts]))

    def occluded(self, origins: np.ndarray, directions: np.ndarray,
                 distances: np.ndarray, threads: int | None = None) -> np.ndarray:
        """True where something lies on the ray before ``distances`` (N,); ``threads``
        overrides the tracer's thread count (1: on the calling thread, for callers that
        run their own pool)."""
        o = np.ascontiguousarray(origins.reshape(-1, 3), np.float32)
        d = np.ascontiguousarray(directions.reshape(-1, 3), np.float32)
        t = np.ascontiguousarray(distances.reshape(-1), np.float32)

        def run(s: slice):
            return self.scene.run(o[s], d[s], dists=t[s].copy(), query="OCCLUDED")

        parts = self._batched(run, len(o), threads)
        if not parts:
            return np.zeros(0, bool)
        return np.concatenate(parts) != -1

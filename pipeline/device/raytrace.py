"""Ray casting with Embree (through embreex), batched across a thread pool.

embreex releases the GIL inside ``EmbreeScene.run``, so batches of a few tens of
thousands of rays run concurrently on a thread pool of this task's share of the cores
(pipeline/engine/executors/local.py ``task_threads``: all of them in a one-worker run, a worker's
threads in a pool). Rays start at their origin (there is no t_near): callers offset
shadow-ray origins off the surface themselves.

:func:`surface_at` turns first hits into surface attributes (position, shading and
geometric normals, tangent, uv, object and material) for every caller that shades or
samples at hits: the G-buffer, the gather samples and the reference path tracer.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from pipeline.device.threads import map_slices, task_threads
from pipeline.math.frames import face_tangents, orthonormalize

BATCH = 32768
# Secondary rays leave a surface point this far along its normal, relative to the scene's
# bounding-box diagonal (every bake stage and the reference use the same offset).
RAY_EPSILON = 1e-4


@dataclass
class Hits:
    """First hits: ``t`` distance along the (unit) ray, ``prim`` global face index or
    -1, ``u``, ``v`` barycentrics of vertices 1 and 2 of the face. All (N,)."""

    t: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray

    def select(self, which: np.ndarray) -> Hits:
        """The hits at ``which`` (a mask or indices)."""
        return Hits(self.t[which], self.prim[which], self.u[which], self.v[which])


class RayTracer:
    """An Embree scene over one triangle soup: ``vertices`` (V, 3), ``faces`` (F, 3).
    Rays are traced in batches on ``threads`` threads (default: ``task_threads()`` at
    each call, so a tracer cached across tasks follows each task's share)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, threads: int | None = None):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self.scene = rtcore_scene.EmbreeScene()
        triangles = np.ascontiguousarray(np.asarray(vertices, np.float32)[faces])
        TriangleMesh(self.scene, triangles)
        self._threads = threads

    @property
    def threads(self) -> int:
        """Threads a batched call uses now."""
        return self._threads or task_threads()

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


class Mesh:
    """What hit points need of a triangle soup (the geometry artifact's arrays):
    ``vertices`` (V, 3), unit vertex ``normals`` (V, 3), ``uv`` (V, 2), ``faces`` (F, 3),
    ``face_object`` (F,), ``object_material`` (objects,). The normals' dtype is the
    precision of the normal blend (see :func:`surface_at`); per-face tangents and normals
    are computed in float64 on first use."""

    def __init__(self, vertices: np.ndarray, normals: np.ndarray, uv: np.ndarray,
                 faces: np.ndarray, face_object: np.ndarray,
                 object_material: np.ndarray) -> None:
        self.vertices, self.normals, self.uv = vertices, normals, uv
        self.faces, self.face_object, self.object_material = faces, face_object, object_material

    @classmethod
    def from_arrays(cls, arrays: dict, normal_dtype: type | None = None) -> Mesh:
        """From a dict of the geometry artifact's arrays; ``normal_dtype`` converts the
        vertex normals (float64: the blend in float64)."""
        normals = np.asarray(arrays["normals"], normal_dtype)
        return cls(np.asarray(arrays["vertices"]), normals, np.asarray(arrays["uv"]),
                   np.asarray(arrays["faces"]), np.asarray(arrays["face_object"]),
                   np.asarray(arrays["object_material"]))

    @cached_property
    def face_tangent(self) -> np.ndarray:
        """Per-face dP/du (F, 3) float64, zero where the uv mapping is degenerate."""
        return face_tangents(self.vertices, self.uv, self.faces)

    @cached_property
    def face_normal(self) -> np.ndarray:
        """Unit face normals (F, 3) float64, (e1 × e2) of the counter-clockwise corners."""
        v = self.vertices.astype(np.float64)
        cross = np.cross(v[self.faces[:, 1]] - v[self.faces[:, 0]],
                         v[self.faces[:, 2]] - v[self.faces[:, 0]])
        return cross / np.maximum(np.linalg.norm(cross, axis=1, keepdims=True), 1e-300)


class Surface:
    """Surface attributes at hits (:func:`surface_at`), each computed on first use.
    All (N, ...) in the world frame, scene units:

    ``position``          o + t d (float64 when o or d is);
    ``normal``            unit shading normal: the barycentric blend of the face's vertex
                          normals (in the normals' precision, the barycentrics taken in
                          it too), normalised in ``normal_dtype`` (at least the blend's)
                          and turned to face the ray (n·d ≤ 0);
    ``geometric_normal``  unit face normal (float64), turned to face the ray;
    ``tangent``           unit tangent along +u of the face's uv, made orthogonal to
                          ``normal`` (float64; where the uv mapping is degenerate, a
                          tangent from the normal alone, math/frames.py);
    ``uv``                the blended texture coordinates;
    ``face``              global face index (int64); ``object_id``, ``material_id``."""

    def __init__(self, mesh: Mesh, hits: Hits, origins: np.ndarray, directions: np.ndarray,
                 normal_dtype: type) -> None:
        self.mesh, self.hits, self.origins, self.directions = mesh, hits, origins, directions
        self.normal_dtype = normal_dtype
        self.face = hits.prim.astype(np.int64)

    @cached_property
    def _weights(self) -> np.ndarray:
        """Barycentric weights (N, 3, 1) of the face's three vertices."""
        dtype = self.mesh.normals.dtype
        u, v = self.hits.u.astype(dtype), self.hits.v.astype(dtype)
        return np.stack([1.0 - u - v, u, v], axis=1)[:, :, None]

    def _facing(self, n: np.ndarray) -> np.ndarray:
        """``n`` turned to face the rays."""
        return np.where(np.sum(n * self.directions, axis=1, keepdims=True) > 0, -n, n)

    @cached_property
    def position(self) -> np.ndarray:
        return self.origins + self.hits.t[:, None] * self.directions

    @cached_property
    def normal(self) -> np.ndarray:
        blend = np.sum(self._weights * self.mesh.normals[self.mesh.faces[self.face]], axis=1)
        n = blend.astype(np.result_type(blend, self.normal_dtype))
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
        # Turned with its face, not on its own: at a silhouette the blended normal of a
        # face that faces the ray may face away from it, and turning it alone would
        # point it into the object.
        face = self.mesh.face_normal[self.face]
        return np.where(np.sum(face * self.directions, axis=1, keepdims=True) > 0, -n, n)

    @cached_property
    def geometric_normal(self) -> np.ndarray:
        return self._facing(self.mesh.face_normal[self.face])

    @cached_property
    def tangent(self) -> np.ndarray:
        return orthonormalize(self.mesh.face_tangent[self.face], self.normal)

    @cached_property
    def uv(self) -> np.ndarray:
        return np.sum(self._weights * self.mesh.uv[self.mesh.faces[self.face]], axis=1)

    @cached_property
    def object_id(self) -> np.ndarray:
        return self.mesh.face_object[self.face]

    @cached_property
    def material_id(self) -> np.ndarray:
        return self.mesh.object_material[self.object_id]


def surface_at(mesh: Mesh, hits: Hits, origins: np.ndarray, directions: np.ndarray,
               normal_dtype: type = np.float64) -> Surface:
    """Surface attributes (:class:`Surface`) where rays ``origins`` + t ``directions``
    (N, 3; unit directions) meet ``mesh`` at ``hits`` (all of them hits: select them
    with ``Hits.select`` first). ``normal_dtype`` is the precision the shading normal is
    normalised in (the G-buffer keeps float32, the gather samples float64)."""
    return Surface(mesh, hits, origins, directions, normal_dtype)

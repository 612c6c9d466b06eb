"""What method sg's transport passes need of the scene at its mesh vertices: the Embree
scene, vertex positions and normals, faces, each vertex's material and the ray offset.

Vertices are the global vertex indices of the ``geometry`` artifact (all objects in scene
order); a vertex belongs to the object whose vertex range holds it and takes that
object's material. World frame, scene units. Rays leave a vertex from its position
pushed ``offset`` along its (unit, smooth) normal.

Rays that start on another surface (a vertex where a wall meets the floor, the bunny's
lowest vertices on the ground) hit that surface at t ≈ 0 whichever way they go.
:meth:`VertexScene.intersect` drops such a hit when the ray leaves the surface's back
side (d·n_face > 0, counter-clockwise faces) within 2·offset, and traces on from just
beyond it: the rays going away from the floor escape, those going into it stay blocked.
Not handled: a vertex whose normal points *into* a surface it touches (a sphere's lowest
vertex on the floor, normal −y) starts its rays offset beyond that surface and sees the
sky behind it. Only vertices within ``offset`` of another surface are affected: on
bunny_sg, the bunny's lowest vertex.

A value stored per vertex (a diffuse SH transfer) is read at a ray's hit by the hit
face's barycentric blend, (1 − u − v)·value[f0] + u·value[f1] + v·value[f2] with Embree's
u, v (:meth:`VertexScene.at_hits`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from pipeline.device.raytrace import RAY_EPSILON, Hits, RayTracer
from pipeline.math.brdf import BrdfParams

UNSEEN = BrdfParams("lambert", (0.0, 0.0, 0.0))  # a material whose section a chunk lacks


def scene_materials(sections: Mapping[str, Any], names: list[str]) -> list[BrdfParams]:
    """BRDF parameters of the geometry's ``material_names`` from a stage's resolved scene
    sections ``materials.NAME`` (declared as ``materials.*``). A vertex-batch chunk sees
    only its own object's material: the others stand as :data:`UNSEEN` (black Lambert),
    which is right for what a chunk evaluates, its own vertices."""
    out = []
    for name in names:
        m = sections.get(f"materials.{name}")
        out.append(UNSEEN if m is None else BrdfParams.from_material(m["model"], m["albedo"], m))
    return out


@dataclass
class VertexScene:
    """``positions``, unit ``normals`` (V, 3) float64, ``faces`` (F, 3) int64,
    ``vertex_material`` (V,) int64 indices into ``materials``, the ``tracer`` (Embree's,
    or pipeline/device/bake_tracer.py's choice) and the ray ``offset`` (scene units)."""

    tracer: Any
    positions: np.ndarray
    normals: np.ndarray
    faces: np.ndarray
    vertex_material: np.ndarray
    materials: list[BrdfParams]
    offset: float

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, Any], materials: list[BrdfParams],
                    tracer: Any = None) -> VertexScene:
        """From the geometry artifact's arrays (``vertices``, ``normals``, ``faces``,
        ``object_ranges``, ``object_material``) and the BRDFs of its ``material_names``
        in order; ``tracer``: a tracer of the same triangles (default: a new Embree
        scene)."""
        positions = np.asarray(arrays["vertices"], np.float64)
        normals = np.asarray(arrays["normals"], np.float64)
        normals = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
        faces = np.asarray(arrays["faces"], np.int64)
        vertex_material = np.zeros(len(positions), np.int64)
        for (start, end, _, _), material in zip(np.asarray(arrays["object_ranges"]),
                                                np.asarray(arrays["object_material"]),
                                                strict=True):
            vertex_material[start:end] = material
        diagonal = float(np.linalg.norm(positions.max(0) - positions.min(0)))
        return cls(tracer or RayTracer(positions, faces), positions, normals, faces,
                   vertex_material, list(materials), RAY_EPSILON * diagonal)

    @cached_property
    def face_normals(self) -> np.ndarray:
        """Unit geometric normals (F, 3) of the counter-clockwise faces."""
        p = self.positions
        cross = np.cross(p[self.faces[:, 1]] - p[self.faces[:, 0]],
                         p[self.faces[:, 2]] - p[self.faces[:, 0]])
        return cross / np.maximum(np.linalg.norm(cross, axis=1, keepdims=True), 1e-300)

    def intersect(self, origins: np.ndarray, directions: np.ndarray) -> Hits:
        """First hits of rays (N, 3) (unit directions), less the back-face hits within
        2·offset of the origin (module docstring), which are traced on once from
        offset beyond them."""
        hits = self.tracer.intersect(origins, directions)
        prim = np.maximum(hits.prim, 0)
        again = np.flatnonzero((hits.prim >= 0) & (hits.t < 2.0 * self.offset)
                               & (np.sum(directions * self.face_normals[prim], axis=1) > 0.0))
        if len(again):
            step = hits.t[again].astype(np.float64) + self.offset
            more = self.tracer.intersect(origins[again] + step[:, None] * directions[again],
                                         directions[again])
            hits.t[again] = np.where(more.prim >= 0, more.t + step, np.inf)
            hits.prim[again], hits.u[again], hits.v[again] = more.prim, more.u, more.v
        return hits

    def diffuse_albedo(self) -> np.ndarray:
        """kd (V, 3) of every vertex's material."""
        table = np.array([m.albedo for m in self.materials], np.float64).reshape(-1, 3)
        return table[self.vertex_material]

    def at_hits(self, values: np.ndarray, hits: Hits) -> np.ndarray:
        """Per-vertex ``values`` (V, ...) blended at ray hits (N,) by the barycentrics of
        the hit face; rows of missed rays (prim < 0) are 0."""
        out = np.zeros((len(hits.prim),) + values.shape[1:], np.float64)
        hit = hits.prim >= 0
        corners = self.faces[hits.prim[hit]]                                   # (H, 3)
        u = hits.u[hit].astype(np.float64)
        v = hits.v[hit].astype(np.float64)
        shape = (-1,) + (1,) * (values.ndim - 1)
        out[hit] = ((1.0 - u - v).reshape(shape) * values[corners[:, 0]]
                    + u.reshape(shape) * values[corners[:, 1]]
                    + v.reshape(shape) * values[corners[:, 2]])
        return out

"""Stage ``geometry``: every object's mesh in world space, validated, repaired and merged.

Per object (one chunk each):
  * with ``objects.NAME.smooth: true``, vertices sharing a position (and uv) welded
    (meshio.weld: a file split by per-face normals is otherwise faceted);
  * vertices transformed by the object's 4×4 matrix; a mirroring transform (negative
    determinant) reverses face winding so normals keep pointing outward;
  * a vertex used by a face with a non-finite coordinate is an error (the mesh is
    broken; nothing sensible can be drawn); unused non-finite vertices are dropped;
  * degenerate faces (repeated indices or area below 1e-12 of the squared bounding-box
    diagonal) are dropped;
  * vertex normals are area-weighted face normals (mesh files' normals are not kept);
    a vertex whose normal cancels out takes the normal of one of its faces;
  * with ``objects.NAME.subdivide: N``, every face split at its edges' midpoints N times
    (meshio.split_edges: the surface and its shading normals kept, more vertices).
The assembled artifact concatenates objects in scene order (schema ``geometry``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.device.raytrace import RAY_EPSILON, Mesh, RayTracer
from pipeline.engine.stage import AssembleContext, Chunk, ChunkContext, Layout, Output
from pipeline.engine.store import Artifact
from pipeline.errors import PrtError
from pipeline.scene.meshio import split_edges, weld

DEGENERATE_AREA = 1e-12  # relative to the squared bbox diagonal


@dataclass(frozen=True)
class TracedGeometry:
    """A ``geometry`` artifact ready for rays: its Embree scene, its mesh attributes
    (``mesh.face_normal``: unit face normals, float64) and the origin offset of
    secondary rays, ``epsilon`` = RAY_EPSILON × its bounding-box diagonal (scene units)."""

    tracer: RayTracer
    mesh: Mesh
    epsilon: float


_TRACED: dict[str, TracedGeometry] = {}


def traced_geometry(geometry: Artifact) -> TracedGeometry:
    """The :class:`TracedGeometry` of ``geometry``, built once per process and artifact
    key (the stages that trace rays share it)."""
    key = geometry.record["key"]
    if key not in _TRACED:
        arrays = {n: geometry.read(n) for n in
                  ("vertices", "normals", "uv", "faces", "face_object", "object_material")}
        diagonal = np.linalg.norm(np.subtract(geometry.attrs["bbox_max"],
                                              geometry.attrs["bbox_min"]))
        _TRACED.clear()
        _TRACED[key] = TracedGeometry(RayTracer(arrays["vertices"], arrays["faces"]),
                                      Mesh.from_arrays(arrays), RAY_EPSILON * float(diagonal))
    return _TRACED[key]


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    name = ctx.chunk.object
    raw = ctx.meshes[name]
    if ctx.scene.get(f"objects.{name}.smooth"):
        raw = weld(raw)
    section = ctx.scene[f"objects.{name}.transform"]
    matrix = np.asarray(section, dtype=np.float64)
    vertices, faces, uv = raw.vertices, raw.faces, raw.uv

    bad_vertex = ~np.isfinite(vertices).all(axis=1)
    if uv is not None:
        bad_vertex |= ~np.isfinite(uv).all(axis=1)
    used = np.zeros(len(vertices), bool)
    used[faces.ravel()] = True
    if (bad_vertex & used).any():
        first = int(np.flatnonzero(bad_vertex & used)[0])
        raise PrtError(raw.source, f"{int((bad_vertex & used).sum())} vertices used by faces "
                       f"have non-finite coordinates (first: vertex {first})")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise PrtError(raw.source, "faces index vertices that do not exist")

    world = vertices @ matrix[:3, :3].T + matrix[:3, 3]
    if np.linalg.det(matrix[:3, :3]) < 0:
        faces = faces[:, ::-1]
    a, b, c = (world[faces[:, i]] for i in range(3))
    face_cross = np.cross(b - a, c - a)
    area2 = np.linalg.norm(face_cross, axis=1)
    finite_world = world[used & ~bad_vertex]
    diag2 = float(np.sum((finite_world.max(0) - finite_world.min(0)) ** 2))
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | \
        (faces[:, 0] == faces[:, 2])
    degenerate = repeated | (0.5 * area2 <= DEGENERATE_AREA * max(diag2, 1e-300))
    faces, face_cross = faces[~degenerate], face_cross[~degenerate]
    if len(faces) == 0:
        raise PrtError(raw.source, "every face of the mesh is degenerate")

    # Keep only vertices that faces use, in their original order.
    keep = np.zeros(len(world), bool)
    keep[faces.ravel()] = True
    remap = np.cumsum(keep) - 1
    faces, world = remap[faces], world[keep]
    uv = np.zeros((len(world), 2)) if uv is None else uv[keep]

    normals = np.zeros_like(world)
    for i in range(3):
        np.add.at(normals, faces[:, i], face_cross)
    length = np.linalg.norm(normals, axis=1)
    cancelled = length < 1e-20 * max(diag2, 1e-300)
    if cancelled.any():
        face_unit = face_cross / np.linalg.norm(face_cross, axis=1, keepdims=True)
        owner = np.zeros(len(world), np.int64)
        owner[faces.ravel()] = np.repeat(np.arange(len(faces)), 3)
        normals[cancelled] = face_unit[owner[cancelled]]
        length = np.linalg.norm(normals, axis=1)
    normals /= length[:, None]
    for _ in range(int(ctx.scene.get(f"objects.{name}.subdivide") or 0)):
        world, normals, uv, faces = split_edges(world, normals, uv, faces)

    vertices = world.astype(np.float32)
    ctx.meta.update({
        "vertices": len(vertices), "faces": len(faces),
        "bbox_min": vertices.min(axis=0).astype(float).tolist(),
        "bbox_max": vertices.max(axis=0).astype(float).tolist(),
        "repairs": dict(zip(REPAIRS, (int(degenerate.sum()), int((bad_vertex & ~used).sum()),
                                      int(cancelled.sum())), strict=True))})
    return {
        "vertices": vertices,
        "normals": normals.astype(np.float32),
        "uv": uv.astype(np.float32),
        "faces": faces.astype(np.int32),  # the object's own vertex indices (offset_by)
        "face_object": np.full(len(faces), ctx.chunk.index, np.int32),
    }


REPAIRS = ("degenerate_faces_dropped", "unused_nonfinite_vertices_dropped",
           "normals_from_face")


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    """Object ranges and materials, the scene's bounding box, the repairs made."""
    material_names = list(ctx.scene["material_table"])
    object_names = [chunk.object for chunk, _ in metas]
    offsets_v = np.cumsum([0] + [m["vertices"] for _, m in metas])
    offsets_f = np.cumsum([0] + [m["faces"] for _, m in metas])
    ranges = np.stack([offsets_v[:-1], offsets_v[1:], offsets_f[:-1], offsets_f[1:]], axis=1)
    materials = [material_names.index(ctx.scene[f"objects.{name}.material"])
                 for name in object_names]
    return Output(
        attrs={
            "object_names": object_names,
            "material_names": material_names,
            "bbox_min": np.min([m["bbox_min"] for _, m in metas], axis=0).tolist(),
            "bbox_max": np.max([m["bbox_max"] for _, m in metas], axis=0).tolist(),
            "repairs": {name: m["repairs"] for (_, m), name in zip(metas, object_names,
                                                                   strict=True)},
            "vertex_counts": {name: int(m["vertices"]) for (_, m), name in
                              zip(metas, object_names, strict=True)},
        },
        arrays={"object_ranges": ranges.astype(np.int64),
                "object_material": np.asarray(materials, dtype=np.int32)})


def layout(ctx: AssembleContext) -> Layout:
    chunk = int(ctx.params["geometry.vertex_chunk"])
    return Layout(sizes={"vertex_chunk": chunk, "face_chunk": chunk})

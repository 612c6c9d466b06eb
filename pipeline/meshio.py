"""Reading triangle meshes from files (via trimesh) and building primitives.

Meshes come back raw, in object space, with no repair: :mod:`pipeline.stages.geometry`
validates and repairs them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.errors import PrtError


@dataclass(frozen=True)
class RawMesh:
    """Object-space triangles: ``vertices`` (V, 3) float64, ``faces`` (F, 3) int64,
    ``uv`` (V, 2) float64 or None. ``source`` names the file (or primitive) for errors."""

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None
    source: str


def read_mesh(path: Path) -> RawMesh:
    """Load a mesh file (OBJ, PLY, STL, ...) without trimesh's merging or repair."""
    import trimesh

    try:
        mesh = trimesh.load(str(path), process=False, force="mesh")
    except Exception as exc:
        raise PrtError(path, f"cannot read mesh ({type(exc).__name__}: {exc})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise PrtError(path, "mesh file holds no triangles")
    uv = getattr(mesh.visual, "uv", None)
    if uv is not None and len(uv) != len(mesh.vertices):
        uv = None
    return RawMesh(np.asarray(mesh.vertices, dtype=np.float64),
                   np.asarray(mesh.faces, dtype=np.int64),
                   None if uv is None else np.asarray(uv, dtype=np.float64), str(path))


def primitive_mesh(spec: dict[str, Any]) -> RawMesh:
    """A built-in primitive: ``plane`` (in the xz plane, normal +y, ``size`` [sx, sz],
    with uv), ``sphere`` (icosphere of ``radius`` and ``subdivisions``), ``box``
    (``size`` [sx, sy, sz], flat faces); all centred at the origin."""
    import trimesh

    kind = spec["type"]
    if kind == "plane":
        sx, sz = spec["size"]
        vertices = np.array([[-sx / 2, 0, -sz / 2], [sx / 2, 0, -sz / 2],
                             [sx / 2, 0, sz / 2], [-sx / 2, 0, sz / 2]])
        faces = np.array([[0, 2, 1], [0, 3, 2]])
        uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
        return RawMesh(vertices, faces, uv, "primitive plane")
    if kind == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=spec["subdivisions"],
                                          radius=spec["radius"])
        return RawMesh(np.asarray(mesh.vertices, dtype=np.float64),
                       np.asarray(mesh.faces, dtype=np.int64), None, "primitive sphere")
    # A box's faces keep their own vertices so that its vertex normals stay flat.
    mesh = trimesh.creation.box(extents=spec["size"])
    corners = np.asarray(mesh.vertices, dtype=np.float64)[mesh.faces].reshape(-1, 3)
    return RawMesh(corners, np.arange(len(corners), dtype=np.int64).reshape(-1, 3), None,
                   "primitive box")

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


# OBJ statements whose numbers this reader checks: the count of numbers each needs (at
# least, at most). ``v`` may carry a weight or an RGB colour; ``vt`` a third coordinate.
_OBJ_NUMBERS = {"v": (3, 6), "vn": (3, 3), "vt": (1, 3)}


def check_obj_text(path: Path, data: bytes) -> str:
    """The text of the OBJ file ``path`` (its bytes ``data``), or PrtError naming the
    first line that is not well-formed: binary data, a vertex with too few or
    non-numeric coordinates (a file cut short), a face with fewer than three corners or
    a corner naming a vertex not defined before it. Trimesh does not check these: it
    crashes or silently reads another mesh."""
    if b"\0" in data:
        raise PrtError(path, "not a text OBJ file (it holds binary data)")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise PrtError(path, f"not a text OBJ file (byte {exc.start} is not UTF-8)") from None
    if not _well_formed(text):
        _first_bad_line(path, text)
    return text


def _well_formed(text: str) -> bool:
    """The checks of :func:`check_obj_text`, vectorised (dragon_100kf.obj in ≈ 1 s);
    False where a line fails, which :func:`_first_bad_line` then finds."""
    rows = [line.split("#", 1)[0].split() if "#" in line else line.split()
            for line in text.splitlines()]
    rows = [r for r in rows if r]
    kinds = np.array([r[0] for r in rows])
    try:
        for kind, (lo, hi) in _OBJ_NUMBERS.items():
            selected = [rows[i] for i in np.flatnonzero(kinds == kind)]
            sizes = np.fromiter(map(len, selected), np.int64, len(selected)) - 1
            if sizes.size and (sizes.min() < lo or sizes.max() > hi):
                return False
            np.array([x for r in selected for x in r[1:]], dtype=np.float64)
        faces = np.flatnonzero(kinds == "f")
        corners = [rows[i][1:] for i in faces]
        sizes = np.fromiter(map(len, corners), np.int64, len(corners))
        if sizes.size and sizes.min() < 3:
            return False
        slots = ("v", "vt", "vn") if any("/" in c for f in corners for c in f) else ("v",)
        for slot, kind in enumerate(slots):
            defined = np.cumsum(kinds == kind)[faces]  # elements above each face
            index = [c.split("/")[slot] if "/" in c else (c if slot == 0 else "")
                     for f in corners for c in f]
            given = np.array([i != "" for i in index])
            if slot == 0 and not given.all():
                return False
            values = np.array([i for i in index if i != ""], dtype=np.int64)
            limit = np.repeat(defined, sizes)[given]
            if values.size and ((values == 0) | (np.abs(values) > limit)).any():
                return False
    except (ValueError, IndexError):
        return False
    return True


def _first_bad_line(path: Path, text: str) -> None:
    """PrtError naming the first line of ``text`` that :func:`check_obj_text` refuses."""
    counts = {"v": 0, "vt": 0, "vn": 0}
    for number, line in enumerate(text.splitlines(), start=1):
        fields = line.split("#", 1)[0].split()
        if not fields:
            continue
        kind, values = fields[0], fields[1:]
        if kind in _OBJ_NUMBERS:
            lo, hi = _OBJ_NUMBERS[kind]
            try:
                [float(v) for v in values]
            except ValueError:
                raise PrtError(path, f"line {number}: '{line.strip()}': expected numbers") \
                    from None
            if not lo <= len(values) <= hi:
                expected = f"{lo}" if lo == hi else f"{lo} to {hi}"
                raise PrtError(path, f"line {number}: '{line.strip()}': expected {expected} "
                               "numbers (is the file cut short?)")
            counts[kind] += 1
        elif kind == "f":
            if len(values) < 3:
                raise PrtError(path, f"line {number}: '{line.strip()}': a face needs at "
                               "least 3 corners (is the file cut short?)")
            for corner in values:
                _check_corner(path, number, line, corner, counts)


def _check_corner(path: Path, number: int, line: str, corner: str,
                  counts: dict[str, int]) -> None:
    """One face corner ``v``, ``v/vt``, ``v//vn`` or ``v/vt/vn``: indices that name an
    element defined above (1-based, or negative: counted back from the last)."""
    for kind, index in zip(("v", "vt", "vn"), corner.split("/"), strict=False):
        if kind != "v" and index == "":
            continue
        try:
            i = int(index)
        except ValueError:
            raise PrtError(path, f"line {number}: '{line.strip()}': corner {corner!r} is "
                           "not v[/vt][/vn] indices") from None
        if i == 0 or abs(i) > counts[kind]:
            raise PrtError(path, f"line {number}: '{line.strip()}': corner {corner!r} names "
                           f"{kind} {i}, but {counts[kind]} are defined above it")


def read_mesh(path: Path) -> RawMesh:
    """Load a mesh file (OBJ, PLY, STL, ...) without trimesh's merging or repair; an OBJ
    file is checked line by line first (:func:`check_obj_text`). Vertices split by the
    file's normals stay split (hard edges); :func:`weld` joins them where a scene asks."""
    import io

    import trimesh

    try:
        data = path.read_bytes()
    except OSError as exc:
        raise PrtError(path, f"cannot read mesh ({exc.strerror or exc})") from None
    kind = path.suffix.lower().lstrip(".")
    if kind == "obj":
        data = check_obj_text(path, data).encode("utf-8")
    try:
        mesh = trimesh.load(io.BytesIO(data), file_type=kind, process=False, force="mesh")
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


def weld(raw: RawMesh) -> RawMesh:
    """``raw`` with vertices that are bit-identical in position and uv merged into the
    first of them (order of first appearance kept; a mesh without such twins comes back
    unchanged): the scene's ``objects.NAME.smooth: true``. An OBJ file whose faces name
    normals (``f v//vn``) is split by trimesh into one vertex per (v, vn) pair, which is
    how a file keeps hard edges (the Cornell box's blocks); a file that gives every face
    its own normal (bunny_6.6kf.obj: 19,794 corners for 3,301 positions) is faceted,
    and per-vertex methods then interpolate nothing across faces. Vertices that differ
    in uv — texture seams — stay apart."""
    keys = raw.vertices if raw.uv is None else np.hstack([raw.vertices, raw.uv])
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    if len(first) == len(keys):
        return raw
    order = np.argsort(first)                  # unique rows in order of first appearance
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    kept = first[order]
    return RawMesh(raw.vertices[kept], rank[inverse.ravel()][raw.faces],
                   None if raw.uv is None else raw.uv[kept], raw.source)


def split_edges(vertices: np.ndarray, normals: np.ndarray, uv: np.ndarray,
                faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The mesh with every face (a, b, c) split at its edges' midpoints into (a, ab, ca),
    (ab, b, bc), (ca, bc, c) and (ab, bc, ca) (winding kept): ``vertices`` (V, 3),
    unit ``normals`` (V, 3), ``uv`` (V, 2), ``faces`` (F, 3) -> the V old vertices first,
    then one per edge (E), faces (4F, 3). A new vertex lies at its edge's midpoint with
    the mean of its ends' uv and their normals' normalised mean (the first end's where
    they cancel), so the surface and the normals shading interpolates across it stay
    the old mesh's: only the vertices that per-vertex light samples are added
    (``objects.NAME.subdivide``)."""
    faces = np.asarray(faces, np.int64)
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    unique, edge_of = np.unique(edges, axis=0, return_inverse=True)
    a, b = unique[:, 0], unique[:, 1]
    mean = normals[a] + normals[b]
    length = np.linalg.norm(mean, axis=1, keepdims=True)
    mean = np.where(length > 1e-12, mean / np.maximum(length, 1e-300), normals[a])
    mid = len(vertices) + edge_of.reshape(-1, 3)            # ab, bc, ca of each face
    ab, bc, ca = mid[:, 0], mid[:, 1], mid[:, 2]
    x, y, z = faces[:, 0], faces[:, 1], faces[:, 2]
    split = np.stack([np.stack([x, ab, ca], 1), np.stack([ab, y, bc], 1),
                      np.stack([ca, bc, z], 1), np.stack([ab, bc, ca], 1)], 1).reshape(-1, 3)
    return (np.concatenate([vertices, 0.5 * (vertices[a] + vertices[b])]),
            np.concatenate([normals, mean]), np.concatenate([uv, 0.5 * (uv[a] + uv[b])]),
            split)


def primitive_mesh(spec: dict[str, Any]) -> RawMesh:
    """A built-in primitive: ``plane`` (in the xz plane, normal +y, ``size`` [sx, sz],
    with uv, a grid of ``segments`` × ``segments`` squares, default 1), ``sphere``
    (icosphere of ``radius`` and ``subdivisions``), ``box`` (``size`` [sx, sy, sz], flat
    faces); all centred at the origin."""
    import trimesh

    kind = spec["type"]
    if kind == "plane":
        return _plane(*spec["size"], spec.get("segments", 1))
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


def _plane(sx: float, sz: float, segments: int) -> RawMesh:
    """The xz plane [−sx/2, sx/2] × [−sz/2, sz/2] as n × n squares (n = ``segments``),
    each cut along its (i, j)–(i+1, j+1) diagonal, counter-clockwise seen from +y;
    u along +x, v along +z. Vertex (i, j) (i along x, j along z) is number j(n + 1) + i,
    except that n = 1 keeps the order the plane had before ``segments`` existed, the
    corners going round, (−,−), (+,−), (+,+), (−,+): the geometry of existing scenes
    stays byte-equal, so nothing downstream of it re-bakes."""
    t = np.linspace(0.0, 1.0, segments + 1)
    u, v = np.meshgrid(t, t)                      # [j, i]: v along rows, u along columns
    vertices = np.stack([(u.ravel() - 0.5) * sx, np.zeros(u.size), (v.ravel() - 0.5) * sz],
                        axis=-1)
    i, j = np.meshgrid(np.arange(segments), np.arange(segments))
    a = (j * (segments + 1) + i).ravel()          # corner (i, j) of each square
    b, c, d = a + 1, a + segments + 2, a + segments + 1   # (i+1, j), (i+1, j+1), (i, j+1)
    faces = np.concatenate([np.stack([a, c, b], -1), np.stack([a, d, c], -1)])
    uv = np.stack([u.ravel(), v.ravel()], -1)
    if segments == 1:
        order = np.array([0, 1, 3, 2])  # new number of old vertex k: order[k]
        vertices, uv, faces = vertices[order], uv[order], np.argsort(order)[faces]
    return RawMesh(vertices, faces, uv, "primitive plane")

"""The hierarchical geodesic sphere that spherical wavelets live on (paper 004 §3.1).

Level 0 is the regular icosahedron's 20 triangles, its vertices on the unit sphere.
Level l + 1 splits every triangle (a, b, c) of level l into four at the midpoints of its
edges pushed onto the sphere, m_ab = (a + b)/‖a + b‖ and so on::

    child 4i     (a,    m_ab, m_ca)     corner at a
    child 4i + 1 (m_ab, b,    m_bc)     corner at b
    child 4i + 2 (m_ca, m_bc, c   )     corner at c
    child 4i + 3 (m_ab, m_bc, m_ca)     centre

so the children of triangle i of level l are 4i .. 4i + 3 of level l + 1 and the leaf
j of level L lies in triangle j >> 2(L − l) of level l. Every triangle is wound
counter-clockwise seen from outside the sphere.

The triangles are *geodesic*: their edges are great-circle arcs, and a direction ω
belongs to triangle (a, b, c) when it lies on the inner side of the three planes
through the origin and each edge, (a × b)·ω ≥ 0, (b × c)·ω ≥ 0, (c × a)·ω ≥ 0.
Their solid angles (steradians) follow Van Oosterom and Strackee's formula

    tan(Ω/2) = |a·(b × c)| / (1 + a·b + b·c + c·a),

and are not equal: the centre child subtends 1.20× a corner child at the first
subdivision, and the 5120 leaves of level 4 span a ratio of 1.30 between the largest and
the smallest. The 20·4^L leaves of level L sum to 4π exactly (to rounding).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

ROOTS = 20  # triangles of level 0 (the icosahedron)


def icosahedron() -> tuple[np.ndarray, np.ndarray]:
    """Unit vertices (12, 3) and counter-clockwise faces (20, 3) of the icosahedron."""
    t = (1.0 + np.sqrt(5.0)) / 2.0
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0],
                  [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
                  [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], dtype=np.float64)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
                  [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
                  [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
                  [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]], dtype=np.int64)
    return v, f


def solid_angles(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Solid angles (sr) of the geodesic triangles with unit corners a, b, c (..., 3)."""
    triple = np.abs(np.einsum("...i,...i->...", a, np.cross(b, c)))
    denominator = 1.0 + np.einsum("...i,...i->...", a, b) \
        + np.einsum("...i,...i->...", b, c) + np.einsum("...i,...i->...", c, a)
    return 2.0 * np.arctan2(triple, denominator)


@dataclass(frozen=True)
class GeodesicLevel:
    """One level: unit ``vertices`` (V, 3) (shared by every level below it), triangles
    ``faces`` (20·4^l, 3) indexing them, their ``areas`` (solid angles, sr) and unit
    ``centroids`` (the normalised mean of the corners)."""

    vertices: np.ndarray
    faces: np.ndarray
    areas: np.ndarray
    centroids: np.ndarray

    @property
    def corners(self) -> np.ndarray:
        """The corners of every triangle (T, 3 corners, 3)."""
        return self.vertices[self.faces]


def _subdivided(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The next level: every face split into its four children in the documented order."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    unique, inverse = np.unique(np.sort(edges, axis=1), axis=0, return_inverse=True)
    mid = vertices[unique[:, 0]] + vertices[unique[:, 1]]
    mid /= np.linalg.norm(mid, axis=1, keepdims=True)
    m = len(vertices) + inverse.reshape(3, len(faces))  # m[0] = m_ab, m[1] = m_bc, m[2] = m_ca
    a, b, c = faces.T
    children = np.stack([np.stack([a, m[0], m[2]], 1), np.stack([m[0], b, m[1]], 1),
                         np.stack([m[2], m[1], c], 1), np.stack([m[0], m[1], m[2]], 1)], 1)
    return np.concatenate([vertices, mid]), children.reshape(-1, 3)


@cache
def geodesic_levels(leaf_level: int) -> tuple[GeodesicLevel, ...]:
    """Levels 0 .. ``leaf_level`` of the geodesic sphere (cached; treat as read-only)."""
    vertices, faces = icosahedron()
    levels = []
    for level in range(leaf_level + 1):
        if level:
            vertices, faces = _subdivided(vertices, faces)
        corners = vertices[faces]
        centroid = corners.sum(axis=1)
        centroid /= np.linalg.norm(centroid, axis=1, keepdims=True)
        levels.append(GeodesicLevel(vertices, faces, solid_angles(*corners.transpose(1, 0, 2)),
                                    centroid))
    return tuple(levels)


def _inside_margin(corners: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """How far inside each triangle each direction lies: the least of the three edge
    plane tests (N, K) for corners (N, K, 3, 3) and unit directions (N, 3)."""
    a, b, c = corners[..., 0, :], corners[..., 1, :], corners[..., 2, :]
    tests = [np.einsum("nki,ni->nk", np.cross(p, q), directions)
             for p, q in ((a, b), (b, c), (c, a))]
    return np.minimum(np.minimum(tests[0], tests[1]), tests[2])


def locate(directions: np.ndarray, leaf_level: int) -> np.ndarray:
    """The leaf (of level ``leaf_level``) holding each unit direction (..., 3) -> (...,).

    Descends the hierarchy: at each level the child whose edge planes the direction is
    most inside of. A direction on a shared edge goes to one of the triangles sharing it
    (the tests are exact up to rounding)."""
    levels = geodesic_levels(leaf_level)
    d = np.asarray(directions, np.float64)
    shape = d.shape[:-1]
    d = d.reshape(-1, 3)
    roots = np.broadcast_to(levels[0].corners, (len(d), ROOTS, 3, 3))
    node = np.argmax(_inside_margin(roots, d), axis=1)
    for level in levels[1:]:
        candidates = 4 * node[:, None] + np.arange(4)
        node = candidates[np.arange(len(d)), np.argmax(
            _inside_margin(level.corners[candidates], d), axis=1)]
    return node.reshape(shape)

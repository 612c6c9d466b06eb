"""Texels of a UV atlas: which triangle each texel samples, and where on it.

Coordinates are in texel units of a texture ``height`` × ``width``: x along the width,
y along the height; texel (row y, column x) has its centre at (x + 0.5, y + 0.5). A
bilinear fetch at a point q reads the four texels whose centres lie less than one texel
from q along both axes, so the texels a triangle's fetches can read are those whose
centre c has its square [c − 1, c + 1]² meeting the triangle: the triangle's *footprint*.

:func:`rasterize` assigns every texel in some footprint to one triangle:

* **covered**: its centre lies inside a triangle (one of them where several share it);
* **dilated**: its centre lies outside every triangle but in a footprint; it takes the
  nearest triangle (in texel units) and the closest point on it, so its surface point
  lies on the mesh (on a chart's edge) and bilinear fetches across the chart's border
  read values continued from the border;
* **empty**: in no footprint; nothing ever reads it.

The triangle-square test is the separating-axis test: a triangle with corners p_k and
edge outward normals m_k (unnormalised) misses the square of half-width 1 at c iff its
bounding box misses the square or, for some edge, m_k·(c − p_k) > |m_k,x| + |m_k,y|.
"""

from __future__ import annotations

import numpy as np

EMPTY, COVERED, DILATED = 0, 1, 2
TEXEL_STATES = {"empty": EMPTY, "covered": COVERED, "dilated": DILATED}
_BATCH = 1 << 20  # candidate (triangle, texel) pairs per vectorised step


def _candidates(corners: np.ndarray, height: int, width: int
                ) -> tuple[np.ndarray, np.ndarray]:
    """(triangle, texel) pairs, texel = y·width + x, of every texel whose centre lies in
    a triangle's bounding box grown by one texel: a superset of the footprints."""
    lo = np.floor(corners.min(axis=1) - 1.5).astype(np.int64) + 1  # first centre > min − 1
    hi = np.ceil(corners.max(axis=1) + 0.5).astype(np.int64)       # past last centre < max + 1
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [width, height])
    span = np.maximum(hi - lo, 0)
    count = span[:, 0] * span[:, 1]
    tri = np.repeat(np.arange(len(corners)), count)
    local = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    x = lo[tri, 0] + local % np.maximum(span[tri, 0], 1)
    y = lo[tri, 1] + local // np.maximum(span[tri, 0], 1)
    return tri, y * width + x


def closest_barycentrics(corners: np.ndarray, points: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Barycentrics (N, 3) of the point of each 2D triangle ``corners`` (N, 3, 2)
    closest to ``points`` (N, 2), and the distance (N,) to it (0 inside). A triangle of
    zero area is treated as its longest edge."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    e1, e2 = b - a, c - a
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    d = points - a
    safe = np.where(np.abs(det) > 1e-300, det, 1.0)
    u = (d[:, 0] * e2[:, 1] - d[:, 1] * e2[:, 0]) / safe
    v = (e1[:, 0] * d[:, 1] - e1[:, 1] * d[:, 0]) / safe
    inside = (np.abs(det) > 1e-300) & (u >= 0) & (v >= 0) & (u + v <= 1)
    bary = np.stack([1 - u - v, u, v], axis=1)
    best = np.full(len(points), np.inf)
    best_bary = bary.copy()
    for i, j in ((0, 1), (1, 2), (2, 0)):  # the closest point of each edge
        p, q = corners[:, i], corners[:, j]
        edge = q - p
        t = np.clip(np.sum((points - p) * edge, axis=1)
                    / np.maximum(np.sum(edge * edge, axis=1), 1e-300), 0.0, 1.0)
        dist = np.linalg.norm(p + t[:, None] * edge - points, axis=1)
        closer = dist < best
        best = np.where(closer, dist, best)
        edge_bary = np.zeros_like(bary)
        edge_bary[:, i], edge_bary[:, j] = 1 - t, t
        best_bary = np.where(closer[:, None], edge_bary, best_bary)
    return np.where(inside[:, None], bary, best_bary), np.where(inside, 0.0, best)


def _in_footprint(corners: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Whether the square [c − 1, c + 1]² of each centre meets its triangle (N,)
    (the bounding-box axes are settled by :func:`_candidates`)."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    orientation = np.sign((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])
    meets = np.ones(len(centres), bool)
    for p, q in ((a, b), (b, c), (c, a)):
        edge = q - p
        outward = np.stack([edge[:, 1], -edge[:, 0]], axis=1) * orientation[:, None]
        reach = np.abs(outward).sum(axis=1)
        meets &= np.sum(outward * (centres - p), axis=1) <= reach
    return meets


def rasterize(face_uv: np.ndarray, height: int, width: int
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Texel assignment of triangles ``face_uv`` (F, 3, 2) in texel units.

    Returns ``state`` (H·W,) uint8 (:data:`TEXEL_STATES`), ``face`` (H·W,) int32 (the
    triangle each texel samples, -1 where empty) and ``bary`` (H·W, 3) float64 (the
    barycentrics of its sample point on that triangle), texels in raster order (row y,
    column x at y·width + x). Among the triangles whose footprint holds a texel, the
    nearest to its centre wins (a covering one at distance 0), ties to the lowest index:
    the result does not depend on anything but the input."""
    corners = np.asarray(face_uv, np.float64)
    size = height * width
    best_dist = np.full(size, np.inf)
    face = np.full(size, -1, np.int64)
    bary = np.zeros((size, 3))
    tri, texel = _candidates(corners, height, width)
    for s in range(0, len(tri), _BATCH):
        t, k = tri[s:s + _BATCH], texel[s:s + _BATCH]
        centres = np.stack([k % width + 0.5, k // width + 0.5], axis=1)
        keep = _in_footprint(corners[t], centres)
        t, k, centres = t[keep], k[keep], centres[keep]
        b, dist = closest_barycentrics(corners[t], centres)
        # Per texel the (distance, triangle) minimum of this batch and the earlier ones.
        order = np.lexsort((t, dist, k))
        first = np.ones(len(order), bool)
        first[1:] = k[order][1:] != k[order][:-1]
        win = order[first]
        better = (dist[win] < best_dist[k[win]]) | (
            (dist[win] == best_dist[k[win]]) & (t[win] < face[k[win]]))
        win = win[better]
        best_dist[k[win]], face[k[win]], bary[k[win]] = dist[win], t[win], b[win]
    state = np.where(face < 0, EMPTY, np.where(best_dist == 0.0, COVERED, DILATED))
    return state.astype(np.uint8), face.astype(np.int32), bary

"""Tabulated glossy transport of method sg (paper 003 §3): the 92 view directions and,
per vertex and view, the direct glossy transport over a sphere grid. The start of the
future ``sg.transport`` stage (its indirect glossy part and the diffuse SH are not built).

**Views.** The paper samples the view direction ωo at the vertices of a frequency-3
geodesic icosahedron: the 12 icosahedron vertices, 2 points on each of its 30 edges and
1 inside each of its 20 faces, 10·3² + 2 = 92 unit vectors in the global frame
(:func:`view_directions`).

**Direct glossy transport.** For a vertex x with shading normal n, tangent t, glossy
BRDF part ρs f_F f_E (pipeline/math/brdf.py ``glossy``, the diffuse kd/π excluded: it
goes to spherical harmonics) and a view ωo, the function to fit by Gaussians is

    T(ωi) = ρs f_F(ωi, ωo) f_E(ωi, ωo) V(x, ωi) max(0, n·ωi)     (1/sr, RGB),

so that the glossy radiance towards ωo under distant light L is ∫ T L dω. V is traced
once per vertex and grid direction (Embree); views with n·ωo ≤ 0 (below the horizon)
and directions below it give 0.
"""

from __future__ import annotations

import numpy as np

from pipeline.math.brdf import BrdfParams, glossy, to_local
from pipeline.math.geodesic import icosahedron
from pipeline.raytrace import RayTracer

VIEW_FREQUENCY = 3  # 10 f² + 2 = 92 views


def view_directions(frequency: int = VIEW_FREQUENCY) -> np.ndarray:
    """The vertices (10 f² + 2, 3) of the frequency-f geodesic icosahedron: on each
    icosahedron face (A, B, C) the points (iA + jB + kC)/f, i + j + k = f, pushed onto
    the unit sphere; shared edge and corner points kept once. Icosahedron vertices first,
    the rest in first-seen order (face by face)."""
    corners, faces = icosahedron()
    points = [np.asarray(corners, np.float64)]
    for a, b, c in faces:
        for i in range(frequency + 1):
            for j in range(frequency + 1 - i):
                k = frequency - i - j
                if max(i, j, k) < frequency:  # not a corner
                    p = i * corners[a] + j * corners[b] + k * corners[c]
                    points.append((p / np.linalg.norm(p))[None])
    points = np.concatenate(points)
    # keep one of each shared point (edge points appear on two faces)
    keep = np.ones(len(points), bool)
    for i in range(len(points)):
        if keep[i]:
            close = np.flatnonzero(np.sum((points[i + 1:] - points[i]) ** 2, axis=1) < 1e-12)
            keep[i + 1 + close] = False
    return points[keep]


def visibility(tracer: RayTracer, position: np.ndarray, normal: np.ndarray,
               directions: np.ndarray, offset: float) -> np.ndarray:
    """V (P, S) bool: True where the ray from position + offset·normal (P, 3) along grid
    direction (S, 3) escapes; False below the normal's horizon and where it hits.
    ``offset``: scene units (a small fraction of the scene's size)."""
    above = normal @ directions.T > 0.0  # (P, S)
    p, s = np.nonzero(above)
    origins = position[p] + offset * normal[p]
    hit = tracer.occluded(origins, directions[s], np.full(len(p), np.inf, np.float32))
    out = np.zeros(above.shape, bool)
    out[p[~hit], s[~hit]] = True
    return out


def direct_glossy(normal: np.ndarray, tangent: np.ndarray, brdf: BrdfParams,
                  views: np.ndarray, directions: np.ndarray, visible: np.ndarray
                  ) -> np.ndarray:
    """T (P, K, S, 3) of the module docstring for P vertices (unit normal and tangent
    (P, 3), one material), K views (K, 3) and S grid directions (S, 3) (global frame),
    with visibility ``visible`` (P, S)."""
    li = to_local(directions[None], normal[:, None], tangent[:, None])      # (P, S, 3)
    lo = to_local(views[None], normal[:, None], tangent[:, None])           # (P, K, 3)
    f = glossy(li[:, None], lo[:, :, None], brdf)                           # (P, K, S)
    weight = f * (visible * np.maximum(li[..., 2], 0.0))[:, None]
    weight = np.where((lo[..., 2] > 0.0)[..., None], weight, 0.0)
    return weight[..., None] * np.asarray(brdf.specular)

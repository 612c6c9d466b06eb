"""Tabulated glossy transport of method sg (paper 003 §3): the 92 view directions and,
per vertex and view, the glossy transport T(ωi) over a sphere grid, direct plus indirect
glossy, the diffuse kd part excluded (it goes to spherical harmonics, stage sg.diffuse).

**Views.** The paper samples the view direction ωo at the vertices of a frequency-3
geodesic icosahedron: the 12 icosahedron vertices, 2 points on each of its 30 edges and
1 inside each of its 20 faces, 10·3² + 2 = 92 unit vectors in the global frame
(:func:`view_directions`).

**Direct glossy transport.** For a vertex x with shading normal n, tangent t, glossy
BRDF part ρs f_F f_E (pipeline/math/brdf.py ``glossy``, the diffuse kd/π excluded) and a
view ωo, the function to fit by Gaussians is

    T_dir(ωi) = ρs f_F(ωi, ωo) f_E(ωi, ωo) V(x, ωi) max(0, n·ωi)     (1/sr, RGB),

so that the glossy radiance towards ωo under distant light L is ∫ T L dω. V is traced
once per vertex and grid direction (Embree); views with n·ωo ≤ 0 (below the horizon)
and directions below it give 0.

**Indirect glossy transport** (:func:`indirect_glossy_sh`). Light reaching x from a
surface point y (where V = 0) and reflected by x's glossy lobe towards ωo. Paper 003 §4.1
traces BRDF-importance-sampled paths from x "until it is absorbed or reflected off to
infinity", recording each where it leaves. Here a path
stops at its first hit y and takes y's *diffuse* outgoing radiance, which stage
sg.diffuse has already expressed in spherical harmonics: radiance leaving y =
Σ_k t_y[c, k] L_k = ∫ t_y(ωi) L(ωi) dωi with t_y(ωi) = Σ_k t_y[c, k] Y_k(ωi) (shadows and
diffuse interreflection included). So

    T_ind(ωi) = E_j[ ρs f_F f_E(ωj, ωo) max(0, n·ωj) / p(ωj) · t_{y_j}(ωi) ],

ωj drawn from brdf_sampling's glossy mixture with density p, y_j the hit of the ray along
ωj (rays that escape carry nothing: they are T_dir), t_y blended from the hit face's
vertices. The estimate is a per-(vertex, view) SH vector (3, 25): a smooth, low-frequency
function, evaluated on the grid at the end. **Approximation:** glossy-to-diffuse paths
only; paths whose second vertex reflects glossily (glossy–glossy, e.g. the bunny seen in
its own highlight) are dropped, as is the glossy part of the light leaving y. The paper
keeps them and gives no figure for their share; what is dropped is at most the glossy
albedo of y (≤ 4ρs for Blinn-Phong, brdf.py) times the share of x's lobe that lands on
glossy surfaces, measured for bunny_sg (decision 0030).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from pipeline.device.raytrace import RayTracer
from pipeline.math import brdf_sampling, sh
from pipeline.math.brdf import BrdfParams, glossy, to_local
from pipeline.math.frames import tangent_from_normal
from pipeline.math.geodesic import icosahedron
from pipeline.methods.sg.vertex_scene import VertexScene

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


def scene_visibility(scene: VertexScene, vertices: np.ndarray, directions: np.ndarray
                     ) -> np.ndarray:
    """V (P, S) bool as :func:`visibility` for global ``vertices`` (P,), traced through
    ``VertexScene.intersect`` (a vertex lying on another surface sees past its back
    side)."""
    position, normal = scene.positions[vertices], scene.normals[vertices]
    above = normal @ directions.T > 0.0
    p, s = np.nonzero(above)
    hits = scene.intersect(position[p] + scene.offset * normal[p], directions[s])
    out = np.zeros(above.shape, bool)
    out[p[hits.prim < 0], s[hits.prim < 0]] = True
    return out


def direct_glossy(normal: np.ndarray, tangent: np.ndarray, brdf: BrdfParams,
                  views: np.ndarray, directions: np.ndarray, visible: np.ndarray
                  ) -> np.ndarray:
    """T (P, K, S, 3) of the module docstring for P vertices (unit normal and tangent
    (P, 3), one material), K views (K, 3) and S grid directions (S, 3) (global frame),
    with visibility ``visible`` (P, S). The BRDF is evaluated only where T can be
    non-zero, views above the horizon × visible directions above it (about a quarter
    of the table; the rest stays 0). float32, as the transport is kept."""
    out = np.zeros((len(normal), len(views), len(directions), 3), np.float32)
    specular = np.asarray(brdf.specular)
    for p in range(len(normal)):
        lo = to_local(views, normal[p], tangent[p])                             # (K, 3)
        li = to_local(directions, normal[p], tangent[p])                        # (S, 3)
        k = np.flatnonzero(lo[:, 2] > 0.0)
        s = np.flatnonzero(visible[p] & (li[:, 2] > 0.0))
        f = glossy(li[s][None], lo[k][:, None], brdf) * li[s, 2]                # (k, s)
        out[p, k[:, None], s[None]] = f[..., None] * specular
    return out


def _world(local: np.ndarray, normal: np.ndarray, tangent: np.ndarray) -> np.ndarray:
    """Local vectors (..., 3) of the frame (tangent, normal × tangent, normal) in world
    terms (the inverse of ``brdf.to_local``)."""
    bitangent = np.cross(normal, tangent)
    return (local[..., :1] * tangent + local[..., 1:2] * bitangent
            + local[..., 2:] * normal)


def indirect_glossy_sh(scene: VertexScene, vertices: np.ndarray, views: np.ndarray,
                       diffuse_transfer: np.ndarray, samples: int,
                       rng: np.random.Generator) -> np.ndarray:
    """The SH coefficients A (P, K, 3, n²) of T_ind (module docstring) for global
    ``vertices`` (P,) and views (K, 3): T_ind(ωi) = Σ_k A[..., c, k] Y_k(ωi). ``samples``
    paths per (vertex, view) above the horizon; ``diffuse_transfer`` (V, 3, n²) the
    sg_diffuse artifact's ``transfer`` of every vertex. Lambertian vertices and views
    below the horizon get 0."""
    coefficients = diffuse_transfer.shape[-1]
    out = np.zeros((len(vertices), len(views), 3, coefficients))
    normal = scene.normals[vertices]
    tangent = tangent_from_normal(normal)
    material = scene.vertex_material[vertices]
    for m in np.unique(material):
        p = scene.materials[m]
        if p.model == "lambert":
            continue
        proposal = replace(p, albedo=(0.0, 0.0, 0.0))  # sample the glossy lobe mostly
        rows = np.flatnonzero(material == m)
        wo = to_local(views[None], normal[rows, None], tangent[rows, None])    # (R, K, 3)
        pv, kv = np.nonzero(wo[..., 2] > 0.0)                                 # pairs above
        pj = np.repeat(pv, samples)
        kj = np.repeat(kv, samples)
        wo_j = wo[pj, kj]
        wi = brdf_sampling.sample(wo_j, rng.random((len(pj), 3)), proposal)
        density = brdf_sampling.pdf(wi, wo_j, proposal)
        ok = (wi[:, 2] > 0.0) & (density > 0.0)
        weight = np.zeros(len(pj))
        weight[ok] = glossy(wi[ok], wo_j[ok], p) * wi[ok, 2] / density[ok]
        v = rows[pj]
        direction = _world(wi, normal[v], tangent[v])
        hits = scene.intersect(scene.positions[vertices[v]]
                                      + scene.offset * normal[v], direction)
        at_y = scene.at_hits(diffuse_transfer, hits)                          # (J, 3, n²)
        contribution = (weight / samples)[:, None, None] * at_y
        # the paths of one (vertex, view) pair are consecutive, `samples` each, and the
        # pairs are distinct: a sum over the paths, not an unbuffered np.add.at
        out[rows[pv], kv] += contribution.reshape(len(pv), samples,
                                                  *contribution.shape[1:]).sum(axis=1)
        out[rows] *= np.asarray(p.specular)[None, None, :, None]
    return out


_GRID_BASIS: dict[tuple[bytes, int], np.ndarray] = {}


def grid_basis(directions: np.ndarray, order: int) -> np.ndarray:
    """sh.basis(directions, order) (S, order²), kept for the last grid asked for: a
    chunk's transport calls evaluate it on the same grid every time."""
    key = (np.ascontiguousarray(directions).tobytes(), order)
    if key not in _GRID_BASIS:
        _GRID_BASIS.clear()
        _GRID_BASIS[key] = sh.basis(directions, order)
    return _GRID_BASIS[key]


def on_grid(coefficients: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """Σ_k A[k_view, c, k] Y_k(ω_s): (K, S, 3) from SH vectors ``coefficients`` (K, 3, n²)
    and the basis at the grid ``basis`` (S, n²) (one matrix product)."""
    k, c, n = coefficients.shape
    return (coefficients.reshape(k * c, n) @ basis.T).reshape(k, c, -1).transpose(0, 2, 1)


def glossy_transport(scene: VertexScene, vertices: np.ndarray, directions: np.ndarray,
                     diffuse_transfer: np.ndarray | None, samples: int,
                     rng: np.random.Generator) -> np.ndarray:
    """T (P, 92, S, 3) float32, direct + indirect glossy transport (module docstring) of
    global ``vertices`` (P,) at the :func:`view_directions` views (in that order) and the
    grid ``directions`` (S, 3) (world, unit), in 1/sr: glossy radiance towards view k =
    Σ_s T[p, k, s] L(ω_s) Ω_s. ``diffuse_transfer`` (V, 3, 25): the sg_diffuse artifact's
    ``transfer`` of all vertices (None: the indirect part is left out); ``samples`` paths
    per vertex and view for the indirect part (0: left out). Lambertian vertices get 0.
    The isotropic BRDFs do not need a tangent; an anisotropic one would take the frame
    of ``tangent_from_normal`` here, not the mesh's uv tangent."""
    views = view_directions()
    vertices = np.asarray(vertices, np.int64)
    normal = scene.normals[vertices]
    tangent = tangent_from_normal(normal)
    material = scene.vertex_material[vertices]
    out = np.zeros((len(vertices), len(views), len(directions), 3), np.float32)
    glossy_rows = np.flatnonzero([scene.materials[m].model != "lambert" for m in material])
    if len(glossy_rows) == 0:
        return out
    visible = scene_visibility(scene, vertices[glossy_rows], directions)
    for m in np.unique(material[glossy_rows]):
        sel = material[glossy_rows] == m
        rows = glossy_rows[sel]
        out[rows] = direct_glossy(normal[rows], tangent[rows], scene.materials[m], views,
                                  directions, visible[sel])
    if diffuse_transfer is not None and samples > 0:
        a = indirect_glossy_sh(scene, vertices, views, diffuse_transfer, samples, rng)
        y = grid_basis(directions, int(round(np.sqrt(diffuse_transfer.shape[-1]))))
        for i in range(len(vertices)):  # one vertex at a time: (92, S, 3) temporaries
            out[i] += on_grid(a[i], y)
    return out

"""Method sg's glossy light from per-vertex visibility and the BRDF at the pixel's normal
(``--option normal=visibility``, decision 0046): no fitted transport lobes.

**What a vertex stores** (stage ``sg.visibility``). Its visibility V(ω) over the whole
sphere as an octahedral map (world frame; :func:`octahedral_encode`) of R × R texels,
each the fraction of S × S rays from the vertex (pushed ``offset`` along its normal) that
escape the scene, with its mip pyramid (2 × 2 means, down to 1 × 1) packed level after
level, uint8 (fraction × 255); and its *occluder transfer* O (3, n²): the mean, over the
cosine-distributed rays that hit the scene, of sg.diffuse's SH transfer at the hit —
the diffuse radiance of what blocks the vertex's view is max(0, O · L_sh).

**The pixel.** With f_a the face's barycentrics, n_p = normalise(Σ f_a n_a) and ωo the
direction to the eye, the BRDF × cosine at n_p, ρs f cos, is held by K = 7 Gaussians
of sharpness 2λ: one at the mean μ of the material's one-Gaussian lobe (brdf_lobe.py's
table: μ, λ at c = n_p·ωo) and six on a ring at angle ``RING``/√λ about it, the first
towards n_p (e1 = the part of n_p across μ, e2 = μ × e1). Their weights, per view
elevation c, are fitted to the exact BRDF × cosine (:func:`node_table`: non-negative
least squares over the sphere; 7–8 % relative L2 on γ 40–60 Blinn–Phong, where the one
Gaussian is 24 % off: the lobe is longer in the plane of incidence and cut by the
horizon). Per node k the light L_k = w_k ρs ∫ G_k L (the prefiltered stack) and per
corner the visibility V_ak, the corner's map looked up at the node's direction,
trilinear in the pyramid at the level whose texel spans ``FILTER`` × the node's
σ = 1/√(2λ). Then

    glossy = Σ_a f_a [ Σ_k V_ak L_k + (1 − V̄_a) ρs Σ_k w_k ∫G_k Ī_a ],

V̄_a = Σ_k s_k V_ak the lobe's visible share at corner a (s_k = w_k / Σ w), Ī_a the
corner's occluder radiance: the light the lobe meets where the scene blocks it. The
product of node means V_ak L_k replaces the mean of the product within each node: its
error is the correlation of light and visibility inside a node (decision 0046).

**Bright sources** (decision 0048, pipeline/methods/sg/sources.py): where the map's
light is held by a few small regions, the nodes' light comes from the stack of the map
less those sources, and each source s adds ρs f(ω_s, ωo) max(0, n_p·ω_s) K_s P_s
Σ_a f_a S_a,s, the exact BRDF at its direction, K_s its spread through the pixel's
lobe (sources.spread) and S_a,s what corner a sees of the source, its visibility
filtered by the source's Gaussian (render.source_seen, decision 0049); where it
is blocked, the occluder term above already stands for
what blocks it (its radiance is sg.diffuse's under the whole map).

Nothing here depends on the material: ρs and γ are read at render time, so editing
them re-bakes nothing (the stage's key holds the geometry, the albedos and sg.diffuse).
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np

from pipeline.math import sg
from pipeline.math.brdf import BrdfParams, to_local
from pipeline.math.brdf import glossy as glossy_brdf
from pipeline.methods.sg.brdf_lobe import LOWEST, brdf_lobe, lobe_table
from pipeline.methods.sg.diffuse import cosine_directions
from pipeline.methods.sg.sources import spread
from pipeline.methods.sg.vertex_scene import VertexScene

RING, SPLIT = 1.18, 2.0  # the ring's angle × the lobe's σ, and the nodes' sharpness / λ
NODES = 7
FILTER = 1.0  # the pyramid level whose texel (√(4π)/R_ℓ rad) spans FILTER × a node's σ
FIT_GRID = (91, 180)  # lat-long grid over ωi of node_table's fit (2° steps)


def octahedral_encode(d: np.ndarray) -> np.ndarray:
    """Unit directions (..., 3) -> octahedral coordinates (..., 2) in [−1, 1]²: the upper
    hemisphere (z ≥ 0) on the diamond |u| + |v| ≤ 1, the lower folded over its edges."""
    d = np.asarray(d, np.float64)
    p = d / np.sum(np.abs(d), axis=-1, keepdims=True)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    sx, sy = np.where(x >= 0, 1.0, -1.0), np.where(y >= 0, 1.0, -1.0)
    u = np.where(z < 0, (1.0 - np.abs(y)) * sx, x)
    v = np.where(z < 0, (1.0 - np.abs(x)) * sy, y)
    return np.stack([u, v], axis=-1)


def octahedral_decode(uv: np.ndarray) -> np.ndarray:
    """Octahedral coordinates (..., 2) -> unit directions (..., 3) (inverse of
    :func:`octahedral_encode`)."""
    uv = np.asarray(uv, np.float64)
    u, v = uv[..., 0], uv[..., 1]
    z = 1.0 - np.abs(u) - np.abs(v)
    su, sv = np.where(u >= 0, 1.0, -1.0), np.where(v >= 0, 1.0, -1.0)
    x = np.where(z < 0, (1.0 - np.abs(v)) * su, u)
    y = np.where(z < 0, (1.0 - np.abs(u)) * sv, v)
    d = np.stack([x, y, z], axis=-1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def texel_directions(resolution: int, supersample: int = 1) -> np.ndarray:
    """Directions (R·S, R·S, 3) at the centres of an R × R octahedral map's texels cut
    S × S (row: v, column: u)."""
    n = resolution * supersample
    g = (np.arange(n) + 0.5) / n * 2.0 - 1.0
    u, v = np.meshgrid(g, g, indexing="xy")
    return octahedral_decode(np.stack([u, v], axis=-1))


def level_offsets(resolution: int) -> list[int]:
    """First texel of each pyramid level (R, R/2, …, 1) in the packed layout, and the
    total as the last entry; R a power of two."""
    offsets, size = [0], resolution
    while size >= 1:
        offsets.append(offsets[-1] + size * size)
        size //= 2
    return offsets


def pyramid(base: np.ndarray) -> np.ndarray:
    """Packed pyramids (V, total) uint8 of escape fractions ``base`` (V, R, R) in [0, 1]:
    each level the 2 × 2 means of the one above, every level rounded to /255."""
    levels, level = [], np.asarray(base, np.float64)
    while True:
        levels.append(level.reshape(len(level), -1))
        if level.shape[1] == 1:
            break
        r = level.shape[1] // 2
        level = level.reshape(len(level), r, 2, r, 2).mean(axis=(2, 4))
    return np.rint(np.concatenate(levels, axis=1) * 255.0).astype(np.uint8)


def visibility_maps(scene: VertexScene, vertices: np.ndarray, resolution: int,
                    supersample: int) -> np.ndarray:
    """Escape fractions (P, R, R) of global ``vertices`` (P,): S × S rays per texel from
    the vertex pushed ``scene.offset`` along its normal."""
    d = texel_directions(resolution, supersample).reshape(-1, 3)
    vertices = np.asarray(vertices, np.int64)
    origins = scene.positions[vertices] + scene.offset * scene.normals[vertices]
    hits = scene.intersect(np.repeat(origins, len(d), axis=0), np.tile(d, (len(vertices), 1)))
    escaped = (hits.prim < 0).reshape(len(vertices), resolution, supersample, resolution,
                                      supersample)
    return escaped.mean(axis=(2, 4))


def occluder_transfer(scene: VertexScene, vertices: np.ndarray, transfer: np.ndarray,
                      samples: int, rng: np.random.Generator) -> np.ndarray:
    """O (P, 3, n²): the mean of sg.diffuse's ``transfer`` (V, 3, n²) at the hits of
    ``samples`` cosine-distributed rays of each vertex that hit the scene (zeros where
    none does): O · L_sh is the diffuse radiance of the vertex's occluders, cosine-
    weighted over its hemisphere."""
    vertices = np.asarray(vertices, np.int64)
    normal = scene.normals[vertices]
    directions = cosine_directions(normal, samples, rng).reshape(-1, 3)
    origins = np.repeat(scene.positions[vertices] + scene.offset * normal, samples, axis=0)
    hits = scene.intersect(origins, directions)
    flat = transfer.reshape(len(transfer), -1)
    at = scene.at_hits(flat, hits).reshape(len(vertices), samples, -1)
    blocked = (hits.prim >= 0).reshape(len(vertices), samples)
    count = blocked.sum(axis=1)
    total = np.einsum("ps,psk->pk", blocked.astype(np.float64), np.nan_to_num(at))
    mean = total / np.maximum(count, 1)[:, None]
    return mean.reshape(len(vertices), *transfer.shape[1:])


def orthonormal_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (P, 3) completing unit ``n`` (P, 3) to a right-handed frame,
    continuous except at n_z = −1 (Duff et al. 2017; the kernel's sg_basis)."""
    sign = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    t = np.stack([1.0 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], axis=1)
    s = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], axis=1)
    return t, s


def node_directions(mu: np.ndarray, lam: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """The 7 node directions (P, 7, 3) of lobes mu (P, 3) unit, λ (P,) at unit normals
    (P, 3): μ, then the ring at RING/√λ at angles 2πj/6 from e1, the normal's part
    across μ (where the normal is μ: the first axis of :func:`orthonormal_basis`)."""
    e1 = normal - np.sum(normal * mu, axis=1, keepdims=True) * mu
    length = np.linalg.norm(e1, axis=1, keepdims=True)
    e1 = np.where(length > 1e-6, e1 / np.maximum(length, 1e-30), orthonormal_basis(mu)[0])
    e2 = np.cross(mu, e1)
    angle = RING / np.sqrt(lam)
    phi = 2.0 * math.pi * np.arange(6) / 6.0
    side = np.cos(phi)[None, :, None] * e1[:, None] + np.sin(phi)[None, :, None] * e2[:, None]
    ring = np.cos(angle)[:, None, None] * mu[:, None] + np.sin(angle)[:, None, None] * side
    return np.concatenate([mu[:, None], ring], axis=1)


@cache
def node_table(brdf: BrdfParams) -> np.ndarray:
    """(brdf_lobe.TABLE, 7) float64: per view elevation c_k = k/(TABLE − 1) (c_0 at
    brdf_lobe.LOWEST) the nodes' weights w (1/sr, ρs apart) whose Σ w_k G(ω; c_k, 2λ)
    is the non-negative least-squares fit of ``brdf``'s f(ωi, ωo) cos θi over the sphere
    (the nodes of :func:`node_directions` about the lobe of brdf_lobe.lobe_table)."""
    from scipy.optimize import nnls

    table = lobe_table(brdf)
    directions, omega = sg.latlong_directions(*FIT_GRID)
    wi = directions.reshape(-1, 3)  # local frame: the normal is +z
    root = np.sqrt(omega.ravel())
    up = np.array([[0.0, 0.0, 1.0]])
    out = np.zeros((len(table), NODES))
    for k in range(len(table)):
        c = max(k / (len(table) - 1), LOWEST)
        wo = np.array([[math.sqrt(1.0 - c * c), 0.0, c]])
        f = np.nan_to_num(glossy_brdf(wi, wo, brdf)) * np.maximum(wi[:, 2], 0.0)
        mu, lam, _ = brdf_lobe(table, up, wo)
        nodes = node_directions(mu, lam, up)[0]
        basis = np.exp(SPLIT * lam[0] * (wi @ nodes.T - 1.0)) * root[:, None]
        out[k] = nnls(basis, f * root)[0]
    return out


def node_weights(table: np.ndarray, cosine: np.ndarray) -> np.ndarray:
    """The nodes' weights (P, 7) at view elevations c = n·ωo (P,) (0 where c ≤ 0): the
    :func:`node_table` ``table`` linear in c between entries (the kernel's)."""
    x = np.clip(cosine, 0.0, 1.0) * (len(table) - 1)
    k = np.minimum(np.floor(x).astype(np.int64), len(table) - 2)
    t = (x - k)[:, None]
    return np.where((cosine > 0)[:, None], (1 - t) * table[k] + t * table[k + 1], 0.0)


def lookup(maps: np.ndarray, resolution: int, vertex: np.ndarray, directions: np.ndarray,
           sigma: np.ndarray) -> np.ndarray:
    """Visibility (P,) of ``vertex`` (P,) towards ``directions`` (P, 3) filtered over
    σ (P,) rad: its packed pyramid ``maps`` (V, total) uint8 bilinear on the two levels
    around ℓ = log2(FILTER σ R / √(4π)) (clamped to the pyramid) and linear between
    them; texel indices clamped at the map's edge (the kernel's sg_visibility)."""
    offsets = level_offsets(resolution)
    count = len(offsets) - 1
    level = np.clip(np.log2(np.maximum(FILTER * sigma * resolution / math.sqrt(4 * math.pi),
                                       1e-30)), 0.0, count - 1)
    lo = np.minimum(np.floor(level).astype(np.int64), max(count - 2, 0))
    hi = np.minimum(lo + 1, count - 1)
    t = level - lo
    uv = octahedral_encode(directions)
    out = np.zeros(len(vertex))
    for which, weight in ((lo, 1.0 - t), (hi, t)):
        size = resolution >> which
        x = (uv[:, 0] + 1.0) * 0.5 * size - 0.5
        y = (uv[:, 1] + 1.0) * 0.5 * size - 0.5
        x0, y0 = np.floor(x), np.floor(y)
        fx, fy = x - x0, y - y0
        x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
        value = np.zeros(len(vertex))
        for dx, dy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)),
                          (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
            xi = np.clip(x0 + dx, 0, size - 1)
            yi = np.clip(y0 + dy, 0, size - 1)
            index = np.asarray(offsets, np.int64)[which] + yi * size + xi
            value += w * maps[vertex, index].astype(np.float64) / 255.0
        out += weight * value
    return out


def source_brdf(brdfs: list[BrdfParams], material: np.ndarray, normal: np.ndarray,
                wo: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """f(ω_s, ωo) max(0, n·ω_s) (P, K) (ρs apart) of pixels with unit normals ``normal``
    (P, 3) towards ``wo`` (P, 3) for world ``directions`` (K, 3), each pixel's BRDF
    ``brdfs[material]`` (P,) taken isotropic about n (the frame of
    :func:`orthonormal_basis`, as the kernel's sg_basis)."""
    tangent = orthonormal_basis(normal)[0]
    lo = to_local(wo, normal, tangent)
    out = np.zeros((len(normal), len(directions)))
    for m in np.unique(material):
        sel = np.flatnonzero(material == m)
        for k, d in enumerate(directions):
            li = to_local(np.broadcast_to(d, (len(sel), 3)), normal[sel], tangent[sel])
            f = np.nan_to_num(glossy_brdf(li, lo[sel], brdfs[m]))
            out[sel, k] = f * np.maximum(li[:, 2], 0.0) * (lo[sel, 2] > 0)
    return out


def glossy(maps: np.ndarray, resolution: int, occluder: np.ndarray, corner: np.ndarray,
           bary: np.ndarray, normal: np.ndarray, mu: np.ndarray, lam: np.ndarray,
           weights: np.ndarray, specular: np.ndarray, stack: list[np.ndarray],
           levels: sg.PrefilterLevels, turn: np.ndarray, sources: np.ndarray | None = None,
           brdf_cos: np.ndarray | None = None, seen: np.ndarray | None = None
           ) -> np.ndarray:
    """The module docstring's glossy radiance (P, 3), float64 (the kernel's twin): pixels'
    corners (P, 3), barycentrics (P, 3) and unit blended normals n_p (P, 3), their BRDF
    lobes mu (P, 3) unit world and λ (P,), node ``weights`` (P, 7) (:func:`node_weights`;
    0 where the pixel has no glossy part) and ρs ``specular`` (P, 3); ``occluder`` (V, 3)
    the vertices' occluder radiance Ī, ``turn`` the map's 3×3 map-to-world rotation;
    ``stack`` the residual's where there are ``sources`` (K, 7) (sources.py, map frame),
    ``brdf_cos`` (P, K) their :func:`source_brdf` at the world directions and ``seen``
    (V, K) what each vertex sees of them (render.source_seen)."""
    p = np.flatnonzero(weights.sum(axis=1) > 0)
    out = np.zeros((len(corner), 3))
    if not len(p):
        return out
    if sources is not None and len(sources):
        world = np.asarray(sources[:, :3], np.float64) @ np.asarray(turn, np.float64).T
        for k, source in enumerate(np.asarray(sources, np.float64)):
            toward = np.broadcast_to(world[k], (len(p), 3))
            v = np.einsum("pa,pa->p", bary[p], seen[corner[p], k])
            k_s = spread(mu[p], lam[p], toward, np.full(len(p), source[6]))
            out[p] += (brdf_cos[p, k] * k_s * v)[:, None] * specular[p] * source[3:6]
    nodes = node_directions(mu[p], lam[p], normal[p])                          # (Q, 7, 3)
    lam_n = np.repeat(SPLIT * lam[p], NODES)
    w = weights[p]
    light = sg.env_integral(stack, levels, nodes.reshape(-1, 3) @ turn, lam_n,
                            (w[:, :, None] * specular[p][:, None, :]).reshape(-1, 3)
                            ).reshape(len(p), NODES, 3)
    share = w / w.sum(axis=1, keepdims=True)
    whole = specular[p] * (w.sum(axis=1) * sg.integral(SPLIT * lam[p]))[:, None]  # ρs ∫lobe
    sigma = 1.0 / np.sqrt(lam_n)
    for c in range(3):
        v = lookup(maps, resolution, np.repeat(corner[p, c], NODES), nodes.reshape(-1, 3),
                   sigma).reshape(len(p), NODES)
        seen = np.sum(v * share, axis=1)
        out[p] += bary[p, c, None] * (np.einsum("qk,qkc->qc", v, light)
                                      + (1.0 - seen)[:, None] * whole * occluder[corner[p, c]])
    return out

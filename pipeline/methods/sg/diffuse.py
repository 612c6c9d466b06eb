"""Diffuse transfer of method sg in spherical harmonics (paper 003 §3 "handled in the
reduced 4D domain [Sloan et al. 2002]"): per vertex, the shadowed and interreflected
diffuse light as an order-5 SH vector per channel (pipeline/math/sh.py).

**Meaning.** Outgoing diffuse radiance at vertex v (any view) under distant light L
(world frame) is Σ_k t[v, c, k] L_k with L_k = ∫ L Y_k dω: ``t`` holds the albedo kd/π,
the cosine, the shadows and the interreflections.

**Direct (bounce 0).** t_0[v, c, k] = kd_c/π ∫ V(x_v, ω) max(0, n_v·ω) Y_k(ω) dω. With N
cosine-distributed directions ω_j about n_v (density cos/π):

    t_0[v, c, k] ≈ kd_c / N · Σ_j V(x_v, ω_j) Y_k(ω_j).

The directions are a Fibonacci lattice (u1 = (j + ½)/N, u2 = frac(j·φ)) under Malley's
mapping, shifted per vertex by a random (u1, u2) offset (Cranley–Patterson rotation):
stratified in both coordinates, unbiased, and different at neighbouring vertices so
that the residual error is noise rather than a shared pattern.

**Interreflection (bounce b ≥ 1)**, the standard PRT gather: light leaving the hit y_j of
a blocked ray ω_j is Σ_k t_{b−1}(y_j)[c, k] L_k, t at y blended from the hit face's
vertices (sg_scene.VertexScene.at_hits), so

    t_b[v, c, :] = kd_c / N · Σ_{j blocked} t_{b−1}(y_j)[c, :] = kd_c · (G t_{b−1})[v, c, :],

G the sparse (V × V) gather matrix: row v holds the barycentric weights of v's hits,
each over N. The same rays serve both: an escaping ray feeds t_0, a blocked one a row
of G. The transfer with n bounces is t_0 + … + t_n. Every surface is taken as
Lambertian on its way (the glossy part of the light leaving y is dropped), and a hit
takes the transfer of the hit face's vertices whichever side of the face was hit.

Vertices whose material has kd = 0 get t = 0 and trace nothing.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

from pipeline.math import sh
from pipeline.math.brdf_sampling import frame_to_world
from pipeline.methods.sg.vertex_scene import VertexScene

GOLDEN = 0.5 * (np.sqrt(5.0) - 1.0)  # frac(φ), the Fibonacci lattice's step in u2


def cosine_directions(normal: np.ndarray, samples: int, rng: np.random.Generator
                      ) -> np.ndarray:
    """World directions (P, N, 3), cosine-distributed about each unit ``normal`` (P, 3):
    the module docstring's shifted Fibonacci lattice of N = ``samples`` points."""
    j = np.arange(samples)
    shift = rng.random((len(normal), 2))
    u1 = np.mod((j + 0.5) / samples + shift[:, :1], 1.0)                       # (P, N)
    u2 = np.mod(j * GOLDEN + shift[:, 1:], 1.0)
    r, phi = np.sqrt(u1), 2.0 * np.pi * u2
    local = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(0.0, 1.0 - u1))],
                     axis=-1)
    axis = np.repeat(normal, samples, axis=0)
    return frame_to_world(local.reshape(-1, 3), axis).reshape(len(normal), samples, 3)


def direct_and_gather(scene: VertexScene, vertices: np.ndarray, samples: int,
                      rng: np.random.Generator, order: int = sh.ORDER
                      ) -> tuple[np.ndarray, sparse.csr_matrix]:
    """t_0 (P, 3, order²) of global ``vertices`` (P,) and their rows (P × V, CSR) of the
    gather matrix G (module docstring), ``samples`` rays per vertex. Vertices with
    kd = 0 have zero rows in both."""
    vertices = np.asarray(vertices, np.int64)
    kd = scene.diffuse_albedo()[vertices]                                      # (P, 3)
    lit = np.flatnonzero(kd.max(axis=1) > 0.0)
    direct = np.zeros((len(vertices), 3, order * order))
    if len(lit) == 0:
        return direct, sparse.csr_matrix((len(vertices), len(scene.positions)))
    normal = scene.normals[vertices[lit]]
    directions = cosine_directions(normal, samples, rng)                       # (L, N, 3)
    origins = scene.positions[vertices[lit]] + scene.offset * normal
    hits = scene.intersect(np.repeat(origins, samples, axis=0),
                                  directions.reshape(-1, 3))
    escaped = (hits.prim < 0).reshape(len(lit), samples)
    # Σ_j V_j Y_k(ω_j): the basis only at escaping rays
    y = np.zeros((len(lit), samples, order * order))
    y[escaped] = sh.basis(directions[escaped], order)
    direct[lit] = kd[lit, :, None] * (y.sum(axis=1) / samples)[:, None, :]
    blocked = np.flatnonzero(hits.prim >= 0)
    rows = np.repeat(lit[blocked // samples], 3)
    corners = scene.faces[hits.prim[blocked]].reshape(-1)
    u, v = hits.u[blocked].astype(np.float64), hits.v[blocked].astype(np.float64)
    weights = np.stack([1.0 - u - v, u, v], axis=-1).reshape(-1) / samples
    gather = sparse.csr_matrix((weights, (rows, corners)),
                               shape=(len(vertices), len(scene.positions)))
    gather.sum_duplicates()
    return direct, gather


def bounce(gather: sparse.csr_matrix, kd: np.ndarray, previous: np.ndarray) -> np.ndarray:
    """t_b (V, 3, n²) = kd ⊙ (G t_{b−1}) for the whole scene's gather matrix ``gather``
    (V × V), albedos ``kd`` (V, 3) and t_{b−1} ``previous`` (V, 3, n²)."""
    gathered = gather @ previous.reshape(len(previous), -1)
    return kd[:, :, None] * gathered.reshape(previous.shape)


def transfer(scene: VertexScene, samples: int, bounces: int, rng: np.random.Generator,
             batch: int = 1024, order: int = sh.ORDER) -> np.ndarray:
    """The diffuse transfer t_0 + … + t_bounces (V, 3, order²) of every vertex of the
    scene, traced ``batch`` vertices at a time."""
    return transfers(scene, samples, bounces, rng, batch, order)[0]


def transfers(scene: VertexScene, samples: int, bounces: int, rng: np.random.Generator,
              batch: int = 1024, order: int = sh.ORDER) -> tuple[np.ndarray, np.ndarray]:
    """The diffuse transfer t_0 + … + t_bounces and its direct part t_0, each (V, 3,
    order²), of every vertex of the scene, traced ``batch`` vertices at a time."""
    count = len(scene.positions)
    parts = [direct_and_gather(scene, np.arange(s, min(s + batch, count)), samples, rng,
                               order) for s in range(0, count, batch)]
    direct = np.concatenate([p[0] for p in parts])
    gather = sparse.vstack([p[1] for p in parts], format="csr")
    return with_bounces(gather, scene.diffuse_albedo(), direct, bounces), direct


def with_bounces(gather: sparse.csr_matrix, kd: np.ndarray, direct: np.ndarray,
                 bounces: int) -> np.ndarray:
    """t_0 + … + t_bounces (V, 3, n²) from the direct transfer t_0 ``direct``."""
    total, term = direct.copy(), direct
    for _ in range(bounces):
        term = bounce(gather, kd, term)
        total += term
    return total

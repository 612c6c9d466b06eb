"""Stage ``sg.fit``: per vertex and each of the 92 views, the glossy transport as N ≤ 3
spherical Gaussians (method sg, paper 003 §4). Schema ``sg_lobes`` (the contract in
data_schema/sg/sg_lobes.yaml); chunked by vertex batches of ``sg.fit_batch`` vertices.

Per chunk (one object's vertices [start, end)):

1. **Material.** A Lambert material (or ρs = 0) has no glossy transport: N = 0, w = 0.
2. **Flood fill.** The batch's vertices are ordered breadth-first over the mesh edges
   inside the batch (paper: "flood-fills the mesh"), and processed in that order in
   groups of :data:`GROUP` (one transport call and one batched fit each).
3. **Transport** (:func:`transport`, the one call to swap for the full direct + indirect
   glossy transport): T (G, 92, S, 3) on the lat-long grid ``sg.fit_grid`` — computed
   in the chunk, fitted, never stored.
4. **Fit** (pipeline/methods/sg/support.py, the fast path: each function on the cap that
   holds its energy). Each function is divided by its norm ‖T‖ = (Σ Ω ‖T‖²)^½ before
   fitting (weights scaled back after), so the energy is the *relative* L² error and the
   coupling weights mean the same for bright and dim views. N per vertex: the smallest
   of 1 … ``sg.fit_max_lobes`` whose vertex error — (Σ_views E_v / Σ_views ‖T_v‖²)^½
   over the vertex's views with data, E_v the least-squares fit's squared L² error on
   the whole grid (before the integral scaling of ``sg.fit_match_integral``) — is ≤
   ``sg.fit_tolerance``; else the largest.
5. **Correspondence and the paper's energy.** The vertex's slots are aligned over its
   views (pipeline/methods/sg/coherence.py ``align_views``), then permuted as a whole to
   best match its already processed mesh neighbours; then every view is refitted from
   its current lobes with the full energy of paper 003 eq. 6 — data, mean alignment
   (β = ``sg.fit_mean_weight``) and σ alignment (γ = ``sg.fit_sigma_weight``) to the
   averages of its neighbouring views' lobes, spatial term (δ =
   ``sg.fit_spatial_weight``) over the already processed neighbour vertices at the same
   view: one block-Jacobi sweep (pipeline/methods/sg/fit.py).
6. **Views without data** (below the horizon, or T ≡ 0): w = 0 and μ, λ filled from
   the neighbouring views (``fill_views``); slots at or beyond the vertex's N: w = 0,
   μ and λ of slot 0; a vertex with no data at all: N = 0, μ the mirror direction of
   each view about the normal, σ = :data:`DEFAULT_SIGMA`.
7. **Flips and relaxation.** Flips (``sg_coherence.count_flips``) are counted over the
   batch's mesh edges and view-graph edges, then ``sg.fit_relaxation_sweeps`` sweeps of
   ``sg_coherence.relax`` relabel slots, and they are counted again. Edges that cross
   batches are neither counted nor relaxed (their vertices are fitted by different
   chunks, possibly at the same time).

Errors (``error``, relative L² per vertex and view on the whole grid, −1 where T ≡ 0:
the runner refuses NaN) are those of the stored lobes. Stored are only the slots a
vertex needs (:func:`pack_slots`; schema version 2): 2.6 kB per vertex at N = 1, as paper
003 counts (7 floats per Gaussian and view), none on a diffuse material.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

import numpy as np

from pipeline.device.bake_tracer import PARAM, bake_tracer
from pipeline.engine.stage import AssembleContext, Chunk, ChunkContext, Layout, Output
from pipeline.errors import PrtError
from pipeline.math import sg
from pipeline.math.brdf import BrdfParams
from pipeline.methods.sg import coherence as sg_coherence
from pipeline.methods.sg import fit as sg_fit
from pipeline.methods.sg import support as sg_support
from pipeline.methods.sg.fit import FitOptions, FitTargets, SGFit
from pipeline.methods.sg.transport import glossy_transport, view_directions
from pipeline.methods.sg.vertex_scene import UNSEEN, VertexScene
from pipeline.stages.geometry import traced_geometry

GROUP = 4             # vertices fitted together (the flood fill's step; 4 × 92 functions)
DEFAULT_SIGMA = 0.5   # radians: σ of the lobes of a vertex without glossy data
FIELDS = 7            # w_r, w_g, w_b, μ_x, μ_y, μ_z, λ
MAX_LOBES = 3         # the schema's lobe slots
VERTEX_CHUNK = 1024   # zarr chunk length along vertices
# the fast path's LM settings: float32 fields, stop when a step gains < 3e-4 of the
# energy (benchmarks/sg/fit.py: at 1e-4, median error equal to 1e-5 of the
# float64, 1e-6 fits' on real transport; what makes the difference is fewer LM steps).
# 1e-4 -> 3e-4 on 32 bunny vertices (one process, 3 rounds): fit 0.097 -> 0.088 s per
# vertex, error mean 0.498 -> 0.500, median 0.3303 -> 0.3306 (1e-3: 0.082 s, 0.505)
FIELDS_DTYPE = "float32"
STOP = 3e-4
# each function's cap holds all but 3 % of its energy, not 1e-4: the indirect glossy
# part (a noisy, ringing SH estimate: a median 1.7 % of the energy on bunny_sg) spread
# the caps over 4,813 of 6,050 directions (median) and the fits cannot follow it anyway.
# Measured on 16 bunny_sg vertices (studies/sg_fit_flips.py set-up, one run): fit
# 0.81-0.89 -> 0.56-0.59 s per vertex, error on the whole grid median 0.182 -> 0.188,
# mean 0.242 -> 0.243
SUPPORT = sg_support.SupportOptions(outside_energy=0.03)
NO_DATA = -1.0        # the error of a view without transport (T ≡ 0)
SHAPE_KEYS = ("specular", "gamma", "alpha_ratio", "cxy", "cz", "f0", "ior")


def grid(params: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """The fit's sphere grid: directions (S, 3) and solid angles (S,) of the lat-long
    grid ``sg.fit_grid`` = [rows, columns] (pipeline/math/sg.py latlong_directions)."""
    rows, cols = (int(n) for n in params["sg.fit_grid"])
    if rows < 3 or cols < 4:
        raise PrtError("sg.fit_grid", f"{[rows, cols]}: needs at least 3 rows and 4 columns")
    d, omega = sg.latlong_directions(rows, cols)
    return d.reshape(-1, 3), omega.ravel()


def settings(params: dict[str, Any]) -> dict[str, Any]:
    """The fit's params, checked."""
    tolerance = float(params["sg.fit_tolerance"])
    max_lobes = int(params["sg.fit_max_lobes"])
    if not tolerance > 0:
        raise PrtError("sg.fit_tolerance", f"{tolerance}: a relative L2 error must be > 0")
    if not 1 <= max_lobes <= MAX_LOBES:
        raise PrtError("sg.fit_max_lobes", f"{max_lobes}: must lie in 1..{MAX_LOBES}")
    weights = {k: float(params[f"sg.fit_{k}_weight"]) for k in ("mean", "sigma", "spatial")}
    for k, w in weights.items():
        if w < 0:
            raise PrtError(f"sg.fit_{k}_weight", f"{w}: must be ≥ 0")
    match = params["sg.fit_match_integral"]
    if not isinstance(match, bool):
        raise PrtError("sg.fit_match_integral", f"{match!r}: expected true or false")
    return {"tolerance": tolerance, "max_lobes": max_lobes, **weights,
            "sweeps": int(params["sg.fit_relaxation_sweeps"]), "match_integral": match}


def material_brdf(ctx: AssembleContext, name: str) -> BrdfParams | None:
    """The glossy BRDF of material ``name`` from the scene sections, or None for a
    material without a glossy part (Lambert, or ρs = 0)."""
    model = ctx.scene.get(f"materials.{name}.model")
    if model in (None, "lambert"):
        return None
    given = {k: ctx.scene.get(f"materials.{name}.{k}") for k in SHAPE_KEYS}
    specular = given["specular"]
    specular = (specular,) * 3 if np.isscalar(specular) else tuple(specular)
    given = {k: v for k, v in given.items() if v is not None}
    brdf = BrdfParams.from_material(model, (0.0, 0.0, 0.0), {**given, "specular": specular})
    return brdf if max(brdf.specular) > 0 else None


def tangents(normals: np.ndarray) -> np.ndarray:
    """A unit tangent (P, 3) per unit normal: n × (+y, or +x where n is near ±y). The
    transport's local frame needs one; isotropic BRDFs do not depend on it."""
    helper = np.where(np.abs(normals[:, 1:2]) < 0.9, [0.0, 1.0, 0.0], [1.0, 0.0, 0.0])
    t = np.cross(normals, helper)
    return t / np.linalg.norm(t, axis=1, keepdims=True)


def flood_order(count: int, edges: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """Breadth-first order (count,) of local vertices over ``edges`` (E, 2) (each
    component from its lowest index) and each vertex's neighbours."""
    neighbours: list[list[int]] = [[] for _ in range(count)]
    for a, b in edges:
        neighbours[a].append(b)
        neighbours[b].append(a)
    nbs = [np.unique(np.asarray(n, np.int64)) for n in neighbours]
    seen = np.zeros(count, bool)
    order = []
    for root in range(count):
        if seen[root]:
            continue
        seen[root] = True
        queue = [root]
        while queue:
            v = queue.pop(0)
            order.append(v)
            for u in nbs[v]:
                if not seen[u]:
                    seen[u] = True
                    queue.append(int(u))
    return np.asarray(order, np.int64), nbs


def batch_edges(faces: np.ndarray, start: int, end: int) -> np.ndarray:
    """Mesh edges (E, 2) with both ends in the global vertex range [start, end), as
    local indices, each once."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = e[((e >= start) & (e < end)).all(axis=1)] - start
    return np.unique(np.sort(e, axis=1), axis=0)


def mirror(views: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Mirror directions (P, V, 3) of the views about each unit normal: 2(n·v)n − v."""
    nv = normals @ views.T
    return 2 * nv[..., None] * normals[:, None] - views[None]


class Lobes:
    """The chunk's lobes under construction, P vertices × V views × L slots."""

    def __init__(self, p: int, v: int, mirrors: np.ndarray):
        self.mean = np.repeat(mirrors[:, :, None], MAX_LOBES, axis=2)   # (P, V, L, 3)
        self.sharpness = np.full((p, v, MAX_LOBES), sg.sharpness(DEFAULT_SIGMA))
        self.weight = np.zeros((p, v, MAX_LOBES, 3))
        self.error = np.full((p, v), NO_DATA)
        self.count = np.zeros(p, np.int64)
        self.active = np.zeros((p, v), bool)
        self.converged = np.ones((p, v), bool)

    def permute(self, perm: np.ndarray) -> None:
        """Relabel every vertex's slots: slot k of (p, v) takes slot perm[p, v, k]
        (perm (P, V, L))."""
        for name in ("mean", "sharpness", "weight"):
            a = getattr(self, name)
            setattr(self, name, np.take_along_axis(
                a, perm.reshape(perm.shape + (1,) * (a.ndim - 3)), axis=2))

    def relabel(self, p: int, perm: np.ndarray) -> None:
        """Relabel vertex p's slots: perm (V, L)."""
        for a in (self.mean, self.sharpness, self.weight):
            a[p] = np.take_along_axis(a[p], perm.reshape(perm.shape + (1,) * (a.ndim - 3)),
                                      axis=1)


def _fit(values: np.ndarray, directions: np.ndarray, omega: np.ndarray, options: FitOptions,
         default_mean: np.ndarray, match_integral: bool, cap: tuple[np.ndarray, np.ndarray],
         targets: FitTargets | None = None, start: SGFit | None = None
         ) -> tuple[SGFit, np.ndarray, SGFit, np.ndarray]:
    """Fast-path fit of normalised functions (F, S, 3) on their support ``cap``
    (sg_support.caps): the least-squares fit and its relative error (F,), then the fit
    as stored — weights scaled to each function's integral if ``match_integral``
    (sg_fit.integral_matched) — and its error. N is chosen by the least-squares error
    (what N lobes can represent; the scaling raises the L² error of a function whose
    integral the lobes miss, up to 4× — not something another lobe fixes), the next N's
    grown start is made from the least-squares lobes, the stored error is the stored
    lobes'."""
    fitted, _ = sg_support.fit(directions, omega, values, options, targets, default_mean,
                               start, SUPPORT, cap)
    if not match_integral:
        error = sg_support.relative_error(directions, omega, values, fitted)
        return fitted, error, fitted, error
    stored = sg_fit.integral_matched(fitted, values, omega)
    error, stored_error = sg_support.relative_errors(directions, omega, values, fitted,
                                                     [fitted.weight, stored.weight])
    return fitted, error, stored, stored_error


def fit_group(lobes: Lobes, group: np.ndarray, t: np.ndarray, views: np.ndarray,
              view_nbs: list[np.ndarray], vertex_nbs: list[np.ndarray], done: np.ndarray,
              directions: np.ndarray, omega: np.ndarray, cfg: dict[str, Any]) -> None:
    """Fit the vertices ``group`` (G,) (local indices) from their transport t
    (G, V, S, 3) into ``lobes`` (module docstring, steps 4–6); ``done`` (P,) marks the
    vertices processed before (their lobes are final but for the relaxation)."""
    strength = np.einsum("gvsc,s->gv", t.astype(np.float64) ** 2, omega)
    active = strength > 0
    lobes.active[group] = active
    g_idx, v_idx = np.nonzero(active)
    if not len(g_idx):
        return
    norm = np.sqrt(strength[g_idx, v_idx])
    values = t[g_idx, v_idx] / norm[:, None, None].astype(np.float32)   # float32
    default = lobes.mean[group[g_idx], v_idx, 0]
    inside, top = sg_support.caps(directions, omega, values, SUPPORT)  # once: every fit's
    need = np.ones(len(group), bool)
    result = previous = None   # the last fit and the functions it covered (mask)
    for n in range(1, cfg["max_lobes"] + 1):
        sel = need[g_idx]
        start = None if result is None else sg_fit.grown_start(
            directions, omega, values[sel], result.subset(sel[previous]), default[sel])
        result, fit_error, stored, err = _fit(
            values[sel], directions, omega,
            FitOptions(lobes=n, fields=FIELDS_DTYPE, tolerance=STOP), default[sel],
            cfg["match_integral"], (inside[sel], top[sel]), start=start)
        previous = sel
        gs, vs = group[g_idx[sel]], v_idx[sel]
        lobes.count[gs] = n
        lobes.mean[gs, vs, :n] = stored.mean
        lobes.sharpness[gs, vs, :n] = stored.sharpness
        lobes.weight[gs, vs] = 0.0
        lobes.weight[gs, vs, :n] = stored.weight * norm[sel, None, None]
        lobes.error[gs, vs] = err
        lobes.converged[gs, vs] = stored.converged
        squared = np.bincount(g_idx[sel], fit_error ** 2 * strength[g_idx[sel], vs],
                              len(group))
        total = np.bincount(g_idx[sel], strength[g_idx[sel], vs], len(group))
        with np.errstate(invalid="ignore", divide="ignore"):
            need &= np.sqrt(squared / total) > cfg["tolerance"]
        if not need.any():
            break
    # correspondence: over the views, then as a whole against processed neighbours
    for g, p in enumerate(group):
        n = int(lobes.count[p])
        if n < 2:
            continue
        perm = sg_coherence.align_views(lobes.mean[p, :, :n], active[g], strength[g],
                                        view_nbs)
        full = np.tile(np.arange(MAX_LOBES), (len(views), 1))
        full[:, :n] = perm
        lobes.relabel(p, full)
        best = sg_coherence.vertex_permutation(lobes.mean[p, :, :n], [
            (lobes.mean[q, :, :n], active[g] & lobes.active[q]) for q in vertex_nbs[p]
            if done[q] and lobes.count[q] >= n])
        if best is not None:
            full[:, :n] = best
            lobes.relabel(p, full)
    _coupled_refit(lobes, group, g_idx, v_idx, values, (inside, top), norm, view_nbs,
                   vertex_nbs, done, directions, omega, cfg)
    for g, p in enumerate(group):
        n = max(int(lobes.count[p]), 1)
        mean, lam = sg_coherence.fill_views(lobes.mean[p, :, :n], lobes.sharpness[p, :, :n],
                                            active[g], view_nbs, lobes.mean[p, :, 0],
                                            sg.sharpness(DEFAULT_SIGMA))
        lobes.mean[p, :, :n], lobes.sharpness[p, :, :n] = mean, lam
        lobes.mean[p, :, n:] = mean[:, :1]
        lobes.sharpness[p, :, n:] = lam[:, :1]
        lobes.weight[p, ~active[g]] = 0.0
        if not active[g].any():
            lobes.count[p] = 0


def _coupled_refit(lobes: Lobes, group: np.ndarray, g_idx: np.ndarray, v_idx: np.ndarray,
                   values: np.ndarray, cap: tuple[np.ndarray, np.ndarray], norm: np.ndarray,
                   view_nbs: list[np.ndarray],
                   vertex_nbs: list[np.ndarray], done: np.ndarray, directions: np.ndarray,
                   omega: np.ndarray, cfg: dict[str, Any]) -> None:
    """One block-Jacobi sweep of the paper's full energy (module docstring, step 5)."""
    if cfg["mean"] == 0 and cfg["sigma"] == 0 and cfg["spatial"] == 0:
        return
    ps = group[g_idx]
    for n in range(1, cfg["max_lobes"] + 1):
        sel = np.flatnonzero(lobes.count[ps] == n)
        if not len(sel):
            continue
        p, v = ps[sel], v_idx[sel]
        target_mean = np.empty((len(sel), n, 3))
        target_sigma = np.empty((len(sel), n))
        for i, (pi, vi) in enumerate(zip(p, v, strict=True)):
            nbs = view_nbs[vi][lobes.active[pi, view_nbs[vi]]]
            nbs = nbs if len(nbs) else np.array([vi])
            m = lobes.mean[pi, nbs, :n].sum(axis=0)
            target_mean[i] = m / np.maximum(np.linalg.norm(m, axis=-1, keepdims=True), 1e-300)
            target_sigma[i] = sg.sigma_of(lobes.sharpness[pi, nbs, :n]).mean(axis=0)
        width = max([len(vertex_nbs[q]) for q in p] + [1])
        neighbour = np.zeros((len(sel), width, n, 3))  # zero rows: no constraint
        for i, (pi, vi) in enumerate(zip(p, v, strict=True)):
            qs = [q for q in vertex_nbs[pi] if done[q] and lobes.count[q] >= n
                  and lobes.active[q, vi]]
            if qs:
                neighbour[i, :len(qs)] = lobes.mean[qs, vi, :n]
        start = SGFit(lobes.mean[p, v, :n], lobes.sharpness[p, v, :n],
                      lobes.weight[p, v, :n] / norm[sel, None, None], np.zeros(len(sel)),
                      np.zeros(len(sel), np.int64), np.ones(len(sel), bool))
        options = FitOptions(lobes=n, mean_weight=cfg["mean"], sigma_weight=cfg["sigma"],
                             spatial_weight=cfg["spatial"], fields=FIELDS_DTYPE, tolerance=STOP)
        _, _, result, err = _fit(values[sel], directions, omega, options,
                                 lobes.mean[p, v, 0], cfg["match_integral"],
                                 (cap[0][sel], cap[1][sel]),
                                 FitTargets(target_mean, target_sigma, neighbour), start)
        lobes.mean[p, v, :n] = result.mean
        lobes.sharpness[p, v, :n] = result.sharpness
        lobes.weight[p, v, :n] = result.weight * norm[sel, None, None]
        lobes.error[p, v] = err
        lobes.converged[p, v] = result.converged


def fit_batch(transport: Callable[[np.ndarray], np.ndarray] | None, normals: np.ndarray,
              edges: np.ndarray, brdf: BrdfParams | None, directions: np.ndarray,
              omega: np.ndarray, cfg: dict[str, Any]) -> tuple[Lobes, dict[str, Any]]:
    """Steps 2–7 of the module docstring for one batch of P vertices: ``transport``
    maps local vertex indices (G,) to their glossy transport T (G, 92, S, 3) on the grid
    ``directions`` (the stage: sg_transport.glossy_transport, direct + indirect), unit
    normals (P, 3), mesh ``edges`` (E, 2) among them (local indices), the glossy BRDF
    (None: no glossy part). Returns the lobes and the chunk's report."""
    views = view_directions()
    lobes = Lobes(len(normals), len(views), mirror(views, normals))
    order, vertex_nbs = flood_order(len(normals), edges)
    view_nbs = sg_coherence.view_neighbours(views)
    flips_before = flips_after = {}
    relaxed = 0
    if brdf is not None:
        done = np.zeros(len(normals), bool)
        for g0 in range(0, len(order), GROUP):
            group = order[g0:g0 + GROUP]
            t = transport(group)
            fit_group(lobes, group, t, views, view_nbs, vertex_nbs, done, directions,
                      omega, cfg)
            done[group] = True
        flips_before = sg_coherence.count_flips(lobes.mean, lobes.active, lobes.count,
                                                edges, view_nbs)
        perm, relaxed = sg_coherence.relax(lobes.mean, lobes.active, lobes.count, vertex_nbs,
                                           view_nbs, order, cfg["sweeps"])
        lobes.permute(perm)
        flips_after = sg_coherence.count_flips(lobes.mean, lobes.active, lobes.count,
                                               edges, view_nbs)
    report = {"vertices": len(normals), "glossy": brdf is not None,
              "counts": np.bincount(lobes.count, minlength=MAX_LOBES + 1).tolist(),
              "not_converged": int((~lobes.converged & lobes.active).sum()),
              "flips_before": flips_before, "flips_after": flips_after,
              "relaxation_sweeps": relaxed, "edges": len(edges), "load": os.getloadavg()[0]}
    return lobes, report


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    geometry = ctx.inputs["geometry"]
    attrs = geometry.attrs
    obj = attrs["object_names"].index(ctx.chunk.object)
    first = int(geometry.read("object_ranges")[obj, 0])
    start, end = (first + s for s in ctx.chunk.span)
    material = attrs["material_names"][int(geometry.read("object_material")[obj])]
    cfg = settings(ctx.params)
    directions, omega = grid(ctx.params)
    brdf = material_brdf(ctx, material)
    transport = chunk_transport(ctx, start, directions) if brdf is not None else None
    normals = geometry.read("normals")[start:end].astype(np.float64)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    lobes, report = fit_batch(transport, normals,
                              batch_edges(geometry.read("faces"), start, end), brdf,
                              directions, omega, cfg)
    ctx.meta.update(report)
    dense = np.concatenate([lobes.weight, lobes.mean, lobes.sharpness[..., None]], axis=-1)
    rows, first = pack_slots(dense.astype(np.float32), stored_slots(lobes.count,
                                                                    brdf is not None))
    return {"lobes": rows, "first": first, "count": lobes.count.astype(np.uint8),
            "error": lobes.error.astype(np.float32)}


def stored_slots(count: np.ndarray, glossy: bool) -> np.ndarray:
    """Slots stored per vertex (P,) of lobe counts ``count`` (P,) (data_schema/
    sg_lobes.yaml): the count, at least 1 on a glossy material, none otherwise."""
    return np.maximum(count, 1).astype(np.int64) if glossy else np.zeros(len(count), np.int64)


def pack_slots(dense: np.ndarray, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The stored form of lobes ``dense`` (P, views, L, 7): rows (R, views, 7), the first
    ``slots`` (P,) slots of each vertex, vertex by vertex, and each vertex's first row
    (P,) int64."""
    keep = np.arange(dense.shape[2]) < np.asarray(slots)[:, None]           # (P, L)
    first = np.concatenate([[0], np.cumsum(slots)[:-1]]).astype(np.int64)
    return np.ascontiguousarray(np.swapaxes(dense, 1, 2)[keep]), first


def unpack_slots(rows: np.ndarray, first: np.ndarray, slots: np.ndarray,
                 max_slots: int = MAX_LOBES) -> np.ndarray:
    """Lobes (P, views, ``max_slots``, 7) from stored ``rows`` (R, views, 7), each
    vertex's ``first`` row (P,) and ``slots`` (P,) (:func:`pack_slots`' inverse): a
    slot beyond the stored ones reads as slot 0's μ and λ with w = 0; a vertex with
    none as w = 0, μ = +z, λ = 1."""
    p, (views, fields) = len(first), rows.shape[1:]
    dense = np.zeros((p, views, max_slots, fields), rows.dtype)
    dense[..., 5] = dense[..., 6] = 1.0
    has_any = np.asarray(slots) > 0
    for s in range(max_slots):
        stored = slots > s
        dense[has_any, :, s] = rows[np.where(stored, first + s, first)[has_any]]
        dense[has_any & ~stored, :, s, 0:3] = 0.0
    return dense


def slot_counts(first: np.ndarray, rows: int) -> np.ndarray:
    """Stored slots per vertex (P,) from the vertices' ``first`` rows (P,) of ``rows``."""
    return np.diff(np.append(first, rows))


def chunk_transport(ctx: ChunkContext, start: int, directions: np.ndarray
                    ) -> Callable[[np.ndarray], np.ndarray]:
    """The chunk's transport function: local vertex indices (G,) (global ``start`` +
    local) to their glossy transport T (G, 92, S, 3) on ``directions`` (S, 3), direct +
    indirect (sg_transport.glossy_transport, ``sg.indirect_samples`` paths per view,
    drawn from ``ctx.rng``)."""
    scene = transport_scene(ctx)
    diffuse = ctx.inputs["sg.diffuse"].read("transfer")
    samples = int(ctx.params["sg.indirect_samples"])

    def transport(local: np.ndarray) -> np.ndarray:
        return glossy_transport(scene, start + local, directions, diffuse, samples, ctx.rng)

    return transport


def transport_scene(ctx: ChunkContext) -> VertexScene:
    """The scene at its vertices for the transport, its rays traced as ``bake.device``
    says (pipeline/device/bake_tracer.py; Embree's: the scene ``traced_geometry`` keeps
    per process). Materials: the glossy BRDFs of the declared
    sections (:func:`material_brdf`), black Lambert for the others: the transport reads
    only its own vertices' glossy part (the light a path finds at a hit is the
    sg.diffuse transfer, which holds the hit's albedo)."""
    geometry = ctx.inputs["geometry"]
    arrays = {name: geometry.read(name) for name in
              ("vertices", "normals", "faces", "object_ranges", "object_material")}
    tracer = bake_tracer(ctx.params[PARAM], geometry.record["key"], arrays["vertices"],
                         arrays["faces"], traced_geometry(geometry).tracer)
    materials = [material_brdf(ctx, name) or UNSEEN
                 for name in geometry.attrs["material_names"]]
    return VertexScene.from_arrays(arrays, materials, tracer)


def layout(ctx: AssembleContext) -> Layout:
    return Layout(sizes={"vertex_chunk": VERTEX_CHUNK, "slot_chunk": VERTEX_CHUNK})


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    """Attributes: the contract's and the totals of the chunks' reports."""
    rows, cols = (int(n) for n in ctx.params["sg.fit_grid"])

    def total(name: str, key: str) -> int:
        return int(sum(m[name].get(key, 0) for _, m in metas))

    kinds = ("vertex_flips", "vertex_flips_5deg", "vertex_pairs", "view_flips",
             "view_flips_5deg", "view_pairs")
    counts = np.sum([m["counts"] for _, m in metas], axis=0)
    cfg = settings(ctx.params)
    return Output(
        attrs={"max_lobes": MAX_LOBES, "tolerance": cfg["tolerance"],
               "lobes_allowed": cfg["max_lobes"],
               "flips_before_relaxation": {k: total("flips_before", k) for k in kinds},
               "flips_after_relaxation": {k: total("flips_after", k) for k in kinds},
               "grid": {"kind": "latlong", "rows": rows, "columns": cols,
                        "directions": rows * cols},
               "count_histogram": [int(c) for c in counts],
               "not_converged": int(sum(m["not_converged"] for _, m in metas)),
               "edges_within_batches": int(sum(m["edges"] for _, m in metas)),
               "transport": "direct glossy (BRDF x visibility x cos) + indirect glossy "
                            "(glossy-to-diffuse paths through the sg.diffuse transfer)",
               "indirect_samples": int(ctx.params["sg.indirect_samples"]),
               "weights": {"mean": cfg["mean"], "sigma": cfg["sigma"],
                           "spatial": cfg["spatial"]}},
        arrays={"views": view_directions()})

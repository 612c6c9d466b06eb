"""Study (issue 42, item 4): where method sg's glossy error comes from, each source
measured in isolation and noise free, on a subset of the glossy object's pixels.

Run from the project root:
    python studies/sg_glossy_error.py [--scenes bunny_sg dragon_sg] [--size 64]
        [--pixels 160] [--fine 181 360] [--images]
Writes benchmarks/results/sg_glossy_error.json (and, with --images, per-pixel error PNGs
benchmarks/results/sg_glossy_error_<scene>_<stage>.png: |ΔE|/mean(E0), white = 1).

Each scene is baked up to sg.diffuse and sg.env_prefilter in .prt/study_<scene> (once).
Camera rays at ``--size``² pick ``--pixels`` random pixels on glossy objects (0: all).
Every quantity is computed deterministically (no Monte-Carlo reference):

* **R(x, n, ωo)**, the exact glossy radiance of a point x with shading normal n towards
  ωo: quadrature on a fine lat-long grid ``--fine`` (1° steps) of ρs f_F f_E cos · L_in,
  L_in the environment (prefiltered at 0.6 grid steps, so that point samples do not
  alias the map's small sources) where the ray from x escapes, and the diffuse radiance
  the method holds at the hit y (the sg.diffuse SH transfer against the map's SH,
  clamped at 0, blended over the hit face) where it hits: exactly what the lobes of
  the method stand for (direct + glossy-to-diffuse indirect).
* **E0** = R at the pixel's hit point (blended normal) and view: the truth.
* **(a) per-vertex sampling**: Σ_a f_a R(v_a, ωo) — the exact transport of the face's
  3 vertices at the pixel's own view, blended by the barycentrics.
* **(c) view interpolation**: Σ_a f_a Σ_b β_b R(v_a, view_b), the 3 stored views around
  ωo blended by the renderer's gnomonic weights (exact transport; against (a)).
* **(b) the lobe fit**: the stage's transport on its fit grid (55 × 110, indirect by
  64 BRDF paths per view), normalised, fitted by the stage's own fit
  (stages/fit.py ``_fit``: support caps, LM settings, integral-matched weights), the
  fitted lobes integrated exactly (fine grid) against the map; at the pixel's own
  view, against (a). Split into the tabulation on the fit grid (and its Monte-Carlo
  indirect part) and the fit proper. N = 1, 2, 3 and the stage's rule (tolerance 0.7
  over the vertex's functions here).
* **(c′) lobe blending**: the renderer blends lobe parameters (w, μ, log λ) over the
  3 vertices × 3 views; against the same fitted lobes' radiances blended (N = 1).
* **(d) prefiltered lookup**: the blended lobe's integral by the stack lookup
  (sg.env_integral) against its quadrature over the map's own samples.
* **chain**: the method's pixel as built here (N = 1 lobes blended, stack lookup)
  against E0; and the indirect part's share of E0, and mean ratios (bias) per stage.

* **turned** (decision 0039): the fitted lobes turned towards the pixel's normal before
  blending — every lobe by the rotation taking the vertex's mirror direction
  reflect(ωo, n_v) to the pixel's (``turned_*``; ``per_view``: each stored view's own),
  or by G(r_v; μ, λ) of that angle, the renderer's ``normal=pixel``
  (``turned_aligned_chain_method_N1_vs_E0``).

* **the BRDF at the pixel's normal** (decision 0042): U_p and U_a, the glossy radiance
  under the map alone (no visibility, no indirect light) at the pixel's normal and at
  each corner's, exact (quadrature), by the renderer's fitted BRDF lobe (brdf_lobe.py's
  table, stack lookup; ``U_p_table_vs_exact``) or by the spherical warp of Wang et al.
  2009 (``U_p_warp_vs_exact``); with F_a what corner a holds at the pixel's view (the
  exact transport, the renderer's N = 1 lobes blended over its views, or the N-lobe
  fits' radiances blended over the views), F = Σ f_a F_a, U = Σ f_a U_a: ``ratio_*``
  U_p F/U, ``additive_*`` F + U_p − U, ``hybrid_*`` F + min(1, F/U)(U_p − U) (the
  renderer's ``normal=ratio``), each against E0.

``--quick`` leaves out the denser-sampling rows; ``--state PREFIX`` pickles the fitted
lobes and pixels (PREFIX_<scene>.pkl) to try render-time variants offline.

Errors: relative RMSE over the selected pixels and channels, ‖E − E_ref‖ / ‖E0‖ (so
stages add up in quadrature where independent), with the stage's mean ratio
ΣE / ΣE_ref. What the method's relaxation and view coupling change is not
modelled (they move lobes by small alignment terms). One BLAS thread.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks.fixtures import baked  # noqa: E402
from pipeline.device.threads import one_blas_thread  # noqa: E402
from pipeline.engine.store import open_artifact  # noqa: E402
from pipeline.images import read_environment, write_png  # noqa: E402
from pipeline.math import sg, sh  # noqa: E402
from pipeline.math.brdf import glossy, to_local  # noqa: E402
from pipeline.math.camera import camera_rays  # noqa: E402
from pipeline.math.frames import tangent_from_normal  # noqa: E402
from pipeline.methods.sg import fit as sg_fit  # noqa: E402
from pipeline.methods.sg import support as sg_support  # noqa: E402
from pipeline.methods.sg.brdf_lobe import brdf_lobe, lobe_table  # noqa: E402
from pipeline.methods.sg.prefilter import prefilter  # noqa: E402
from pipeline.methods.sg.render import view_triangles, view_triangulation  # noqa: E402
from pipeline.methods.sg.stages import fit as stage  # noqa: E402
from pipeline.methods.sg.stages.env_prefilter import read_stack  # noqa: E402
from pipeline.methods.sg.transport import (  # noqa: E402
    direct_glossy,
    grid_basis,
    indirect_glossy_sh,
    on_grid,
    scene_visibility,
    view_directions,
)
from pipeline.methods.sg.vertex_scene import VertexScene  # noqa: E402

OUT = ROOT / "benchmarks" / "results"
MAX_N = 3


def blurred_map(rgb: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """The map convolved by a normalised SG of σ = 0.6 grid steps, sampled at the
    lat-long grid (rows, cols) (sg.latlong_directions' directions), (rows·cols, 3)."""
    sigma = 0.6 * math.pi / (rows - 1)
    levels = sg.PrefilterLevels(sigma, 2.0, ((rows, cols),))
    return prefilter(rgb, levels)[0].reshape(-1, 3)


class Truth:
    """Exact glossy radiance R(x, n, views) on the fine grid (module docstring)."""

    def __init__(self, scene: VertexScene, brdf, env_fine: np.ndarray, dirs: np.ndarray,
                 omega: np.ndarray, vertex_diffuse: np.ndarray):
        self.scene, self.brdf, self.env, self.dirs, self.omega = scene, brdf, env_fine, dirs, omega
        self.vertex_diffuse = vertex_diffuse
        self.specular = np.asarray(brdf.specular)

    def incoming(self, x: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Above-horizon grid indices, L_in there (direct | indirect), and a miss mask."""
        s = np.flatnonzero(self.dirs @ n > 0)
        d = self.dirs[s]
        hits = self.scene.intersect(np.repeat((x + self.scene.offset * n)[None], len(s), 0), d)
        miss = hits.prim < 0
        lin = self.scene.at_hits(self.vertex_diffuse, hits)
        lin[miss] = self.env[s[miss]]
        return s, lin, miss

    def radiance(self, x: np.ndarray, n: np.ndarray, views: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
        """(K, 3) total and direct-only glossy radiance towards ``views`` (K, 3)."""
        s, lin, miss = self.incoming(x, n)
        t = tangent_from_normal(n[None])[0]
        li = to_local(self.dirs[s], n, t)
        lo = to_local(views, n, t)
        f = glossy(li[None], lo[:, None], self.brdf) * li[None, :, 2] * self.omega[s]
        f[lo[:, 2] <= 0] = 0.0
        total = (f @ lin) * self.specular
        direct = (f[:, miss] @ lin[miss]) * self.specular
        return total, direct

    def unshadowed(self, n: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """(3,) glossy radiance towards ``wo`` (3,) of a surface with normal n under the
        map alone: no visibility, no indirect light (decision 0042's U, exact)."""
        s = np.flatnonzero(self.dirs @ n > 0)
        t = tangent_from_normal(n[None])[0]
        lo = to_local(wo[None], n, t)
        if lo[0, 2] <= 0:
            return np.zeros(3)
        li = to_local(self.dirs[s], n, t)
        f = glossy(li, lo, self.brdf) * li[:, 2] * self.omega[s]
        return (f @ self.env[s]) * self.specular

    def lobes(self, mean: np.ndarray, lam: np.ndarray, weight: np.ndarray) -> np.ndarray:
        """∫ Σ_k w_k G_k L dω on the fine grid: mean (F, N, 3), lam (F, N), weight
        (F, N, 3) -> (F, 3)."""
        out = np.zeros((len(mean), 3))
        le = self.env * self.omega[:, None]
        for start in range(0, len(mean), 64):
            m, lm, w = (a[start:start + 64] for a in (mean, lam, weight))
            g = np.exp(lm[..., None] * (m @ self.dirs.T - 1.0))            # (f, N, S)
            out[start:start + 64] = np.einsum("fns,sc,fnc->fc", g, le, w)
        return out


def fit_functions(values: np.ndarray, directions: np.ndarray, omega: np.ndarray,
                  default: np.ndarray) -> list[sg_fit.SGFit]:
    """The stage's fit (stages/fit.py fit_group's per-N loop, without the coupling) of
    functions ``values`` (F, S, 3) for N = 1..3: the stored fits (weights in the
    functions' units) and the least-squares error (F,) per N."""
    strength = np.einsum("fsc,s->f", values.astype(np.float64) ** 2, omega)
    norm = np.sqrt(strength)
    v = (values / np.maximum(norm, 1e-30)[:, None, None]).astype(np.float32)
    inside, top = sg_support.caps(directions, omega, v, stage.SUPPORT)
    fits, errors, result = [], [], None
    for n in range(1, MAX_N + 1):
        start = None if result is None else sg_fit.grown_start(directions, omega, v, result,
                                                               default)
        result, error, stored, _ = stage._fit(
            v, directions, omega, sg_fit.FitOptions(lobes=n, fields=stage.FIELDS_DTYPE,
                                                    tolerance=stage.STOP),
            default, True, (inside, top), start=start)
        fits.append(sg_fit.SGFit(stored.mean, stored.sharpness,
                                 stored.weight * norm[:, None, None], stored.energy,
                                 stored.iterations, stored.converged))
        errors.append(error)
    return fits, errors, strength


def sub_triangle(b: np.ndarray, s: int) -> tuple[np.ndarray, np.ndarray]:
    """The corners (3, 3) (integer lattice barycentrics, sums s) of the sub-triangle of
    a face cut into s² that holds barycentrics ``b``, and b's weights (3,) in it."""
    big = np.asarray(b, np.float64) * s
    low = np.floor(big)
    while low.sum() >= s:                  # on a lattice point or edge: step back
        low[np.argmax(big - low == 0)] -= 1
    r = big - low
    if r.sum() < 1.5:                      # an upward sub-triangle
        return low + np.eye(3), r
    down = np.array([[1, 1, 0], [1, 0, 1], [0, 1, 1]], np.float64)
    return low + down, np.array([1 - r[2], 1 - r[1], 1 - r[0]])


def rel(a: np.ndarray, b: np.ndarray, norm: float) -> dict:
    return {"rel_rmse": float(np.sqrt(np.sum((a - b) ** 2)) / norm),
            "mean_ratio": float(np.sum(a) / np.sum(b)) if np.sum(b) else float("nan")}


def turn(a: np.ndarray, b: np.ndarray, v: np.ndarray) -> np.ndarray:
    """v (..., 3) turned by the smallest rotation taking unit a (3,) to unit b (3,)
    (identity where a and b are opposite): v + w×v + w×(w×v)/(1 + a·b), w = a×b — the
    kernel's sg_turn."""
    w, c = np.cross(a, b), float(a @ b)
    if 1.0 + c < 1e-6:
        return v
    wv = np.cross(w, v)
    return v + wv + np.cross(w, wv) / (1.0 + c)


def turn_part(a: np.ndarray, b: np.ndarray, v: np.ndarray, fraction: float) -> np.ndarray:
    """v (3,) turned about a×b by ``fraction`` of the angle from unit a to unit b (none
    where |a×b| ≤ 1e-6): the renderer's turn (render.turn_means)."""
    t = np.cross(a, b)
    sine = float(np.linalg.norm(t))
    if sine <= 1e-6:
        return v
    t /= sine
    theta = fraction * math.atan2(sine, float(a @ b))
    return (math.cos(theta) * v + math.sin(theta) * np.cross(t, v)
            + (1 - math.cos(theta)) * float(t @ v) * t)


def reflect(wo: np.ndarray, n: np.ndarray) -> np.ndarray:
    """The mirror direction 2(ωo·n)n − ωo."""
    return 2.0 * float(wo @ n) * n - wo


def warp_lobe(n: np.ndarray, wo: np.ndarray, gamma: float
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The Blinn–Phong lobe × cosine as one SG in ωi by Wang et al. (2009)'s spherical
    warp (decision 0042's first try): mean reflect(ωo, n), λ = γ / (4 n·ωo), peak
    (γ + 2)/(2π) n·ωo, without ρs; n, wo (P, 3) unit -> (P, 3), (P,), (P,); peak 0
    where n·ωo ≤ 0."""
    c = np.sum(n * wo, axis=-1)
    mu = 2.0 * c[:, None] * n - wo
    lam = gamma / (4.0 * np.maximum(c, 1e-3))
    return mu, lam, (gamma + 2.0) / (2.0 * math.pi) * np.maximum(c, 0.0)


def corrected(up: np.ndarray, f: np.ndarray, u: np.ndarray, bary: np.ndarray,
              form: str) -> np.ndarray:
    """Decision 0042's estimators, per channel, from U_p (P, 3) and per corner F_a, U_a
    (P, 3, 3) with F = Σ f_a F_a, U = Σ f_a U_a: ``ratio`` U_p F / U, ``additive``
    F + U_p − U, ``hybrid`` (the renderer's) F + min(1, F/U)(U_p − U); where U ≤ 1e-6
    U_p the ratio is 1 and v = 1."""
    fs = np.einsum("pa,pac->pc", bary, f)
    us = np.einsum("pa,pac->pc", bary, u)
    ok = us > 1e-6 * up
    if form == "ratio":
        return np.where(ok, fs * up / np.where(ok, us, 1.0), fs)
    if form == "additive":
        return fs + up - us
    v = np.where(ok, np.minimum(fs / np.where(ok, us, 1.0), 1.0), 1.0)
    return fs + v * (up - us)


def setup(name: str, size: int, pixels: int, fine: tuple[int, int], seed: int
          ) -> SimpleNamespace:
    """The scene baked up to sg.diffuse and sg.env_prefilter, the exact truth and the
    chosen glossy pixels (their faces' corners, barycentrics, points, blended normals
    and views, the views' 3 stored neighbours): what every row of the study reads."""
    t_start = time.perf_counter()
    path = Path(name) if name.endswith(".yaml") else ROOT / "scenes" / f"{name}.yaml"
    name = path.stem
    scene, wd = baked(path, workdir=ROOT / ".prt" / f"study_{name}",
                      until=("sg.diffuse", "sg.env_prefilter"))
    from pipeline import job
    graph = job.stages()
    geometry = open_artifact(wd.artifact("geometry"), graph.stages["geometry"].output)
    transfer = open_artifact(wd.artifact("sg.diffuse"),
                             graph.stages["sg.diffuse"].output).read("transfer")
    stack, levels = read_stack(open_artifact(wd.artifact("sg.env_prefilter"),
                                             graph.stages["sg.env_prefilter"].output))
    arrays = {k: geometry.read(k) for k in ("vertices", "normals", "faces", "object_ranges",
                                           "object_material")}
    material_names = geometry.attrs["material_names"]
    materials = []
    for m in material_names:
        mat = scene.materials[m]
        sec = {"model": mat.model, **mat.params}

        class _Ctx:  # the stage's material_brdf reads scene sections by key
            def __init__(self, section):
                self.section = section
                self.scene = self

            def get(self, key):
                return self.section.get(key.split(".")[-1])
        from pipeline.methods.sg.vertex_scene import UNSEEN
        materials.append(stage.material_brdf(_Ctx(sec), m) or UNSEEN)
    vscene = VertexScene.from_arrays(arrays, materials)
    glossy_material = [i for i, m in enumerate(materials) if m.model != "lambert"]
    assert len(glossy_material) == 1, "one glossy material expected"
    brdf = materials[glossy_material[0]]
    env = read_environment(scene.environment.file)
    order = int(round(math.sqrt(transfer.shape[-1])))
    light_sh = sh.project_latlong(env, order=order)
    vdiff = np.maximum(np.einsum("vck,kc->vc", transfer, light_sh), 0.0)
    rows, cols = fine
    fdirs, fomega = sg.latlong_directions(rows, cols)
    truth = Truth(vscene, brdf, blurred_map(env, rows, cols), fdirs.reshape(-1, 3),
                  fomega.ravel(), vdiff)

    # ---- pixels on the glossy object
    cam = scene.camera
    origins, directions = camera_rays(cam.position, cam.look_at, cam.up, cam.fov, size, size)
    origins, directions = origins.reshape(-1, 3), directions.reshape(-1, 3)
    hits = vscene.tracer.intersect(origins, directions)
    faces = vscene.faces
    hit = np.flatnonzero(hits.prim >= 0)
    corner_all = faces[hits.prim[hit]]
    on_glossy = vscene.vertex_material[corner_all[:, 0]] == glossy_material[0]
    candidates = hit[on_glossy]
    rng = np.random.default_rng(seed)
    chosen = np.sort(candidates if pixels <= 0 or pixels >= len(candidates)
                     else rng.choice(candidates, pixels, replace=False))
    corner = faces[hits.prim[chosen]]
    u, v = hits.u[chosen].astype(np.float64), hits.v[chosen].astype(np.float64)
    bary = np.stack([1 - u - v, u, v], axis=1)
    wo = -directions[chosen].astype(np.float64)
    x = origins[chosen] + hits.t[chosen, None].astype(np.float64) * directions[chosen]
    nrm = np.einsum("pa,pac->pc", bary, vscene.normals[corner])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    flip = np.sum(nrm * wo, axis=1) < 0     # turned to face the ray, as the reference
    nrm[flip] *= -1
    tri = view_triangulation()
    vidx, vw = view_triangles(tri, wo)
    views92 = view_directions()
    P = len(chosen)
    print(f"{name}: {P} pixels of {len(candidates)} on the glossy object, "
          f"{len(np.unique(corner))} vertices", flush=True)

    return SimpleNamespace(name=name, t_start=t_start, scene=scene, vscene=vscene, brdf=brdf,
                           env=env, transfer=transfer, order=order, stack=stack, levels=levels,
                           truth=truth, corner=corner, bary=bary, wo=wo, x=x, nrm=nrm, vidx=vidx,
                           vw=vw, views92=views92, P=P, candidates=candidates, chosen=chosen,
                           glossy_material=glossy_material)


def study(name: str, size: int, pixels: int, fine: tuple[int, int], seed: int,
          images: bool, quick: bool = False, state: str = "") -> dict:
    c = setup(name, size, pixels, fine, seed)
    (name, t_start, vscene, brdf, env, transfer, order, stack, levels, truth, corner, bary, wo,
     x, nrm, vidx, vw, views92, P, candidates, chosen) = (
        c.name, c.t_start, c.vscene, c.brdf, c.env, c.transfer, c.order, c.stack, c.levels,
        c.truth, c.corner, c.bary, c.wo, c.x, c.nrm, c.vidx, c.vw, c.views92, c.P, c.candidates,
        c.chosen)
    # ---- E0 at the pixels
    e0 = np.zeros((P, 3))
    e0_direct = np.zeros((P, 3))
    for p in range(P):
        t, d = truth.radiance(x[p], nrm[p], wo[p][None])
        e0[p], e0_direct[p] = t[0], d[0]
    t_e0 = time.perf_counter() - t_start
    # what denser sampling would give (exact transport): the face cut into 4^L
    # sub-triangles (points on the flat face, normals blended), L = 1, 2 (4x, 16x
    # the vertices); views on a finer geodesic sphere (10 f² + 2 views), f = 4, 6
    a_sub = {level: np.zeros((P, 3)) for level in (1, 2)}
    c_freq = {f: np.zeros((P, 3)) for f in (4, 6)}
    if quick:  # --quick: these rows are left out (they read as (a)'s and (c)'s)
        a_sub, c_freq = {}, {}
    tri_f = {}
    for f in c_freq:
        from scipy.spatial import ConvexHull
        vf = view_directions(f)
        fc = np.asarray(ConvexHull(vf).simplices, np.int64)
        tri_f[f] = (vf, fc, np.linalg.inv(np.transpose(vf[fc], (0, 2, 1))))
    pos = vscene.positions
    for p in range(P):
        for level in a_sub:
            corners, weights = sub_triangle(bary[p], 2 ** level)
            for c, w in zip(corners, weights, strict=True):
                b = c / 2 ** level
                xs = b @ pos[corner[p]]
                ns = b @ vscene.normals[corner[p]]
                a_sub[level][p] += w * truth.radiance(xs, ns / np.linalg.norm(ns),
                                                      wo[p][None])[0][0]
        vv, ww = [], []
        for vf, fc, inv in tri_f.values():
            beta = np.einsum("fij,j->fi", inv, wo[p])
            face = int(np.argmax(beta.min(axis=1)))
            b = np.maximum(beta[face], 0)
            vv.append(vf[fc[face]])
            ww.append(b / b.sum())
        for a in range(3 if vv else 0):
            q = int(corner[p, a])
            r = truth.radiance(pos[q], vscene.normals[q], np.concatenate(vv))[0]
            for i, f in enumerate(tri_f):
                c_freq[f][p] += bary[p, a] * (ww[i] @ r[3 * i:3 * i + 3])
    # (a) split: the vertices' normals at the pixel's point, the vertices' points (their
    # visibility) with the pixel's normal
    a_normal = np.zeros((P, 3))
    a_point = np.zeros((P, 3))
    for p in range(P):
        for a in range(3):
            q = int(corner[p, a])
            a_normal[p] += bary[p, a] * truth.radiance(x[p], vscene.normals[q], wo[p][None])[0][0]
            a_point[p] += bary[p, a] * truth.radiance(vscene.positions[q], nrm[p],
                                                      wo[p][None])[0][0]

    # ---- requests per vertex: its 92-view indices and the pixels' own views
    verts = np.unique(corner)
    req: dict[int, list] = {int(q): [] for q in verts}    # entries: ("v", k) or ("p", p)
    for p in range(P):
        for a in range(3):
            q = int(corner[p, a])
            req[q].append(("p", p))
            for b in range(3):
                if ("v", int(vidx[p, b])) not in req[q]:
                    req[q].append(("v", int(vidx[p, b])))
    fdir, fom = stage.grid({"sg.fit_grid": [55, 110]})
    grid_env = blurred_map(env, 55, 110)
    basis = grid_basis(fdir, order)
    irng = np.random.default_rng(seed + 1)
    exact: dict[tuple, np.ndarray] = {}        # (q, key) -> R (3,)
    tab: dict[tuple, np.ndarray] = {}          # (q, key) -> ∫ T_tab L (3,)
    lobe: dict[tuple, tuple] = {}              # (q, key) -> fits per N (mean, lam, w)
    rfit: dict[tuple, np.ndarray] = {}         # (q, key) -> (N, 3) fitted radiance
    lserr: dict[tuple, np.ndarray] = {}        # (q, key) -> (N,) least-squares error
    strength_of: dict[tuple, float] = {}
    batch_keys, batch_values, batch_default = [], [], []

    def flush():
        if not batch_keys:
            return
        values = np.concatenate(batch_values)
        default = np.concatenate(batch_default)
        active = np.einsum("fsc,s->f", values.astype(np.float64) ** 2, fom) > 0
        idx = np.flatnonzero(active)
        fits, errs, strength = (fit_functions(values[idx], fdir, fom, default[idx])
                                if len(idx) else ([], [], []))
        for key in batch_keys:
            strength_of[key] = 0.0
        for i, j in enumerate(idx):
            key = batch_keys[j]
            lobe[key] = [(f.mean[i], f.sharpness[i], f.weight[i]) for f in fits]
            lserr[key] = np.array([e[i] for e in errs])
            strength_of[key] = float(strength[i])
        if len(idx):
            for n, f in enumerate(fits):
                r = truth.lobes(f.mean, f.sharpness, f.weight)
                for i, j in enumerate(idx):
                    rfit.setdefault(batch_keys[j], np.zeros((MAX_N, 3)))[n] = r[i]
        batch_keys.clear()
        batch_values.clear()
        batch_default.clear()

    for count, q in enumerate(verts):
        entries = req[int(q)]
        vv = np.array([views92[k] if kind == "v" else wo[k] for kind, k in entries])
        tot, _ = truth.radiance(vscene.positions[q], vscene.normals[q], vv)
        for e, r in zip(entries, tot, strict=True):
            exact[(int(q), e)] = r
        n_q = vscene.normals[q][None]
        visible = scene_visibility(vscene, np.array([q]), fdir)
        t_grid = direct_glossy(n_q, tangent_from_normal(n_q), brdf, vv, fdir, visible)[0]
        a = indirect_glossy_sh(vscene, np.array([q]), vv, transfer, 64, irng)[0]
        t_grid = t_grid + on_grid(a, basis)
        integ = np.einsum("ksc,s,sc->kc", t_grid.astype(np.float64), fom, grid_env)
        mirror = stage.mirror(vv, vscene.normals[q][None])[0]
        for j, e in enumerate(entries):
            key = (int(q), e)
            tab[key] = integ[j]
            batch_keys.append(key)
        batch_values.append(t_grid)
        batch_default.append(mirror)
        if len(batch_keys) >= 256:
            flush()
        if count % 100 == 0:
            print(f"  vertex {count}/{len(verts)}  {time.perf_counter() - t_start:.0f} s",
                  flush=True)
    flush()

    # ---- N per vertex by the stage's rule over the vertex's functions here
    n_rule = {}
    for q in verts:
        keys = [(int(q), e) for e in req[int(q)] if strength_of.get((int(q), e), 0) > 0]
        if not keys:
            n_rule[int(q)] = 1
            continue
        s = np.array([strength_of[k] for k in keys])
        n_rule[int(q)] = MAX_N
        for n in range(MAX_N):
            err = np.sqrt(np.sum(np.array([lserr[k][n] for k in keys]) ** 2 * s) / s.sum())
            if err <= 0.7:
                n_rule[int(q)] = n + 1
                break

    def fitted(q, e, n):  # radiance of the N-lobe fit (0 where no data)
        return rfit[(q, e)][n] if (q, e) in rfit else np.zeros(3)

    ea = np.zeros((P, 3))
    ec = np.zeros((P, 3))
    etab = np.zeros((P, 3))
    eb = np.zeros((MAX_N + 1, P, 3))        # N = 1..3, then the rule
    ebc = np.zeros((MAX_N + 1, P, 3))
    em = np.zeros((P, 3))                   # lobe-parameter blend, N = 1, exact integral
    em_raw = np.zeros((P, 3))               # the same, quadrature over the map's samples
    ed = np.zeros((P, 3))                   # the same, stack lookup
    blended = []
    emv = np.zeros((P, 3))                  # lobes blended over views per vertex, N = 1
    blended_area = []                       # the blended lobes' w, integrals blended
    per_vertex = []                         # (p, a, mu, lam, w) of those
    for p in range(P):
        mus, lams, ws, wts = [], [], [], []
        for a in range(3):
            first = len(wts)
            q = int(corner[p, a])
            ea[p] += bary[p, a] * exact[(q, ("p", p))]
            etab[p] += bary[p, a] * tab[(q, ("p", p))]
            for n in range(MAX_N):
                eb[n, p] += bary[p, a] * fitted(q, ("p", p), n)
            eb[MAX_N, p] += bary[p, a] * fitted(q, ("p", p), n_rule[q] - 1)
            # the vertex's fallback lobe for views without data: mean of its fitted ones
            have = [lobe[(q, e)][0] for e in req[q] if (q, e) in lobe]
            for b in range(3):
                e = ("v", int(vidx[p, b]))
                wgt = bary[p, a] * vw[p, b]
                ec[p] += wgt * exact[(q, e)]
                for n in range(MAX_N):
                    ebc[n, p] += wgt * fitted(q, e, n)
                ebc[MAX_N, p] += wgt * fitted(q, e, n_rule[q] - 1)
                if (q, e) in lobe:
                    m, lam, w = lobe[(q, e)][0]
                elif have:
                    mm = np.sum([h[0][0] for h in have], axis=0)
                    m = (mm / np.linalg.norm(mm))[None]
                    lam = np.exp(np.mean([np.log(h[1][0]) for h in have]))[None]
                    w = np.zeros((1, 3))
                else:
                    continue
                mus.append(m[0])
                lams.append(lam[0])
                ws.append(w[0])
                wts.append(wgt)
            if len(wts) > first and bary[p, a] > 0:
                k = np.array(wts[first:]) / bary[p, a]
                mv = np.einsum("k,kc->c", k, np.array(mus[first:]))
                per_vertex.append((p, a, mv / np.linalg.norm(mv),
                                   float(np.exp(np.sum(k * np.log(lams[first:])))),
                                   np.einsum("k,kc->c", k, np.array(ws[first:]))))
        if not wts:
            blended.append((np.array([0, 1.0, 0]), 1.0, np.zeros(3)))
            blended_area.append(np.zeros(3))
            continue
        wts = np.array(wts)
        mu = np.einsum("k,kc->c", wts, np.array(mus))
        mu /= np.linalg.norm(mu)
        lam = float(np.exp(np.sum(wts * np.log(lams))))
        w = np.einsum("k,kc->c", wts, np.array(ws))
        blended.append((mu, lam, w))
        # the lobes' integrals w ∫G blended instead of their peaks w (energy kept)
        area = np.einsum("k,kc->c", wts, np.array(ws) * sg.integral(np.array(lams))[:, None])
        blended_area.append(area / sg.integral(np.array([lam]))[0])
    bm = np.array([b[0] for b in blended])
    bl = np.array([b[1] for b in blended])
    bw = np.array([b[2] for b in blended])
    em[:] = truth.lobes(bm[:, None], bl[:, None], bw[:, None])
    em_area = truth.lobes(bm[:, None], bl[:, None], np.array(blended_area)[:, None])
    if per_vertex:
        r = truth.lobes(np.array([t[2] for t in per_vertex])[:, None],
                        np.array([t[3] for t in per_vertex])[:, None],
                        np.array([t[4] for t in per_vertex])[:, None])
        for (p, a, *_), ri in zip(per_vertex, r, strict=True):
            emv[p] += bary[p, a] * ri
    em_raw[:] = sg.env_integral_reference(env, bm, bl, bw)
    ed[:] = sg.env_integral(stack, levels, bm, bl, bw)

    # ---- the pixel's normal at render time (decision 0039): each vertex's lobes turned
    # by the smallest rotation taking its mirror direction reflect(ωo, n_v) to the
    # pixel's reflect(ωo, n_p) (n_p the blended normal), before blending; "per view":
    # the rotation of each stored view's own mirror directions instead of ωo's;
    # "aligned" (the renderer's): by G(r_v; μ, λ) of the angle, the lobes about the
    # mirror direction all the way, the others (occlusion, indirect light) not
    rb = np.zeros((MAX_N, P, 3))       # fits at the pixel's view, turned, blended over a
    rbc = np.zeros((MAX_N, P, 3))      # fits at the 3 views, turned, radiances blended
    jobs: dict[int, list] = {n: [] for n in range(MAX_N)}
    turned = {"wo": [], "per_view": [], "aligned": []}  # N = 1 lobes blended after turning
    for p in range(P):
        rp = reflect(wo[p], nrm[p])
        par = {k: ([], [], [], []) for k in turned}
        for a in range(3):
            q = int(corner[p, a])
            nq = vscene.normals[q]
            rv = reflect(wo[p], nq)
            have = [lobe[(q, e)][0] for e in req[q] if (q, e) in lobe]
            keys = [(("p", p), bary[p, a], rb)] + [
                (("v", int(vidx[p, b])), bary[p, a] * vw[p, b], rbc) for b in range(3)]
            for e, wgt, into in keys:
                if (q, e) in lobe:
                    for n in range(MAX_N):
                        m, lam, w = lobe[(q, e)][n]
                        jobs[n].append((into, p, wgt, turn(rv, rp, m), lam, w))
                    m, lam, w = lobe[(q, e)][0]
                elif have and e[0] == "v":
                    mm = np.sum([h[0][0] for h in have], axis=0)
                    m = (mm / np.linalg.norm(mm))[None]
                    lam = np.exp(np.mean([np.log(h[1][0]) for h in have]))[None]
                    w = np.zeros((1, 3))
                else:
                    continue
                if e[0] != "v":
                    continue
                view = views92[e[1]]
                for k, (a_dir, b_dir) in (("wo", (rv, rp)),
                                          ("per_view", (reflect(view, nq),
                                                        reflect(view, nrm[p])))):
                    par[k][0].append(turn(a_dir, b_dir, m[0]))
                    par[k][1].append(lam[0])
                    par[k][2].append(w[0])
                    par[k][3].append(wgt)
                along = math.exp(-0.5 * lam[0] * float(np.sum((rv - m[0]) ** 2)))
                par["aligned"][0].append(turn_part(rv, rp, m[0], along))
                par["aligned"][1].append(lam[0])
                par["aligned"][2].append(w[0])
                par["aligned"][3].append(wgt)
        for k, (mus, lams, ws, wts) in par.items():
            if not wts:
                turned[k].append((np.array([0, 1.0, 0]), 1.0, np.zeros(3)))
                continue
            wts = np.array(wts)
            mu = np.einsum("k,kc->c", wts, np.array(mus))
            turned[k].append((mu / np.linalg.norm(mu),
                              float(np.exp(np.sum(wts * np.log(lams)))),
                              np.einsum("k,kc->c", wts, np.array(ws))))
    for n, items in jobs.items():
        for start in range(0, len(items), 512):
            part = items[start:start + 512]
            r = truth.lobes(np.array([t[3] for t in part]), np.array([t[4] for t in part]),
                            np.array([t[5] for t in part]))
            for (into, p, wgt, *_), ri in zip(part, r, strict=True):
                into[n, p] += wgt * ri
    ed_turn = {k: sg.env_integral(stack, levels, np.array([t[0] for t in v]),
                                  np.array([t[1] for t in v]), np.array([t[2] for t in v]))
               for k, v in turned.items()}

    norm = float(np.sqrt(np.sum(e0 ** 2)))
    # ---- decision 0042: the BRDF at the pixel's normal, visibility and indirect light
    # from the vertices: U_p, U_a the glossy radiance under the map alone (no
    # visibility) at the pixel's and the corners' normals, F_a what corner a holds at
    # the pixel's view; U exact (quadrature), by the renderer's fitted BRDF lobe
    # (brdf_lobe.py's table, stack lookup) or by the spherical warp
    vn = vscene.normals[corner]                                         # (P, 3, 3)
    u_exact = (np.array([truth.unshadowed(nrm[p], wo[p]) for p in range(P)]),
               np.array([[truth.unshadowed(vn[p, a], wo[p]) for a in range(3)]
                         for p in range(P)]))
    table = lobe_table(replace(brdf, albedo=(0.0, 0.0, 0.0)))

    def lobe_u(lobe_of):  # U_p (P, 3) and U_a (P, 3, 3) by a lobe and the stack lookup
        nn = np.concatenate([nrm, vn.reshape(-1, 3)])
        mu, lam, peak = lobe_of(nn / np.linalg.norm(nn, axis=1, keepdims=True),
                                np.concatenate([wo, np.repeat(wo, 3, axis=0)]))
        mu /= np.linalg.norm(mu, axis=1, keepdims=True)
        u = sg.env_integral(stack, levels, mu, lam,
                            peak[:, None] * np.asarray(brdf.specular, np.float64))
        return u[:P], u[P:].reshape(P, 3, 3)
    u_table = lobe_u(lambda n, w: brdf_lobe(table, n, w))
    u_warp = lobe_u(lambda n, w: warp_lobe(n, w, float(brdf.gamma)))
    r_exact = np.array([[exact[(int(corner[p, a]), ("p", p))] for a in range(3)]
                        for p in range(P)])                             # (P, 3, 3)
    fit_views = np.zeros((MAX_N, P, 3, 3))  # N-lobe fits' radiances blended over views
    for p in range(P):
        for a in range(3):
            for b in range(3):
                for n in range(MAX_N):
                    fit_views[n, p, a] += vw[p, b] * fitted(int(corner[p, a]),
                                                            ("v", int(vidx[p, b])), n)
    f_lobes = np.zeros((P, 3, 3))  # the renderer's: N = 1 lobes blended over the views
    if per_vertex:
        f_lookup = sg.env_integral(stack, levels, np.array([t[2] for t in per_vertex]),
                                   np.array([t[3] for t in per_vertex]),
                                   np.array([t[4] for t in per_vertex]))
        for (p, a, *_), fi in zip(per_vertex, f_lookup, strict=True):
            f_lobes[p, a] = fi
    ratio_rows = {"method_vertex_lobes_radiance_blend": np.einsum("pa,pac->pc", bary,
                                                                  f_lobes)}
    for u_name, (up, ua) in (("exact_U", u_exact), ("table_U", u_table),
                             ("warp_U", u_warp)):
        for f_name, f in (("exact_transport", r_exact), ("method_vertex_lobes", f_lobes),
                          *((f"fit_N{n + 1}_views_radiance_blend", fit_views[n])
                            for n in range(MAX_N))):
            for form in ("ratio", "additive", "hybrid"):
                ratio_rows[f"{form}_{u_name}_{f_name}"] = corrected(up, f, ua, bary, form)
    u_rows = {f"U_p_{name}_vs_exact": rel(u[0], u_exact[0],
                                          float(np.sqrt(np.sum(u_exact[0] ** 2))))
              for name, u in (("table", u_table), ("warp", u_warp))}
    n_counts = np.bincount(list(n_rule.values()), minlength=MAX_N + 1)[1:].tolist()
    stages = {
        "a_vertex_sampling": rel(ea, e0, norm),
        "a_normals_only": rel(a_normal, e0, norm),
        "a_points_only": rel(a_point, e0, norm),
        **({} if quick else {"a_subdivided_4x": rel(a_sub[1], e0, norm),
                             "a_subdivided_16x": rel(a_sub[2], e0, norm)}),
        "c_view_interpolation": rel(ec, ea, norm),
        **({} if quick else {
            "c_view_interpolation_162_views": rel(c_freq[4], ea, norm),
            "c_view_interpolation_362_views": rel(c_freq[6], ea, norm)}),
        "b_tabulation_fit_grid_and_mc_indirect": rel(etab, ea, norm),
        "b_fit_N1": rel(eb[0], ea, norm),
        "b_fit_N2": rel(eb[1], ea, norm),
        "b_fit_N3": rel(eb[2], ea, norm),
        "b_fit_rule": rel(eb[3], ea, norm),
        "b_fit_proper_N1": rel(eb[0], etab, norm),
        "b_plus_c_N1_radiance_blend": rel(ebc[0], ea, norm),
        "b_plus_c_rule_radiance_blend": rel(ebc[3], ea, norm),
        "c_view_interpolation_lobe_blend_N1": rel(emv, eb[0], norm),
        "vertex_lobe_blend_vs_radiance_blend_N1": rel(em, emv, norm),
        "c_prime_lobe_parameter_blend_vs_radiance_blend_N1": rel(em, ebc[0], norm),
        "c_prime_integral_blend_vs_radiance_blend_N1": rel(em_area, ebc[0], norm),
        "chain_lobe_parameter_blend_N1_vs_E0": rel(em, e0, norm),
        "chain_integral_blend_N1_vs_E0": rel(em_area, e0, norm),
        "chain_radiance_blend_N1_vs_E0": rel(ebc[0], e0, norm),
        "chain_radiance_blend_N3_vs_E0": rel(ebc[2], e0, norm),
        "chain_exact_transport_radiance_blend_vs_E0": rel(ec, e0, norm),
        "d_prefiltered_lookup": rel(ed, em_raw, norm),
        "d_fine_grid_vs_map_samples": rel(em, em_raw, norm),
        "chain_method_N1_vs_E0": rel(ed, e0, norm),
        "turned_chain_method_N1_vs_E0": rel(ed_turn["wo"], e0, norm),
        "turned_per_view_chain_method_N1_vs_E0": rel(ed_turn["per_view"], e0, norm),
        "turned_aligned_chain_method_N1_vs_E0": rel(ed_turn["aligned"], e0, norm),
        **{f"fit_N{n + 1}_pixel_view_vs_E0": rel(eb[n], e0, norm) for n in range(MAX_N)},
        **{f"turned_fit_N{n + 1}_pixel_view_vs_E0": rel(rb[n], e0, norm)
           for n in range(MAX_N)},
        **{f"chain_radiance_blend_N{n + 1}_vs_E0": rel(ebc[n], e0, norm)
           for n in range(MAX_N)},
        **{f"turned_chain_radiance_blend_N{n + 1}_vs_E0": rel(rbc[n], e0, norm)
           for n in range(MAX_N)},
        "chain_without_vertex_sampling": rel(ed, ea, norm),
        **{k: rel(v, e0, norm) for k, v in ratio_rows.items()},
        **u_rows,
    }
    report = {"scene": name, "size": size, "pixels": P, "glossy_pixels": len(candidates),
              "vertices": len(verts), "fine_grid": list(fine),
              "indirect_share_of_E0": float(1 - e0_direct.sum() / e0.sum()),
              "n_rule_counts_N1_N2_N3": n_counts,
              "stages": stages, "seconds": time.perf_counter() - t_start,
              "seconds_E0": t_e0}
    for k, s in stages.items():
        print(f"  {k:55s} {100 * s['rel_rmse']:6.1f} %   mean ratio {s['mean_ratio']:.3f}")
    print(f"  indirect share of E0 {100 * report['indirect_share_of_E0']:.1f} %, "
          f"N rule counts {n_counts}, {report['seconds']:.0f} s", flush=True)
    if images:
        scale = float(np.mean(e0))
        for label, a, b in (("E0", e0, 0 * e0), ("a", ea, e0), ("c", ec, ea),
                            ("b_N1", eb[0], ea), ("c_lobes", emv, eb[0]),
                            ("vertex_lobes", em, emv), ("d", ed, em_raw),
                            ("chain", ed, e0)):
            img = np.zeros((size * size, 3))
            diff = np.abs(a - b).mean(axis=1) / scale if label != "E0" else a.mean(1) / (2 * scale)
            img[chosen] = np.clip(diff, 0, 1)[:, None]
            if label != "E0":  # pixels not studied: dark blue
                mask = np.ones(size * size, bool)
                mask[chosen] = False
                img[mask] = [0.0, 0.0, 0.15]
            write_png(OUT / f"sg_glossy_error_{name}_{label}.png",
                      img.reshape(size, size, 3))
        report["images"] = [f"sg_glossy_error_{name}_*.png"]
    if state:  # the fitted lobes and pixels, for trying render-time variants offline
        import pickle
        Path(state).write_bytes(pickle.dumps({
            "lobe": lobe, "req": req, "corner": corner, "bary": bary, "wo": wo,
            "normal": nrm, "vertex_normals": vscene.normals, "vidx": vidx, "vw": vw,
            "views": views92, "e0": e0, "ed": ed, "stack": stack, "levels": levels,
            "u_exact": u_exact, "u_table": u_table, "u_warp": u_warp,
            "r_exact": r_exact, "fit_views": fit_views, "f_lobes": f_lobes}))
    np.savez_compressed(OUT / f"sg_glossy_error_{name}.npz", pixel=chosen, e0=e0,
                        e0_direct=e0_direct, ea=ea, a_normal=a_normal, a_point=a_point,
                        ec=ec, etab=etab, eb=eb, ebc=ebc, em=em,
                        em_raw=em_raw, ed=ed, ed_turn=ed_turn["wo"],
                        ed_aligned=ed_turn["aligned"], rb=rb, rbc=rbc, emv=emv,
                        em_area=em_area, corner=corner,
                        bary=bary, wo=wo, normal=nrm)
    return report


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["bunny_sg", "dragon_sg"])
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--pixels", type=int, default=160, help="random glossy pixels (0: all)")
    ap.add_argument("--fine", type=int, nargs=2, default=[181, 360])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--images", action="store_true")
    ap.add_argument("--state", default="", help="pickle the fitted lobes and pixels here "
                    "(per scene: the name gets the scene's)")
    ap.add_argument("--quick", action="store_true",
                    help="leave out the denser-sampling rows (faces cut, 162/362 views)")
    ap.add_argument("--out", default=str(OUT / "sg_glossy_error.json"))
    args = ap.parse_args()
    one_blas_thread()
    OUT.mkdir(parents=True, exist_ok=True)
    reports = [study(s, args.size, args.pixels, tuple(args.fine), args.seed, args.images,
                     args.quick, args.state and f"{args.state}_{Path(s).stem}.pkl")
               for s in args.scenes]
    Path(args.out).write_text(json.dumps({"args": vars(args), "scenes": reports}, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()

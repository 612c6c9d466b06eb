"""Paper 003 Fig. 5 reproduced: relative L² error of 1 … 10 spherical Gaussians against
nonlinear Haar wavelet truncation and spherical harmonics at equal coefficient counts,
for three transport functions taken from a real scene (issue 17, "Must show").

Run from the project root:
    python studies/sg_fig5.py [--leaf-level 5] [--max-gaussians 10] [--workdir W]
Writes benchmarks/results/sg_fig5.json and sg_fig5.png.

**Transport.** Scene studies/sg_fig5_scene.yaml (the 6.6k-face bunny on a ground
plane; its ``geometry`` artifact is baked in ``--workdir``). For one vertex and one of
the 92 view directions of method sg (pipeline/methods/sg/transport.py), the direct glossy
transport T(ωi) = ρs f_F f_E V max(0, n·ωi) (1/sr, RGB), with Embree visibility against
the whole scene, tabulated at the leaf centroids of the geodesic sphere of level
``--leaf-level`` (20·4^L directions; L = 5: 20,480, 1.4° apart; quadrature weights the
leaves' solid angles). The three functions of the paper's figure:

- ``small_glossy``: Blinn–Phong γ = 200 (a lobe of σ ≈ 2/√γ ≈ 8°) at a bunny vertex that
  sees the whole lobe, view 20–40° from the normal (a nearly symmetric lobe);
- ``large_visibility``: Blinn–Phong γ = 8 (σ ≈ 40°) at the bunny vertex whose visible
  share of the unoccluded lobe's energy is closest to 55 % (partly occluded), view 20–45°
  from the normal;
- ``anisotropic``: anisotropic Ward αx = 0.04, αy = 0.4 (pipeline/math/brdf.py) at an
  unoccluded vertex, the most grazing view of the 92 that is still ≥ 10° above the
  horizon.

The fits with ``sg_fit.FitOptions()``'s defaults (tolerance 1e-6, moment start only,
N ≤ 3: what the ``sg.fit`` stage runs) are reported beside (``gaussians_stage_default``).

The bunny's normals are welded (area-weighted over the faces around each position): the
OBJ stores one normal per face, so the ``geometry`` artifact holds 19,794 unshared,
flat-shaded vertices for 3,301 positions; the study takes the smooth normal a vertex of
the paper's meshes has. The tangent is ``frames.tangent_from_normal``.

**Representations**, all of the same tabulated data and measured in the same norm,
‖f‖² = Σ_s Ω_s ‖f(ω_s)‖² (the sphere's L² by the leaves' quadrature):

- Gaussians: ``sg_fit.fit`` with N = 1 … 10 lobes (RGB weights, shared mean and
  sharpness; the paper's energy D alone, as a single function has no neighbours), the
  better of two starts per N: the fit's own greedy moment start, and the N − 1 fit plus
  one lobe fitted to the positive residual (continuation). 7 floats per Gaussian
  (3 RGB weights + 3 mean + 1 σ), as the paper stores them.
- Haar: pipeline/math/sphwavelet.py's orthonormal spherical Haar basis on the same
  geodesic leaves (the basis of method triple, paper 004), keeping the K largest
  coefficients (by RGB norm): nonlinear truncation. The paper used Haar on a cube map.
  This basis is orthonormal in the solid-angle inner product, so keeping the largest
  coefficients is the best K-term approximation in exactly the norm measured here; a
  cube map's Haar is orthonormal in the texel sum instead (texels at a face's corner
  subtend 5.2× less than at its centre) and needs a weighting to be compared in the
  sphere's norm. Same family: piecewise constant, each node refining into four.
- SH: real spherical harmonics of pipeline/math/sh.py, all bands l < n (n² coefficients),
  fitted by weighted least squares on the grid (the orthogonal projection in the norm
  measured; it differs from the quadrature projection ``sh.project`` only by the
  quadrature's error, which at order 10 on 20k leaves is < 1e-3 of the function).

**Counting** as the paper does: one Gaussian is compared with seven Haar and seven SH
coefficients, N Gaussians with 7N, a coefficient being one value per channel (the
transport here is grey × ρs, so channels are proportional and nothing depends on that
choice). Haar is evaluated at K = 1 … 7·max_gaussians, SH at each full order n = 1 … 10
(1 … 100 coefficients: the paper's 10th-order SH picture) and plotted at its count; the
table at 7N gives SH with the largest n² ≤ 7N (``sh_at_most``) and the smallest
n² ≥ 7N (``sh_at_least``, the paper's "generous allotment").

Fit times (wall, one BLAS thread) and ``os.getloadavg()`` are recorded: the machine is
shared; re-run on a quiet one to quote times.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.math import sg, sh
from pipeline.math.brdf import BrdfParams
from pipeline.math.frames import tangent_from_normal
from pipeline.math.geodesic import geodesic_levels, locate
from pipeline.math.sphwavelet import wavelet_basis
from pipeline.methods.sg import fit as sg_fit
from pipeline.methods.sg.transport import direct_glossy, view_directions, visibility

ROOT = Path(__file__).resolve().parent.parent
SCENE = ROOT / "studies" / "sg_fig5_scene.yaml"
FLOATS_PER_GAUSSIAN = 7     # 3 RGB weights + 3 mean + 1 σ (paper 003 §6.1)
SH_MAX_ORDER = 10           # bands l < 10: 100 coefficients (the paper's 10th-order SH)
RAY_OFFSET = 1e-4           # ray origin offset along the normal, × the scene diagonal
FIT_OPTIONS = sg_fit.FitOptions(max_iterations=500, tolerance=1e-8, batch=1)


@dataclass(frozen=True)
class Case:
    """One transport function of the study: a material, where it sits and what it shows."""

    name: str
    title: str
    brdf: BrdfParams


CASES = (
    Case("small_glossy", "small glossy lobe",
         BrdfParams("blinn_phong", (0.0, 0.0, 0.0), (0.1, 0.1, 0.1), gamma=200.0)),
    Case("large_visibility", "large lobe with visibility",
         BrdfParams("blinn_phong", (0.0, 0.0, 0.0), (0.1, 0.1, 0.1), gamma=8.0)),
    Case("anisotropic", "anisotropic specular lobe (grazing)",
         BrdfParams("ward_anisotropic", (0.0, 0.0, 0.0), (0.8, 0.8, 0.8), gamma=0.04,
                    alpha_ratio=10.0)),
)


# ------------------------------------------------------------------ representations

def sphere_grid(leaf_level: int) -> tuple[np.ndarray, np.ndarray]:
    """Directions (S, 3) (the leaf centroids of the geodesic sphere of ``leaf_level``,
    S = 20·4^L, in the leaf order of sphwavelet's basis) and solid angles (S,) (sr)."""
    leaves = geodesic_levels(leaf_level)[leaf_level]
    return leaves.centroids, leaves.areas


def relative_l2(approx: np.ndarray, data: np.ndarray, omega: np.ndarray) -> float:
    """‖approx − data‖ / ‖data‖ with ‖f‖² = Σ_s Ω_s Σ_c f_sc² for (S, C) arrays."""
    num = np.einsum("s,sc->", omega, (approx - data) ** 2)
    den = np.einsum("s,sc->", omega, data ** 2)
    return float(math.sqrt(num / den))


def haar_truncation(data: np.ndarray, leaf_level: int, keep: int) -> np.ndarray:
    """The leaf values (S, C) of ``data`` (S, C) rebuilt from its ``keep`` largest
    spherical Haar coefficients (by their RGB norm), the rest set to 0."""
    basis = wavelet_basis(leaf_level)
    coefficients = basis.forward(data.T)                                  # (C, S)
    order = np.argsort(-np.linalg.norm(coefficients, axis=0), kind="stable")
    kept = np.zeros_like(coefficients)
    kept[:, order[:keep]] = coefficients[:, order[:keep]]
    return basis.inverse(kept).T


def sh_coefficients(directions: np.ndarray, omega: np.ndarray, data: np.ndarray,
                    order: int) -> np.ndarray:
    """Coefficients (order², C) of the SH expansion with bands l < ``order`` closest to
    ``data`` (S, C) at ``directions`` in the Ω-weighted norm (weighted least squares)."""
    root = np.sqrt(omega)[:, None]
    return np.linalg.lstsq(sh.basis(directions, order) * root, data * root, rcond=None)[0]


def sh_least_squares(directions: np.ndarray, omega: np.ndarray, data: np.ndarray,
                     order: int) -> np.ndarray:
    """The values (S, C) at ``directions`` of :func:`sh_coefficients`' expansion."""
    return sh.basis(directions, order) @ sh_coefficients(directions, omega, data, order)


def sg_values(directions: np.ndarray, fit: sg_fit.SGFit, index: int = 0) -> np.ndarray:
    """Σ_k w_k G(ω; μ_k, λ_k) (S, C) of function ``index`` of a fit."""
    g = sg.evaluate(directions[:, None], fit.mean[index][None], fit.sharpness[index][None])
    return g @ fit.weight[index]


def _continuation_start(directions: np.ndarray, omega: np.ndarray, data: np.ndarray,
                        previous: sg_fit.SGFit) -> sg_fit.SGFit:
    """The N − 1 lobes of ``previous`` plus one lobe fitted to the positive part of the
    residual: a start for N lobes (``sg_fit.fit``'s ``start``; weights are re-solved)."""
    residual = np.maximum(data - sg_values(directions, previous), 0.0)
    extra = sg_fit.fit(directions, omega, residual[None], sg_fit.FitOptions(lobes=1))
    return sg_fit.SGFit(mean=np.concatenate([previous.mean, extra.mean], axis=1),
                        sharpness=np.concatenate([previous.sharpness, extra.sharpness], 1),
                        weight=np.zeros((1, previous.mean.shape[1] + 1, data.shape[1])),
                        energy=extra.energy, iterations=extra.iterations,
                        converged=extra.converged)


def fit_gaussians(directions: np.ndarray, omega: np.ndarray, data: np.ndarray,
                  max_lobes: int, options: sg_fit.FitOptions = FIT_OPTIONS) -> list[dict]:
    """Fits with N = 1 … ``max_lobes`` lobes to one function ``data`` (S, C): per N the
    better (lower energy) of the moment start and the continuation start, with each
    start's energy, wall time and convergence. Returns one dict per N holding the
    chosen ``fit`` (sg_fit.SGFit) and its report."""
    results: list[dict] = []
    previous = None
    for n in range(1, max_lobes + 1):
        opts = sg_fit.FitOptions(**{**options.__dict__, "lobes": n})
        tried = {}
        t0 = time.perf_counter()
        tried["moments"] = (sg_fit.fit(directions, omega, data[None], opts),
                            time.perf_counter() - t0)
        if previous is not None:
            t0 = time.perf_counter()
            start = _continuation_start(directions, omega, data, previous)
            tried["continuation"] = (sg_fit.fit(directions, omega, data[None], opts,
                                                start=start), time.perf_counter() - t0)
        best = min(tried, key=lambda k: tried[k][0].energy[0])
        previous = tried[best][0]
        results.append({
            "lobes": n, "fit": previous, "start": best,
            "starts": {k: {"energy": float(f.energy[0]), "seconds": s,
                           "iterations": int(f.iterations[0]),
                           "converged": bool(f.converged[0])}
                       for k, (f, s) in tried.items()},
        })
    return results


# ------------------------------------------------------------------ the scene's functions

def scene_geometry(workdir: Path) -> dict[str, np.ndarray]:
    """The study scene's ``geometry`` artifact (baked in ``workdir`` when stale); its
    vertex normals are smooth (pipeline/scene/meshio.py welds the OBJ's per-face splits)."""
    from pipeline.engine.runner import run
    from pipeline.engine.store import Workdir, open_artifact
    from pipeline.scene.file import load_scene

    work = Workdir(workdir)
    from pipeline import job

    run(load_scene(SCENE), job.stages(), work,
        targets={"geometry"}, progress=False)
    geo = open_artifact(work.artifact("geometry"))
    arrays = {n: np.asarray(geo.read(n)) for n in ("vertices", "normals", "faces",
                                                     "face_object")}
    arrays["object_names"] = np.asarray(geo.attrs["object_names"])
    return arrays


def tabulate(tracer, geometry: dict[str, np.ndarray], vertex: int, view: np.ndarray,
             brdf: BrdfParams, directions: np.ndarray) -> np.ndarray:
    """T (S, 3) of one vertex and view (module docstring), visibility included."""
    position = geometry["vertices"][vertex][None].astype(np.float64)
    normal = geometry["normals"][vertex][None]
    diagonal = float(np.linalg.norm(np.ptp(geometry["vertices"], axis=0)))
    visible = visibility(tracer, position, normal, directions, RAY_OFFSET * diagonal)
    return direct_glossy(normal, tangent_from_normal(normal), brdf, view[None], directions,
                         visible)[0, 0]


def choose_vertices(tracer, geometry: dict[str, np.ndarray], leaf_level: int,
                    seed: int = 0) -> dict[str, tuple[int, int]]:
    """(vertex, view index) of each case, chosen on a coarse grid (level
    ``leaf_level``) among up to 400 random bunny vertices (one per position):
    the visible share of each candidate's lobe energy, ∫T² with visibility over ∫T²
    without, decides (module docstring)."""
    rng = np.random.default_rng(seed)
    views = view_directions()
    directions, omega = sphere_grid(leaf_level)
    bunny = np.flatnonzero(geometry["object_names"][geometry["face_object"]] == "bunny")
    candidates = np.unique(geometry["faces"][bunny, 0])
    candidates = rng.choice(candidates, size=min(400, len(candidates)), replace=False)
    diagonal = float(np.linalg.norm(np.ptp(geometry["vertices"], axis=0)))
    normal = geometry["normals"][candidates]
    position = geometry["vertices"][candidates].astype(np.float64)
    visible = visibility(tracer, position, normal, directions, RAY_OFFSET * diagonal)
    open_sky = directions @ normal.T > 0                                       # (S, P)
    cos_view = normal @ views.T                                                # (P, 92)
    chosen = {}
    for case in CASES:
        if case.name == "anisotropic":
            angle_ok = cos_view >= math.sin(math.radians(10.0))
            view_of = np.where(angle_ok, cos_view, np.inf).argmin(axis=1)      # most grazing
        else:
            low, high = (20.0, 40.0) if case.name == "small_glossy" else (20.0, 45.0)
            angle = np.degrees(np.arccos(np.clip(cos_view, -1, 1)))
            angle_ok = (angle >= low) & (angle <= high)
            view_of = np.where(angle_ok, np.abs(angle - 0.5 * (low + high)), np.inf).argmin(1)
        tangent = tangent_from_normal(normal)
        share = np.zeros(len(candidates))
        for p in range(len(candidates)):
            if not angle_ok[p, view_of[p]]:
                share[p] = np.nan
                continue
            args = (normal[p:p + 1], tangent[p:p + 1], case.brdf, views[view_of[p]][None],
                    directions)
            t_vis = direct_glossy(*args, visible[p:p + 1])[0, 0, :, 0]
            t_all = direct_glossy(*args, open_sky[:, p][None])[0, 0, :, 0]
            total = float(np.sum(omega * t_all ** 2))
            share[p] = np.sum(omega * t_vis ** 2) / total if total > 0 else np.nan
        target = 0.55 if case.name == "large_visibility" else 1.0
        pick = int(np.nanargmin(np.abs(share - target)))
        chosen[case.name] = (int(candidates[pick]), int(view_of[pick]), float(share[pick]))
    return chosen


# ------------------------------------------------------------------ the figure

def _local_image(values_of, centre: np.ndarray, radius: float, size: int = 96) -> np.ndarray:
    """An image (size, size, C) of a function on the cap of angular ``radius`` around
    unit ``centre`` in the azimuthal equidistant projection; ``values_of`` maps
    directions (M, 3) to values (M, C). Outside the cap: NaN."""
    u = np.linspace(-1, 1, size)
    x, y = np.meshgrid(u, -u)
    rho = np.hypot(x, y) * radius
    a = tangent_from_normal(centre[None])[0]
    b = np.cross(centre, a)
    phi = np.arctan2(y, x)
    d = (np.cos(rho)[..., None] * centre + np.sin(rho)[..., None]
         * (np.cos(phi)[..., None] * a + np.sin(phi)[..., None] * b))
    img = values_of(d.reshape(-1, 3)).reshape(size, size, -1)
    img[np.hypot(x, y) > 1] = np.nan
    return img


def case_pictures(directions: np.ndarray, omega: np.ndarray, data: np.ndarray,
                  leaf_level: int, fit: sg_fit.SGFit) -> tuple[dict[str, np.ndarray], float]:
    """Images of the data and of its three approximations at the study's largest count
    (the fit's N Gaussians, 7N Haar coefficients, SH of order SH_MAX_ORDER: the paper's
    top row) on the cap of 3 × the half-maximum angle around the data's peak, and that
    half-maximum angle (radians)."""
    peak = directions[np.argmax(data[:, 0])]
    half = float(np.arccos(np.clip(directions[data[:, 0] >= 0.5 * data[:, 0].max()] @ peak,
                                   -1, 1)).max())
    radius = float(np.clip(3.0 * half, math.radians(10), math.radians(90)))
    keep = FLOATS_PER_GAUSSIAN * fit.mean.shape[1]
    haar = haar_truncation(data, leaf_level, keep)
    coefficients = sh_coefficients(directions, omega, data, SH_MAX_ORDER)
    sh_values = sh.basis(directions, SH_MAX_ORDER) @ coefficients
    gaussians = fit.mean.shape[1]

    def label(name: str, approx: np.ndarray) -> str:
        return f"{name}\n{100 * relative_l2(approx, data, omega):.2g} %"

    images = {
        "data\n": _local_image(lambda d: data[locate(d, leaf_level)], peak, radius),
        label(f"{gaussians} Gaussians", sg_values(directions, fit)):
            _local_image(lambda d: sg_values(d, fit), peak, radius),
        label(f"Haar {keep}", haar):
            _local_image(lambda d: haar[locate(d, leaf_level)], peak, radius),
        label(f"SH order {SH_MAX_ORDER}", sh_values): _local_image(
            lambda d: sh.basis(d, SH_MAX_ORDER) @ coefficients, peak, radius),
    }
    return images, half


def plot(report: dict, pictures: dict, path: Path) -> None:
    """Three columns (the cases): the four functions as images over the lobe's cap, and
    the percentage L² error against coefficients (log scale)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cases = report["cases"]
    fig = plt.figure(figsize=(4.6 * len(cases), 6.8))
    grid = fig.add_gridspec(2, 4 * len(cases), height_ratios=[1, 2.6], hspace=0.18,
                            wspace=0.35)
    for c, case in enumerate(cases):
        imgs = pictures[case["name"]]
        top = max(np.nanmax(i) for i in imgs.values())
        for k, (label, img) in enumerate(imgs.items()):
            ax = fig.add_subplot(grid[0, 4 * c + k])
            ax.imshow(np.clip(img[..., 0] / top, 0, 1), cmap="magma", vmin=0, vmax=1)
            ax.set_title(label, fontsize=7)
            ax.set_xticks([])
            ax.set_yticks([])
        ax = fig.add_subplot(grid[1, 4 * c:4 * c + 4])
        g = case["gaussians"]
        ax.plot([r["coefficients"] for r in g], [100 * r["error"] for r in g], "o-",
                label="Gaussians (7 per lobe)")
        h = case["haar"]
        ax.plot([r["coefficients"] for r in h], [100 * r["error"] for r in h], "-",
                label="Haar, K largest")
        s = case["sh"]
        ax.plot([r["coefficients"] for r in s], [100 * r["error"] for r in s], "s--",
                label="SH, order n (n²)")
        ax.set_yscale("log")
        ax.set_xlabel("coefficients (Gaussians: 7 N)")
        if c == 0:
            ax.set_ylabel("relative L² error (%)")
        ax.set_title(f"{case['title']}\nvertex {case['vertex']}, "
                     f"{case['view_angle_deg']:.0f}° view, "
                     f"visible {100 * case['visible_share']:.0f} %", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def study(workdir: Path, leaf_level: int, max_gaussians: int) -> tuple[dict, dict]:
    """The report (JSON-ready) and the pictures of the three cases."""
    from pipeline.device.raytrace import RayTracer

    geometry = scene_geometry(workdir)
    tracer = RayTracer(geometry["vertices"], geometry["faces"])
    chosen = choose_vertices(tracer, geometry, min(leaf_level, 3))
    directions, omega = sphere_grid(leaf_level)
    views = view_directions()
    report_cases, pictures = [], {}
    for case in CASES:
        vertex, view_index, share = chosen[case.name]
        view = views[view_index]
        normal = geometry["normals"][vertex]
        data = tabulate(tracer, geometry, vertex, view, case.brdf, directions)
        load_before = os.getloadavg()
        fits = fit_gaussians(directions, omega, data, max_gaussians)
        gaussians = [{
            "lobes": r["lobes"], "coefficients": FLOATS_PER_GAUSSIAN * r["lobes"],
            "error": relative_l2(sg_values(directions, r["fit"]), data, omega),
            "start": r["start"], "starts": r["starts"],
            "sigma_deg": np.degrees(r["fit"].sigma[0]).round(2).tolist(),
        } for r in fits]
        stage_default = []  # the fit as the sg.fit stage runs it: default options, N ≤ 3
        for n in range(1, min(3, max_gaussians) + 1):
            t0 = time.perf_counter()
            f = sg_fit.fit(directions, omega, data[None], sg_fit.FitOptions(lobes=n))
            stage_default.append({"lobes": n, "seconds": time.perf_counter() - t0,
                                  "iterations": int(f.iterations[0]),
                                  "error": relative_l2(sg_values(directions, f), data, omega)})
        haar_counts = range(1, FLOATS_PER_GAUSSIAN * max_gaussians + 1)
        haar = [{"coefficients": k, "error": relative_l2(haar_truncation(data, leaf_level, k),
                                                         data, omega)} for k in haar_counts]
        sh_rows = [{"order": n, "coefficients": n * n,
                    "error": relative_l2(sh_least_squares(directions, omega, data, n), data,
                                         omega)} for n in range(1, SH_MAX_ORDER + 1)]
        table = []
        for r in gaussians:
            k = r["coefficients"]
            at_most = max((s for s in sh_rows if s["coefficients"] <= k),
                          key=lambda s: s["coefficients"])
            at_least = [s for s in sh_rows if s["coefficients"] >= k]
            table.append({"lobes": r["lobes"], "coefficients": k, "gaussians": r["error"],
                          "haar": haar[k - 1]["error"],
                          "sh_at_most": {"order": at_most["order"], "error": at_most["error"]},
                          "sh_at_least": ({"order": at_least[0]["order"],
                                           "error": at_least[0]["error"]}
                                          if at_least else None)})
        pictures[case.name], half = case_pictures(directions, omega, data, leaf_level,
                                                  fits[-1]["fit"])
        report_cases.append({
            "name": case.name, "title": case.title, "vertex": vertex,
            "position": geometry["vertices"][vertex].tolist(), "normal": normal.tolist(),
            "view_index": view_index, "view": view.tolist(),
            "view_angle_deg": float(np.degrees(np.arccos(np.clip(normal @ view, -1, 1)))),
            "visible_share": share,
            "brdf": {"model": case.brdf.model, "specular": list(case.brdf.specular),
                     "gamma": case.brdf.gamma, "alpha_ratio": case.brdf.alpha_ratio},
            "half_max_angle_deg": math.degrees(half),
            "fit_seconds": sum(s["seconds"] for r in gaussians for s in r["starts"].values()),
            "load_before": load_before, "load_after": os.getloadavg(),
            "gaussians": gaussians, "gaussians_stage_default": stage_default,
            "haar": haar, "sh": sh_rows, "table": table,
        })
    report = {
        "study": "paper 003 Fig. 5: relative L2 error of N Gaussians vs Haar and SH",
        "scene": str(SCENE.relative_to(ROOT)), "leaf_level": leaf_level,
        "directions": len(directions), "max_gaussians": max_gaussians,
        "floats_per_gaussian": FLOATS_PER_GAUSSIAN,
        "fit_options": {k: v for k, v in FIT_OPTIONS.__dict__.items() if k != "lobes"},
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count()},
        "cases": report_cases,
    }
    return report, pictures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--leaf-level", type=int, default=5)
    parser.add_argument("--max-gaussians", type=int, default=10)
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/sg_fig5"))
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "sg_fig5")
    args = parser.parse_args()
    from pipeline.device.threads import one_blas_thread

    one_blas_thread()
    report, pictures = study(args.workdir, args.leaf_level, args.max_gaussians)
    args.out.with_suffix(".json").write_text(json.dumps(report, indent=1))
    plot(report, pictures, args.out.with_suffix(".png"))
    for case in report["cases"]:
        print(case["name"], f"fit {case['fit_seconds']:.1f} s, load {case['load_before']}")
        for row in case["table"]:
            print(f"  N={row['lobes']:2d} K={row['coefficients']:3d}  "
                  f"SG {100 * row['gaussians']:6.2f} %"
                  f"  Haar {100 * row['haar']:6.2f} %  SH(n={row['sh_at_most']['order']}) "
                  f"{100 * row['sh_at_most']['error']:6.2f} %")


if __name__ == "__main__":
    main()

"""Noise-free answers at sample pixels of bunny_grace, and what leaf level 4 costs.

For ``--pixels`` surface pixels (a fixed-seed sample, a third each from the bunny, the
ground the bunny shadows and the rest of the ground; regions as
studies/triple_accuracy.py) it integrates B = ∫ L(Fω) V(ω) ρ̃(ω, ω_o) dω by
quadrature over the leaves of geodesic level ``--fine`` (7: 327 680 directions, one per
leaf centroid weighted by its solid angle, ≈ 0.35°: about a texel of the 1024×512 map),
with L the raw map (bilinear, EnvironmentMap), V traced with Embree in the method's
convention (pipeline/methods/triple/stages/visibility.py: above both horizons, from p + 1e-4·diag·g)
and ρ̃ = (kd/π + ρs f_g) cos⁺θi (pipeline/math/brdf.py ``evaluate``), in the pixel's
shading frame (the renderer's normal and tangent). Per pixel it also forms, on the
leaves of level 4 (each the union of 4^(fine − 4) fine leaves):

* ``leaf4``: Σ Ω·L̄·V̄·ρ̃̄, the triple product of the three leaf-mean functions: what
  method triple computes with rows kept whole and no interpolation;
* ``leaf4 L`` = Σ Ω·L̄·(Vρ̃)‾, ``leaf4 V`` = Σ Ω·V̄·(Lρ̃)‾, ``leaf4 rho`` = Σ Ω·ρ̃̄·(LV)‾:
  one function averaged over the leaf at a time (which one's averaging costs);

and, on the fine leaves (no leaf averaging), one interpolation of the renderer at a time:

* ``frames``: L replaced by the trilinear blend of the map seen in the 8 nearest frames
  of the rotation grid (``--frame-grid``, FrameGrid.weights: Σ w_f L(F_f ω));
* ``views``: the glossy term replaced by the bilinear blend of it at the 4 nearest views
  of the view grid (``--view-grid``, ViewGrid.weights).

It compares them (relative RMSE over the sampled pixels, per region) with the quadrature,
and, given ``--frame`` (a .npy of a triple frame) and ``--reference`` (an env-direct
reference artifact, .zarr), the frame and the reference too: the frame's error at those
pixels without reference noise, and the reference's bias (its mean against the quadrature,
in units of its own standard error: a z-score that is ≈ N(0, 1) when it is unbiased).

    python studies/triple_quadrature.py --workdir /tmp/acc/w/default --pixels 150 \\
        --frame default.npy --reference REF.zarr \\
        --out benchmarks/results/triple_accuracy/quadrature.json
"""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path

import click
import numpy as np

from pipeline import job
from pipeline.device.raytrace import Mesh, RayTracer, surface_at
from pipeline.engine.store import open_artifact
from pipeline.images import read_environment
from pipeline.math.brdf import evaluate, glossy, scene_brdfs, to_local
from pipeline.math.camera import camera_rays
from pipeline.math.envmap import EnvironmentMap
from pipeline.math.geodesic import geodesic_levels
from pipeline.methods.triple.frame_grids import FrameGrid, ViewGrid

SCENE = "scenes/bunny_grace.yaml"
COARSE = 4  # the method's leaf level


def _sample_pixels(regions: dict[str, np.ndarray], count: int, seed: int = 0
                   ) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {name: rng.choice(np.flatnonzero(mask), min(count // 3, int(mask.sum())),
                             replace=False) for name, mask in regions.items()}


@click.command()
@click.option("--workdir", type=click.Path(path_type=Path), required=True,
              help="A baked bunny_grace work directory (its root).")
@click.option("--size", type=int, default=128, show_default=True)
@click.option("--pixels", type=int, default=150, show_default=True)
@click.option("--fine", type=int, default=7, show_default=True)
@click.option("--frame-grid", nargs=3, type=int, default=(32, 16, 32), show_default=True)
@click.option("--view-grid", nargs=2, type=int, default=(128, 64), show_default=True)
@click.option("--frame", "frame_path", type=click.Path(path_type=Path))
@click.option("--reference", "reference_path", type=click.Path(path_type=Path))
@click.option("--worst", is_flag=True, help="Instead of a sample: the --pixels bunny pixels "
              "where the frame differs most from the reference (needs --frame, --reference).")
@click.option("--out", type=click.Path(path_type=Path), required=True)
def main(workdir, size, pixels, fine, frame_grid, view_grid, frame_path, reference_path, worst,
         out):
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    from triple_accuracy import regions

    start = time.perf_counter()
    scene = job.open_scene(SCENE, (size, size))
    wd = job.workdir_for(scene, workdir)
    geo = open_artifact(wd.artifact("geometry"), "geometry")
    arrays = {n: geo.read(n) for n in
              ("vertices", "normals", "uv", "faces", "face_object", "object_material")}
    names = list(geo.attrs["material_names"])
    frame = np.load(frame_path) if frame_path else None
    masks = regions(scene, wd, frame if frame is not None else
                    np.ones((size, size, 3), np.float32))
    if worst:  # the bunny pixels where the frame differs most from the reference
        gap = np.linalg.norm(frame - open_artifact(reference_path, "reference").read("mean"),
                             axis=-1)
        gap[~masks["bunny"]] = -1
        chosen = {"worst bunny": np.argsort(gap.ravel())[::-1][:pixels]}
    else:
        chosen = _sample_pixels({"bunny": masks["bunny"],
                                 "shadowed ground": masks["shadowed ground"],
                                 "open ground": masks["ground"] & ~masks["shadowed ground"]},
                                pixels)
    flat = np.concatenate(list(chosen.values()))
    cam = scene.camera
    o, d = camera_rays(cam.position, cam.look_at, cam.up, cam.fov, cam.width, cam.height)
    o, d = o.reshape(-1, 3)[flat].astype(np.float64), d.reshape(-1, 3)[flat].astype(np.float64)
    tracer = RayTracer(arrays["vertices"], arrays["faces"])
    mesh = Mesh.from_arrays(arrays)
    hits = tracer.intersect(o, d)
    surface = surface_at(mesh, hits, o, d)
    light = next(li for li in scene.lights if li.type == "environment").params
    env = EnvironmentMap(read_environment(light["file"]), light.get("rotation", 0.0),
                         light.get("scale", 1.0))
    brdfs = scene_brdfs(scene, names)
    level = geodesic_levels(fine)[fine]
    omega, dirs = level.areas, level.centroids  # (N,), (N, 3) local directions
    group = 4 ** (fine - COARSE)
    coarse_area = omega.reshape(-1, group).sum(1)
    eps = 1e-4 * float(np.ptp(arrays["vertices"], 0).max())
    g_normal = mesh.face_normal[surface.face]
    grid, views = FrameGrid(*frame_grid), ViewGrid(*view_grid)
    grid_frames = grid.frames()
    view_dirs = views.directions()
    results = []
    for k in range(len(flat)):
        n, t = surface.normal[k], surface.tangent[k]
        b = np.cross(n, t)
        world = dirs[:, :1] * t + dirs[:, 1:2] * b + dirs[:, 2:] * n
        up = (dirs[:, 2] > 0) & (world @ g_normal[k] > 0)
        origin = surface.position[k] + eps * g_normal[k]
        vis = np.zeros(len(dirs))
        idx = np.flatnonzero(up)
        vis[idx] = ~tracer.occluded(np.broadcast_to(origin, (len(idx), 3)), world[idx],
                                    np.full(len(idx), 1e30))
        radiance = env.radiance(world)
        wo = to_local(-d[k][None], n[None], t[None])[0]
        rho = evaluate(dirs, np.broadcast_to(wo, dirs.shape),
                       brdfs[surface.material_id[k]]) * np.clip(dirs[:, 2:], 0, None)
        lv_rho = radiance * vis[:, None] * rho
        entries, weights = grid.weights(n[None], t[None])
        blended = sum(w * env.radiance(dirs @ grid_frames[e].T)
                      for e, w in zip(entries[0], weights[0], strict=True) if w > 0)
        p = brdfs[surface.material_id[k]]
        cos = np.clip(dirs[:, 2:], 0, None)
        v_entries, v_weights = views.weights(wo[None])
        glossy_blend = sum(w * glossy(dirs, np.broadcast_to(view_dirs[e], dirs.shape), p)
                           for e, w in zip(v_entries[0], v_weights[0], strict=True) if w > 0)
        rho_views = (np.asarray(p.albedo) / np.pi + np.asarray(p.specular)
                     * glossy_blend[:, None]) * cos * (wo[2] > 0)
        truth = (omega[:, None] * lv_rho).sum(0)

        def mean(f):  # leaf-4 means (area-weighted) of a fine function (N,) or (N, 3)
            f2 = f.reshape(len(coarse_area), group, -1)
            return (f2 * omega.reshape(-1, group, 1)).sum(1) / coarse_area[:, None]

        lm, vm, rm = mean(radiance), mean(vis), mean(rho)
        area = coarse_area[:, None]
        results.append({
            "pixel": int(flat[k]), "truth": truth,
            "leaf4": (area * lm * vm * rm).sum(0),
            "leaf4 L": (area * lm * mean(vis[:, None] * rho)).sum(0),
            "leaf4 V": (area * vm * mean(radiance * rho)).sum(0),
            "leaf4 rho": (area * rm * mean(radiance * vis[:, None])).sum(0),
            "frames": (omega[:, None] * blended * vis[:, None] * rho).sum(0),
            "views": (omega[:, None] * radiance * vis[:, None] * rho_views).sum(0)})
    region_of = np.concatenate([[name] * len(v) for name, v in chosen.items()])
    truth = np.array([r["truth"] for r in results])
    report = {"size": size, "fine_level": fine, "pixels": {k: len(v) for k, v in chosen.items()},
              "seconds": time.perf_counter() - start, "loadavg": os.getloadavg(),
              "errors": {}}
    candidates = {name: np.array([r[name] for r in results])
                  for name in ("leaf4", "leaf4 L", "leaf4 V", "leaf4 rho", "frames", "views")}
    if frame is not None:
        candidates["frame"] = frame.reshape(-1, 3)[flat]
    ref = None
    if reference_path:
        stored = open_artifact(reference_path, "reference")
        ref = (stored.read("mean").reshape(-1, 3)[flat].astype(np.float64),
               stored.read("variance").reshape(-1, 3)[flat].astype(np.float64))
        candidates["reference"] = ref[0]
    for name, values in candidates.items():
        report["errors"][name] = {}
        for region in [*chosen, "all"]:
            m = np.ones(len(flat), bool) if region == "all" else region_of == region
            err = math.sqrt(float(np.sum((values[m] - truth[m]) ** 2))
                            / float(np.sum(truth[m] ** 2)))
            entry = {"rel_rmse": err,
                     "mean_ratio": float(values[m].mean() / truth[m].mean())}
            if name == "reference":
                entry["noise"] = math.sqrt(float(ref[1][m].sum()) / float(np.sum(truth[m] ** 2)))
                z = (ref[0][m] - truth[m]) / np.sqrt(np.maximum(ref[1][m], 1e-30))
                entry["z_mean"], entry["z_rms"] = float(z.mean()), float(np.sqrt((z * z).mean()))
            report["errors"][name][region] = entry
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=1))
    np.save(out.with_suffix(".npy"), np.concatenate([flat[:, None].astype(float), truth], 1))
    print(json.dumps(report["errors"], indent=1))


if __name__ == "__main__":
    main()

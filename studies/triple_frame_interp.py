"""Which interpolation of the rotation grid costs method triple how much on bunny_grace.

Method triple bakes the lighting in a grid of local frames F
(pipeline/methods/triple/frame_grids.py)
and shades a point in frame R with Σ_f w_f L_F_f: since the triple product is linear in
the lighting, its answer is Σ_f w_f B(F_f), with

    B(F) = ∫ L(F ω) T(ω) dω,   T(ω) = V(ω) ρ̃(ω, ω_o)   (ω local, the pixel's own T),

so the grid's error at a point is how well the weights w interpolate B from the grid's
frames to R. This script measures that, noise free, for grids and weightings: for
``--pixels`` bunny pixels (fixed seed; the floor's normal is a grid row, its error is
0) it forms T on the leaves of geodesic level ``--fine`` (visibility traced with Embree,
the BRDF of studies/triple_quadrature.py), B(R) for the pixel's own frame (the truth)
and Σ w_f B(F_f) for each case:

* ``trilinear`` on grids [n_phi, n_theta, n_psi]: the method's interpolation
  (FrameGrid.weights, 8 frames); grids refined along one axis at a time say which
  Euler angle carries the error;
* ``simplex``: 4 frames, barycentric weights in the grid cell's Freudenthal tetrahedron,
  with the cell's φψ-diagonal along the short one of the rotation metric
  ds² = dθ² + dφ² + dψ² + 2 cos θ dφ dψ (φ − ψ where cos θ > 0);
* ``cubic``: 64 frames, Catmull-Rom weights per axis (θ clamped at the poles).

Writes ``--out`` (JSON: relative RMSE and mean ratio per case, over the pixels; frames
and bytes per case) and prints a table.

    python studies/triple_frame_interp.py --workdir /tmp/acc2/w/default --pixels 60 \\
        --out benchmarks/results/triple_accuracy/frame_interp.json
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from pathlib import Path

import click
import numpy as np

from pipeline import job
from pipeline.device.raytrace import Mesh, RayTracer, surface_at
from pipeline.engine.store import open_artifact
from pipeline.images import read_environment
from pipeline.math.brdf import evaluate, scene_brdfs, to_local
from pipeline.math.camera import camera_rays
from pipeline.math.envmap import EnvironmentMap
from pipeline.math.geodesic import geodesic_levels
from pipeline.methods.triple.frame_grids import FrameGrid, euler_angles

SCENE = "scenes/bunny_grace.yaml"
GRIDS = [(32, 16, 32), (32, 17, 32), (64, 16, 32), (32, 31, 32), (32, 16, 64),
         (48, 16, 48), (48, 17, 48), (32, 24, 32), (48, 24, 48), (64, 32, 64)]
SCHEMES = {(32, 16, 32): ("trilinear", "simplex", "cubic"),
           (32, 17, 32): ("trilinear", "simplex", "cubic"),
           (48, 17, 48): ("trilinear", "simplex")}


def simplex_weights(grid: FrameGrid, normal: np.ndarray, tangent: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """4 entries (P, 4) and barycentric weights (P, 4) of the frames around each point:
    the Freudenthal tetrahedron of its grid cell that contains it, the cell's ψ axis
    reversed where cos θ > 0 so that the φψ-diagonal used is φ − ψ, the short one."""
    phi, theta, psi = euler_angles(normal, tangent)
    x = np.stack([phi * grid.n_phi / (2 * np.pi),
                  np.clip(theta * (grid.n_theta - 1) / np.pi, 0, grid.n_theta - 1 - 1e-9),
                  psi * grid.n_psi / (2 * np.pi)], -1)
    base = np.floor(x)
    frac = x - base
    flip = np.cos(theta) > 0  # walk ψ downwards from the cell's upper ψ corner
    step = np.ones_like(x)
    base[flip, 2] += 1
    frac[flip, 2] = 1 - frac[flip, 2]
    step[flip, 2] = -1
    order = np.argsort(-frac, -1)
    f = np.take_along_axis(frac, order, -1)
    weights = np.stack([1 - f[:, 0], f[:, 0] - f[:, 1], f[:, 1] - f[:, 2], f[:, 2]], -1)
    corners = [base.copy()]
    for a in range(3):
        c = corners[-1].copy()
        axis = order[:, a]
        c[np.arange(len(c)), axis] += step[np.arange(len(c)), axis]
        corners.append(c)
    entries = [_index(grid, c) for c in corners]
    return np.stack(entries, -1), weights


def _index(grid: FrameGrid, c: np.ndarray) -> np.ndarray:
    j = np.mod(c[:, 0].astype(np.int64), grid.n_phi)
    i = np.clip(c[:, 1].astype(np.int64), 0, grid.n_theta - 1)
    k = np.mod(c[:, 2].astype(np.int64), grid.n_psi)
    return (j * grid.n_theta + i) * grid.n_psi + k


def cubic_weights(grid: FrameGrid, normal: np.ndarray, tangent: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """64 entries (P, 64) and Catmull-Rom weights (P, 64) (θ indices clamped)."""
    phi, theta, psi = euler_angles(normal, tangent)
    x = np.stack([phi * grid.n_phi / (2 * np.pi), theta * (grid.n_theta - 1) / np.pi,
                  psi * grid.n_psi / (2 * np.pi)], -1)
    base = np.floor(x)
    t = x - base

    def cr(t):  # Catmull-Rom weights of offsets −1, 0, 1, 2
        return np.stack([(-t ** 3 + 2 * t ** 2 - t) / 2, (3 * t ** 3 - 5 * t ** 2 + 2) / 2,
                         (-3 * t ** 3 + 4 * t ** 2 + t) / 2, (t ** 3 - t ** 2) / 2], -1)

    w = [cr(t[:, a]) for a in range(3)]
    entries, weights = [], []
    for a in range(4):
        for b in range(4):
            for c in range(4):
                corner = base + np.array([a - 1, b - 1, c - 1])
                entries.append(_index(grid, corner))
                weights.append(w[0][:, a] * w[1][:, b] * w[2][:, c])
    return np.stack(entries, -1), np.stack(weights, -1)


@click.command()
@click.option("--workdir", type=click.Path(path_type=Path), required=True,
              help="A baked bunny_grace work directory (its root; the geometry is read).")
@click.option("--size", type=int, default=128, show_default=True)
@click.option("--pixels", type=int, default=60, show_default=True)
@click.option("--fine", type=int, default=6, show_default=True)
@click.option("--out", type=click.Path(path_type=Path), required=True)
def main(workdir, size, pixels, fine, out):
    sys.path.insert(0, str(Path(__file__).parent))
    from triple_accuracy import regions

    start, load0 = time.perf_counter(), os.getloadavg()
    scene = job.open_scene(SCENE, (size, size))
    wd = job.workdir_for(scene, workdir)
    geo = open_artifact(wd.artifact("geometry"), "geometry")
    arrays = {n: geo.read(n) for n in
              ("vertices", "normals", "uv", "faces", "face_object", "object_material")}
    names = list(geo.attrs["material_names"])
    masks = regions(scene, wd, np.ones((size, size, 3), np.float32))
    bunny = masks["bunny"] & ~masks["turned normals"] if "turned normals" in masks \
        else masks["bunny"]
    flat = np.random.default_rng(0).choice(np.flatnonzero(bunny), pixels, replace=False)
    cam = scene.camera
    o, d = camera_rays(cam.position, cam.look_at, cam.up, cam.fov, cam.width, cam.height)
    o, d = o.reshape(-1, 3)[flat].astype(np.float64), d.reshape(-1, 3)[flat].astype(np.float64)
    tracer = RayTracer(arrays["vertices"], arrays["faces"])
    mesh = Mesh.from_arrays(arrays)
    surface = surface_at(mesh, tracer.intersect(o, d), o, d)
    light = next(li for li in scene.lights if li.type == "environment").params
    env = EnvironmentMap(read_environment(light["file"]), light.get("rotation", 0.0),
                         light.get("scale", 1.0))
    brdfs = scene_brdfs(scene, names)
    level = geodesic_levels(fine)[fine]
    omega, dirs = level.areas, level.centroids
    eps = 1e-4 * float(np.ptp(arrays["vertices"], 0).max())
    g_normal = mesh.face_normal[surface.face]
    grids = {g: FrameGrid(*g) for g in GRIDS}
    frames = {g: grid.frames() for g, grid in grids.items()}
    cases: dict[str, tuple] = {}  # name → (grid, entries (P, k), weights (P, k))
    for g, grid in grids.items():
        n, t = surface.normal, surface.tangent
        for scheme in SCHEMES.get(g, ("trilinear",)):
            fn = {"trilinear": grid.weights, "simplex": lambda n, t, grid=grid:
                  simplex_weights(grid, n, t), "cubic": lambda n, t, grid=grid:
                  cubic_weights(grid, n, t)}[scheme]
            cases[f"{scheme} {g[0]}x{g[1]}x{g[2]}"] = (g, *fn(n, t))
    truth = np.zeros((len(flat), 3))
    values = {name: np.zeros((len(flat), 3)) for name in cases}
    for k in range(len(flat)):
        n, t = surface.normal[k], surface.tangent[k]
        b = np.cross(n, t)
        world = dirs[:, :1] * t + dirs[:, 1:2] * b + dirs[:, 2:] * n
        up = (dirs[:, 2] > 0) & (world @ g_normal[k] > 0)
        vis = np.zeros(len(dirs))
        idx = np.flatnonzero(up)
        vis[idx] = ~tracer.occluded(
            np.broadcast_to(surface.position[k] + eps * g_normal[k], (len(idx), 3)),
            world[idx], np.full(len(idx), 1e30))
        wo = to_local(-d[k][None], n[None], t[None])[0]
        rho = evaluate(dirs, np.broadcast_to(wo, dirs.shape),
                       brdfs[surface.material_id[k]]) * np.clip(dirs[:, 2:], 0, None)
        weight = omega[:, None] * vis[:, None] * rho  # Ω T, (N, 3)
        keep = np.flatnonzero(weight.any(1))
        weight, local = weight[keep], dirs[keep]
        truth[k] = (env.radiance(world[keep]) * weight).sum(0)
        cache: dict[tuple, np.ndarray] = {}

        def b_of(g, e, cache=cache, local=local, weight=weight):  # B(F_e), grid g's entry e
            if (g, e) not in cache:
                cache[(g, e)] = (env.radiance(local @ frames[g][e].T) * weight).sum(0)
            return cache[(g, e)]

        for name, (g, entries, w) in cases.items():
            values[name][k] = sum(wf * b_of(g, int(e))
                                  for e, wf in zip(entries[k], w[k], strict=True) if wf != 0)
    report = {"size": size, "fine_level": fine, "pixels": len(flat),
              "seconds": time.perf_counter() - start, "loadavg": [load0, os.getloadavg()],
              "cases": {}}
    for name, (g, entries, _) in cases.items():
        v = values[name]
        report["cases"][name] = {
            "grid": list(g), "frames": int(np.prod(g)), "frames_per_point": entries.shape[1],
            "rel_rmse": math.sqrt(float(np.sum((v - truth) ** 2) / np.sum(truth ** 2))),
            "mean_ratio": float(v.mean() / truth.mean())}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=1))
    for name, c in report["cases"].items():
        print(f"{name:28s} frames {c['frames']:6d} x{c['frames_per_point']:<3d} "
              f"rmse {100 * c['rel_rmse']:5.2f} %  mean {c['mean_ratio']:.4f}")


if __name__ == "__main__":
    main()

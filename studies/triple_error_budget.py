"""Error budget of method triple on bunny_grace (issue 16): where each point of the
bunny's error comes from, per pixel on the same pixels, noise free.

Without truncation the triple product of three functions held as wavelet rows on the
leaves of level L (``triple.leaf_level``) is exactly Σ_leaves Ω_l L_l V_l ρ_l of their
leaf values (the basis is orthonormal and spans the functions constant on the leaves,
pipeline/math/sphwavelet.py), so each approximation the method makes is one factor of
that sum replaced. For ``--pixels`` bunny pixels (fixed seed; the turned-normal rim
pixels left out: both triple and the reference are black there) in the method's own
shading frame (n, t, ω_o from its G-buffer) this script forms, in order:

====  ==========================================================================
A0    truth: Σ over the leaves of level ``--fine`` of Ω L V ρ (raw map, V by ray
      casting at the pixel in its frame, ρ = f(ω_i, ω_o)·cos⁺θ_i at the exact ω_o)
A1    leaf level: the same samples averaged to level-L leaf means (Ω-weighted), the
      product of the means summed: the method's floor at its leaf level
A2    + the method's own leaf sampling: L from 4^light_refine samples of the map
      prefiltered to their spacing (light_grid.prefilter), V from
      4^visibility_refine rays, ρ from 4^brdf_refine samples (still the pixel's
      own frame, ω_o and position)
A3    + the rotation grid: L = Σ_f w_f L_{F_f}, the 8 grid frames and trilinear
      weights of FrameGrid.weights
A4    + the BRDF table's view grid: ρ = Σ_v w_v ρ(ω_v), its 4 views (ViewGrid)
A5    + the visibility texture: V = Σ_t w_t V_t, the 4 texels of the bilinear
      lookup, each cast from its own surface point in its own frame (atlas);
      split (``texture_split_alone``) into the texels' points seen in the pixel's
      frame and the pixel's point seen in the texels' frames
A6    + truncation and float16: the stored rows (the method as rendered; checked
      against the renderer's frame at the same pixels: ``render_check``)
====  ==========================================================================

Reported per step (relative RMSE over the pixels, RGB, against ‖A0‖): its error
against the truth, the step's own change ‖A_k − A_(k−1)‖, and for steps 3–6 the change
when only that factor is replaced in A2 (``alone``). With ``--grids`` each extra frame
grid (and ``--cubic-axis``: Catmull-Rom weights along one Euler axis, trilinear on the
others, 16 frames) gives the A3 step it would give, and ``--canonical`` the step with
ψ exact (bilinear in φ, θ: 4 frames at the pixel's own ψ, what baking each texel and
pixel of an isotropic material in the tangent whose ψ is a grid value would give).
With ``--reference`` (a reference artifact) the pixels' truth is compared with the
path tracer there (noise-corrected).

    python studies/triple_error_budget.py --workdir /tmp/h18acc/w/default \\
        --pixels 100 --grids 48x17x48,64x17x64,32x33x32 \\
        --out benchmarks/results/triple_accuracy/error_budget.json
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
from pipeline.math.envmap import EnvironmentMap
from pipeline.math.geodesic import geodesic_levels
from pipeline.methods.triple.brdf_tables import diffuse_leaf_means, glossy_leaf_means
from pipeline.methods.triple.frame_grids import FrameGrid, euler_angles, euler_frame
from pipeline.methods.triple.gbuffer import LookupTables, lookups_numpy
from pipeline.methods.triple.light_grid import prefilter, sample_spacing
from pipeline.methods.triple.render import camera_gbuffer, load_tables
from pipeline.registry import get_method
from pipeline.render.surface_detail import SceneDetail
from pipeline.stages.geometry import traced_geometry

SCENE = "scenes/bunny_grace.yaml"
STEPS = ["A0 truth", "A1 leaf level", "A2 leaf sampling", "A3 rotation grid",
         "A4 view grid", "A5 visibility texture", "A6 truncation"]


def cubic_axis_weights(grid: FrameGrid, normal: np.ndarray, tangent: np.ndarray,
                       axis: int) -> tuple[np.ndarray, np.ndarray]:
    """16 entries (P, 16) and weights: Catmull-Rom along Euler axis ``axis`` (0 φ, 1 θ
    clamped at the poles, 2 ψ), linear along the other two."""
    phi, theta, psi = euler_angles(normal, tangent)
    x = np.stack([phi * grid.n_phi / (2 * np.pi), theta * (grid.n_theta - 1) / np.pi,
                  psi * grid.n_psi / (2 * np.pi)], -1)
    x[:, 1] = np.clip(x[:, 1], 0, grid.n_theta - 1 - 1e-9)
    base = np.floor(x)
    t = x - base

    def taps(a):  # offsets and weights along axis a
        if a == axis:
            s = t[:, a]
            w = np.stack([(-s ** 3 + 2 * s ** 2 - s) / 2, (3 * s ** 3 - 5 * s ** 2 + 2) / 2,
                          (-3 * s ** 3 + 4 * s ** 2 + s) / 2, (s ** 3 - s ** 2) / 2], -1)
            return [-1, 0, 1, 2], w
        return [0, 1], np.stack([1 - t[:, a], t[:, a]], -1)

    (oa, wa), (ob, wb), (oc, wc) = taps(0), taps(1), taps(2)
    entries, weights = [], []
    for p, a in enumerate(oa):
        for q, b in enumerate(ob):
            for r, c in enumerate(oc):
                j = np.mod(base[:, 0] + a, grid.n_phi).astype(np.int64)
                i = np.clip(base[:, 1] + b, 0, grid.n_theta - 1).astype(np.int64)
                k = np.mod(base[:, 2] + c, grid.n_psi).astype(np.int64)
                entries.append((j * grid.n_theta + i) * grid.n_psi + k)
                weights.append(wa[:, p] * wb[:, q] * wc[:, r])
    return np.stack(entries, -1), np.stack(weights, -1)


def _grid(text: str) -> tuple[int, int, int]:
    a, b, c = (int(v) for v in text.split("x"))
    return a, b, c


@click.command()
@click.option("--workdir", type=click.Path(path_type=Path), required=True,
              help="A baked bunny_grace work directory (root) at --size.")
@click.option("--size", type=int, default=128, show_default=True)
@click.option("--pixels", type=int, default=100, show_default=True)
@click.option("--fine", type=int, default=6, show_default=True,
              help="Geodesic level of the truth's samples (the leaf level + 2 at least).")
@click.option("--grids", default="", help="Extra frame grids for the A3 step, e.g. "
              "48x17x48,64x17x64 (comma-separated).")
@click.option("--cubic-axis/--no-cubic-axis", default=True, show_default=True,
              help="Also Catmull-Rom along each one Euler axis of the baked grid.")
@click.option("--canonical/--no-canonical", default=True, show_default=True,
              help="Also the grid with ψ exact (each pixel's tangent the one whose ψ is "
              "a grid value, as an isotropic material could choose): bilinear in φ, θ.")
@click.option("--reference", type=click.Path(path_type=Path),
              help="An env-direct reference artifact (.zarr) of the scene at --size.")
@click.option("--out", type=click.Path(path_type=Path), required=True)
def main(workdir, size, pixels, fine, grids, cubic_axis, canonical, reference, out):
    sys.path.insert(0, str(Path(__file__).parent))
    from triple_accuracy import regions

    start, load0 = time.perf_counter(), os.getloadavg()
    method = get_method("triple")
    scene = job.open_scene(SCENE, (size, size))
    wd = job.workdir_for(scene, workdir)
    artifacts = job.method_artifacts(method, wd)
    geo = artifacts["geometry"]
    names = list(geo.attrs["material_names"])
    tables, atlas = load_tables(artifacts, names)
    level = tables.basis.leaf_level
    light_attrs = artifacts["triple.light_rotations"].attrs
    vis_attrs = artifacts["triple.visibility"].attrs
    brdf_attrs = artifacts["triple.brdf_tables"].attrs
    light_refine = int(light_attrs["refine"])
    vis_refine = int(vis_attrs["visibility_refine"])
    brdf_refine = int(brdf_attrs["refine"])

    masks = regions(scene, wd, np.ones((size, size, 3), np.float32))
    chosen = masks["bunny"] & ~masks["turned normals"]
    flat = np.sort(np.random.default_rng(0).choice(np.flatnonzero(chosen), pixels,
                                                    replace=False))
    arrays = {n: geo.read(n) for n in
              ("vertices", "normals", "uv", "faces", "face_object", "object_material")}
    mesh = Mesh.from_arrays(arrays)
    tracer = RayTracer(arrays["vertices"], arrays["faces"])
    gbuffer = camera_gbuffer(tracer, mesh, atlas, SceneDetail(scene, names), scene.camera)
    g_index = np.searchsorted(gbuffer.pixel, flat)
    assert np.array_equal(gbuffer.pixel[g_index], flat)
    brdfs = scene_brdfs(scene, names)
    kd = np.array([b.albedo for b in brdfs], np.float64)
    rho_s = np.array([b.specular for b in brdfs], np.float64)
    lookups = lookups_numpy(gbuffer, tables, LookupTables.of(tables, atlas, kd, rho_s), 0.0)

    # the pixels' surface points (positions and face normals; frames from the G-buffer)
    cam = scene.camera
    from pipeline.math.camera import camera_rays
    o, d = camera_rays(cam.position, cam.look_at, cam.up, cam.fov, cam.width, cam.height)
    o, d = o.reshape(-1, 3)[flat].astype(np.float64), d.reshape(-1, 3)[flat].astype(np.float64)
    surface = surface_at(mesh, tracer.intersect(o, d), o, d)
    normal = gbuffer.normal[g_index].astype(np.float64)
    tangent = gbuffer.tangent[g_index].astype(np.float64)
    view = gbuffer.view[g_index].astype(np.float64)
    material = gbuffer.material_a[g_index]
    traced = traced_geometry(open_artifact(wd.artifact("geometry"), "geometry"))
    ray_tracer, face_normal_all, epsilon = traced.tracer, traced.mesh.face_normal, traced.epsilon
    g_normal = face_normal_all[surface.face]

    # the texels (flat over objects, as load_tables' atlas) and their surface points
    atlas_art = artifacts["triple.atlas"]
    from pipeline.engine.chunkwrite import segment_name
    objects = list(atlas_art.attrs["texture_sizes"])
    texel = {n: np.concatenate([np.asarray(atlas_art.group[n][segment_name(obj)])
                                for obj in objects])
             for n in ("texel_face", "texel_position", "texel_normal", "texel_tangent")}
    object_ranges = geo.read("object_ranges")
    obj_names = list(geo.attrs["object_names"])
    first_face = np.concatenate([np.full(int(np.prod(atlas_art.attrs["texture_sizes"][o])),
                                         object_ranges[obj_names.index(o), 2])
                                 for o in objects])

    env_file = next(li for li in scene.lights if li.type == "environment").params["file"]
    rgb = read_environment(env_file)
    raw = EnvironmentMap(rgb)
    filtered = EnvironmentMap(prefilter(rgb, sample_spacing(level, light_refine),
                                        tables.frames.n_phi))
    fine_level = geodesic_levels(fine)[fine]
    dirs, omega = fine_level.centroids, fine_level.areas
    n_leaf = 20 * 4 ** level
    omega_leaf = omega.reshape(n_leaf, -1).sum(1)

    def means(values: np.ndarray, lvl: int) -> np.ndarray:
        """Ω-weighted leaf means (N, ...) of level-L leaves of values on level ``lvl``."""
        a = geodesic_levels(lvl)[lvl].areas.reshape(n_leaf, -1)
        v = values.reshape(n_leaf, a.shape[1], -1)
        return np.einsum("nk,nkc->nc", a, v) / a.sum(1)[:, None]

    sample_dirs = {r: geodesic_levels(level + r)[level + r].centroids
                   for r in {light_refine, vis_refine, brdf_refine}}

    def light_means(frame: np.ndarray) -> np.ndarray:
        return means(filtered.radiance(sample_dirs[light_refine] @ frame.T), level + light_refine)

    def vis_means(position, n, t, g) -> np.ndarray:
        local = sample_dirs[vis_refine]
        b = np.cross(n, t)
        world = local[:, :1] * t + local[:, 1:2] * b + local[:, 2:] * n
        up = np.flatnonzero((local[:, 2] > 0) & (world @ g > 0))
        vis = np.zeros(len(local))
        vis[up] = ~ray_tracer.occluded(
            np.broadcast_to(position + epsilon * g, (len(up), 3)).astype(np.float32),
            world[up].astype(np.float32), np.full(len(up), np.inf, np.float32))
        return means(vis, level + vis_refine)

    diffuse = diffuse_leaf_means(level, brdf_refine)[:, None]

    def brdf_means(m: int, wo: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Leaf means (N, 3) of kd ρ̃_d + ρs Σ_v w_v ρ̃_g(·; ω_v) for views wo (V, 3)."""
        out = diffuse * kd[m]
        if brdfs[m].model != "lambert":
            g = glossy_leaf_means(brdfs[m], wo, level, brdf_refine)  # (V, N)
            out = out + (weights @ g)[:, None] * rho_s[m]
        return out

    extra = [_grid(g) for g in grids.split(",") if g]
    grid_cases: dict[str, tuple[FrameGrid, np.ndarray, np.ndarray]] = {}
    for g in [tuple((tables.frames.n_phi, tables.frames.n_theta, tables.frames.n_psi)),
              *extra]:
        fg = FrameGrid(*g)
        grid_cases[f"trilinear {g[0]}x{g[1]}x{g[2]}"] = (fg, *fg.weights(normal, tangent))
    if cubic_axis:
        fg = tables.frames
        for axis, name in enumerate(("phi", "theta", "psi")):
            grid_cases[f"cubic {name} {fg.n_phi}x{fg.n_theta}x{fg.n_psi}"] = \
                (fg, *cubic_axis_weights(fg, normal, tangent, axis))
    baked = next(iter(grid_cases))
    frames_of = {name: grid_cases[name][0].frames() for name in grid_cases}
    filled = np.flatnonzero(atlas.filled)
    texel_of_row = np.zeros(int(atlas.row[filled].max()) + 1, np.int64)
    texel_of_row[atlas.row[filled]] = filled  # the flat texel holding each visibility row

    size_c = tables.basis.size
    value = {s: np.zeros((pixels, 3)) for s in STEPS}
    alone = {s: np.zeros((pixels, 3)) for s in STEPS[3:]}
    grid_a3 = {name: np.zeros((pixels, 3)) for name in grid_cases}
    canonical_a3 = np.zeros((pixels, 3))
    phi_p, theta_p, psi_p = euler_angles(normal, tangent)
    texture_split = {name: np.zeros((pixels, 3)) for name in
                     ("texel points, pixel frame", "pixel point, texel frames")}
    for k in range(pixels):
        n, t, wo_world = normal[k], tangent[k], view[k]
        b = np.cross(n, t)
        frame = np.stack([t, b, n], 1)  # columns: local → world
        world = dirs @ frame.T
        up = np.flatnonzero((dirs[:, 2] > 0) & (world @ g_normal[k] > 0))
        vis6 = np.zeros(len(dirs))
        vis6[up] = ~ray_tracer.occluded(
            np.broadcast_to(surface.position[k] + epsilon * g_normal[k], (len(up), 3))
            .astype(np.float32), world[up].astype(np.float32),
            np.full(len(up), np.inf, np.float32))
        wo = to_local(wo_world[None], n[None], t[None])[0]
        m = int(material[k])
        rho6 = evaluate(dirs, np.broadcast_to(wo, dirs.shape), brdfs[m]) \
            * np.clip(dirs[:, 2:], 0, None)
        light6 = raw.radiance(world)
        value["A0 truth"][k] = (omega[:, None] * light6 * vis6[:, None] * rho6).sum(0)
        lm, vm, rm = means(light6, fine), means(vis6, fine), means(rho6, fine)
        value["A1 leaf level"][k] = (omega_leaf[:, None] * lm * vm * rm).sum(0)
        # the method's sampling, the pixel's own frame, view and point
        L2 = light_means(frame)
        V2 = vis_means(surface.position[k], n, t, g_normal[k])
        R2 = brdf_means(m, wo[None], np.ones(1))

        def product(L, V, R):
            return (omega_leaf[:, None] * L * V * R).sum(0)

        value["A2 leaf sampling"][k] = product(L2, V2, R2)
        # the rotation grid
        cache: dict[tuple, np.ndarray] = {}

        def grid_light(name, k=k, cache=cache):
            fg, entries, weights = grid_cases[name]
            total = np.zeros((n_leaf, 3))
            for e, w in zip(entries[k], weights[k], strict=True):
                if w == 0:
                    continue
                key = (name.split()[-1], int(e))
                if key not in cache:
                    cache[key] = light_means(frames_of[name][e])
                total += w * cache[key]
            return total

        for name in grid_cases:
            grid_a3[name][k] = product(grid_light(name), V2, R2)
        if canonical:  # ψ on the grid (an isotropic material's free tangent): φθ only
            fg = tables.frames
            x = (phi_p[k] * fg.n_phi / (2 * np.pi),
                 min(theta_p[k] * (fg.n_theta - 1) / np.pi, fg.n_theta - 1 - 1e-9))
            j, i = int(np.floor(x[0])), int(np.floor(x[1]))
            fj, fi = x[0] - j, x[1] - i
            total = np.zeros((n_leaf, 3))
            for dj, wj in ((0, 1 - fj), (1, fj)):
                for di, wi in ((0, 1 - fi), (1, fi)):
                    frame_e = euler_frame(np.array([2 * np.pi * (j + dj) / fg.n_phi]),
                                          np.array([np.pi * (i + di) / (fg.n_theta - 1)]),
                                          np.array([psi_p[k]]))[0]
                    total += wj * wi * light_means(frame_e)
            canonical_a3[k] = product(total, V2, R2)
        L3 = grid_light(baked)
        value["A3 rotation grid"][k] = product(L3, V2, R2)
        alone["A3 rotation grid"][k] = value["A3 rotation grid"][k]
        # the view grid
        entries, weights = tables.views.weights(wo[None])
        R4 = brdf_means(m, tables.views.directions()[entries[0]], weights[0])
        value["A4 view grid"][k] = product(L3, V2, R4)
        alone["A4 view grid"][k] = product(L2, V2, R4)
        # the visibility texture
        p = g_index[k]
        V5 = np.zeros((n_leaf, 1))
        V5_point = np.zeros((n_leaf, 1))  # the texels' points in the pixel's frame
        V5_frame = np.zeros((n_leaf, 1))  # the pixel's point in the texels' frames
        for tx, w in zip(texel_of_row[lookups.vis_rows[p]], lookups.vis_weight[p],
                         strict=True):
            if w == 0:
                continue
            tp, tn, tt = (texel[a][tx].astype(np.float64) for a in
                          ("texel_position", "texel_normal", "texel_tangent"))
            tg = face_normal_all[first_face[tx] + texel["texel_face"][tx]]
            V5 += w * vis_means(tp, tn, tt, tg)
            V5_point += w * vis_means(tp, n, t, tg)
            V5_frame += w * vis_means(surface.position[k], tn, tt, g_normal[k])
        value["A5 visibility texture"][k] = product(L3, V5, R4)
        alone["A5 visibility texture"][k] = product(L2, V5, R2)
        texture_split["texel points, pixel frame"][k] = product(L2, V5_point, R2)
        texture_split["pixel point, texel frames"][k] = product(L2, V5_frame, R2)
        # the stored rows (truncated, float16)
        inv = tables.basis.inverse
        Ls = sum(w * inv(tables.light.dense(int(r), size_c).T).T
                 for r, w in zip(lookups.light_rows[p], lookups.light_weight[p], strict=True)
                 if w)
        Vs = sum(w * inv(tables.visibility.dense(int(r), size_c).T).T
                 for r, w in zip(lookups.vis_rows[p], lookups.vis_weight[p], strict=True) if w)
        Rs = sum(w[None, :] * inv(tables.brdf.dense(int(r), size_c).T).T
                 for r, w in zip(lookups.brdf_rows[p], lookups.brdf_weight[p], strict=True)
                 if np.any(w))
        value["A6 truncation"][k] = product(Ls, Vs, Rs)
        alone["A6 truncation"][k] = value["A6 truncation"][k] - value["A5 visibility texture"][k] \
            + value["A2 leaf sampling"][k]
        if k % 10 == 9:
            print(f"{k + 1}/{pixels} pixels, {time.perf_counter() - start:.0f} s", flush=True)

    truth = value["A0 truth"]
    norm = math.sqrt(float(np.sum(truth ** 2)))

    def rel(a, b):
        return math.sqrt(float(np.sum((a - b) ** 2))) / norm

    report = {"size": size, "pixels": pixels, "fine_level": fine, "leaf_level": level,
              "refine": {"light": light_refine, "visibility": vis_refine,
                         "brdf": brdf_refine},
              "frame_grid": baked.split()[-1],
              "seconds": time.perf_counter() - start,
              "loadavg": [load0, os.getloadavg()], "steps": {}, "grids_A3": {}}
    for i, s in enumerate(STEPS):
        entry = {"error": rel(value[s], truth), "mean_ratio": float(value[s].mean()
                                                                    / truth.mean())}
        if i:
            entry["step"] = rel(value[s], value[STEPS[i - 1]])
        if s in alone:
            entry["alone"] = rel(alone[s], value["A2 leaf sampling"])
        report["steps"][s] = entry
    for name in grid_cases:
        report["grids_A3"][name] = {
            "frames_per_pixel": int(grid_cases[name][1].shape[1]),
            "frames": grid_cases[name][0].size,
            "alone": rel(grid_a3[name], value["A2 leaf sampling"]),
            "error": rel(grid_a3[name], truth)}
    if canonical:
        report["grids_A3"]["bilinear phi theta, psi exact (canonical tangents)"] = {
            "frames_per_pixel": 4, "alone": rel(canonical_a3, value["A2 leaf sampling"]),
            "error": rel(canonical_a3, truth)}
    report["texture_split_alone"] = {name: rel(v, value["A2 leaf sampling"])
                                     for name, v in texture_split.items()}
    # the method as rendered at these pixels (scale 1, no turn)
    from pipeline.methods.triple.render import TripleRenderer
    image = TripleRenderer(scene, artifacts).frame(scene).rgb.reshape(-1, 3)[flat]
    report["render_check"] = rel(image, value["A6 truncation"])
    if reference:
        ref = open_artifact(reference, "reference")
        mean = ref.read("mean").reshape(-1, 3)[flat].astype(np.float64)
        var = ref.read("variance").reshape(-1, 3)[flat].astype(np.float64)
        err2 = float(np.sum((truth - mean) ** 2))
        report["truth_vs_reference"] = {
            "reference": str(reference), "raw": math.sqrt(err2) / norm,
            "noise": math.sqrt(float(var.sum())) / norm,
            "corrected": math.sqrt(max(err2 - float(var.sum()), 0.0)) / norm,
            "method_corrected": math.sqrt(max(float(np.sum((image - mean) ** 2))
                                              - float(var.sum()), 0.0)) / norm}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=1))
    for s, e in report["steps"].items():
        print(f"{s:24s} error {100 * e['error']:6.2f} %  step {100 * e.get('step', 0):6.2f} %"
              f"  alone {100 * e.get('alone', 0):6.2f} %  mean {e['mean_ratio']:.4f}")
    for name, e in report["grids_A3"].items():
        print(f"{name:28s} x{e['frames_per_pixel']:<3d} alone {100 * e['alone']:6.2f} %")
    print("render check", report["render_check"], report.get("truth_vs_reference"))


if __name__ == "__main__":
    main()

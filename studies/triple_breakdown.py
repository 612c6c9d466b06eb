"""Where method triple breaks down (issue 16, Must show bullet 4): studies on small
scenes built here, each against the reference renderer's ``env-direct`` transport (the
environment reflected once with shadows: what triple approximates), the reference's own
noise taken out in quadrature as studies/d2i_accuracy.py does (√(e² − noise²)).

``sun``       hard shadows from a small bright source: the bunny (6.6k faces, glossy)
              in front of a wall on a ground under venice_sunset (its sun 3° above the
              horizon, from the camera's front left at rotation 0: the bunny's shadow
              falls on the wall). Error over the surfaces and over the sun's shadow
              boundary (pixels whose 3×3 neighbourhood holds both sun-lit and
              sun-shadowed points, by shadow rays to the sun) at top-only 20/80/320,
              adaptive 80/320 and as stored.
``texels``    the sun scene at ``triple.texels_per_pixel`` 0.125 … 4 (as stored).
``seams``     the sun scene at the defaults: error of pixels whose bilinear visibility
              fetch reads a dilated or empty texel (chart boundaries) against pixels
              reading covered texels only.
``grazing``   a glossy floor alone (no occluder: visibility is 1 above the horizon)
              under Grace, seen from a low camera so that θ_o runs from 60° to 89°
              across the image: error per θ_o bin, γ 10 and 200.
``dragon``    a mesh and maps the method was not tuned on: dragon_23kf on a ground under
              pisa (256×128), glossy; as stored and top-only 80.
``closeup``   a camera edit at run time: the bunny baked from the scene's camera, then
              rendered (from that atlas) with the camera 2.5× closer, against a bake
              whose atlas follows the closer camera.

Each study writes ``triple_breakdown_<study>.json``, a chart where there is a sweep, the
frames (triple and reference) and per-pixel error heat maps into ``--out``; every
result has the load average at its start (timings are not the point here).

    python studies/triple_breakdown.py sun --workdir /tmp/tb --size 96 --spp 1024
"""

from __future__ import annotations

import json
import math
import os
import shutil
from pathlib import Path
from typing import Any

import click
import numpy as np
import yaml

from pipeline import job
from pipeline.device.raytrace import Mesh, RayTracer, surface_at
from pipeline.engine.store import open_artifact
from pipeline.evaluation import metrics, reference_cache
from pipeline.evaluation.charts import heatmap
from pipeline.evaluation.reference import ReferenceSettings
from pipeline.images import read_environment, write_png
from pipeline.math.camera import camera_rays
from pipeline.math.envmap import EnvironmentMap, uv_to_direction
from pipeline.methods.triple.render import load_tables
from pipeline.methods.triple.tables import texel_lookups
from pipeline.registry import get_method
from pipeline.scene.file import load_scene
from pipeline.scene.model import Scene, shared_data_dir

DATA = shared_data_dir() or Path("../shared/data")
GROUND_Y = -0.7685  # the bunny's lowest point (bunny_grace.yaml)


def _scene(folder: Path, name: str, objects: dict, materials: dict, env: str,
           rotation: float, size: int, camera: dict | None = None) -> Scene:
    """A one-environment-light scene written to ``folder/<name>.yaml`` and loaded."""
    doc = {"format": "prt-scene/1", "name": name, "methods": ["triple"],
           "camera": camera or {"position": [0.0, 0.55, 3.4], "look_at": [0.0, -0.05, 0.0],
                                "up": [0, 1, 0], "fov": 32},
           "materials": materials, "objects": objects,
           "lights": [{"type": "environment", "file": str(DATA / "envmaps" / env),
                       "rotation": rotation, "scale": 1.0}]}
    doc["camera"].update(width=size, height=size)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return load_scene(path)


BUNNY_MATERIALS = {"bunny": {"model": "blinn_phong", "albedo": [0.55, 0.45, 0.35],
                             "specular": 0.1, "gamma": 60, "gamma_range": [3, 300]},
                   "grey": {"model": "lambert", "albedo": [0.5, 0.5, 0.5]}}


def _sun_scene(folder: Path, size: int) -> Scene:
    """The bunny in front of a wall (normal +z, 1.2 behind it) on a ground, venice_sunset."""
    objects = {"bunny": {"mesh": str(DATA / "meshes" / "bunny_6.6kf.obj"),
                         "material": "bunny"},
               "ground": {"primitive": {"type": "plane", "size": [6, 6]},
                          "transform": {"translate": [0, GROUND_Y, 0]}, "material": "grey"},
               "wall": {"primitive": {"type": "plane", "size": [6, 3]},
                        "transform": {"rotate": [90, 0, 0],
                                      "translate": [0, GROUND_Y + 1.5, -1.2]},
                        "material": "grey"}}
    return _scene(folder, "sun_wall", objects, BUNNY_MATERIALS,
                  "venice_sunset_1024x512.hdr", 0.0, size)


# ------------------------------------------------------------------------ measuring


def _pixels(scene: Scene, wd) -> dict[str, np.ndarray]:
    """Per pixel (flat, row-major): ``object`` id (−1: miss), world ``position``,
    ``normal`` (shading), ``theta_o`` (degrees between normal and view), the surface
    (for texel lookups) and the tracer."""
    geometry, _ = job.load_geometry(scene, wd)
    cam = scene.camera
    origins, directions = camera_rays(cam.position, cam.look_at, cam.up, cam.fov,
                                      cam.width, cam.height)
    origins, directions = origins.reshape(-1, 3), directions.reshape(-1, 3)
    tracer = RayTracer(geometry["vertices"], geometry["faces"])
    hits = tracer.intersect(origins, directions)
    hit = hits.prim >= 0
    surface = surface_at(Mesh.from_arrays(geometry), hits.select(hit),
                         origins[hit].astype(np.float64), directions[hit].astype(np.float64))
    n = len(hit)
    obj = np.full(n, -1)
    obj[hit] = surface.object_id
    position = np.zeros((n, 3))
    position[hit] = surface.position
    normal = np.zeros((n, 3))
    normal[hit] = surface.normal
    cos_o = -np.einsum("pc,pc->p", normal, directions)
    return {"object": obj, "hit": hit, "position": position, "normal": normal,
            "theta_o": np.degrees(np.arccos(np.clip(cos_o, -1, 1))), "surface": surface,
            "tracer": tracer, "names": geometry["object_names"]}


def _sun_direction(scene: Scene) -> np.ndarray:
    """World direction of the map's brightest texel (luminance) at the scene's rotation."""
    light = next(light for light in scene.lights if light.type == "environment")
    rgb = read_environment(light.params["file"])
    y, x = np.unravel_index(np.argmax(rgb.mean(2)), rgb.shape[:2])
    d = uv_to_direction(np.array((x + 0.5) / rgb.shape[1]), np.array(y / (rgb.shape[0] - 1)))
    return EnvironmentMap(rgb[:2, :2], light.params.get("rotation", 0.0)).to_world @ d


def _shadow_boundary(scene: Scene, px: dict) -> tuple[np.ndarray, np.ndarray]:
    """(sun-lit, boundary) flat masks: a surface pixel is sun-lit when its shadow ray to
    the sun escapes; a boundary pixel has lit and shadowed surface pixels of its own
    object in its 3×3 neighbourhood."""
    sun = _sun_direction(scene)
    hit = px["hit"]
    origins = px["position"][hit] + 1e-3 * px["normal"][hit]
    facing = px["normal"][hit] @ sun > 0
    blocked = px["tracer"].occluded(origins, np.broadcast_to(sun, origins.shape),
                                    np.full(len(origins), 1e4))
    lit = np.zeros(len(hit), bool)
    lit[hit] = facing & ~blocked
    h, w = scene.camera.height, scene.camera.width
    lit2, obj2 = lit.reshape(h, w), px["object"].reshape(h, w)
    boundary = np.zeros((h, w), bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            a = np.roll(np.roll(lit2, dy, 0), dx, 1)
            same = np.roll(np.roll(obj2, dy, 0), dx, 1) == obj2
            boundary |= same & (a != lit2)
    boundary &= obj2 >= 0
    return lit, boundary.reshape(-1)


def _errors(image: np.ndarray, ref, masks: dict[str, np.ndarray]) -> dict[str, Any]:
    """Relative RMSE, reference noise, noise-corrected error and mean ratio per mask
    (flat masks over the pixels)."""
    h, w = image.shape[:2]
    out = {}
    for key, flat in masks.items():
        mask = flat.reshape(h, w)
        if not mask.any():
            continue
        error = metrics.relative_rmse(image, ref.mean, mask)
        noise = math.sqrt(float(ref.variance[mask].sum())
                          / float(np.square(ref.mean[mask]).sum()))
        out[key] = {"pixels": int(mask.sum()), "rel_rmse": error, "reference_noise": noise,
                    "noise_corrected": math.sqrt(max(error ** 2 - noise ** 2, 0.0)),
                    "mean_ratio": float(image[mask].mean() / ref.mean[mask].mean())}
    return out


def _reference(scene: Scene, wd, spp: int):
    return reference_cache.reference(scene, wd, ReferenceSettings("env-direct", tolerance=0.0,
                                                      min_spp=spp, max_spp=spp),
                         quiet=True).image


def _pictures(out: Path, stem: str, image: np.ndarray, ref, exposure: float = 1.0,
              vmax: float = 0.5) -> None:
    write_png(out / f"{stem}.png", image, exposure)
    heatmap(out / f"{stem}_error.png", metrics.error_map(image, ref.mean), vmax,
            "relative error per pixel, |I - R| / |R|", title=stem, percent=True)


def _load() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def _write(out: Path, study: str, result: dict[str, Any]) -> None:
    (out / f"triple_breakdown_{study}.json").write_text(json.dumps(result, indent=1))
    click.echo(json.dumps(result, indent=1))


def _chart(out: Path, study: str, rows: list[dict], x: str, series: list[str],
           xlabel: str, logx: bool = True) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4.0), dpi=120)
    for label in series:
        pts = [(r[x], r["errors"][label]["noise_corrected"]) for r in rows
               if label in r["errors"]]
        ax.plot(*zip(*pts, strict=True), "o-", label=label)
    if logx:
        ax.set_xscale("log", base=2)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("rel. RMSE vs env-direct (reference noise removed)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / f"triple_breakdown_{study}.png")
    plt.close(fig)


# -------------------------------------------------------------------------- studies


CUTS = [("top-only", 20), ("top-only", 80), ("top-only", 320), ("adaptive", 80),
        ("adaptive", 320), ("as stored", 0)]


def _sun(out: Path, workdir: Path, size: int, spp: int) -> None:
    scene = _sun_scene(workdir, size)
    wd = job.workdir_for(scene, workdir / "sun")
    load = _load()
    job.bake(scene, wd, quiet=True)
    px = _pixels(scene, wd)
    lit, boundary = _shadow_boundary(scene, px)
    ref = _reference(scene, wd, spp)
    names = list(px["names"])
    masks = {"surfaces": px["hit"], "shadow boundary": boundary,
             "wall": px["object"] == names.index("wall"),
             "wall boundary": boundary & (px["object"] == names.index("wall"))}
    rows = []
    for selection, budget in CUTS:
        options = {"budget": budget} | ({"selection": selection} if budget else {})
        image = job.render_frame(scene, wd, "triple", options).rgb
        label = f"{selection} {budget}" if budget else selection
        rows.append({"rows": label, "errors": _errors(image, ref, masks)})
        _pictures(out, f"triple_breakdown_sun_{label.replace(' ', '_')}", image, ref)
    # the wall's normal (+z, θ 90° from the pole) lies between two θ rows of the default
    # 32×16×32 frame grid (12° apart); with 17 rows it lies on one (a copy of the bake,
    # only the lighting re-baked)
    grid = scene.with_settings({"triple.frame_grid": [32, 17, 32]})
    copy = workdir / "sun_grid17"
    if not copy.exists():
        shutil.copytree(wd.root, copy)
    wd17 = job.workdir_for(grid, copy)
    job.bake(grid, wd17, quiet=True)
    image = job.render_frame(grid, wd17, "triple", {"budget": 0}).rgb
    rows.append({"rows": "as stored, frame grid 32×17×32", "errors": _errors(image, ref, masks)})
    _pictures(out, "triple_breakdown_sun_grid17", image, ref)
    write_png(out / "triple_breakdown_sun_reference.png", ref.mean)
    h, w = ref.mean.shape[:2]
    write_png(out / "triple_breakdown_sun_boundary.png",
              np.stack([boundary, lit, np.zeros_like(lit)], -1).reshape(h, w, 3)
              .astype(np.float32))
    _write(out, "sun", {"scene": str(scene.path), "size": size, "spp": spp,
                        "sun_direction": _sun_direction(scene).round(4).tolist(),
                        "load_average": load, "rows": rows})


def _texels(out: Path, workdir: Path, size: int, spp: int) -> None:
    scene = _sun_scene(workdir, size)
    wd = job.workdir_for(scene, workdir / "texels")
    ref = _reference(scene, wd, spp)
    px = _pixels(scene, wd)
    _, boundary = _shadow_boundary(scene, px)
    masks = {"surfaces": px["hit"], "shadow boundary": boundary}
    for name in px["names"]:
        masks[name] = px["object"] == list(px["names"]).index(name)
    rows = []
    for density in (0.125, 0.25, 0.5, 1.0, 2.0, 4.0):
        baked = scene.with_settings({"triple.texels_per_pixel": density})
        load = _load()
        job.bake(baked, wd, quiet=True)
        image = job.render_frame(baked, wd, "triple", {"budget": 0}).rgb
        sizes = open_artifact(wd.artifact("triple.atlas"), "triple_atlas").attrs[
            "texture_sizes"]
        rows.append({"texels_per_pixel": density, "texture_sizes": sizes,
                     "load_average": load, "errors": _errors(image, ref, masks)})
        _pictures(out, f"triple_breakdown_texels_{density:g}", image, ref)
        click.echo(f"texels {density}: {rows[-1]['errors']['surfaces']['noise_corrected']:.4f}")
    write_png(out / "triple_breakdown_texels_reference.png", ref.mean)
    _chart(out, "texels", rows, "texels_per_pixel", list(masks),
           "triple.texels_per_pixel")
    _write(out, "texels", {"scene": str(scene.path), "size": size, "spp": spp, "rows": rows})


def _seams(out: Path, workdir: Path, size: int, spp: int) -> None:
    scene = _sun_scene(workdir, size)
    wd = job.workdir_for(scene, workdir / "sun")
    load = _load()
    job.bake(scene, wd, quiet=True)
    px = _pixels(scene, wd)
    artifacts = job.method_artifacts(get_method("triple"), wd)
    _, atlas = load_tables(artifacts, open_artifact(wd.artifact("geometry"), "geometry")
                           .attrs["material_names"])
    surface = px["surface"]
    bary = np.stack([1 - surface.hits.u - surface.hits.v, surface.hits.u, surface.hits.v], 1)
    texel_xy = np.einsum("pc,pcd->pd", bary, atlas.face_uv[surface.face])
    obj = surface.object_id
    texels, weight = texel_lookups(texel_xy, atlas.size[obj], atlas.offset[obj],
                                   atlas.filled)
    stored = open_artifact(wd.artifact("triple.atlas"), "triple_atlas")
    state = stored.read("texel_state")
    interior_hit = (state[texels] == stored.attrs["texel_states"]["covered"]).all(1)
    # does a fetch read another part of the surface? the farthest texel (of weight > 0)
    # from the shaded point, in scene units
    far = np.where(weight > 0, np.linalg.norm(stored.read("texel_position")[texels]
                                              - surface.position[:, None], axis=-1), 0.0)
    # in texels: an object's texel edge in scene units is √(its area / its filled texels)
    geometry, _ = job.load_geometry(scene, wd)
    v = geometry["vertices"][geometry["faces"]].astype(np.float64)
    face_area = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
    counts = stored.attrs["texel_counts"]
    names = list(px["names"])
    edge = np.array([math.sqrt(face_area[geometry["face_object"] == i].sum()
                               / (counts[n]["covered"] + counts[n]["dilated"]))
                     for i, n in enumerate(names)])
    far = far.max(1) / edge[obj]
    reach = {}
    for tag, m in (("seam", ~interior_hit), ("interior", interior_hit)):
        reach[f"{tag} (texels)"] = {f"p{q}": float(np.percentile(far[m], q))
                                    for q in (50, 99, 100)}
    interior = np.zeros_like(px["hit"])
    interior[px["hit"]] = interior_hit
    seam = px["hit"] & ~interior
    ref = _reference(scene, wd, spp)
    image = job.render_frame(scene, wd, "triple", {"budget": 0}).rgb
    masks = {"surfaces": px["hit"], "seam": seam, "interior": interior}
    for name in ("bunny", "wall", "ground"):
        o = px["object"] == names.index(name)
        masks[f"{name} seam"], masks[f"{name} interior"] = o & seam, o & interior
    h, w = ref.mean.shape[:2]
    write_png(out / "triple_breakdown_seams_mask.png",
              np.stack([seam, interior, np.zeros_like(seam)], -1).reshape(h, w, 3)
              .astype(np.float32))
    _pictures(out, "triple_breakdown_seams", image, ref)
    _write(out, "seams", {"scene": str(scene.path), "size": size, "spp": spp,
                          "load_average": load, "fetch_distance": reach,
                          "errors": _errors(image, ref, masks)})


def _table_rows(gamma: float, refine: int = 1, level: int = 4) -> list[dict[str, float]]:
    """The BRDF table's bilinear blend of view rows against the true ρ̃_g = f_g cos⁺θi of
    a Blinn-Phong lobe at views between the grid's rows and columns (θ_o at the midpoint
    of two θ rows, φ_o at the midpoint of two columns), as leaf means: ``interpolation``
    (both sampled as the stage does, 4^refine points per leaf) and ``total`` (the truth
    sampled with 4^(refine+2) points: the stage's sampling error added); relative L2
    over the leaves (solid-angle weighted) and the ratio of the integrals (albedo)."""
    from pipeline.math.geodesic import geodesic_levels
    from pipeline.methods.triple.frame_grids import ViewGrid
    from pipeline.methods.triple.stages.brdf_tables import glossy_params, kernel_leaf_means

    grid = ViewGrid()
    params = glossy_params("blinn_phong", {"gamma": gamma})
    areas = geodesic_levels(level)[level].areas
    step = 0.5 * np.pi / (grid.n_theta - 1)
    out = []
    for i in (0, 16, 32, 48, 56, 59, 60, 61, 62):
        theta, phi = (i + 0.5) * step, (5.5) * 2 * np.pi / grid.n_phi
        wo = np.array([[np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                        np.cos(theta)]])
        entries, weights = grid.weights(wo)
        rows = kernel_leaf_means(params, grid.directions()[entries[0]], level, refine)
        blend = weights[0] @ rows.astype(np.float64)
        row = {"theta_o": round(float(np.degrees(theta)), 3)}
        for tag, r in (("interpolation", refine), ("total", refine + 2)):
            true = kernel_leaf_means(params, wo, level, r)[0].astype(np.float64)
            norm = math.sqrt(float(np.sum(areas * true ** 2)))
            row[tag] = math.sqrt(float(np.sum(areas * (blend - true) ** 2))) / norm
            row[f"{tag}_albedo_ratio"] = float(np.sum(areas * blend) / np.sum(areas * true))
        out.append(row)
    return out


def _grazing(out: Path, workdir: Path, size: int, spp: int) -> None:
    rows = []
    for gamma in (10, 200):
        materials = {"floor": {"model": "blinn_phong", "albedo": [0.05, 0.05, 0.05],
                               "specular": 0.2, "gamma": gamma}}
        objects = {"floor": {"primitive": {"type": "plane", "size": [40, 40]},
                             "material": "floor"}}
        camera = {"position": [0.0, 0.5, 2.0], "look_at": [0.0, 0.0, -2.0], "up": [0, 1, 0],
                  "fov": 40}
        scene = _scene(workdir, f"glossy_floor_{gamma}", objects, materials,
                       "grace_latlong_1024x512.exr", 0.0, size, camera)
        wd = job.workdir_for(scene, workdir / "grazing")  # only the BRDF table re-bakes
        load = _load()
        job.bake(scene, wd, quiet=True)
        px = _pixels(scene, wd)
        ref = _reference(scene, wd, spp)
        image = job.render_frame(scene, wd, "triple", {"budget": 0}).rgb
        edges = [0, 60, 70, 75, 80, 84, 87, 90]
        masks = {"floor": px["hit"]}
        for lo, hi in zip(edges[:-1], edges[1:], strict=True):
            masks[f"θo {lo}–{hi}°"] = px["hit"] & (px["theta_o"] >= lo) & (px["theta_o"] < hi)
        rows.append({"gamma": gamma, "load_average": load, "errors": _errors(image, ref, masks),
                     "table_vs_true_brdf": _table_rows(gamma)})
        _pictures(out, f"triple_breakdown_grazing_{gamma}", image, ref, exposure=8.0)
        write_png(out / f"triple_breakdown_grazing_{gamma}_reference.png", ref.mean, 8.0)
    _write(out, "grazing", {"size": size, "spp": spp, "rows": rows})


def _dragon(out: Path, workdir: Path, size: int, spp: int) -> None:
    materials = {"jade": {"model": "blinn_phong", "albedo": [0.25, 0.45, 0.3],
                          "specular": 0.1, "gamma": 40},
                 "grey": {"model": "lambert", "albedo": [0.5, 0.5, 0.5]}}
    # dragon_23kf: y up, 155 units tall, centred off the origin: scaled to 1.55
    objects = {"dragon": {"mesh": str(DATA / "meshes" / "dragon_23kf.ply"),
                          "transform": {"scale": [0.01, 0.01, 0.01],
                                        "translate": [0.104, GROUND_Y + 7.4934, -2.982]},
                          "material": "jade"},
               "ground": {"primitive": {"type": "plane", "size": [6, 6]},
                          "transform": {"translate": [0, GROUND_Y, 0]}, "material": "grey"}}
    scene = _scene(workdir, "dragon_pisa", objects, materials, "pisa_256x128.hdr", 0.0, size)
    wd = job.workdir_for(scene, workdir / "dragon")
    load = _load()
    job.bake(scene, wd, quiet=True)
    px = _pixels(scene, wd)
    ref = _reference(scene, wd, spp)
    names = list(px["names"])
    masks = {"surfaces": px["hit"], "all pixels": np.ones_like(px["hit"]),
             "dragon": px["object"] == names.index("dragon"),
             "ground": px["object"] == names.index("ground")}
    rows = []
    for budget in (0, 80):
        image = job.render_frame(scene, wd, "triple", {"budget": budget}).rgb
        label = f"top-only {budget}" if budget else "as stored"
        rows.append({"rows": label, "errors": _errors(image, ref, masks)})
        _pictures(out, f"triple_breakdown_dragon_{label.replace(' ', '_')}", image, ref)
    # the atlas at 4 texels per pixel (a copy of the bake: atlas and visibility re-baked)
    dense = scene.with_settings({"triple.texels_per_pixel": 4.0})
    copy = workdir / "dragon_tpp4"
    if not copy.exists():
        shutil.copytree(wd.root, copy)
    wd4 = job.workdir_for(dense, copy)
    job.bake(dense, wd4, quiet=True)
    image = job.render_frame(dense, wd4, "triple", {"budget": 0}).rgb
    rows.append({"rows": "as stored, texels_per_pixel 4", "errors": _errors(image, ref, masks)})
    _pictures(out, "triple_breakdown_dragon_tpp4", image, ref)
    atlases = {tag: {k: open_artifact(w.artifact("triple.atlas"), "triple_atlas").attrs[k]
                     for k in ("texture_sizes", "texel_counts")}
               for tag, w in (("texels_per_pixel 1", wd), ("texels_per_pixel 4", wd4))}
    write_png(out / "triple_breakdown_dragon_reference.png", ref.mean)
    _write(out, "dragon", {"atlases": atlases, "scene": str(scene.path), "size": size, "spp": spp,
                           "load_average": load, "rows": rows})


def _closeup(out: Path, workdir: Path, size: int, spp: int) -> None:
    from pipeline.scene.edits import with_camera_position

    scene = _sun_scene(workdir, size)
    wd = job.workdir_for(scene, workdir / "sun")
    job.bake(scene, wd, quiet=True)
    cam = scene.camera
    near = tuple(np.add(cam.look_at, np.subtract(cam.position, cam.look_at) / 2.5))
    moved = with_camera_position(scene, near)
    ref = _reference(moved, wd, spp)
    px = _pixels(moved, wd)
    names = list(px["names"])
    masks = {"surfaces": px["hit"], "bunny": px["object"] == names.index("bunny")}
    load = _load()
    run_time = job.render_frame(moved, wd, "triple", {"budget": 0}).rgb
    # the same edit made in the scene file: a copy of the bake, re-baked where stale
    doc = yaml.safe_load(Path(scene.path).read_text())
    doc["camera"]["position"] = [float(v) for v in near]
    doc["name"] = "sun_wall_near"
    path = workdir / "sun_wall_near.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    edited = load_scene(path)
    copy = workdir / "closeup"
    shutil.rmtree(copy, ignore_errors=True)
    shutil.copytree(wd.root, copy)
    wd_near = job.workdir_for(edited, copy)
    report = job.bake(edited, wd_near, quiet=True)
    rebaked = job.render_frame(edited, wd_near, "triple", {"budget": 0}).rgb
    sizes = {tag: open_artifact(w.artifact("triple.atlas"), "triple_atlas").attrs[
        "texture_sizes"] for tag, w in (("baked camera", wd), ("near camera", wd_near))}
    rows = [{"atlas": "baked camera (run-time edit)", "errors": _errors(run_time, ref, masks)},
            {"atlas": "near camera (scene-file edit)", "errors": _errors(rebaked, ref, masks)}]
    _pictures(out, "triple_breakdown_closeup_run_time", run_time, ref)
    _pictures(out, "triple_breakdown_closeup_rebaked", rebaked, ref)
    write_png(out / "triple_breakdown_closeup_reference.png", ref.mean)
    _write(out, "closeup", {"size": size, "spp": spp, "camera_near": list(near),
                            "load_average": load, "texture_sizes": sizes,
                            "stages_run_after_the_edit": {
                                r.name: [r.action, len(r.ran_chunks), r.reason]
                                for r in report},
                            "rows": rows})


STUDIES = {"sun": _sun, "texels": _texels, "seams": _seams, "grazing": _grazing,
           "dragon": _dragon, "closeup": _closeup}


@click.command()
@click.argument("study", type=click.Choice(list(STUDIES)))
@click.option("--out", type=click.Path(path_type=Path),
              default=Path("benchmarks/results/triple_breakdown"), show_default=True)
@click.option("--workdir", type=click.Path(path_type=Path), required=True)
@click.option("--size", type=int, default=64, show_default=True)
@click.option("--spp", type=int, default=1024, show_default=True)
def main(study: str, out: Path, workdir: Path, size: int, spp: int) -> None:
    out.mkdir(parents=True, exist_ok=True)
    STUDIES[study](out, workdir.resolve(), size, spp)


if __name__ == "__main__":
    main()

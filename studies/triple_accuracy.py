"""Where method triple's error on bunny_grace comes from (issue 16), one suspect at a time.

Bakes the scene at ``--size`` (default 128²) with the default stage parameters, then one
variant per suspect (``VARIANTS``: each changes only the parameters of that suspect, in
a copy of the default work directory, so only the stages those parameters key re-run),
renders every variant's frame and compares it with one env-direct reference
(``prt reference``'s path tracer at ``--spp``, seed 0, cached under ``--reference-dir``):

* per region (``bunny``, ``ground``, ``shadowed ground``: ground pixels whose cosine-
  weighted hemisphere the bunny blocks by ≥ ``SHADOW_BLOCKED``, ``shadow edges``: ground
  pixels where the noise-free default frame changes by ≥ ``EDGE_RATIO`` within their
  3×3 neighbourhood, ``ground, no edge``: the rest of the ground; ``turned normals``:
  pixels whose shading normal faces away from the camera on a face that faces it, which
  Surface.normal turns round, and ``surfaces, no turned normal``): the relative RMSE
  ‖I − R‖/‖R‖ (``raw``), the reference's own estimated error √(Σ var)/‖R‖ (``noise``),
  the noise-corrected error √(‖I − R‖² − Σ var)/‖R‖ (``corrected``: the estimate of the
  error against the converged answer, as studies/d2i_accuracy.py does) and the mean
  radiance over the reference's (``mean_ratio``);
* ``change``: ‖I − I_default‖/‖R‖ per region, noise free: how much the suspect moves the
  image (a lower bound of the error it carries);
* ``--check-spp N`` renders a second reference (seed 1, N spp) and checks the noise
  estimate: E‖R₀ − R₁‖² = Σ var₀ + Σ var₁ (``noise_check`` ratio, 1 when the variance
  estimate holds);
* per run-time cut (``--budgets``: top-only and adaptive at 20, 80, 320 of the default
  bake), the same split plus the bytes of the rows that cut keeps (``rows_bytes``).

``--spp 0`` renders no reference: every error is then against the as-stored frame (the
cuts' errors are their changes; no noise). ``--env FILE`` lights the scene with another
map (a new lighting bake only).

Mixed variants (``light only``, ...) take some stages' artifacts from variants and the
others from the default bake: they split a variant that changes several stages, or join
two (``--mixed`` names variants an earlier run baked under ``--workdir``).

Writes ``OUT/results.json`` (a later run with other ``--variants`` adds to it), the
default frame, the reference, heat maps of the default's error against the reference
(``error_default.png``, 0–20 %), of each variant's change
(``change_<variant>.png``, 0–10 %), the region masks (``regions.png``) and a bar chart
of the corrected error per variant and region (``breakdown.png``).

    python studies/triple_accuracy.py --workdir /tmp/acc/w --reference-dir /tmp/acc/ev \\
        --spp 4096 --check-spp 1024 --out benchmarks/results/triple_accuracy
"""

from __future__ import annotations

import json
import math
import os
import shutil
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import click
import numpy as np

from pipeline import job
from pipeline.device.raytrace import Mesh, RayTracer, surface_at
from pipeline.engine.store import Workdir, open_artifact
from pipeline.evaluation import metrics, reference_cache
from pipeline.evaluation.charts import heatmap
from pipeline.evaluation.reference import ReferenceSettings
from pipeline.images import write_png
from pipeline.math.camera import camera_rays
from pipeline.methods.triple.render import load_tables
from pipeline.registry import get_method
from pipeline.scene.edits import with_environment_file

SCENE = "scenes/bunny_grace.yaml"
SHADOW_BLOCKED = 0.02  # shadowed ground: the bunny blocks ≥ 2 % of the cos-weighted sky
EDGE_RATIO = 1.25      # shadow edge: max/min luminance of the 3×3 neighbourhood ≥ 1.25
AO_RAYS = 256          # cosine-weighted rays per ground pixel for the shadow mask

# suspect → stage parameters (each a change of one suspect's settings only)
VARIANTS: dict[str, dict[str, Any]] = {
    "rows near-lossless": {"triple.store_tolerance": 0.0001, "triple.store_budget": 5120},
    "lighting cap off": {"triple.store_budget": 5120},
    "frame grid 64x32x64": {"triple.frame_grid": [64, 32, 64]},
    "frame grid 32x17x32": {"triple.frame_grid": [32, 17, 32]},
    "frame grid 48x17x48": {"triple.frame_grid": [48, 17, 48]},
    "light_refine 3": {"triple.light_refine": 3},
    "light_refine 1": {"triple.light_refine": 1},
    "view grid 256x128 + brdf_refine 2": {"triple.view_grid": [256, 128],
                                         "triple.brdf_refine": 2},
    "texels_per_pixel 2": {"triple.texels_per_pixel": 2.0},
    "texels_per_pixel 3": {"triple.texels_per_pixel": 3.0},
    "frame grid 32x33x32": {"triple.frame_grid": [32, 33, 32]},
    "frame grid 64x33x32": {"triple.frame_grid": [64, 33, 32]},
    "visibility_refine 2": {"triple.visibility_refine": 2},
    "leaf level 5": {"triple.leaf_level": 5, "triple.store_budget": 5120},
}
# mixed: (name, {stage: the variant it is taken from}; the other stages from the default
# bake); a variant baked by an earlier run (its folder under --workdir) is read back
MIXED = [("lossless lighting only", {"triple.light_rotations": "rows near-lossless"}),
         ("lossless visibility only", {"triple.visibility": "rows near-lossless"}),
         ("lossless BRDF only", {"triple.brdf_tables": "rows near-lossless"}),
         ("cap off, lighting only", {"triple.light_rotations": "lighting cap off"}),
         ("frame grid 32x33x32 + texels_per_pixel 3",
          {"triple.light_rotations": "frame grid 32x33x32",
           "triple.atlas": "texels_per_pixel 3", "triple.visibility": "texels_per_pixel 3"}),
         ("frame grid 64x33x32 + texels_per_pixel 3",
          {"triple.light_rotations": "frame grid 64x33x32",
           "triple.atlas": "texels_per_pixel 3", "triple.visibility": "texels_per_pixel 3"})]


def _workdir(scene, root: Path) -> Workdir:
    return job.workdir_for(scene, root)


def regions(scene, wd: Workdir, default: np.ndarray) -> dict[str, np.ndarray]:
    """Pixel masks (H, W) by region (see the module docstring)."""
    geo = open_artifact(wd.artifact("geometry"), "geometry")
    arrays = {n: geo.read(n) for n in
              ("vertices", "normals", "uv", "faces", "face_object", "object_material")}
    names = list(geo.attrs["object_names"])
    cam = scene.camera
    o, d = camera_rays(cam.position, cam.look_at, cam.up, cam.fov, cam.width, cam.height)
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    tracer = RayTracer(arrays["vertices"], arrays["faces"])
    hits = tracer.intersect(o, d)
    hit = hits.prim >= 0
    obj = np.full(len(o), -1)
    surface = surface_at(Mesh.from_arrays(arrays), hits.select(hit),
                         o[hit].astype(np.float64), d[hit].astype(np.float64))
    obj[hit] = surface.object_id
    # pixels whose blended shading normal faces away from the camera on a face that faces
    # it: Surface.normal turns such a normal round (into the object), the texels' frames
    # keep it outward, so the frame's visibility and lighting frames disagree
    blend = np.sum(surface._weights * surface.mesh.normals[surface.mesh.faces[surface.face]], 1)
    turned = np.zeros(len(o), bool)
    turned[hit] = (np.sum(blend * d[hit], 1) > 0) \
        & (np.sum(surface.mesh.face_normal[surface.face] * d[hit], 1) < 0)
    ground = obj == names.index("ground")
    # cosine-weighted visibility of the ground points (stratified, fixed seed)
    g = np.flatnonzero(ground)
    gi = np.flatnonzero(ground[hit])
    rng = np.random.default_rng(0)
    side = int(math.sqrt(AO_RAYS))
    u = (np.arange(side)[:, None] + rng.random((side, side))) / side
    v = (np.arange(side)[None, :] + rng.random((side, side))) / side
    r, phi = np.sqrt(u.ravel()), 2 * np.pi * v.ravel()
    local = np.stack([r * np.cos(phi), np.sqrt(1 - r * r), r * np.sin(phi)], 1)  # +y up
    p = surface.position[gi] + 1e-4 * np.ptp(arrays["vertices"], 0).max() * np.array([0, 1, 0])
    blocked = tracer.occluded(np.repeat(p, len(local), 0), np.tile(local, (len(g), 1)),
                              np.full(len(g) * len(local), 1e30)).reshape(len(g), -1)
    shadowed = np.zeros(len(o), bool)
    shadowed[g] = blocked.mean(1) >= SHADOW_BLOCKED
    shape = (cam.height, cam.width)
    ground2 = ground.reshape(shape)
    lum = default @ np.array([0.2126, 0.7152, 0.0722])
    pad = np.pad(lum, 1, mode="edge")
    pad_ground = np.pad(ground2, 1, constant_values=False)
    windows = [pad[i:i + shape[0], j:j + shape[1]] for i in range(3) for j in range(3)]
    all_ground = np.all([pad_ground[i:i + shape[0], j:j + shape[1]]
                         for i in range(3) for j in range(3)], 0)
    ratio = np.max(windows, 0) / np.maximum(np.min(windows, 0), 1e-12)
    edges = ground2 & all_ground & (ratio >= EDGE_RATIO)
    return {"surfaces": hit.reshape(shape), "bunny": (obj == names.index("bunny")).reshape(shape),
            "ground": ground2, "shadowed ground": shadowed.reshape(shape),
            "shadow edges": edges, "ground, no edge": ground2 & ~edges,
            "turned normals": turned.reshape(shape),
            "surfaces, no turned normal": (hit & ~turned).reshape(shape)}


def split(image: np.ndarray, ref, masks: dict[str, np.ndarray],
          default: np.ndarray | None = None) -> dict[str, dict[str, float]]:
    """Per region: raw, noise, corrected, mean_ratio (and change against ``default``)."""
    out = {}
    for name, m in masks.items():
        if not m.any():
            continue
        r = ref.mean[m].astype(np.float64)
        norm2 = float(np.sum(r * r))
        if norm2 == 0.0:  # black in the reference (relative errors undefined)
            out[name] = {"pixels": int(m.sum()), "reference_black": True,
                         "image_rms": math.sqrt(float(np.mean(image[m] ** 2)))}
            continue
        err2 = float(np.sum((image[m] - r) ** 2))
        var = float(np.sum(ref.variance[m], dtype=np.float64))
        out[name] = {"pixels": int(m.sum()), "raw": math.sqrt(err2 / norm2),
                     "noise": math.sqrt(var / norm2),
                     "corrected": math.sqrt(max(err2 - var, 0.0) / norm2),
                     "mean_ratio": float(image[m].mean() / r.mean())}
        if default is not None:
            out[name]["change"] = math.sqrt(float(np.sum((image[m] - default[m]) ** 2))
                                            / norm2)
    return out


def patched_reference(scene, reference_dir: Path, stale: Path, patch_spp: int,
                      masks: dict[str, np.ndarray]) -> tuple[SimpleNamespace, dict]:
    """The ``stale`` reference with its turned-normal pixels taken from a new one
    (``patch_spp``, seed 2), and the check that nothing else moved: outside those pixels
    E‖R_new − R_stale‖² = Σ var_new + Σ var_stale (``ratio_kept`` ≈ 1; inside,
    ``ratio_patched`` ≫ 1 where the change moved them)."""
    old = open_artifact(stale, "reference")
    old_mean, old_var = old.read("mean"), old.read("variance")
    new = reference_cache.reference(scene, Workdir(reference_dir), ReferenceSettings(
        "env-direct", tolerance=0.0, min_spp=patch_spp, max_spp=patch_spp, seed=2),
        quiet=True).image
    patch = masks["turned normals"]

    def ratio(m):
        diff2 = float(np.sum((new.mean[m].astype(np.float64) - old_mean[m]) ** 2))
        return diff2 / float(np.sum(new.variance[m], dtype=np.float64)
                             + np.sum(old_var[m], dtype=np.float64))

    mean = np.where(patch[..., None], new.mean, old_mean)
    variance = np.where(patch[..., None], new.variance, old_var)
    return SimpleNamespace(mean=mean, variance=variance), {
        "stale": str(stale), "stale_spp": int(old.attrs["spp"]), "patch_spp": patch_spp,
        "patched_pixels": int(patch.sum()),
        "ratio_kept": ratio(masks["surfaces"] & ~patch), "ratio_patched": ratio(patch)}


def rows_bytes(tables) -> dict[str, int]:
    """Bytes of each table's rows (row starts, uint16 indices, float32 values)."""
    return {"lighting": tables.light.nbytes, "visibility": tables.visibility.nbytes,
            "brdf": tables.brdf.nbytes}


def _render(scene, artifacts, options: dict[str, Any]) -> tuple[np.ndarray, float]:
    from pipeline.methods.triple.render import TripleRenderer

    frame = TripleRenderer(scene, artifacts, **options).frame(scene)
    return frame.rgb, frame.timings["total_ms"]


@click.command()
@click.option("--workdir", type=click.Path(path_type=Path), required=True)
@click.option("--reference-dir", type=click.Path(path_type=Path), required=True)
@click.option("--size", type=int, default=128, show_default=True)
@click.option("--spp", type=int, default=4096, show_default=True)
@click.option("--check-spp", type=int, default=0, help="Second reference (seed 1) to check "
              "the noise estimate; 0: none.")
@click.option("--variants", default="all", show_default=True,
              help="Comma-separated VARIANTS names (or 'all', or 'none').")
@click.option("--budgets/--no-budgets", default=True, show_default=True)
@click.option("--env", "env_file", type=click.Path(path_type=Path),
              help="Another environment map for the scene (e.g. venice_sunset's sun).")
@click.option("--stale-reference", type=click.Path(path_type=Path),
              help="A reference artifact (.zarr, at --spp) rendered before a change of the "
              "surface code that moved only the turned-normal pixels: used with those "
              "pixels re-rendered (--patch-spp) instead of a new reference at --spp.")
@click.option("--patch-spp", type=int, default=256, show_default=True)
@click.option("--edge-frame", type=click.Path(path_type=Path),
              help="A frame (.npy, H×W×3) whose 3×3 contrast defines the shadow edges "
              "(default: the default frame; a smooth frame may have none).")
@click.option("--mixed", default="", help="Comma-separated variants baked by an earlier "
              "run whose MIXED combinations to render (besides those of --variants).")
@click.option("--out", type=click.Path(path_type=Path), required=True)
def main(workdir, reference_dir, size, spp, check_spp, variants, budgets, env_file,
         stale_reference, patch_spp, edge_frame, mixed, out):
    out.mkdir(parents=True, exist_ok=True)
    method = get_method("triple")
    scene = job.open_scene(SCENE, (size, size))
    if env_file:
        scene = with_environment_file(scene, env_file)
    base_root = workdir / "default"
    wd = _workdir(scene, base_root)
    t = time.perf_counter()
    job.bake(scene, wd, quiet=True, methods=[method])
    previous = out / "results.json"  # earlier runs' variants and cuts are kept
    kept = json.loads(previous.read_text()) if previous.exists() else {}
    if (kept.get("size"), kept.get("spp")) != (size, spp):
        kept = {}
    result: dict[str, Any] = {"size": size, "spp": spp, "loadavg_start": os.getloadavg(),
                              "default_bake_s": time.perf_counter() - t,
                              "variants": kept.get("variants", {})}
    if "budgets" in kept:
        result["budgets"] = kept["budgets"]
    base_artifacts = job.method_artifacts(method, wd)
    default, ms = _render(scene, base_artifacts, {})
    masks = regions(scene, wd, np.load(edge_frame) if edge_frame else default)
    if spp and stale_reference:
        ref, result["reference_patch"] = patched_reference(
            scene, reference_dir, stale_reference, patch_spp, masks)
    elif spp:
        ref = reference_cache.reference(scene, Workdir(reference_dir), ReferenceSettings(
            "env-direct", tolerance=0.0, min_spp=spp, max_spp=spp), quiet=True).image
    else:  # no reference: errors against the as-stored frame (noise free)
        ref = SimpleNamespace(mean=default, variance=np.zeros_like(default))
    stored = load_tables(base_artifacts, _materials(base_artifacts))[0]
    result["default"] = {"regions": split(default, ref, masks), "frame_ms": ms,
                         "rows_bytes": rows_bytes(stored)}
    write_png(out / "default.png", default)
    write_png(out / "reference.png", ref.mean)
    heatmap(out / "error_default.png", metrics.error_map(default, ref.mean), 0.2,
            "relative error per pixel, |I - R| / |R|",
            f"triple as stored against env-direct {spp} spp", percent=True)
    _regions_png(out / "regions.png", masks)
    if check_spp or "noise_check" in kept:
        result["noise_check"] = kept.get("noise_check")
    if check_spp:
        other = reference_cache.reference(scene, Workdir(reference_dir), ReferenceSettings(
            "env-direct", tolerance=0.0, min_spp=check_spp, max_spp=check_spp, seed=1),
            quiet=True).image
        result["noise_check"] = {}
        for name, m in masks.items():
            diff2 = float(np.sum((other.mean[m].astype(np.float64) - ref.mean[m]) ** 2))
            var = float(np.sum(ref.variance[m], dtype=np.float64)
                        + np.sum(other.variance[m], dtype=np.float64))
            result["noise_check"][name] = {"check_spp": check_spp, "ratio": diff2 / var,
                                           "other": split(other, ref, {name: m})[name]}
    if budgets:
        result["budgets"] = {}
        for selection in ("top-only", "adaptive"):
            for budget in (20, 80, 320):
                options = {"budget": budget, "selection": selection}
                image, ms = _render(scene, base_artifacts, options)
                tables = stored.truncated(selection, budget)
                result["budgets"][f"{selection} {budget}"] = {
                    "regions": split(image, ref, masks, default), "frame_ms": ms,
                    "rows_bytes": rows_bytes(tables)}
                write_png(out / f"budget_{selection}_{budget}.png", image)
                _save(out, result)
    mixed = [m for m in mixed.split(",") if m]
    names = list(VARIANTS) if variants == "all" else \
        [] if variants == "none" else variants.split(",")
    images = {}
    for name in names:
        settings = VARIANTS[name]
        root = workdir / _slug(name)
        if not root.exists():
            shutil.copytree(base_root, root, symlinks=True)
        sc = scene.with_settings(settings)
        vwd = _workdir(sc, root)
        t = time.perf_counter()
        report = job.bake(sc, vwd, quiet=True, methods=[method])
        bake_s = time.perf_counter() - t
        artifacts = job.method_artifacts(method, vwd)
        image, ms = _render(sc, artifacts, {})
        images[name] = artifacts
        result["variants"][name] = {
            "settings": settings, "regions": split(image, ref, masks, default),
            "frame_ms": ms, "bake_s": bake_s, "loadavg": os.getloadavg(),
            "ran": {r.name: r.seconds for r in report if r.action == "ran"},
            "rows_bytes": rows_bytes(load_tables(artifacts, _materials(artifacts))[0])}
        heatmap(out / f"change_{root.name}.png",
                metrics.error_map(image, default), 0.1,
                "relative change per pixel, |I - I_default| / |I_default|",
                f"{name} against the default", percent=True)
        _save(out, result)
    for name, taken in MIXED:
        if not set(taken.values()) <= set(images) | set(mixed):
            continue
        artifacts = dict(base_artifacts)
        for stage, variant in taken.items():
            artifacts[stage] = (images.get(variant) or _baked(scene, workdir, variant))[stage]
        image, ms = _render(scene, artifacts, {})
        heatmap(out / f"error_{_slug(name)}.png", metrics.error_map(image, ref.mean), 0.2,
                "relative error per pixel, |I - R| / |R|",
                f"triple, {name}, against env-direct {spp} spp", percent=True)
        result["variants"][name] = {"mixed": taken,
                                    "regions": split(image, ref, masks, default),
                                    "frame_ms": ms,
                                    "rows_bytes": rows_bytes(load_tables(
                                        artifacts, _materials(artifacts))[0])}
        _save(out, result)
    result["loadavg_end"] = os.getloadavg()
    _save(out, result)
    _breakdown_png(out / "breakdown.png", result)
    print(json.dumps({k: v["regions"]["surfaces"]["corrected"]
                      for k, v in result.get("variants", {}).items()}, indent=1))


def _baked(scene, workdir: Path, variant: str):
    """The artifacts of ``variant`` as an earlier run baked them under ``workdir``."""
    sc = scene.with_settings(VARIANTS[variant])
    return job.method_artifacts(get_method("triple"), _workdir(sc, workdir / _slug(variant)))


def _slug(name: str) -> str:
    """A variant's folder name: letters, digits, '_' and '-' kept, the rest '_'."""
    return "".join(c if c.isalnum() or c in "-" else "_" for c in name)


def _materials(artifacts) -> list[str]:
    return list(artifacts["geometry"].attrs["material_names"])


def _save(out: Path, result: dict[str, Any]) -> None:
    (out / "results.json").write_text(json.dumps(result, indent=1))


def _regions_png(path: Path, masks: dict[str, np.ndarray]) -> None:
    """The regions as colours: bunny blue, ground grey, shadowed ground green, shadow
    edges red."""
    rgb = np.zeros((*masks["bunny"].shape, 3), np.float32)
    rgb[masks["bunny"]] = (0.1, 0.2, 0.8)
    rgb[masks["ground"]] = (0.3, 0.3, 0.3)
    rgb[masks["shadowed ground"]] = (0.1, 0.6, 0.1)
    rgb[masks["shadow edges"]] = (0.9, 0.1, 0.1)
    write_png(path, rgb)


def _breakdown_png(path: Path, result: dict[str, Any]) -> None:
    """Bars: the noise-corrected error per region of the default, each variant and cut."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = {"default (as stored)": result["default"]}
    rows.update(result.get("variants", {}))
    rows.update({f"cut {k}": v for k, v in result.get("budgets", {}).items()})
    regions_shown = ("surfaces", "bunny", "ground", "shadowed ground", "shadow edges")
    fig, ax = plt.subplots(figsize=(11, 0.32 * len(rows) * len(regions_shown) / 2 + 2),
                           dpi=110)
    height = 0.8 / len(regions_shown)
    for k, region in enumerate(regions_shown):
        values = [100 * r["regions"][region]["corrected"] for r in rows.values()]
        ax.barh(np.arange(len(rows)) + k * height, values, height, label=region)
    ax.set_yticks(np.arange(len(rows)) + 0.4 - height / 2)
    ax.set_yticklabels(list(rows))
    ax.invert_yaxis()
    ax.axvline(5, color="k", ls=":", lw=1)
    ax.set_xlabel(f"noise-corrected relative RMSE (%) against env-direct {result['spp']} spp")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


if __name__ == "__main__":
    main()

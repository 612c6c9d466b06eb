"""Cross-check: the project's reference renderer against Mitsuba 3 at equal settings, for
every BRDF model the project ships.

Two scenes, each rendered once per model (``pipeline.math.brdf.MATERIAL_PARAMETERS``:
Lambert through Mitsuba's ``diffuse``, every other model through the Python BSDFs of
pipeline/evaluation/mitsuba_bsdfs.py, written independently of pipeline/math/brdf.py):

* ``scenes/cornell_box.yaml`` (Mitsuba's ``cbox-rgb.xml`` geometry), transport ``full``,
  the floor and both boxes of the model (``mitsuba.with_model``: half their albedo plus
  the model's lobe from ``mitsuba.CROSSCHECK_PARAMETERS``);
* ``scenes/bunny_grace_lambert.yaml`` (60k-face bunny under the Grace Cathedral map,
  rotated 40° about +y), transport ``env-direct``, the bunny and the ground of the model.

Both renderers use a box pixel filter (uniform jitter over the pixel), the same camera,
light units, environment mapping and shading frame (pipeline/evaluation/mitsuba.py). Ours
renders ``spp`` paths per pixel and estimates each pixel's variance from its samples;
Mitsuba renders ``MITSUBA_RUNS`` frames with independent seeds of ``spp / MITSUBA_RUNS``
each, whose mean has ``spp`` samples and whose per-pixel variance comes from the spread of
the runs. If both are unbiased estimates of one image, E‖I − M‖² = Σ (σ²_I + σ²_M), so the
measured relative difference ‖I − M‖/‖M‖ should match the "noise" relative RMSE
√Σ(σ²_I + σ²_M)/‖M‖; the check passes when it is within 3× of it. The rule is applied
twice: over the whole image, and over the *model's pixels* alone (those whose pixel-centre
ray first meets an object of the edited materials), where the glossy lobe is not diluted
by the rest of the image.

Run from the project root (needs the ``mitsuba`` extra):
    python studies/mitsuba_crosscheck.py [--spp 256] [--size 64] [--models ward,...]
Writes benchmarks/results/mitsuba_crosscheck.json and, per scene and model, PNG previews
of both renders and a heat map of |I − M| in units of the combined standard deviation.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import tempfile
from pathlib import Path

import numpy as np

from pipeline import job
from pipeline.device.raytrace import RayTracer
from pipeline.evaluation import metrics, mitsuba
from pipeline.evaluation.charts import heatmap
from pipeline.evaluation.mitsuba_bsdfs import MODELS
from pipeline.evaluation.reference import ReferenceSettings, render
from pipeline.images import write_png
from pipeline.math.camera import pixel_directions

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
MITSUBA_RUNS = 8
CASES = (  # scene file, transport, materials turned into each model, preview exposure
    ("cornell_box.yaml", "full", ("glossy_floor", "box"), 1.0),
    ("bunny_grace_lambert.yaml", "env-direct", ("bunny", "ground"), 4.0),  # dim map
)


def mitsuba_mean_and_variance(scene, geometry, transport: str, spp: int
                              ) -> tuple[np.ndarray, np.ndarray, float]:
    """Mean of ``MITSUBA_RUNS`` seeded Mitsuba frames, the variance of that mean per
    pixel (from the runs' spread), and the seconds of the renders."""
    frames, seconds = [], 0.0
    for seed in range(MITSUBA_RUNS):
        result = mitsuba.render(scene, geometry, transport, spp // MITSUBA_RUNS, seed=seed)
        frames.append(result.rgb.astype(np.float64))
        seconds += result.render_s
    stack = np.stack(frames)
    return stack.mean(axis=0), stack.var(axis=0, ddof=1) / MITSUBA_RUNS, seconds


def model_pixels(scene, geometry, materials: tuple[str, ...]) -> np.ndarray:
    """(height, width) True where the pixel-centre ray first meets an object whose
    material is one of ``materials``."""
    cam = scene.camera
    rows, cols = np.mgrid[0:cam.height, 0:cam.width]
    d = pixel_directions(cam.position, cam.look_at, cam.up, cam.fov, cam.width, cam.height,
                         cols + 0.5, rows + 0.5).reshape(-1, 3)
    tracer = RayTracer(np.asarray(geometry["vertices"]), np.asarray(geometry["faces"]))
    hits = tracer.intersect(np.broadcast_to(np.asarray(cam.position, float), d.shape), d)
    names = list(geometry["object_names"])
    wanted = np.array([scene.objects[n].material in materials for n in names])
    prim = hits.prim
    face_object = np.asarray(geometry["face_object"])
    inside = prim >= 0
    out = np.zeros(len(prim), bool)
    out[inside] = wanted[face_object[prim[inside]]]
    return out.reshape(cam.height, cam.width)


def agreement(ours: np.ndarray, ours_var: np.ndarray, theirs: np.ndarray,
              theirs_var: np.ndarray, mask: np.ndarray | None = None) -> dict:
    """Relative difference, combined noise, their ratio and the 3× rule over the pixels
    of ``mask`` (all if None)."""
    if mask is not None:
        ours, ours_var, theirs, theirs_var = (a[mask] for a in (ours, ours_var, theirs,
                                                                theirs_var))
    norm = math.sqrt(float(np.sum(theirs ** 2)))
    measured = metrics.relative_rmse(ours, theirs)
    noise = math.sqrt(float(np.sum(ours_var + theirs_var))) / norm
    return {"rel_rmse_between": measured, "rel_rmse_noise": noise,
            "ratio_to_noise": measured / noise, "within_3x_noise": measured <= 3 * noise,
            # Sums per channel: a bias of the mean brightness shows here first.
            "mean_ratio_rgb": (ours.reshape(-1, 3).sum(0)
                               / theirs.reshape(-1, 3).sum(0)).tolist()}


def cross_check(scene_file: str, transport: str, materials: tuple[str, ...], model: str,
                exposure: float, spp: int, size: int) -> dict:
    scene = job.open_scene(ROOT / "scenes" / scene_file).with_image_size(size, size)
    scene = mitsuba.with_model(scene, materials, model)
    with tempfile.TemporaryDirectory() as tmp:
        geometry, _ = job.load_geometry(scene, job.workdir_for(scene, Path(tmp) / "work"),
                                        quiet=True)
    ours = render(scene, geometry, ReferenceSettings(
        transport, tolerance=0.0, max_spp=spp, min_spp=spp, seed=0, pixel_filter="box"))
    theirs, theirs_var, theirs_s = mitsuba_mean_and_variance(scene, geometry, transport, spp)
    ours_mean = ours.mean.astype(np.float64)
    ours_var = ours.variance.astype(np.float64)
    mask = model_pixels(scene, geometry, materials)
    stem = f"{Path(scene_file).stem}_{model}"
    write_png(RESULTS / f"mitsuba_crosscheck_{stem}_ours.png", ours_mean, exposure)
    write_png(RESULTS / f"mitsuba_crosscheck_{stem}_mitsuba.png", theirs, exposure)
    combined_var = ours_var + theirs_var
    z = np.linalg.norm(ours_mean - theirs, axis=-1) / np.sqrt(
        np.maximum(combined_var.sum(axis=-1), 1e-30))
    heatmap(RESULTS / f"mitsuba_crosscheck_{stem}_z.png", z, 4.0,
            "|ours - Mitsuba| per pixel in standard deviations of the difference")
    return {
        "scene": f"scenes/{scene_file}", "transport": transport, "model": model,
        "materials": list(materials), "parameters": mitsuba.CROSSCHECK_PARAMETERS[model],
        "spp": spp, "size": [scene.camera.width, scene.camera.height], "pixel_filter": "box",
        "image": agreement(ours_mean, ours_var, theirs, theirs_var),
        "model_pixels": {"count": int(mask.sum()),
                         **agreement(ours_mean, ours_var, theirs, theirs_var, mask)},
        "ours_seconds": ours.seconds, "ours_rel_rmse_estimate": ours.estimate,
        "mitsuba_seconds": theirs_s, "mitsuba_variant": mitsuba.variant(),
        "mitsuba_runs": MITSUBA_RUNS,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spp", type=int, default=256,
                        help=f"paths per pixel of each renderer (a multiple of {MITSUBA_RUNS})")
    parser.add_argument("--size", type=int, default=64, help="image width and height")
    parser.add_argument("--models", default=",".join(MODELS),
                        help="comma-separated models (default: all)")
    args = parser.parse_args()
    RESULTS.mkdir(parents=True, exist_ok=True)
    cases = []
    print(f"{'scene':<26} {'model':<18} {'image: diff':>11} {'noise':>7} {'ratio':>5}"
          f" | {'model px: diff':>14} {'noise':>7} {'ratio':>5}  mean ratio (model px)")
    for scene_file, transport, materials, exposure in CASES:
        for model in args.models.split(","):
            case = cross_check(scene_file, transport, materials, model, exposure, args.spp,
                               args.size)
            cases.append(case)
            im, px = case["image"], case["model_pixels"]
            print(f"{Path(scene_file).stem:<26} {model:<18} {im['rel_rmse_between']:>11.4f}"
                  f" {im['rel_rmse_noise']:>7.4f} {im['ratio_to_noise']:>5.2f} |"
                  f" {px['rel_rmse_between']:>14.4f} {px['rel_rmse_noise']:>7.4f}"
                  f" {px['ratio_to_noise']:>5.2f}  "
                  f"{np.round(px['mean_ratio_rgb'], 4).tolist()}", flush=True)
    out = RESULTS / "mitsuba_crosscheck.json"
    out.write_text(json.dumps({"machine": platform.machine(), "cases": cases}, indent=1))
    print(f"wrote {out}")
    failed = [f"{c['scene']} {c['model']}" for c in cases
              if not (c["image"]["within_3x_noise"] and c["model_pixels"]["within_3x_noise"])]
    print("all within 3x the noise" if not failed else f"OUTSIDE 3x the noise: {failed}")


if __name__ == "__main__":
    main()

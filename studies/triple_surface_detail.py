"""Method triple's surface detail (paper 004 §4.2, Fig. 11) against the env-direct
reference: scenes/sbrdf_bump.yaml (a checker-blended floor and a bump-mapped sphere)
as shipped (ridges of height 0.04), with a 4× lower bump (0.01), without its bump and
without its blend, and scenes/aniso_sphere.yaml (anisotropic Ward).

    python studies/triple_surface_detail.py [--size 96] [--spp 1024] [--workdir DIR]

Per variant: relative RMSE of the triple frame against the reference over the pixels of
each object (raw, and "corrected" = √(‖I − R‖² − Σ var R) / ‖R‖, the reference's own
noise removed as studies/d2i_accuracy.py does), the mean ratio, and frame times
(median of ``--repeats`` frames from one loaded renderer; load averages recorded) with
and without the blend. The bump's error is the difference the bump makes to the ball's
error: the triple frame keeps the unbumped visibility, the reference shades the bumped
normal with shadow rays from the real surface. Writes
benchmarks/results/triple_surface_detail.json and a PNG panel per variant (triple |
reference | |difference| × 4, auto exposure).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

import numpy as np
import yaml

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def scene_variant(path: Path, out: Path, edit) -> Path:
    """A copy of scene ``path`` (paths made absolute) with ``edit`` applied to its doc."""
    doc = yaml.safe_load(path.read_text())
    for material in doc["materials"].values():
        for key in ("blend", "bump"):
            if key in material:
                material[key]["texture"] = str((path.parent / material[key]["texture"]).resolve())
    for obj in doc["objects"].values():
        if "mesh" in obj and not obj["mesh"].startswith("$"):
            obj["mesh"] = str((path.parent / obj["mesh"]).resolve())
    edit(doc)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(yaml.safe_dump(doc, sort_keys=False))
    return out


def object_masks(scene, workdir) -> dict[str, np.ndarray]:
    """Per object, the pixels whose camera ray first hits it."""
    from pipeline import job
    from pipeline.device.raytrace import RayTracer
    from pipeline.math.camera import camera_rays

    geometry, _ = job.load_geometry(scene, workdir)
    cam = scene.camera
    origins, directions = camera_rays(cam.position, cam.look_at, cam.up, cam.fov,
                                      cam.width, cam.height)
    hits = RayTracer(geometry["vertices"], geometry["faces"]).intersect(
        origins.reshape(-1, 3), directions.reshape(-1, 3))
    obj = np.where(hits.prim >= 0, np.asarray(geometry["face_object"])[hits.prim], -1)
    obj = obj.reshape(cam.height, cam.width)
    masks = {name: obj == i for i, name in enumerate(geometry["object_names"])}
    masks["surfaces"] = obj >= 0
    return masks


def errors(frame: np.ndarray, ref, mask: np.ndarray) -> dict[str, float]:
    diff2 = float(np.sum((frame - ref.mean)[mask] ** 2))
    norm2 = float(np.sum(ref.mean[mask] ** 2))
    noise2 = float(np.sum(ref.variance[mask]))
    return {"raw": np.sqrt(diff2 / norm2),
            "corrected": np.sqrt(max(diff2 - noise2, 0.0) / norm2),
            "reference_noise": np.sqrt(noise2 / norm2),
            "mean_ratio": float(frame[mask].mean() / ref.mean[mask].mean()),
            "pixels": int(mask.sum())}


def panel(path: Path, frame: np.ndarray, ref: np.ndarray, surfaces: np.ndarray) -> float:
    """Write triple | reference | |difference| × 4, exposed so that the reference's
    99th percentile surface value is 1 (Grace is dark: about 2⁻⁶); the exposure (stops)."""
    from pipeline.images import write_png

    exposure = float(-np.log2(max(np.percentile(ref[surfaces], 99), 1e-12)))
    diff = np.abs(frame - ref) * 4
    write_png(path, np.concatenate([frame, ref, diff], axis=1), exposure=exposure)
    return exposure


def run_variant(name: str, scene_path: Path, args, results: dict) -> None:
    from pipeline import job
    from pipeline.evaluation import reference_cache
    from pipeline.evaluation.reference import ReferenceSettings
    from pipeline.scene.file import load_scene

    scene = load_scene(scene_path).with_image_size(args.size, args.size)
    # variants of a scene share its bake (blends and bumps are in no stage key)
    workdir = job.workdir_for(scene, Path(args.workdir) / scene.name)
    job.bake(scene, workdir, quiet=True)
    render = job.frame_renderer(scene, workdir, "triple", {"budget": 0})  # rows as stored
    times, loads = [], []
    for _ in range(args.repeats):
        loads.append(os.getloadavg()[0])
        start = time.perf_counter()
        frame = render.frame(scene)
        times.append({"total_ms": (time.perf_counter() - start) * 1e3,
                      "kernel_ms": frame.timings["kernel_ms"],
                      "lookup_ms": frame.timings["lookup_ms"]})
    settings = ReferenceSettings("env-direct", tolerance=0.002, max_spp=args.spp)
    ref = reference_cache.reference(scene, workdir, settings, quiet=True).image
    masks = object_masks(scene, workdir)
    results[name] = {
        "scene": str(scene_path), "size": args.size, "reference_spp": ref.spp,
        "errors": {k: errors(frame.rgb, ref, m) for k, m in masks.items() if m.any()},
        "frame_ms_median": {k: statistics.median(t[k] for t in times) for k in times[0]},
        "load_average": loads,
    }
    results[name]["panel_exposure"] = panel(
        HERE / "results" / f"triple_surface_detail_{name}.png", frame.rgb, ref.mean,
        masks["surfaces"])
    print(name, json.dumps(results[name]["errors"], indent=None), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=96)
    parser.add_argument("--spp", type=int, default=1024)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--workdir", default="/tmp/prt_surface_detail")
    args = parser.parse_args()
    variants = Path(args.workdir) / "scenes"
    scenes = ROOT / "scenes"

    def no_bump(doc):
        del doc["materials"]["ridged"]["bump"]

    def low_bump(doc):
        doc["materials"]["ridged"]["bump"]["height"] = 0.01

    def no_blend(doc):
        del doc["materials"]["matte"]["blend"]

    results: dict = {"settings": vars(args)}
    run_variant("sbrdf_bump", scenes / "sbrdf_bump.yaml", args, results)
    run_variant("sbrdf_nobump", scene_variant(scenes / "sbrdf_bump.yaml",
                                              variants / "sbrdf_nobump.yaml", no_bump),
                args, results)
    run_variant("sbrdf_bump_low", scene_variant(scenes / "sbrdf_bump.yaml",
                                                variants / "sbrdf_bump_low.yaml", low_bump),
                args, results)
    run_variant("sbrdf_noblend", scene_variant(scenes / "sbrdf_bump.yaml",
                                               variants / "sbrdf_noblend.yaml", no_blend),
                args, results)
    run_variant("aniso_sphere", scenes / "aniso_sphere.yaml", args, results)
    out = HERE / "results" / "triple_surface_detail.json"
    out.write_text(json.dumps(results, indent=2))
    print("wrote", out)


if __name__ == "__main__":
    main()

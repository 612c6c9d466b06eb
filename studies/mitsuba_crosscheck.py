"""Cross-check: the project's reference renderer against Mitsuba 3 at equal settings.

Two scenes, both Lambertian so that Mitsuba has an exact equivalent:

* ``scenes/cornell_box_lambert.yaml`` (Mitsuba's ``cbox-rgb.xml``), transport ``full``;
* ``scenes/bunny_grace_lambert.yaml`` (60k-face bunny under the Grace Cathedral map,
  rotated 40° about +y), transport ``env-direct``.

Both renderers use a box pixel filter (uniform jitter over the pixel), the same camera,
light units and environment mapping (pipeline/evaluation/mitsuba.py). Ours renders ``spp`` paths
per pixel and estimates each pixel's variance from its samples; Mitsuba renders
``MITSUBA_RUNS`` frames with independent seeds of ``spp / MITSUBA_RUNS`` each, whose
mean has ``spp`` samples and whose per-pixel variance comes from the spread of the runs.
If both are unbiased estimates of one image, E‖I − M‖² = Σ (σ²_I + σ²_M), so the
measured relative difference ‖I − M‖/‖M‖ should match the "noise" relative RMSE
√Σ(σ²_I + σ²_M)/‖M‖; the check passes when it is within 3× of it.

Run from the project root (needs the ``mitsuba`` extra):
    python studies/mitsuba_crosscheck.py [--spp 256]
Writes benchmarks/results/mitsuba_crosscheck.json and, per scene, PNG previews of both
renders and a heat map of |I − M| in units of the combined standard deviation.
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
from pipeline.evaluation import metrics, mitsuba
from pipeline.evaluation.charts import heatmap
from pipeline.evaluation.reference import ReferenceSettings, render
from pipeline.images import write_png

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
MITSUBA_RUNS = 8
CASES = (  # scene file, transport, preview exposure
    ("cornell_box_lambert.yaml", "full", 1.0),
    ("bunny_grace_lambert.yaml", "env-direct", 4.0),  # the map is dim: brighten the PNG
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


def cross_check(scene_file: str, transport: str, exposure: float, spp: int) -> dict:
    scene = job.open_scene(ROOT / "scenes" / scene_file)
    with tempfile.TemporaryDirectory() as tmp:
        geometry, _ = job.load_geometry(scene, job.workdir_for(scene, Path(tmp) / "work"))
    ours = render(scene, geometry, ReferenceSettings(
        transport, tolerance=0.0, max_spp=spp, min_spp=spp, seed=0, pixel_filter="box"))
    theirs, theirs_var, theirs_s = mitsuba_mean_and_variance(scene, geometry, transport, spp)
    ours_mean = ours.mean.astype(np.float64)
    combined_var = ours.variance.astype(np.float64) + theirs_var
    norm = math.sqrt(float(np.sum(theirs ** 2)))
    measured = metrics.relative_rmse(ours_mean, theirs)
    noise = math.sqrt(float(np.sum(combined_var))) / norm
    stem = Path(scene_file).stem
    write_png(RESULTS / f"mitsuba_crosscheck_{stem}_ours.png", ours_mean, exposure)
    write_png(RESULTS / f"mitsuba_crosscheck_{stem}_mitsuba.png", theirs, exposure)
    z = np.linalg.norm(ours_mean - theirs, axis=-1) / np.sqrt(
        np.maximum(combined_var.sum(axis=-1), 1e-30))
    heatmap(RESULTS / f"mitsuba_crosscheck_{stem}_z.png", z, 4.0,
            "|ours - Mitsuba| per pixel in standard deviations of the difference")
    return {
        "scene": f"scenes/{scene_file}", "transport": transport, "spp": spp,
        "size": [scene.camera.width, scene.camera.height], "pixel_filter": "box",
        "rel_rmse_between": measured, "rel_rmse_noise": noise,
        "ratio_to_noise": measured / noise, "within_3x_noise": measured <= 3 * noise,
        # Sums per channel: a bias of the mean brightness shows here first.
        "mean_ratio_rgb": (ours_mean.sum(axis=(0, 1)) / theirs.sum(axis=(0, 1))).tolist(),
        "ours_seconds": ours.seconds, "ours_rel_rmse_estimate": ours.estimate,
        "mitsuba_seconds": theirs_s, "mitsuba_variant": mitsuba.variant(),
        "mitsuba_runs": MITSUBA_RUNS,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spp", type=int, default=256,
                        help=f"paths per pixel of each renderer (a multiple of {MITSUBA_RUNS})")
    args = parser.parse_args()
    RESULTS.mkdir(parents=True, exist_ok=True)
    cases = []
    for scene_file, transport, exposure in CASES:
        case = cross_check(scene_file, transport, exposure, args.spp)
        cases.append(case)
        print(f"{scene_file:<28} {transport:<10} rel. RMSE between {case['rel_rmse_between']:.4f}"
              f"  noise {case['rel_rmse_noise']:.4f}  ratio {case['ratio_to_noise']:.2f}"
              f"  mean ratio {np.round(case['mean_ratio_rgb'], 4).tolist()}")
    out = RESULTS / "mitsuba_crosscheck.json"
    out.write_text(json.dumps({"machine": platform.machine(), "cases": cases}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()

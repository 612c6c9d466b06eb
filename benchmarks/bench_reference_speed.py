"""Benchmark: the reference renderer's speed against Mitsuba 3 at equal samples per pixel.

Scene: ``scenes/cornell_box_lambert.yaml`` (Mitsuba's ``cbox-rgb.xml``), transport
``full``, 256×256, box pixel filter, both renderers at ``SPP`` paths per pixel. Each is
timed ``REPEATS`` times, alternating, in one run on this machine; the ratio of the
medians is the result. Mitsuba's time is ``mi.render`` plus the copy into NumPy; its first
frame (JIT compilation in the LLVM variant) is run once before timing and reported apart.
Ours counts rays traced (camera, continuation and shadow rays); Mitsuba reports none, so
the comparison is in samples (paths) per second.

Run from the project root (needs the ``mitsuba`` extra):
    python benchmarks/bench_reference_speed.py
Writes benchmarks/results/reference_speed.json.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import tempfile
from pathlib import Path

from pipeline import job, mitsuba
from pipeline.reference import ReferenceSettings, render

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
SPP = 32
REPEATS = 5


def main() -> None:
    scene = job.open_scene(ROOT / "scenes" / "cornell_box_lambert.yaml")
    with tempfile.TemporaryDirectory() as tmp:
        geometry, _ = job.load_geometry(scene, job.workdir_for(scene, Path(tmp) / "work"))
    settings = ReferenceSettings("full", tolerance=0.0, max_spp=SPP, min_spp=SPP,
                                 pixel_filter="box")
    first_mitsuba = mitsuba.render(scene, geometry, "full", SPP, seed=100)
    ours_s, ours_rays, theirs_s = [], [], []
    for repeat in range(REPEATS):
        image = render(scene, geometry, ReferenceSettings(**{**vars(settings), "seed": repeat}))
        ours_s.append(image.seconds)
        ours_rays.append(image.rays)
        theirs_s.append(mitsuba.render(scene, geometry, "full", SPP, seed=repeat).render_s)
    paths = scene.camera.width * scene.camera.height * SPP
    ours, theirs = statistics.median(ours_s), statistics.median(theirs_s)
    result = {
        "scene": "scenes/cornell_box_lambert.yaml", "transport": "full",
        "size": [scene.camera.width, scene.camera.height], "spp": SPP, "repeats": REPEATS,
        "machine": platform.machine(), "cpus": os.cpu_count(),
        "ours_seconds": ours_s, "mitsuba_seconds": theirs_s,
        "mitsuba_first_frame_seconds": first_mitsuba.render_s,
        "mitsuba_variant": first_mitsuba.variant,
        "ours_paths_per_s": paths / ours, "mitsuba_paths_per_s": paths / theirs,
        "ours_rays_per_s": statistics.median(ours_rays) / ours,
        "ours_rays_per_path": statistics.median(ours_rays) / paths,
        "mitsuba_speedup_over_ours": ours / theirs,
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    out = RESULTS / "reference_speed.json"
    out.write_text(json.dumps(result, indent=1))
    print(f"ours {result['ours_paths_per_s'] / 1e6:.3f} M paths/s "
          f"({result['ours_rays_per_s'] / 1e6:.2f} M rays/s), Mitsuba "
          f"{result['mitsuba_paths_per_s'] / 1e6:.3f} M paths/s ({first_mitsuba.variant}): "
          f"Mitsuba is {result['mitsuba_speedup_over_ours']:.1f}x faster; wrote {out}")


if __name__ == "__main__":
    main()

"""The reference path tracer against Mitsuba 3 at equal spp: paths per second, alternated.

The reference renderer's speed against Mitsuba 3 at equal samples per pixel: both timed
alternately in one run, paths per second and the ratio of the medians.

Scene: ``scenes/cornell_box_lambert.yaml`` (Mitsuba's ``cbox-rgb.xml``), transport
``full``, 256×256, box pixel filter, both renderers at ``--spp`` paths per pixel. Each is
timed ``--repeats`` times, alternating, in one run on this machine; the ratio of the
medians is the result. Mitsuba's time is ``mi.render`` plus the copy into NumPy; its first
frame (JIT compilation in the LLVM variant) is run once before timing and reported apart.
Ours counts rays traced (camera, continuation and shadow rays); Mitsuba reports none, so
the comparison is in samples (paths) per second.

Needs the ``mitsuba`` extra (``--mitsuba if-installed``: without it, ours alone and the
Mitsuba fields None).
"""

from __future__ import annotations

import argparse
import importlib.util
import tempfile
from pathlib import Path
from typing import Any

from benchmarks.fixtures import ROOT, SCENES, load, median, write_result

NAME = "engine.reference"
PRESETS = {"default": [],
           "tiny": ["--size", "16", "--spp", "1", "--repeats", "1", "--mitsuba",
                    "if-installed"]}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    from pipeline import job
    from pipeline.evaluation import mitsuba
    from pipeline.evaluation.reference import ReferenceSettings, render

    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME} --",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", type=Path, default=SCENES / "cornell_box_lambert.yaml")
    parser.add_argument("--size", type=int, default=None,
                        help="image edge [default: the scene's, 256]")
    parser.add_argument("--spp", type=int, default=32, help="paths per pixel, both renderers")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--mitsuba", choices=["required", "if-installed"], default="required",
                        help="if-installed: time ours alone where mitsuba is missing")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    spp = args.spp
    with_mitsuba = args.mitsuba == "required" or importlib.util.find_spec("mitsuba") is not None
    scene = job.open_scene(args.scene)
    if args.size:
        scene = scene.with_image_size(args.size, args.size)
    with tempfile.TemporaryDirectory() as tmp:
        geometry, _ = job.load_geometry(scene, job.workdir_for(scene, Path(tmp) / "work"))
    settings = ReferenceSettings("full", tolerance=0.0, max_spp=spp, min_spp=spp,
                                 pixel_filter="box")
    before = load()
    first_mitsuba = mitsuba.render(scene, geometry, "full", spp, seed=100) \
        if with_mitsuba else None
    ours_s, ours_rays, theirs_s = [], [], []
    for repeat in range(args.repeats):
        image = render(scene, geometry, ReferenceSettings(**{**vars(settings), "seed": repeat}))
        ours_s.append(image.seconds)
        ours_rays.append(image.rays)
        if with_mitsuba:
            theirs_s.append(mitsuba.render(scene, geometry, "full", spp, seed=repeat).render_s)
    paths = scene.camera.width * scene.camera.height * spp
    ours = median(ours_s)
    theirs = median(theirs_s) if theirs_s else None
    scene_name = args.scene.resolve()
    result = {
        "scene": str(scene_name.relative_to(ROOT) if scene_name.is_relative_to(ROOT)
                     else scene_name), "transport": "full",
        "size": [scene.camera.width, scene.camera.height], "spp": spp,
        "repeats": args.repeats, "load": [before, load()],
        "ours_seconds": ours_s, "mitsuba_seconds": theirs_s if with_mitsuba else None,
        "mitsuba_first_frame_seconds": first_mitsuba.render_s if first_mitsuba else None,
        "mitsuba_variant": first_mitsuba.variant if first_mitsuba else None,
        "ours_paths_per_s": paths / ours,
        "mitsuba_paths_per_s": paths / theirs if theirs else None,
        "ours_rays_per_s": median(ours_rays) / ours,
        "ours_rays_per_path": median(ours_rays) / paths,
        "mitsuba_speedup_over_ours": ours / theirs if theirs else None,
    }
    mitsuba_text = (f"Mitsuba {result['mitsuba_paths_per_s'] / 1e6:.3f} M paths/s "
                    f"({result['mitsuba_variant']}): Mitsuba is "
                    f"{result['mitsuba_speedup_over_ours']:.1f}x faster") if theirs else \
        "Mitsuba not installed"
    print(f"ours {result['ours_paths_per_s'] / 1e6:.3f} M paths/s "
          f"({result['ours_rays_per_s'] / 1e6:.2f} M rays/s), {mitsuba_text}")
    return write_result(NAME, result, args.out)

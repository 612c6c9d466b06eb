"""The stages that trace visibility rays, baked with ``bake.device`` embree and device.

Issue 44: the bake's rays on the OpenCL device (the project's BVH kernel) against Embree
on the host's cores, in one run. Per scene (``--scenes``: d2i's Cornell box at paper
000's setting, 400² and 16k gathers; triple's bunny_grace at its own size) and per
choice, a fresh work directory baked up to the scene's tracing stages (d2i.transfer and
d2i.bounce; triple.visibility): each stage's seconds, the whole bake's, and for
triple.visibility the rays it cast per second. The upstream stages (geometry, G-buffer,
gathers, atlas) do not read ``bake.device``, so they are baked once into a shared
folder first and copied; with ``--whole`` every stage the scene's methods read is baked
from an empty folder instead (the issue's "whole bake": its seconds and every stage's).
``--repeats`` bakes of each (fresh each time), medians.

On a CPU device Embree is the faster (decision 0047); the figures the issue asks for
are a GPU's (``benchmarks/device_run.sh``).
"""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path
from typing import Any

from benchmarks.fixtures import CACHE, SCENES, TINY, load, median, write_result

NAME = "engine.bake_device"
# scene: (file, its stages that trace, settings: "size" N for N², stage parameters)
BAKES = {"cornell_box": (SCENES / "cornell_box.yaml", ("d2i.transfer", "d2i.bounce"),
                         {"size": 400, "gather.count": 16384}),
         "bunny_grace": (SCENES / "bunny_grace.yaml", ("triple.visibility",), {}),
         # smaller stand-ins for a 2-core machine (minutes, not hours)
         "cornell_box_128": (SCENES / "cornell_box.yaml", ("d2i.transfer", "d2i.bounce"),
                             {"size": 128, "gather.count": 4096}),
         "bunny_grace_64": (SCENES / "bunny_grace.yaml", ("triple.visibility",),
                            {"size": 64}),
         "tiny_d2i": (TINY / "tiny_d2i.yaml", ("d2i.transfer", "d2i.bounce"), {}),
         "tiny_triple": (TINY / "tiny_triple.yaml", ("triple.visibility",), {})}
PRESETS = {"default": [],
           "tiny": ["--scenes", "tiny_d2i,tiny_triple", "--repeats", "1"]}


def bake_once(scene: Any, upstream: Path | None, folder: Path, stages: tuple[str, ...]
              ) -> dict[str, Any]:
    """``stages`` baked in ``folder`` (a copy of ``upstream``'s artifacts), or with
    ``upstream`` None every stage the scene's methods read, from nothing: seconds per
    stage that ran and in all, and triple.visibility's rays."""
    from pipeline import job
    from pipeline.engine.store import open_artifact

    if folder.exists():
        shutil.rmtree(folder)
    if upstream is not None:
        shutil.copytree(upstream, folder)
    work = job.workdir_for(scene, folder)
    start = time.perf_counter()
    report = job.bake(scene, work, until=None if upstream is None else stages, quiet=True)
    out = {"seconds": time.perf_counter() - start,
           "stages": {r.name: r.seconds for r in report if r.action == "ran"}}
    if "triple.visibility" in stages:
        out["rays"] = open_artifact(work.artifact("triple.visibility")).attrs["rays"]
    return out


def main(argv: list[str] | None = None) -> dict[str, Any]:
    from pipeline import job
    from pipeline.device import bake_tracer, cl
    from pipeline.engine.graph import with_upstream

    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME} --",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", default="cornell_box,bunny_grace",
                        help=f"comma-separated, of {', '.join(BAKES)}")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--whole", action="store_true",
                        help="bake every stage from nothing, not only the tracing ones")
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    load_before = load()
    rows = {}
    for name in args.scenes.split(","):
        path, stages, settings = BAKES[name]
        size = settings.get("size")
        scene = job.open_scene(path, (size, size) if size else None)
        scene = scene.with_settings({k: v for k, v in settings.items() if k != "size"})
        upstream = None if args.whole else CACHE / f"bake_device_{name}" / "upstream"
        if upstream is not None:
            before = sorted(with_upstream(job.stages(), list(stages)) - set(stages))
            job.bake(scene, job.workdir_for(scene, upstream), until=tuple(before), quiet=True)
        row: dict[str, Any] = {}
        for choice in bake_tracer.TRACERS:
            chosen = scene.with_settings({bake_tracer.PARAM: choice})
            runs = [bake_once(chosen, upstream, CACHE / f"bake_device_{name}" / choice, stages)
                    for _ in range(args.repeats)]
            row[choice] = {"seconds": median(r["seconds"] for r in runs),
                           "stages": {s: median(r["stages"][s] for r in runs)
                                      for s in runs[0]["stages"]},
                           "runs": runs}
            if "rays" in runs[0]:
                row[choice]["rays_per_s"] = runs[0]["rays"] / row[choice]["stages"][
                    "triple.visibility"]
        row["device_over_embree"] = row["embree"]["seconds"] / row["device"]["seconds"]
        rows[name] = row
        print(f"{name}: embree {row['embree']['seconds']:.1f} s, device "
              f"{row['device']['seconds']:.1f} s ({row['device_over_embree']:.2f}× the speed)",
              flush=True)
    return write_result(NAME, {"device_kind": "gpu" if bake_tracer.device_is_gpu() else "cpu",
                               "opencl_device": cl.device().name.strip(), "scenes": rows,
                               "load": [load_before, load()]}, args.out)

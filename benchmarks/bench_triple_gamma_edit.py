"""Benchmark: a material's γ edit in method triple's renderer (issue 16, aim ≤ 0.5 s per
edit; paper 004: 2–3 s), as stored and at ``budget=320``, in one run.

bunny_grace baked at ``--size``² (``--reuse`` takes the workdir's bake as is); the
renderer (``triple_renderer``) draws the scene once, then one frame per γ of a sweep of
the bunny's Blinn–Phong exponent. Each edit re-samples the material's glossy table
(leaf means, forward transform, selection: kernels) and splices it into the BRDF rows;
``resample_ms`` is the renderer's own timing of that, ``total_ms`` the whole frame.
The renderers (as stored; ``budget=320``) are alternated, two rounds of the sweep each.
The parts of one re-sample (leaf means, forward, selection) are timed on their own
after the frames, each followed by a queue ``finish``.

Timings on a shared machine are contended: ``os.getloadavg()`` is recorded with each.
Run from the project root: python benchmarks/bench_triple_gamma_edit.py [--workdir DIR]
[--reuse] [--size 128]; writes benchmarks/results/triple_gamma_edit.json.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

from bench_triple import RESULTS, ROOT, SCENE, median

GAMMAS = [20, 25, 31, 38, 47, 58, 72, 90, 110]  # the bake's γ is 40: every one an edit


def sweep(renderer: Any, scene: Any, offset: float) -> list[dict[str, float]]:
    """One frame per γ (each shifted by ``offset`` so that no table is reused)."""
    from pipeline.scene_edits import with_material_edits

    rows = []
    for gamma in GAMMAS:
        frame = renderer(with_material_edits(scene, [f"bunny.gamma={gamma + offset}"]))
        rows.append({"resample_ms": frame.timings["resample_ms"],
                     "total_ms": frame.timings["total_ms"], "load": os.getloadavg()[0]})
    return rows


def parts(scene: Any, attrs: dict[str, Any], repeats: int) -> dict[str, float]:
    """Median milliseconds of one re-sample's kernels, each waited for."""
    from pipeline import cl
    from pipeline.methods.triple.stages import brdf_tables as stage
    from pipeline.methods.triple.wavelet_select_cl import select_rows_buffer
    from pipeline.sphwavelet_cl import forward_device

    material = scene.materials["bunny"]
    level, refine = int(attrs["leaf_level"]), int(attrs["refine"])
    grid = stage.view_grid({"triple.view_grid": attrs["view_grid"]})
    times: dict[str, list[float]] = {"leaf_means_ms": [], "forward_ms": [], "select_ms": []}
    for k in range(repeats):
        shape = {key: material.params.get(key) for key in stage.SHAPE_KEYS}
        shape["gamma"] = GAMMAS[k % len(GAMMAS)] + 0.5
        t0 = time.perf_counter()
        means = stage.view_leaf_means_buffer(stage.glossy_params(material.model, shape),
                                             grid, level, refine)
        cl.queue().finish()
        t1 = time.perf_counter()
        coefficients = forward_device(means, grid.size, level)
        cl.queue().finish()
        t2 = time.perf_counter()
        select_rows_buffer(coefficients, 0, grid.size, 1, level, int(attrs["store_budget"]),
                           float(attrs["store_tolerance"]), int(attrs["store_top"]),
                           half=True)
        t3 = time.perf_counter()
        for key, seconds in zip(times, (t1 - t0, t2 - t1, t3 - t2), strict=True):
            times[key].append(seconds * 1e3)
    return {key: median(values) for key, values in times.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", type=int, default=128, help="image side in pixels")
    parser.add_argument("--workdir", type=Path, default=ROOT / ".prt" / "bench_triple_gamma")
    parser.add_argument("--reuse", action="store_true", help="use the workdir's bake as is")
    parser.add_argument("--out", type=Path, default=RESULTS / "triple_gamma_edit.json")
    args = parser.parse_args()

    from pipeline import job
    from pipeline.method import get_method
    from pipeline.methods.triple import render

    scene = job.open_scene(SCENE, (args.size, args.size))
    workdir = job.workdir_for(scene, args.workdir)
    if not args.reuse:
        job.bake(scene, workdir)
    artifacts = job.method_artifacts(get_method("triple"), workdir)
    result: dict[str, Any] = {"scene": "bunny_grace", "size": args.size, "gammas": GAMMAS,
                              "cpus": os.cpu_count(), "load_average_start": os.getloadavg()[0]}
    renderers = {"as_stored": render.triple_renderer(scene, artifacts),
                 "budget_320": render.triple_renderer(scene, artifacts, budget=320)}
    for renderer in renderers.values():
        renderer(scene)  # warm-up: kernels built, tables uploaded
    rows: dict[str, list[dict[str, float]]] = {name: [] for name in renderers}
    for rounds in range(2):  # alternated, so that drifting load falls on both
        for name, renderer in renderers.items():
            rows[name] += sweep(renderer, scene, 0.25 * rounds)
    result["edits"] = {name: {"resample_ms_median": median([r["resample_ms"] for r in rs]),
                              "total_ms_median": median([r["total_ms"] for r in rs]),
                              "all": rs} for name, rs in rows.items()}
    result["one_resample_parts"] = parts(scene, artifacts["triple.brdf_tables"].attrs, 7)
    result["load_average_end"] = os.getloadavg()[0]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1, default=float))
    print(json.dumps({k: v for k, v in result.items() if k != "edits"}, default=float))
    for name, r in result["edits"].items():
        print(f"{name}: re-sample {r['resample_ms_median']:.0f} ms, frame "
              f"{r['total_ms_median']:.0f} ms (medians of {len(r['all'])})")


if __name__ == "__main__":
    main()

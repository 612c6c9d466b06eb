"""A material's γ edit in method triple's renderer: re-sample and frame time, as stored and at 320.

Aim ≤ 0.5 s per edit (paper 004: 2–3 s); frames over a γ sweep of bunny_grace's bunny at
128². Issue 16. The scene baked at ``--size``² (fixtures ``baked``); the renderer
(``TripleRenderer``) draws the scene once, then one frame per γ of a sweep of the
``--material``'s Blinn–Phong exponent. Each edit re-samples the material's glossy table
(leaf means, forward transform, selection: kernels) and splices it into the BRDF rows;
``resample_ms`` is the renderer's own timing of that, ``total_ms`` the whole frame. The
renderers (as stored; ``budget=320``) are alternated, ``--rounds`` rounds of the sweep
each. The parts of one re-sample (leaf means, forward, selection) are timed on their own
after the frames, each followed by a queue ``finish``.

Timings on a shared machine are contended: the load average is recorded with each.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

from benchmarks.fixtures import TINY, load, median, write_result
from benchmarks.triple.frames import SCENE, triple_bake

NAME = "triple.gamma_edit"
GAMMAS = [20, 25, 31, 38, 47, 58, 72, 90, 110]  # the bake's γ is 60: every one an edit
PRESETS = {"default": [],
           "tiny": ["--scene", str(TINY / "tiny_triple.yaml"), "--size", "16",
                    "--material", "shiny", "--gammas", "25,47", "--rounds", "1",
                    "--parts-repeats", "2"]}


def sweep(renderer: Any, scene: Any, material: str, gammas: list[float], offset: float
          ) -> list[dict[str, float]]:
    """One frame per γ (each shifted by ``offset`` so that no table is reused)."""
    from pipeline.scene.edits import with_material_edits

    rows = []
    for gamma in gammas:
        frame = renderer.frame(with_material_edits(scene, [f"{material}.gamma={gamma + offset}"]))
        rows.append({"resample_ms": frame.timings["resample_ms"],
                     "total_ms": frame.timings["total_ms"], "load": load()[0]})
    return rows


def parts(scene: Any, material_name: str, gammas: list[float], attrs: dict[str, Any],
          repeats: int) -> dict[str, float]:
    """Median milliseconds of one re-sample's kernels, each waited for."""
    from pipeline.device import cl
    from pipeline.device.sphwavelet_cl import forward_device
    from pipeline.methods.triple.stages import brdf_tables as stage
    from pipeline.methods.triple.wavelet_select_cl import select_rows_buffer

    material = scene.materials[material_name]
    level, refine = int(attrs["leaf_level"]), int(attrs["refine"])
    grid = stage.view_grid({"triple.view_grid": attrs["view_grid"]})
    times: dict[str, list[float]] = {"leaf_means_ms": [], "forward_ms": [], "select_ms": []}
    for k in range(repeats):
        shape = {key: material.params.get(key) for key in stage.SHAPE_KEYS}
        shape["gamma"] = gammas[k % len(gammas)] + 0.5
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


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME} --",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--scene", type=Path, default=SCENE)
    parser.add_argument("--size", type=int, default=128, help="image side in pixels")
    parser.add_argument("--material", default="bunny",
                        help="the glossy material (or object) whose γ is edited")
    parser.add_argument("--gammas", default=",".join(map(str, GAMMAS)),
                        help="the sweep (none the bake's γ)")
    parser.add_argument("--rounds", type=int, default=2, help="sweeps per renderer")
    parser.add_argument("--parts-repeats", type=int, default=7)
    parser.add_argument("--workdir", type=Path, default=None,
                        help="bake there [default: a cache folder per scene and size]")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    gammas = [float(g) for g in args.gammas.split(",")]

    from pipeline.methods.triple import render

    scene, artifacts = triple_bake(args.scene, args.size, args.workdir)
    material = scene.objects[args.material].material if args.material in scene.objects \
        else args.material
    result: dict[str, Any] = {"scene": scene.name, "size": args.size, "material": material,
                              "gammas": gammas, "cpus": os.cpu_count(),
                              "load_average_start": load()[0]}
    renderers = {"as_stored": render.TripleRenderer(scene, artifacts),
                 "budget_320": render.TripleRenderer(scene, artifacts, budget=320)}
    for renderer in renderers.values():
        renderer.frame(scene)  # warm-up: kernels built, tables uploaded
    rows: dict[str, list[dict[str, float]]] = {name: [] for name in renderers}
    for rounds in range(args.rounds):  # alternated, so that drifting load falls on both
        for name, renderer in renderers.items():
            rows[name] += sweep(renderer, scene, material, gammas, 0.25 * rounds)
    result["edits"] = {name: {"resample_ms_median": median(r["resample_ms"] for r in rs),
                              "total_ms_median": median(r["total_ms"] for r in rs),
                              "all": rs} for name, rs in rows.items()}
    result["one_resample_parts"] = parts(scene, material, gammas,
                                         artifacts["triple.brdf_tables"].attrs,
                                         args.parts_repeats)
    result["load_average_end"] = load()[0]
    print(json.dumps({k: v for k, v in result.items() if k != "edits"}, default=float))
    for name, r in result["edits"].items():
        print(f"{name}: re-sample {r['resample_ms_median']:.0f} ms, frame "
              f"{r['total_ms_median']:.0f} ms (medians of {len(r['all'])})")
    return write_result(NAME, result, args.out)

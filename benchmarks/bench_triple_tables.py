"""Benchmark: method triple's lighting rotation grid and BRDF tables (issue 16).

Run from the project root:  python benchmarks/bench_triple_tables.py [--quick]
Writes benchmarks/results/triple_tables.json. Scene: scenes/bunny_grace.yaml (the Grace
map, the bunny's Blinn-Phong material, the Lambertian ground); settings the stage
defaults of stages.yaml unless a sweep says otherwise; times are medians over repeats
(this machine is shared and noisy).

* ``light``: the rebuild of the whole rotation grid (every chunk of
  triple.light_rotations, as the stage computes it, without the zarr writes) per
  refinement r, split into prefilter, leaf-mean kernel, forward transform and row
  selection; aim ≤ 2 s.
* ``light_accuracy``: leaf means of a few grid frames against a reference of 4^5
  samples per leaf on the unfiltered map (NumPy), with and without the prefilter, per r:
  luminance-weighted relative L2 over the leaves, and the worst leaf's error relative
  to the brightest leaf.
* ``brdf``: one material's table (what a γ edit re-bakes) per r: the stage's
  run_chunk (total) and its steps timed apart (leaf means of a quarter of the views
  mirrored to all, forward transform, selection);
  aim ≤ 0.5 s (paper 004: 2–3 s); accuracy against 4^4 samples per leaf.
* ``storage``: bytes of the stored rows at top-only 80 / 320 (each stored entry: uint16
  index + float32 value per channel) and as stored at the tolerance, against paper 004
  §5's 11.5 / 46.1 MB (lighting) and 7.2 / 28.6 MB (BRDF) at 80 / 320.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pipeline import cl
from pipeline.chunk import make_chunk
from pipeline.images import read_environment
from pipeline.math.brdf_tables import glossy_leaf_means
from pipeline.math.envmap import LUMINANCE
from pipeline.math.geodesic import geodesic_levels
from pipeline.math.light_grid import frame_leaf_means
from pipeline.math.wavelet_rows import select_rows
from pipeline.scene import load_scene
from pipeline.sphwavelet_cl import forward, forward_buffer
from pipeline.stages import ChunkContext
from pipeline.stages import brdf_tables as brdf_stage
from pipeline.stages import light_rotations as light_stage

ROOT = Path(__file__).resolve().parent.parent
PARAMS = yaml.safe_load((ROOT / "stages.yaml").read_text())["params"]
QUICK = "--quick" in sys.argv
REPEATS = 1 if QUICK else 3
PAPER_MB = {"lighting": {"80": 11.5, "320": 46.1}, "brdf": {"80": 7.2, "320": 28.6}}


def _median(runs: list[dict[str, float]]) -> dict[str, float]:
    return {k: statistics.median(r[k] for r in runs) for k in runs[0]}


def _timed(fn: Any, *args: Any) -> tuple[Any, float]:
    start = time.perf_counter()
    out = fn(*args)
    cl.queue().finish()
    return out, time.perf_counter() - start


def light_rebuild(rgb: np.ndarray, params: dict[str, Any]) -> tuple[dict[str, float], dict]:
    """One rebuild of every chunk, split by step; and the stored rows' arrays."""
    grid = light_stage.frame_grid(params)
    level, refine = params["triple.leaf_level"], params["triple.light_refine"]
    per_phi = grid.n_theta * grid.n_psi
    block = params["triple.light_block"]
    times = {"prefilter": 0.0, "leaf_means": 0.0, "forward": 0.0, "select": 0.0}
    parts = []
    total = time.perf_counter()
    for start in range(0, grid.size, block):
        end = min(start + block, grid.size)
        phi_first, phis = start // per_phi, -(-end // per_phi) - start // per_phi
        pm, t = _timed(light_stage.prefiltered_map, rgb, params)
        times["prefilter"] += t
        means, t = _timed(light_stage.leaf_means_buffer, pm, grid, phi_first, phis, level,
                          refine)
        times["leaf_means"] += t
        coefficients, t = _timed(forward_buffer, means, phis * per_phi * 3, level)
        times["forward"] += t
        coefficients = coefficients.reshape(phis * per_phi, 3, -1)[
            start - phi_first * per_phi:end - phi_first * per_phi]
        rows, t = _timed(select_rows, coefficients, level, params["triple.store_budget"],
                         params["triple.store_tolerance"], params["triple.store_top"],
                         LUMINANCE)
        times["select"] += t
        parts.append(rows)
    times["total"] = time.perf_counter() - total
    rows = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return times, rows


def light_accuracy(rgb: np.ndarray, params: dict[str, Any], refines: list[int]) -> dict:
    """Errors of the leaf means of 6 frames (φ = 0, θ from pole to pole) per r."""
    grid = light_stage.frame_grid(params)
    level = params["triple.leaf_level"]
    picks = np.linspace(0, grid.n_theta * grid.n_psi - 1, 6).astype(int)
    frames = grid.frames()[picks]
    reference = frame_leaf_means(rgb, frames, level, 5)
    areas = geodesic_levels(level)[level].areas

    def errors(means: np.ndarray) -> dict[str, float]:
        lum = np.einsum("c,fcn->fn", LUMINANCE, means - reference)
        ref = np.einsum("c,fcn->fn", LUMINANCE, reference)
        l2 = np.sqrt(np.sum(areas * lum ** 2, axis=1) / np.sum(areas * ref ** 2, axis=1))
        worst = np.abs(lum).max(axis=1) / ref.max(axis=1)
        return {"rel_l2_median": float(np.median(l2)), "rel_l2_max": float(l2.max()),
                "worst_leaf_over_brightest_max": float(worst.max())}

    out = {}
    for refine in refines:
        p = {**params, "triple.light_refine": refine}
        pm = light_stage.prefiltered_map(rgb, p)
        kernel = light_stage.kernel_leaf_means(pm, grid, 0, 1, level, refine)[0][picks]
        out[str(refine)] = {"prefiltered": errors(kernel),
                            "unfiltered_map": errors(frame_leaf_means(rgb, frames, level,
                                                                      refine)),
                            "prefiltered_width": int(pm.shape[1])}
        print(f"light accuracy r={refine}: {out[str(refine)]}")
    return out


def _material_ctx(scene: Any, name: str, params: dict[str, Any]) -> ChunkContext:
    keys = ("model", *brdf_stage.SHAPE_KEYS)
    return ChunkContext(params=params, scene={f"materials.{name}.{k}": scene.section(
        f"materials.{name}.{k}") for k in keys}, inputs={},
        chunk=make_chunk(name, "material", material=name, index=0))


def brdf_table(scene: Any, name: str, params: dict[str, Any]) -> tuple[dict[str, float], dict]:
    """One material's table through the stage's run_chunk (total), and split."""
    ctx = _material_ctx(scene, name, params)
    rows, total = _timed(brdf_stage.run_chunk, ctx)
    level, refine = params["triple.leaf_level"], params["triple.brdf_refine"]
    material = brdf_stage.glossy_params(scene.materials[name].model, {
        k: ctx.scene[f"materials.{name}.{k}"] for k in brdf_stage.SHAPE_KEYS})
    grid = brdf_stage.view_grid(params)
    means, t_means = _timed(brdf_stage.view_leaf_means, material, grid, level, refine)
    coefficients, t_forward = _timed(forward, means, level)
    _, t_select = _timed(select_rows, coefficients[:, None], level,
                         params["triple.store_budget"], params["triple.store_tolerance"],
                         params["triple.store_top"])
    return {"total": total, "leaf_means": t_means, "forward": t_forward,
            "select": t_select}, rows


def brdf_accuracy(scene: Any, name: str, params: dict[str, Any], refines: list[int]) -> dict:
    level = params["triple.leaf_level"]
    ctx = _material_ctx(scene, name, params)
    material = brdf_stage.glossy_params(scene.materials[name].model, {
        k: ctx.scene[f"materials.{name}.{k}"] for k in brdf_stage.SHAPE_KEYS})
    grid = brdf_stage.view_grid(params)
    views = grid.directions()[np.linspace(0, grid.size - 1, 5).astype(int)]
    views = np.concatenate([views, [[0.0, 0.0, 1.0]]])
    reference = glossy_leaf_means(material, views, level, 4)
    areas = geodesic_levels(level)[level].areas
    out = {}
    for refine in refines:
        got = brdf_stage.kernel_leaf_means(material, views, level, refine)
        l2 = np.sqrt(np.sum(areas * (got - reference) ** 2, axis=1)
                     / np.sum(areas * reference ** 2, axis=1))
        out[str(refine)] = {"rel_l2_median": float(np.median(l2)), "rel_l2_max": float(l2.max())}
        print(f"brdf accuracy r={refine}: {out[str(refine)]}")
    return out


def storage(rows: dict[str, np.ndarray], channels: int) -> dict[str, Any]:
    """Bytes of the rows cut to top-only 80 / 320, and as stored."""
    entry = 2 + 4 * channels
    index = rows["index"].astype(np.int64)
    out = {"rows": int(len(rows["count"])), "bytes_per_entry": entry,
           "stored_MB": float((len(index) * entry + 8 * len(rows["count"])) / 1e6),
           "mean_count": float(rows["count"].mean()),
           "worst_residual": float(rows["residual"].max())}
    for n in (80, 320):
        out[f"top_{n}_MB"] = float(((index < n).sum() * entry) / 1e6)
    return out


def main() -> None:
    scene = load_scene(ROOT / "scenes" / "bunny_grace.yaml")
    rgb = read_environment(scene.environment_file())
    params = dict(PARAMS)
    refines = [0, 1] if QUICK else [0, 1, 2]
    result: dict[str, Any] = {
        "machine": {"cpu_count": os.cpu_count(), "processor": platform.processor(),
                    "device": cl.device().name, "python": platform.python_version(),
                    "load_average_at_start": os.getloadavg()},
        "scene": "scenes/bunny_grace.yaml",
        "settings": {k: v for k, v in PARAMS.items() if k.startswith("triple.")},
        "targets": {"light_rebuild_s": 2.0, "brdf_table_s": 0.5, "paper_MB": PAPER_MB},
        "light": {}, "brdf": {}}
    result["light_accuracy"] = light_accuracy(rgb, params, refines)
    light_rows = None
    for refine in refines:
        p = {**params, "triple.light_refine": refine}
        light_stage.leaf_means_buffer(light_stage.prefiltered_map(rgb, p),
                                      light_stage.frame_grid(p), 0, 1, 4, refine)  # build
        runs = []
        for _ in range(REPEATS):
            times, rows = light_rebuild(rgb, p)
            runs.append(times)
        result["light"][str(refine)] = {"seconds_median": _median(runs), "runs": len(runs)}
        if refine == params["triple.light_refine"]:
            light_rows = rows
        print(f"light rebuild r={refine}: {result['light'][str(refine)]}")
    for refine in refines:
        p = {**params, "triple.brdf_refine": refine}
        brdf_table(scene, "bunny", p)  # build the kernels
        runs = [brdf_table(scene, "bunny", p) for _ in range(REPEATS + 2)]
        result["brdf"][str(refine)] = {"seconds_median": _median([r[0] for r in runs]),
                                       "runs": len(runs)}
        print(f"brdf table r={refine}: {result['brdf'][str(refine)]}")
    result["brdf_accuracy"] = brdf_accuracy(scene, "bunny", params, refines)
    _, bunny_rows = brdf_table(scene, "bunny", params)
    _, ground_rows = brdf_table(scene, "ground", params)
    result["storage"] = {"lighting": storage(light_rows, 3),
                         "brdf": {"bunny": storage(bunny_rows, 1),
                                  "ground": storage(ground_rows, 1)},
                         "paper_MB": PAPER_MB}
    print(json.dumps(result["storage"], indent=1))
    path = ROOT / "benchmarks" / "results" / "triple_tables.json"
    path.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()

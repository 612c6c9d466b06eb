"""Benchmark: method triple's lighting rotation grid and BRDF tables (issue 16).

Run from the project root:
  python benchmarks/bench_triple_tables.py [--quick] [--defaults] [--compare REV]
  python benchmarks/bench_triple_tables.py --light-only [--out FILE]   (a GPU run)
Writes benchmarks/results/triple_tables.json and triple_storage.png. Scene:
scenes/bunny_grace.yaml (the Grace map, the bunny's Blinn-Phong material, the Lambertian
ground); settings the stage defaults of stages.yaml unless a sweep says otherwise; times
are medians over repeats, wall-clock and this process's CPU seconds (all its threads:
on a shared machine the CPU seconds say more than the wall clock), with the load
average.

* ``light``: the rebuild of the whole rotation grid (every chunk of
  triple.light_rotations, as the stage computes it, without the zarr writes) per
  refinement r, split into the samples' texel coordinates (once per process),
  prefilter, leaf-mean kernel, forward transform, row selection with the float16
  conversion (both on the device); aim ≤ 2 s; and the leaf-mean kernel's bilinear map
  lookups (``lookups``: those it computes) per second of its wall time; each step's
  CPU seconds as ``<step>_cpu`` (the wall clock of a shared machine says little).
* ``light_accuracy``: leaf means of a few grid frames against a reference of 4^5
  samples per leaf on the unfiltered map (NumPy), with and without the prefilter, per r:
  luminance-weighted relative L2 over the leaves, and the worst leaf's error relative
  to the brightest leaf.
* ``brdf``: one material's table (what a γ edit re-bakes) per r: the stage's
  run_chunk (total) and its steps timed apart (leaf means of a quarter of the views
  mirrored to all, forward transform, selection with the float16 conversion, all on
  the device; the total also has the diffuse row, NumPy);
  aim ≤ 0.5 s (paper 004: 2–3 s); accuracy against 4^4 samples per leaf.
* ``storage``: bytes of the stored rows at top-only 80 / 320 and as stored at the
  tolerance (each entry: uint16 index + float16 value per channel, 8 B lighting / 4 B
  BRDF; each row: int32 count, float32 residual and scale, 12 B; and as schema v1 had
  them, float32 values, 14 / 6 B per entry, 8 B per row), against paper 004 §5's
  11.5 / 46.1 MB (lighting) and 7.2 / 28.6 MB (BRDF) at 80 / 320; chart
  triple_storage.png.
* ``compare`` (``--compare REV``, e.g. the commit before the device selection): the
  stages' own run_chunk — whole rotation grid, one BRDF table — timed in fresh
  processes on the code of REV (``git archive``) and of this checkout, alternating,
  ROUNDS times each: medians and the ratio before / after from one run.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pipeline import cl
from pipeline.chunk import make_chunk
from pipeline.images import read_environment
from pipeline.math.envmap import LUMINANCE
from pipeline.math.geodesic import geodesic_levels
from pipeline.methods.triple.brdf_tables import glossy_leaf_means
from pipeline.methods.triple.light_grid import frame_leaf_means
from pipeline.methods.triple.stages import brdf_tables as brdf_stage
from pipeline.methods.triple.stages import light_rotations as light_stage
from pipeline.methods.triple.wavelet_select_cl import select_rows_buffer
from pipeline.scene import load_scene, shared_data_dir
from pipeline.sphwavelet_cl import forward_device
from pipeline.stages import ChunkContext

ROOT = Path(__file__).resolve().parent.parent
PARAMS = yaml.safe_load((ROOT / "stages.yaml").read_text())["params"]
QUICK = "--quick" in sys.argv
REPEATS = 1 if QUICK else 3
ROUNDS = 3  # --compare: fresh processes per code version
PAPER_MB = {"lighting": {"80": 11.5, "320": 46.1}, "brdf": {"80": 7.2, "320": 28.6}}
ENTRY_BYTES = {"lighting": 2 + 3 * 2, "brdf": 2 + 2}      # uint16 index + float16 values
ENTRY_BYTES_V1 = {"lighting": 2 + 3 * 4, "brdf": 2 + 4}   # schema v1: float32 values
ROW_BYTES, ROW_BYTES_V1 = 12, 8  # count, residual (and scale)


def _median(runs: list[dict[str, float]]) -> dict[str, float]:
    return {k: statistics.median(r[k] for r in runs) for k in runs[0]}


def _timed(fn: Any, *args: Any) -> tuple[Any, float]:
    """``fn(*args)`` and its wall-clock seconds (the queue finished); its CPU seconds
    (this process, all threads) are added to ``CPU[fn.__name__]``."""
    start, cpu = time.perf_counter(), time.process_time()
    out = fn(*args)
    cl.queue().finish()
    name = getattr(fn, "__name__", "call")
    CPU[name] = CPU.get(name, 0.0) + time.process_time() - cpu
    return out, time.perf_counter() - start


CPU: dict[str, float] = {}  # CPU seconds per timed function since the last clear


def _cpu(fn: Any) -> tuple[Any, dict[str, float]]:
    """``fn()``'s result, and its wall-clock and CPU seconds (this process, all threads)."""
    wall, cpu = time.perf_counter(), time.process_time()
    out = fn()
    cl.queue().finish()
    return out, {"wall_s": time.perf_counter() - wall, "cpu_s": time.process_time() - cpu}


def bilinear_lookups(grid: Any, start: int, end: int, leaves: int, samples: int) -> int:
    """Bilinear map lookups (4 float4 texel loads each) of the leaf-mean kernel for grid
    entries [start, end): per φ plane the span touches and frame given (ψ < π for an
    even n_ψ), one per sample of every leaf when the entry or its ψ + π partner is in
    the span (kernels/triple/light_rotations.cl)."""
    per_phi = grid.n_theta * grid.n_psi
    given = grid.n_psi // 2 if grid.n_psi % 2 == 0 else grid.n_psi
    rows = np.arange(grid.n_theta)[:, None] * grid.n_psi + np.arange(given)[None, :]
    total = 0
    for phi in range(start // per_phi, -(-end // per_phi)):
        entry = phi * per_phi + rows
        wanted = (entry >= start) & (entry < end)
        if given < grid.n_psi:
            wanted |= (entry + given >= start) & (entry + given < end)
        total += int(wanted.sum())
    return total * leaves * samples


def light_rebuild(rgb: np.ndarray, params: dict[str, Any]) -> tuple[dict[str, float], dict]:
    """One rebuild of every chunk in a process that has not seen the grid (the samples'
    texel coordinates computed once, then kept), split by step; and the stored rows."""
    grid = light_stage.frame_grid(params)
    level, refine = params["triple.leaf_level"], params["triple.light_refine"]
    block = params["triple.light_block"]
    times = {"coords": 0.0, "prefilter": 0.0, "leaf_means": 0.0, "forward": 0.0,
             "select": 0.0, "lookups": 0}
    parts = []
    light_stage._sample_coords.cache_clear()
    light_stage._PREFILTERED.clear()
    CPU.clear()
    total, cpu = time.perf_counter(), time.process_time()
    for start in range(0, grid.size, block):
        end = min(start + block, grid.size)
        pm, t = _timed(light_stage.prefiltered_map, rgb, params)
        times["prefilter"] += t
        _, t = _timed(light_stage._sample_coords, grid, level, refine, *pm.shape[1::-1])
        times["coords"] += t
        means, t = _timed(light_stage.leaf_means_buffer, pm, grid, start, end, level,
                          refine)
        times["leaf_means"] += t
        times["lookups"] += bilinear_lookups(grid, start, end, 20 * 4 ** level, 4 ** refine)
        coefficients, t = _timed(forward_device, means, (end - start) * 3, level)
        times["forward"] += t
        rows, t = _timed(select_rows_buffer, coefficients, 0, end - start, 3, level,
                         params["triple.store_budget"], params["triple.store_tolerance"],
                         params["triple.store_top"], LUMINANCE, True)
        times["select"] += t
        parts.append(rows)
    times["total"] = time.perf_counter() - total
    times["total_cpu"] = time.process_time() - cpu
    times["lookups_per_s"] = times["lookups"] / times["leaf_means"]
    names = {"prefiltered_map": "prefilter", "_sample_coords": "coords",
             "leaf_means_buffer": "leaf_means", "forward_device": "forward",
             "select_rows_buffer": "select"}
    times.update({f"{step}_cpu": CPU.get(name, 0.0) for name, step in names.items()})
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
        kernel = light_stage.kernel_leaf_means(pm, grid, 0, grid.n_theta * grid.n_psi,
                                               level, refine)[picks]
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
    CPU.clear()
    cpu = time.process_time()
    rows, total = _timed(brdf_stage.run_chunk, ctx)
    total_cpu = time.process_time() - cpu
    level, refine = params["triple.leaf_level"], params["triple.brdf_refine"]
    material = brdf_stage.glossy_params(scene.materials[name].model, {
        k: ctx.scene[f"materials.{name}.{k}"] for k in brdf_stage.SHAPE_KEYS})
    grid = brdf_stage.view_grid(params)
    means, t_means = _timed(brdf_stage.view_leaf_means_buffer, material, grid, level, refine)
    coefficients, t_forward = _timed(forward_device, means, grid.size, level)
    _, t_select = _timed(select_rows_buffer, coefficients, 0, grid.size, 1, level,
                         params["triple.store_budget"], params["triple.store_tolerance"],
                         params["triple.store_top"], None, True)
    return {"total": total, "total_cpu": total_cpu, "leaf_means": t_means,
            "forward": t_forward, "select": t_select,
            "leaf_means_cpu": CPU["view_leaf_means_buffer"], "forward_cpu": CPU["forward_device"],
            "select_cpu": CPU["select_rows_buffer"]}, rows


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


def storage(rows: dict[str, np.ndarray], kind: str) -> dict[str, Any]:
    """MB of the rows cut to top-only 80 / 320 (every row keeps its count, residual and
    scale), and as stored; also as schema v1 stored them (float32 values)."""
    index = rows["index"].astype(np.int64)
    n_rows = len(rows["count"])
    out = {"rows": int(n_rows), "bytes_per_entry": ENTRY_BYTES[kind],
           "bytes_per_row": ROW_BYTES, "bytes_per_entry_v1": ENTRY_BYTES_V1[kind],
           "bytes_per_row_v1": ROW_BYTES_V1, "entries": int(len(index)),
           "mean_count": float(rows["count"].mean()),
           "worst_residual": float(rows["residual"].max())}
    for label, entry, row in (("", ENTRY_BYTES[kind], ROW_BYTES),
                              ("_v1", ENTRY_BYTES_V1[kind], ROW_BYTES_V1)):
        out[f"stored_MB{label}"] = (len(index) * entry + n_rows * row) / 1e6
        for n in (80, 320):
            out[f"top_{n}_MB{label}"] = ((index < n).sum() * entry + n_rows * row) / 1e6
    return out


def storage_chart(store: dict[str, Any], path: Path) -> None:
    """Bars: MB at top-only 80 / 320 and as stored, float16 and v1's float32, against
    the paper's (lighting; the glossy bunny's BRDF table)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9.0, 3.8), dpi=120)
    for ax, (title, s, paper) in zip(axes, (
            ("lighting (16384 frames)", store["lighting"], PAPER_MB["lighting"]),
            ("BRDF table (bunny, 8192 views)", store["brdf"]["bunny"], PAPER_MB["brdf"])),
            strict=True):
        labels = ["top 80", "top 320", "as stored"]
        ours = [s["top_80_MB"], s["top_320_MB"], s["stored_MB"]]
        v1 = [s["top_80_MB_v1"], s["top_320_MB_v1"], s["stored_MB_v1"]]
        theirs = [paper["80"], paper["320"], 0.0]
        x = np.arange(3)
        ax.bar(x - 0.27, theirs, 0.27, label="paper 004", color="0.6")
        ax.bar(x, v1, 0.27, label="float32 (v1)", color="tab:orange")
        ax.bar(x + 0.27, ours, 0.27, label="float16 + row scale (v2)", color="tab:blue")
        for xi, v in zip(x + 0.27, ours, strict=True):
            ax.text(xi, v, f"{v:.1f}", ha="center", va="bottom", fontsize=7)
        ax.set_xticks(x, labels)
        ax.set_ylabel("MB (raw bytes)")
        ax.set_title(title, fontsize=9)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def compare(rev: str) -> dict[str, Any]:
    """benchmarks/triple_stage_times.py in fresh processes on REV's code and on this
    checkout's, alternating ROUNDS times: medians and before / after ratios."""
    driver = ROOT / "benchmarks" / "triple_stage_times.py"
    runs: dict[str, list[dict[str, float]]] = {"before": [], "after": []}
    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.run(["git", "archive", rev], cwd=ROOT, check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        trees = {"before": Path(tmp), "after": ROOT}
        for _ in range(ROUNDS):
            for label, tree in trees.items():
                env = {**os.environ, "PYTHONPATH": str(tree),
                       "PRT_DATA": str(shared_data_dir())}  # REV's tree is elsewhere
                out = subprocess.run([sys.executable, str(driver)], cwd=tree, env=env,
                                     check=True, capture_output=True, text=True).stdout
                runs[label].append(json.loads(out.strip().splitlines()[-1]))
                print(f"compare {label}: {runs[label][-1]}")
    before, after = _median(runs["before"]), _median(runs["after"])
    return {"rev_before": rev, "rounds": ROUNDS, "before": before, "after": after,
            "ratio_before_over_after": {k: before[k] / after[k] for k in before
                                        if k.endswith("_s")}}


def light_only(rgb: np.ndarray, scene: Any, params: dict[str, Any]) -> None:
    """``--light-only [--out FILE]``: the rotation-grid rebuild and one BRDF table at
    the stages' defaults, on ``cl.device()`` (PRT_CL_DEVICE: a GPU run), no accuracy
    references; JSON to FILE (default benchmarks/results/triple_tables_<device>.json)."""
    result: dict[str, Any] = {"device": cl.device().name, "cpu_count": os.cpu_count(),
                              "load_average_at_start": os.getloadavg()}
    light_stage.leaf_means_buffer(light_stage.prefiltered_map(rgb, params),
                                  light_stage.frame_grid(params), 0, 1, 4,
                                  int(params["triple.light_refine"]))  # build the kernels
    result["light"] = _median([light_rebuild(rgb, params)[0] for _ in range(REPEATS)])
    print(f"light rebuild: {result['light']}", flush=True)
    brdf_table(scene, "bunny", params)  # build the kernels
    result["brdf_table"] = _median([brdf_table(scene, "bunny", params)[0]
                                    for _ in range(REPEATS + 2)])
    print(f"brdf table: {result['brdf_table']}", flush=True)
    name = cl.device().name.replace(" ", "_")
    out = Path(sys.argv[sys.argv.index("--out") + 1]) if "--out" in sys.argv else \
        ROOT / "benchmarks" / "results" / f"triple_tables_{name}.json"
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {out}")


def main() -> None:
    scene = load_scene(ROOT / "scenes" / "bunny_grace.yaml")
    rgb = read_environment(scene.environment_file())
    rgb.setflags(write=False)  # as the runner's chunks get it: prefiltered once
    params = dict(PARAMS)
    if "--compare" in sys.argv:
        rev = sys.argv[sys.argv.index("--compare") + 1]
        path = ROOT / "benchmarks" / "results" / "triple_tables.json"
        result = json.loads(path.read_text())
        result["compare"] = compare(rev)
        result["compare"]["load_average_at_end"] = os.getloadavg()
        path.write_text(json.dumps(result, indent=1) + "\n")
        print(json.dumps(result["compare"], indent=1))
        return
    if "--light-only" in sys.argv:
        light_only(rgb, scene, params)
        return
    refines = [0, 1] if QUICK else [0, 1, 2]
    light_refines = brdf_refines = refines
    if "--defaults" in sys.argv:  # the stages' default refinements only
        light_refines = [int(params["triple.light_refine"])]
        brdf_refines = [int(params["triple.brdf_refine"])]
    result: dict[str, Any] = {
        "machine": {"cpu_count": os.cpu_count(), "processor": platform.processor(),
                    "device": cl.device().name, "python": platform.python_version(),
                    "load_average_at_start": os.getloadavg()},
        "scene": "scenes/bunny_grace.yaml",
        "settings": {k: v for k, v in PARAMS.items() if k.startswith("triple.")},
        "targets": {"light_rebuild_s": 2.0, "brdf_table_s": 0.5, "paper_MB": PAPER_MB},
        "light": {}, "brdf": {}}
    result["light_accuracy"] = light_accuracy(rgb, params, light_refines)
    light_rows = None
    for refine in light_refines:
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
    for refine in brdf_refines:
        p = {**params, "triple.brdf_refine": refine}
        brdf_table(scene, "bunny", p)  # build the kernels
        runs = [brdf_table(scene, "bunny", p) for _ in range(REPEATS + 2)]
        result["brdf"][str(refine)] = {"seconds_median": _median([r[0] for r in runs]),
                                       "runs": len(runs)}
        print(f"brdf table r={refine}: {result['brdf'][str(refine)]}")
    result["brdf_accuracy"] = brdf_accuracy(scene, "bunny", params, brdf_refines)
    _, bunny_rows = brdf_table(scene, "bunny", params)
    _, ground_rows = brdf_table(scene, "ground", params)
    result["storage"] = {"lighting": storage(light_rows, "lighting"),
                         "brdf": {"bunny": storage(bunny_rows, "brdf"),
                                  "ground": storage(ground_rows, "brdf")},
                         "paper_MB": PAPER_MB}
    print(json.dumps(result["storage"], indent=1))
    storage_chart(result["storage"], ROOT / "benchmarks" / "results" / "triple_storage.png")
    result["machine"]["load_average_at_end"] = os.getloadavg()
    path = ROOT / "benchmarks" / "results" / "triple_tables.json"
    path.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()

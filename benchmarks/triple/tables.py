"""Method triple's rotation grid and BRDF tables: rebuild times per refinement, accuracy, storage.

On bunny_grace (aims: 2 s for the grid, 0.5 s for a table). Issue 16. Settings: the
stage defaults with the scene's settings (pipeline/methods/triple/stages.yaml); times
are medians over repeats, wall-clock and this process's CPU seconds (all its threads: on
a shared machine the CPU seconds say more than the wall clock), with the load average.
Options: ``--quick`` (1 repeat, r = 0, 1), ``--defaults`` (the stages' default
refinements only), ``--light-only`` (a GPU run: the rotation-grid rebuild and one BRDF
table at the defaults, no accuracy; its own result) and ``--compare REV`` (adds
``compare`` to the result already at ``--out``).

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
* ``brdf``: one material's table (``--material``: what a γ edit re-bakes) per r: the
  stage's run_chunk (total) and its steps timed apart (leaf means of a quarter of the
  views mirrored to all, forward transform, selection with the float16 conversion, all
  on the device; the total also has the diffuse row, NumPy);
  aim ≤ 0.5 s (paper 004: 2–3 s); accuracy against 4^4 samples per leaf.
* ``storage``: bytes of the stored rows at top-only 80 / 320 and as stored at the
  tolerance (each entry: uint16 index + float16 value per channel, 8 B lighting / 4 B
  BRDF; each row: int32 count, float32 residual and scale, 12 B; and as schema v1 had
  them, float32 values, 14 / 6 B per entry, 8 B per row), against paper 004 §5's
  11.5 / 46.1 MB (lighting) and 7.2 / 28.6 MB (BRDF) at 80 / 320; the BRDF tables of
  every material of the scene; chart beside the JSON (``<name>_storage.png``).
* ``compare`` (``--compare REV``, e.g. the commit before the device selection): the
  stages' own run_chunk — whole rotation grid, one BRDF table — timed in fresh
  processes (benchmarks/triple/_stage_times.py) on the code of REV (``git archive``) and
  of this checkout, alternating, ``--rounds`` times each: medians and the ratio before /
  after from one run.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.fixtures import (
    ROOT,
    SCENES,
    TINY,
    cpu_ms,
    load,
    medians,
    result_path,
    write_result,
)

NAME = "triple.tables"
PRESETS = {"default": [],
           "tiny": ["--scene", str(TINY / "tiny_triple.yaml"), "--material", "shiny",
                    "--quick"]}
PAPER_MB = {"lighting": {"80": 11.5, "320": 46.1}, "brdf": {"80": 7.2, "320": 28.6}}
ENTRY_BYTES = {"lighting": 2 + 3 * 2, "brdf": 2 + 2}      # uint16 index + float16 values
ENTRY_BYTES_V1 = {"lighting": 2 + 3 * 4, "brdf": 2 + 4}   # schema v1: float32 values
ROW_BYTES, ROW_BYTES_V1 = 12, 8  # count, residual (and scale)
DRIVER = Path(__file__).with_name("_stage_times.py")

CPU: dict[str, float] = {}  # CPU seconds per timed function since the last clear


def _step(fn: Any, *args: Any) -> tuple[Any, float]:
    """``fn(*args)`` and its wall-clock seconds (the queue finished); its CPU seconds
    (this process, all threads) are added to ``CPU[fn.__name__]``."""
    from pipeline.device import cl

    start, cpu = time.perf_counter(), cpu_ms()
    out = fn(*args)
    cl.queue().finish()
    name = getattr(fn, "__name__", "call")
    CPU[name] = CPU.get(name, 0.0) + (cpu_ms() - cpu) / 1e3
    return out, time.perf_counter() - start


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
    from pipeline.device.sphwavelet_cl import forward_device
    from pipeline.math.envmap import LUMINANCE
    from pipeline.methods.triple.stages import light_rotations as light_stage
    from pipeline.methods.triple.wavelet_select_cl import select_rows_buffer

    grid = light_stage.frame_grid(params)
    level, refine = params["triple.leaf_level"], params["triple.light_refine"]
    block = params["triple.light_block"]
    times = {"coords": 0.0, "prefilter": 0.0, "leaf_means": 0.0, "forward": 0.0,
             "select": 0.0, "lookups": 0}
    parts = []
    light_stage._sample_coords.cache_clear()
    light_stage._PREFILTERED.clear()
    CPU.clear()
    total, cpu = time.perf_counter(), cpu_ms()
    for start in range(0, grid.size, block):
        end = min(start + block, grid.size)
        pm, t = _step(light_stage.prefiltered_map, rgb, params)
        times["prefilter"] += t
        _, t = _step(light_stage._sample_coords, grid, level, refine, *pm.shape[1::-1])
        times["coords"] += t
        means, t = _step(light_stage.leaf_means_buffer, pm, grid, start, end, level, refine)
        times["leaf_means"] += t
        times["lookups"] += bilinear_lookups(grid, start, end, 20 * 4 ** level, 4 ** refine)
        coefficients, t = _step(forward_device, means, (end - start) * 3, level)
        times["forward"] += t
        rows, t = _step(select_rows_buffer, coefficients, 0, end - start, 3, level,
                        params["triple.store_budget"], params["triple.store_tolerance"],
                        params["triple.store_top"], LUMINANCE, True)
        times["select"] += t
        parts.append(rows)
    times["total"] = time.perf_counter() - total
    times["total_cpu"] = (cpu_ms() - cpu) / 1e3
    times["lookups_per_s"] = times["lookups"] / times["leaf_means"]
    names = {"prefiltered_map": "prefilter", "_sample_coords": "coords",
             "leaf_means_buffer": "leaf_means", "forward_device": "forward",
             "select_rows_buffer": "select"}
    times.update({f"{step}_cpu": CPU.get(name, 0.0) for name, step in names.items()})
    rows = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return times, rows


def build_light_kernels(rgb: np.ndarray, params: dict[str, Any]) -> None:
    """Build the rotation grid's kernels (one entry), so that no timing holds a build."""
    from pipeline.methods.triple.stages import light_rotations as light_stage

    light_stage.leaf_means_buffer(light_stage.prefiltered_map(rgb, params),
                                  light_stage.frame_grid(params), 0, 1,
                                  int(params["triple.leaf_level"]),
                                  int(params["triple.light_refine"]))


def light_accuracy(rgb: np.ndarray, params: dict[str, Any], refines: list[int]) -> dict:
    """Errors of the leaf means of 6 frames (φ = 0, θ from pole to pole) per r."""
    from pipeline.math.envmap import LUMINANCE
    from pipeline.math.geodesic import geodesic_levels
    from pipeline.methods.triple.light_grid import frame_leaf_means
    from pipeline.methods.triple.stages import light_rotations as light_stage

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


def _material_ctx(scene: Any, name: str, params: dict[str, Any]) -> Any:
    from pipeline.engine.chunk import make_chunk
    from pipeline.engine.stage import ChunkContext
    from pipeline.methods.triple.stages import brdf_tables as brdf_stage

    keys = ("model", *brdf_stage.SHAPE_KEYS)
    return ChunkContext(params=params, scene={f"materials.{name}.{k}": scene.section(
        f"materials.{name}.{k}") for k in keys}, inputs={},
        chunk=make_chunk(name, "material", material=name, index=0))


def _glossy(scene: Any, name: str, ctx: Any) -> Any:
    from pipeline.methods.triple.stages import brdf_tables as brdf_stage

    return brdf_stage.glossy_params(scene.materials[name].model, {
        k: ctx.scene[f"materials.{name}.{k}"] for k in brdf_stage.SHAPE_KEYS})


def brdf_table(scene: Any, name: str, params: dict[str, Any]) -> tuple[dict[str, float], dict]:
    """One material's table through the stage's run_chunk (total), and split."""
    from pipeline.device.sphwavelet_cl import forward_device
    from pipeline.methods.triple.stages import brdf_tables as brdf_stage
    from pipeline.methods.triple.wavelet_select_cl import select_rows_buffer

    ctx = _material_ctx(scene, name, params)
    CPU.clear()
    cpu = cpu_ms()
    rows, total = _step(brdf_stage.run_chunk, ctx)
    total_cpu = (cpu_ms() - cpu) / 1e3
    level, refine = params["triple.leaf_level"], params["triple.brdf_refine"]
    material = _glossy(scene, name, ctx)
    grid = brdf_stage.view_grid(params)
    means, t_means = _step(brdf_stage.view_leaf_means_buffer, material, grid, level, refine)
    coefficients, t_forward = _step(forward_device, means, grid.size, level)
    _, t_select = _step(select_rows_buffer, coefficients, 0, grid.size, 1, level,
                        params["triple.store_budget"], params["triple.store_tolerance"],
                        params["triple.store_top"], None, True)
    return {"total": total, "total_cpu": total_cpu, "leaf_means": t_means,
            "forward": t_forward, "select": t_select,
            "leaf_means_cpu": CPU["view_leaf_means_buffer"], "forward_cpu": CPU["forward_device"],
            "select_cpu": CPU["select_rows_buffer"]}, rows


def brdf_accuracy(scene: Any, name: str, params: dict[str, Any], refines: list[int]) -> dict:
    from pipeline.math.geodesic import geodesic_levels
    from pipeline.methods.triple.brdf_tables import glossy_leaf_means
    from pipeline.methods.triple.stages import brdf_tables as brdf_stage

    level = params["triple.leaf_level"]
    material = _glossy(scene, name, _material_ctx(scene, name, params))
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


def storage_chart(store: dict[str, Any], material: str, params: dict[str, Any],
                  path: Path) -> None:
    """Bars: MB at top-only 80 / 320 and as stored, float16 and v1's float32, against
    the paper's (lighting; the glossy material's BRDF table)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    frames, views = np.prod(params["triple.frame_grid"]), np.prod(params["triple.view_grid"])
    fig, axes = plt.subplots(1, 2, figsize=(9.0, 3.8), dpi=120)
    for ax, (title, s, paper) in zip(axes, (
            (f"lighting ({frames} frames)", store["lighting"], PAPER_MB["lighting"]),
            (f"BRDF table ({material}, {views} views)", store["brdf"][material],
             PAPER_MB["brdf"])), strict=True):
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


def compare(rev: str, scene_file: Path, rounds: int) -> dict[str, Any]:
    """benchmarks/triple/_stage_times.py in fresh processes on REV's code and on this
    checkout's, alternating ``rounds`` times: medians and before / after ratios. The
    scene: each tree's own copy of ``scene_file`` where it has one, else this one."""
    from pipeline.scene.model import shared_data_dir

    runs: dict[str, list[dict[str, float]]] = {"before": [], "after": []}
    scene_file = scene_file.resolve()
    inside = scene_file.relative_to(ROOT) if scene_file.is_relative_to(ROOT) else None
    data = shared_data_dir()
    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.run(["git", "archive", rev], cwd=ROOT, check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        trees = {"before": Path(tmp), "after": ROOT}
        for _ in range(rounds):
            for label, tree in trees.items():
                scene = tree / inside if inside and (tree / inside).is_file() else scene_file
                env = {**os.environ, "PYTHONPATH": str(tree)}
                if data is not None:
                    env["PRT_DATA"] = str(data)  # REV's tree is elsewhere
                out = subprocess.run([sys.executable, str(DRIVER), str(scene)], cwd=tree,
                                     env=env, check=True, capture_output=True, text=True).stdout
                runs[label].append(json.loads(out.strip().splitlines()[-1]))
                print(f"compare {label}: {runs[label][-1]}")
    before, after = medians(runs["before"]), medians(runs["after"])
    return {"rev_before": rev, "rounds": rounds, "scene": str(scene_file),
            "before": before, "after": after,
            "ratio_before_over_after": {k: before[k] / after[k] for k in before
                                        if k.endswith("_s")}}


def light_only(rgb: np.ndarray, scene: Any, material: str, params: dict[str, Any],
               repeats: int) -> dict[str, Any]:
    """``--light-only``: the rotation-grid rebuild and one BRDF table at the stages'
    defaults, on ``cl.device()`` (PRT_CL_DEVICE: a GPU run), no accuracy references."""
    from pipeline.device import cl

    result: dict[str, Any] = {"mode": "light-only", "device": cl.device().name,
                              "cpu_count": os.cpu_count(), "load_average_at_start": load()}
    build_light_kernels(rgb, params)
    result["light"] = medians([light_rebuild(rgb, params)[0] for _ in range(repeats)])
    print(f"light rebuild: {result['light']}", flush=True)
    brdf_table(scene, material, params)  # build the kernels
    result["brdf_table"] = medians([brdf_table(scene, material, params)[0]
                                    for _ in range(repeats + 2)])
    print(f"brdf table: {result['brdf_table']}", flush=True)
    result["load_average_at_end"] = load()
    return result


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME} --",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--scene", type=Path, default=SCENES / "bunny_grace.yaml")
    parser.add_argument("--material", default="bunny",
                        help="the glossy material whose BRDF table is timed")
    parser.add_argument("--quick", action="store_true", help="1 repeat, r = 0 and 1 only")
    parser.add_argument("--defaults", action="store_true",
                        help="the stages' default refinements only")
    parser.add_argument("--light-only", action="store_true",
                        help="the rebuilds alone at the defaults (a GPU run)")
    parser.add_argument("--compare", metavar="REV", default=None,
                        help="time the stages on REV's code and this checkout's, into the "
                             "result at --out")
    parser.add_argument("--rounds", type=int, default=3,
                        help="--compare: fresh processes per code version")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    repeats = 1 if args.quick else 3

    from pipeline import job
    from pipeline.engine.planning import stage_params
    from pipeline.images import read_environment

    if args.compare:
        path = result_path(NAME, args.out)
        result = json.loads(path.read_text()) if path.is_file() else {}
        for key in ("benchmark", "machine", "finished"):
            result.pop(key, None)
        result["compare"] = compare(args.compare, args.scene, args.rounds)
        result["compare"]["load_average_at_end"] = load()
        print(json.dumps(result["compare"], indent=1))
        return write_result(NAME, result, args.out)

    scene = job.open_scene(args.scene)
    params = stage_params(job.stages(), scene)
    rgb = read_environment(scene.environment_file())
    rgb.setflags(write=False)  # as the runner's chunks get it: prefiltered once
    if args.light_only:
        return write_result(NAME, light_only(rgb, scene, args.material, params, repeats),
                            args.out)
    refines = [0, 1] if args.quick else [0, 1, 2]
    light_refines = brdf_refines = refines
    if args.defaults:  # the stages' default refinements only
        light_refines = [int(params["triple.light_refine"])]
        brdf_refines = [int(params["triple.brdf_refine"])]
    result: dict[str, Any] = {
        "scene": str(args.scene), "load_average_at_start": load(),
        "settings": {k: v for k, v in params.items() if k.startswith("triple.")},
        "targets": {"light_rebuild_s": 2.0, "brdf_table_s": 0.5, "paper_MB": PAPER_MB},
        "light": {}, "brdf": {}}
    result["light_accuracy"] = light_accuracy(rgb, params, light_refines)
    light_rows = None
    for refine in light_refines:
        p = {**params, "triple.light_refine": refine}
        build_light_kernels(rgb, p)
        runs = []
        for _ in range(repeats):
            times, rows = light_rebuild(rgb, p)
            runs.append(times)
        result["light"][str(refine)] = {"seconds_median": medians(runs), "runs": len(runs)}
        if refine == params["triple.light_refine"]:
            light_rows = rows
        print(f"light rebuild r={refine}: {result['light'][str(refine)]}")
    if light_rows is None:  # the default refinement was not swept (--quick): its rows
        _, light_rows = light_rebuild(rgb, params)
    for refine in brdf_refines:
        p = {**params, "triple.brdf_refine": refine}
        brdf_table(scene, args.material, p)  # build the kernels
        runs = [brdf_table(scene, args.material, p) for _ in range(repeats + 2)]
        result["brdf"][str(refine)] = {"seconds_median": medians([r[0] for r in runs]),
                                       "runs": len(runs)}
        print(f"brdf table r={refine}: {result['brdf'][str(refine)]}")
    result["brdf_accuracy"] = brdf_accuracy(scene, args.material, params, brdf_refines)
    result["storage"] = {"lighting": storage(light_rows, "lighting"),
                         "brdf": {name: storage(brdf_table(scene, name, params)[1], "brdf")
                                  for name in scene.materials},
                         "paper_MB": PAPER_MB}
    print(json.dumps(result["storage"], indent=1))
    target = result_path(NAME, args.out)
    target.parent.mkdir(parents=True, exist_ok=True)
    storage_chart(result["storage"], args.material, params,
                  target.with_name(f"{target.stem}_storage.png"))
    result["load_average_at_end"] = load()
    return write_result(NAME, result, args.out)

"""Benchmark: the fit of method sg on real transport lobes — the fast path (each function
on its support cap, pipeline/methods/sg/support.py) against the whole-grid batched fit of
the second session and the paper-faithful trf path (pipeline/methods/sg/fit.py), same
functions, same start rule; and the stage's per-vertex cost (pipeline/methods/sg/stages/fit.py:
N chosen from the tolerance, alignment, coupled refit, view filling).

Run from the project root:
    python benchmarks/sg_fit_stage.py [--vertices 12] [--trf 24] [--grid 55 110]
Writes benchmarks/results/sg_fit_stage.json.

Data: scenes/bunny_sg.yaml baked to sg.diffuse in ``--workdir`` (benchmarks/sg_bunny.py);
``--vertices`` bunny vertices from a breadth-first walk; their glossy transport, direct
+ indirect, by the stage's own function, for the 92 views on the lat-long grid
``--grid``; the functions with data (views above the horizon, T ≠ 0) are fitted
after dividing by their norm (as the stage does). Reported per path and N = 1, 2, 3:
milliseconds per function (median of 3 repeats of the whole set; trf: on the first
``--trf`` functions, one repeat), the relative L² error on the whole grid (median,
90th percentile, max) and the error ratio of each path to the whole-grid fit on the
same functions; then the stage's fit_group per vertex (median over groups) and its
extrapolation to the bunny's vertex count. os.getloadavg() with every timing; one BLAS
thread (a bake runs one chunk per core). The machine is shared: quote ratios taken in
one run, re-run on a quiet machine for absolute times.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from sg_bunny import bunny_patch  # noqa: E402

from pipeline.executors import one_blas_thread  # noqa: E402
from pipeline.methods.sg import coherence as sg_coherence  # noqa: E402
from pipeline.methods.sg import fit as sg_fit  # noqa: E402
from pipeline.methods.sg import support as sg_support  # noqa: E402
from pipeline.methods.sg.stages import fit as stage  # noqa: E402
from pipeline.methods.sg.transport import view_directions  # noqa: E402


def timed(fn, repeats: int):
    """(result, median seconds, load averages) of ``repeats`` calls."""
    seconds, loads, out = [], [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        seconds.append(time.perf_counter() - t)
        loads.append(os.getloadavg()[0])
    return out, statistics.median(seconds), loads


def error_summary(err: np.ndarray) -> dict:
    return {"median": float(np.median(err)), "p90": float(np.percentile(err, 90)),
            "max": float(err.max())}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--vertices", type=int, default=12)
    ap.add_argument("--trf", type=int, default=24)
    ap.add_argument("--grid", type=int, nargs=2, default=[55, 110])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--workdir", default=str(ROOT / ".prt" / "bench_sg_fit"))
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/sg_fit_stage.json"))
    args = ap.parse_args()
    one_blas_thread()
    patch = bunny_patch(Path(args.workdir), args.vertices, {"sg.fit_grid": args.grid})
    directions, omega, normals = patch.directions, patch.omega, patch.normals
    vertex_count = patch.bunny_vertices
    views = view_directions()
    t_start = time.perf_counter()
    t = patch.transport(np.arange(args.vertices))
    transport_s = time.perf_counter() - t_start
    strength = np.einsum("gvsc,s->gv", t.astype(np.float64) ** 2, omega)
    g_idx, v_idx = np.nonzero(strength > 0)
    values = t[g_idx, v_idx].astype(np.float64) / np.sqrt(strength[g_idx, v_idx])[:, None, None]
    values32 = values.astype(np.float32)   # as the stage holds them
    f = len(values)
    report = {"scene": "scenes/bunny_sg.yaml, direct + indirect glossy (the stage's)",
              "grid": args.grid, "directions": len(directions), "vertices": args.vertices,
              "functions": f, "transport_seconds": transport_s,
              "transport_load": os.getloadavg()[0], "paths": {}}
    print(f"{f} functions from {args.vertices} vertices; transport {transport_s:.2f} s")
    for n in (1, 2, 3):
        base = sg_fit.FitOptions(lobes=n)
        fast = sg_fit.FitOptions(lobes=n, fields=stage.FIELDS_DTYPE, tolerance=stage.STOP)
        runs = {
            "whole_grid": lambda o=base: sg_fit.fit(directions, omega, values, o),
            "support": lambda o=base: sg_support.fit(directions, omega, values32, o)[0],
            "support_fast": lambda o=fast: sg_support.fit(directions, omega, values32, o)[0],
        }
        row = {}
        errors = {}
        for name, fn in runs.items():
            result, seconds, loads = timed(fn, args.repeats)
            err = sg_support.relative_error(directions, omega, values, result)
            errors[name] = err
            row[name] = {"ms_per_function": 1e3 * seconds / f, "load": loads,
                         "error": error_summary(err),
                         "iterations_median": float(np.median(result.iterations)),
                         "not_converged": int((~result.converged).sum())}
        m = min(args.trf, f)
        sub = np.linspace(0, f - 1, m).astype(np.int64)
        result, seconds, loads = timed(
            lambda sub=sub, base=base: sg_fit.fit_trf(directions, omega, values[sub], base), 1)
        err = sg_support.relative_error(directions, omega, values[sub], result)
        errors["trf"] = err
        row["trf"] = {"ms_per_function": 1e3 * seconds / m, "load": loads, "functions": m,
                      "error": error_summary(err)}
        for name in ("support", "support_fast"):
            ratio = errors[name] / errors["whole_grid"]
            row[name]["error_ratio_to_whole_grid"] = error_summary(ratio)
            row[name]["speedup_over_whole_grid"] = (row["whole_grid"]["ms_per_function"]
                                                    / row[name]["ms_per_function"])
            row[name]["speedup_over_trf"] = (row["trf"]["ms_per_function"]
                                             / row[name]["ms_per_function"])
        ratio = errors["whole_grid"][sub] / errors["trf"]
        row["whole_grid"]["error_ratio_to_trf_on_subset"] = error_summary(ratio)
        row["support"]["error_ratio_to_trf_on_subset"] = error_summary(
            errors["support"][sub] / errors["trf"])
        for name in row:  # one fit of every function of 1,000 vertices at this N
            row[name]["seconds_per_1000_vertices"] = (row[name]["ms_per_function"] * f
                                                      / args.vertices)
        report["paths"][f"N={n}"] = row
        print(f"N={n}: " + ", ".join(f"{k} {v['ms_per_function']:.2f} ms "
                                     f"err {v['error']['median']:.4f}"
                                     for k, v in row.items()), os.getloadavg()[0])
    # the stage's fit of whole vertices (N from the tolerance, alignment, coupled refit)
    cfg = stage.settings({"sg.fit_tolerance": 0.1, "sg.fit_max_lobes": 3,
                          "sg.fit_mean_weight": 0.01, "sg.fit_sigma_weight": 0.01,
                          "sg.fit_spatial_weight": 0.1, "sg.fit_relaxation_sweeps": 4,
                          "sg.fit_match_integral": True})
    lobes = stage.Lobes(args.vertices, len(views), stage.mirror(views, normals))
    view_nbs = sg_coherence.view_neighbours(views)
    nbs = [np.array([], np.int64)] * args.vertices
    done = np.zeros(args.vertices, bool)
    per_vertex, loads = [], []
    for g0 in range(0, args.vertices, stage.GROUP):
        group = np.arange(g0, min(g0 + stage.GROUP, args.vertices))
        start = time.perf_counter()
        stage.fit_group(lobes, group, t[group], views, view_nbs, nbs, done, directions,
                        omega, cfg)
        per_vertex.append((time.perf_counter() - start) / len(group))
        loads.append(os.getloadavg()[0])
    seconds = statistics.median(per_vertex)
    report["stage_fit"] = {
        "seconds_per_vertex_median": seconds, "load": loads,
        "counts": np.bincount(lobes.count, minlength=4).tolist(),
        "error_median": float(np.median(lobes.error[lobes.error >= 0])),
        "bunny_vertices": vertex_count,
        "whole_bunny_fit_minutes_one_core": seconds * vertex_count / 60,
        "transport_seconds_per_vertex": transport_s / args.vertices}
    print(json.dumps(report["stage_fit"]))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()

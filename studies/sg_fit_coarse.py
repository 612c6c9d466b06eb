"""Benchmark: SG fits on a coarser grid first, then on the full grid from the coarse
lobes (pipeline/methods/sg/fit.py ``fit(..., start=)``), against the direct full-grid fit;
with ``--float32``, instead the direct fit with float32 fields (FitOptions.fields,
stopping tolerance ``--float32-tolerance``) against float64.

Run from the project root:  python studies/sg_fit_coarse.py [--count F] [--repeats R]
[--lobes N ...] [--float32 [--float32-tolerance T]]
Writes benchmarks/results/sg_fit_coarse.json (--float32: sg_fit_float32.json; with
another tolerance: sg_fit_float32_tolerance.json).

Data: studies/sg_fit_speed.py's synthetic transport-like functions (N true lobes of
σ 8–20°, cut by a visibility edge, 1 % noise) on its 55 × 110 lat-long grid (6050
directions). The coarse grid is 28 × 55: the fine grid's even rows, each coarse texel
the mean of two fine columns (same centres: rows π i/27, columns (j + ½)/55), 1540
directions. For N = 1, 2, 3: time of the direct fit, of the coarse fit, and of the fine
fit started from it (medians over repeats, one BLAS thread), the energy of the
coarse-to-fine result over the direct one per function (the fine-grid energy both
minimise), and the LM iterations each path took. os.getloadavg() with every timing:
the machine is shared, re-run on a quiet one for figures to quote.
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

from pipeline.device.threads import one_blas_thread
from pipeline.math import sg
from pipeline.methods.sg import fit as sg_fit

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
from sg_fit_speed import functions  # noqa: E402


def coarse(values: np.ndarray) -> np.ndarray:
    """(F, 55·110, 3) fine values → (F, 28·55, 3): even rows, column pairs averaged."""
    f = values.reshape(len(values), 55, 110, -1)[:, ::2]
    return (0.5 * (f[:, :, 0::2] + f[:, :, 1::2])).reshape(len(values), 28 * 55, -1)


def timed(fn, *args, **kwargs):
    load = [round(x, 2) for x in os.getloadavg()]
    start = time.perf_counter()
    result = fn(*args, **kwargs)
    return time.perf_counter() - start, result, load


def run(lobes: int, count: int, repeats: int) -> dict:
    fine_d, fine_w = (a.reshape(-1, *a.shape[2:]) for a in sg.latlong_directions(55, 110))
    coarse_d, coarse_w = (a.reshape(-1, *a.shape[2:]) for a in sg.latlong_directions(28, 55))
    values = functions(fine_d, count, lobes, seed=lobes)
    small = coarse(values)
    options = sg_fit.FitOptions(lobes=lobes, batch=92)
    direct, first, second = [], [], []
    for _ in range(repeats):
        direct.append(timed(sg_fit.fit, fine_d, fine_w, values, options))
        first.append(timed(sg_fit.fit, coarse_d, coarse_w, small, options))
        second.append(timed(sg_fit.fit, fine_d, fine_w, values, options,
                             start=first[-1][1]))
    ratio = second[0][1].energy / np.maximum(direct[0][1].energy, 1e-300)
    t_direct = statistics.median(t[0] for t in direct)
    t_two = statistics.median(a[0] + b[0] for a, b in zip(first, second, strict=True))
    return {
        "lobes": lobes, "functions": count,
        "direct_seconds": [t[0] for t in direct], "direct_load": [t[2] for t in direct],
        "coarse_seconds": [t[0] for t in first], "coarse_load": [t[2] for t in first],
        "fine_from_coarse_seconds": [t[0] for t in second],
        "fine_from_coarse_load": [t[2] for t in second],
        "speedup_median": t_direct / t_two,
        "direct_s_per_1000_vertices": 1000 * 92 * t_direct / count,
        "coarse_to_fine_s_per_1000_vertices": 1000 * 92 * t_two / count,
        "iterations_direct_median": float(np.median(direct[0][1].iterations)),
        "iterations_coarse_median": float(np.median(first[0][1].iterations)),
        "iterations_fine_from_coarse_median": float(np.median(second[0][1].iterations)),
        "energy_ratio_quantiles_0_50_90_100": np.quantile(ratio, [0, .5, .9, 1]).tolist(),
        "worse_by_more_than_1_percent": int((ratio > 1.01).sum()),
        "converged_direct": int(direct[0][1].converged.sum()),
        "converged_coarse_to_fine": int(second[0][1].converged.sum()),
    }


def run_float32(lobes: int, count: int, repeats: int, tolerance: float = 1e-6) -> dict:
    fine_d, fine_w = (a.reshape(-1, *a.shape[2:]) for a in sg.latlong_directions(55, 110))
    values = functions(fine_d, count, lobes, seed=lobes)
    double = sg_fit.FitOptions(lobes=lobes, batch=92)
    single = sg_fit.FitOptions(lobes=lobes, batch=92, fields="float32", tolerance=tolerance)
    a, b = [], []
    for _ in range(repeats):
        a.append(timed(sg_fit.fit, fine_d, fine_w, values, double))
        b.append(timed(sg_fit.fit, fine_d, fine_w, values, single))
    ratio = b[0][1].energy / np.maximum(a[0][1].energy, 1e-300)
    cos = np.clip(np.sum(a[0][1].mean * b[0][1].mean, axis=-1), -1, 1)
    return {
        "lobes": lobes, "functions": count, "float32_tolerance": tolerance,
        "float64_seconds": [t[0] for t in a], "float64_load": [t[2] for t in a],
        "float32_seconds": [t[0] for t in b], "float32_load": [t[2] for t in b],
        "speedup_median": statistics.median(t[0] for t in a)
        / statistics.median(t[0] for t in b),
        "iterations_float64_median": float(np.median(a[0][1].iterations)),
        "iterations_float32_median": float(np.median(b[0][1].iterations)),
        "energy_ratio_quantiles_0_50_90_100": np.quantile(ratio, [0, .5, .9, 1]).tolist(),
        "mean_angle_deg_max": float(np.degrees(np.arccos(cos)).max()),
        "converged_float64": int(a[0][1].converged.sum()),
        "converged_float32": int(b[0][1].converged.sum()),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=184)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--lobes", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--float32", action="store_true")
    parser.add_argument("--float32-tolerance", type=float, default=1e-6,
                        help="FitOptions.tolerance of the float32 fits (float64: 1e-6)")
    args = parser.parse_args()
    one_blas_thread()
    runs = []
    for lobes in args.lobes:
        runs.append(run_float32(lobes, args.count, args.repeats, args.float32_tolerance)
                    if args.float32 else run(lobes, args.count, args.repeats))
        print(json.dumps({k: v for k, v in runs[-1].items() if not k.endswith(("seconds",
                                                                             "load"))}),
              flush=True)
    name = ("sg_fit_coarse" if not args.float32 else "sg_fit_float32"
            if args.float32_tolerance == 1e-6 else "sg_fit_float32_tolerance")
    out = ROOT / "benchmarks" / "results" / f"{name}.json"
    out.write_text(json.dumps({"benchmark": name, "cores": os.cpu_count(),
                               "runs": runs}, indent=1) + "\n")
    print(out)


if __name__ == "__main__":
    main()

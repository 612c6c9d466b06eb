"""Benchmark: PCA basis construction per material and c(γ) evaluation (paper 000 §4).

Run from the project root:  python studies/bench_brdf_basis.py
Writes benchmarks/results/brdf_timing.json. Settings are the stage defaults of
stages.yaml; medians over repeats (these machines are noisy). Targets (issue 4): basis
construction under 1 s per material, c(γ) under 1 ms.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from pipeline import job  # noqa: E402
from pipeline.math.brdf import BrdfParams
from pipeline.methods.d2i.brdf_pca import PAPER_GAMMA_RANGES, build_basis

ROOT = Path(__file__).resolve().parent.parent
PARAMS = job.stages().params  # the project's stages and every method's
RANGES = PAPER_GAMMA_RANGES
BUILD_REPEATS = 7
EVAL_CALLS = 2000


def main() -> None:
    results = {}
    for model, (lo, hi) in RANGES.items():
        params = BrdfParams(model, (0, 0, 0), gamma=lo, alpha_ratio=4.0)
        build = []
        for _ in range(BUILD_REPEATS):
            t = time.perf_counter()
            basis = build_basis(params, (lo, hi), PARAMS["brdf_basis.tolerance"],
                                PARAMS["brdf_basis.max_k"], PARAMS["brdf_basis.gamma_samples"],
                                PARAMS["brdf_basis.coordinate_samples"])
            build.append(time.perf_counter() - t)
        gammas = np.random.default_rng(0).uniform(lo, hi, EVAL_CALLS)
        calls = []
        for g in gammas:
            t = time.perf_counter()
            basis.coefficients(float(g))
            calls.append(time.perf_counter() - t)
        results[model] = {"k": basis.k, "build_s_median": statistics.median(build),
                          "build_s_max": max(build),
                          "coefficients_us_median": statistics.median(calls) * 1e6,
                          "coefficients_us_p99": float(np.percentile(calls, 99)) * 1e6}
        print(f"{model:18s} k={basis.k:2d} build {results[model]['build_s_median'] * 1e3:6.1f} "
              f"ms  c(γ) {results[model]['coefficients_us_median']:5.1f} µs")
    out = {"machine": {"cpu_count": os.cpu_count(), "processor": platform.processor(),
                       "python": platform.python_version()},
           "settings": {k: v for k, v in PARAMS.items() if k.startswith("brdf_basis.")},
           "targets": {"build_s": 1.0, "coefficients_us": 1000.0},
           "models": results}
    path = ROOT / "benchmarks" / "results" / "brdf_timing.json"
    path.write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()

"""Benchmark: batched Levenberg–Marquardt SG fits against scipy's trust-region-reflective
path on the same energy (pipeline/methods/sg/fit.py; groundwork of issue 17).

Run from the project root:  python studies/sg_fit_speed.py [--quick | --small]
Writes benchmarks/results/sg_fit_speed.json (--small: 184 functions, subset 5; for a
busy machine).

Data: synthetic transport-like functions on a 55 × 110 lat-long grid (6050 directions,
the size of the paper's 6 × 32² cubemaps): N true lobes (σ 8–20°, ≥ 50° apart, RGB
weights 0.5–2) cut by a random occluding half-space (a visibility edge) plus noise of
1 % of the largest weight — the model cannot fit them exactly. For N = 1, 2, 3: the
batched fit of F functions (460 = 5 vertices × 92 views; --quick: 92) and the trf fit
of a subset (10; --quick: 3), both single-threaded BLAS (a bake runs one per core).
Reported: functions per second (batched: median over repeats of the whole batch; trf:
median per function), their ratio, the extrapolated time of 1,000 vertices × 92 views,
and the energy of the batched fit relative to trf's on the shared subset (both from the
same moment-based start). os.getloadavg() is recorded with every timing: the machine is
shared; re-run on a quiet one for figures to quote.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from pipeline.device.threads import one_blas_thread
from pipeline.math import sg
from pipeline.methods.sg import fit as sg_fit

ROOT = Path(__file__).resolve().parent.parent
QUICK = "--quick" in sys.argv
SMALL = "--small" in sys.argv
BATCH = 92 if QUICK else 184 if SMALL else 460
SUBSET = 3 if QUICK else 5 if SMALL else 10
REPEATS = 1 if QUICK else 3
VIEWS = 92


def grid() -> tuple[np.ndarray, np.ndarray]:
    d, omega = sg.latlong_directions(55, 110)
    return d.reshape(-1, 3), omega.ravel()


def functions(directions: np.ndarray, count: int, lobes: int, seed: int) -> np.ndarray:
    """``count`` occluded, noisy sums of ``lobes`` lobes (module docstring): (F, S, 3)."""
    rng = np.random.default_rng(seed)
    out = np.empty((count, len(directions), 3))
    for i in range(count):
        while True:
            m = rng.normal(size=(lobes, 3))
            m /= np.linalg.norm(m, axis=1, keepdims=True)
            if lobes == 1 or (m @ m.T - 2 * np.eye(lobes)).max() < np.cos(np.radians(50)):
                break
        lam = sg.sharpness(np.radians(rng.uniform(8, 20, lobes)))
        w = rng.uniform(0.5, 2, (lobes, 3))
        out[i] = sg.evaluate(directions[None], m[:, None], lam[:, None]).T @ w
        plane = m[0] + rng.normal(size=3) * 0.8
        out[i, directions @ plane < 0.2 * np.linalg.norm(plane)] = 0.0
    return out + rng.normal(size=out.shape) * 0.02


def timed(call):
    load = os.getloadavg()
    start = time.perf_counter()
    result = call()
    return time.perf_counter() - start, result, load


def run(lobes: int, directions: np.ndarray, omega: np.ndarray) -> dict:
    values = functions(directions, BATCH, lobes, seed=lobes)
    options = sg_fit.FitOptions(lobes=lobes, batch=92)
    batched = [timed(lambda: sg_fit.fit(directions, omega, values, options))
               for _ in range(REPEATS)]
    lm = batched[0][1]
    per_trf = [timed(lambda i=i: sg_fit.fit_trf(directions, omega, values[i:i + 1], options))
               for i in range(SUBSET)]
    trf_energy = np.concatenate([t[1].energy for t in per_trf])
    lm_fps = BATCH / statistics.median(t[0] for t in batched)
    trf_fps = 1.0 / statistics.median(t[0] for t in per_trf)
    return {
        "lobes": lobes,
        "functions_batched": BATCH,
        "functions_trf": SUBSET,
        "batched_seconds": [t[0] for t in batched],
        "batched_load": [t[2] for t in batched],
        "trf_seconds": [t[0] for t in per_trf],
        "trf_load": [t[2] for t in per_trf],
        "batched_functions_per_s": lm_fps,
        "trf_functions_per_s": trf_fps,
        "speedup": lm_fps / trf_fps,
        "batched_s_per_1000_vertices": 1000 * VIEWS / lm_fps,
        "trf_s_per_1000_vertices": 1000 * VIEWS / trf_fps,
        "batched_converged": int(lm.converged.sum()),
        "batched_iterations_median": float(np.median(lm.iterations)),
        "trf_evaluations_median": float(np.median([t[1].iterations[0] for t in per_trf])),
        "energy_batched_over_trf": (lm.energy[:SUBSET] / trf_energy).tolist(),
    }


def main() -> None:
    one_blas_thread()
    directions, omega = grid()
    results = {
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                    "numpy": np.__version__},
        "grid_directions": len(directions),
        "quick": QUICK,
        "small": SMALL,
        "runs": [run(lobes, directions, omega) for lobes in (1, 2, 3)],
    }
    out = ROOT / "benchmarks" / "results" / "sg_fit_speed.json"
    out.write_text(json.dumps(results, indent=1))
    for r in results["runs"]:
        print(f"N={r['lobes']}: batched {r['batched_functions_per_s']:.1f}/s, "
              f"trf {r['trf_functions_per_s']:.2f}/s, ×{r['speedup']:.0f}; "
              f"1000 vertices: {r['batched_s_per_1000_vertices']:.0f} s batched, "
              f"{r['trf_s_per_1000_vertices']:.0f} s trf; energy ratio "
              f"{min(r['energy_batched_over_trf']):.6f}–{max(r['energy_batched_over_trf']):.6f}")
    print(out)


if __name__ == "__main__":
    main()

"""Benchmark: the kernels inside one BRDF table of method triple (issue 16), apart.

Run from the project root:
  python studies/bench_triple_kernels.py [--compare REV]
On the bunny's material of scenes/bunny_grace.yaml (Blinn-Phong, γ 60) at the stage
defaults (leaf level 4, view grid 128 × 64, r = 1), medians of 3 after a warm-up (kernel
builds), wall-clock and this process's CPU seconds (all threads), with the load average:

* ``leaf_means``: the leaf-means kernel on a quarter of the views (φ_o ∈ [0, π/2]:
  2112 views; ``brdf_tables.kernel_leaf_means``, download included);
* ``forward``: the forward wavelet transform of the 8192 views' leaf means on the device;
* ``select``: the stored-row selection of those 8192 rows (1280 / 1 % / head 320).

Only APIs that older checkouts share are used, so ``--compare REV`` runs this file in
fresh processes with PYTHONPATH at REV's code (``git archive``) and at this checkout's,
alternating ROUNDS times: medians and before / after ratios from one run, written to
benchmarks/results/triple_kernels.json. Without it, one process's times are printed.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
ROUNDS = 3


def _time(fn: Any) -> dict[str, float]:
    from pipeline.device import cl

    fn()  # warm-up: kernel builds
    runs = []
    for _ in range(3):
        cl.queue().finish()
        wall, cpu = time.perf_counter(), time.process_time()
        fn()
        cl.queue().finish()
        runs.append((time.perf_counter() - wall, time.process_time() - cpu))
    return {"wall_s": statistics.median(r[0] for r in runs),
            "cpu_s": statistics.median(r[1] for r in runs)}


def measure() -> dict[str, Any]:
    """Times of the three kernels in this process."""
    from pipeline.device import cl
    from pipeline.device.sphwavelet_cl import forward_device
    from pipeline.methods.triple.frame_grids import ViewGrid
    from pipeline.methods.triple.stages import brdf_tables as brdf_stage
    from pipeline.methods.triple.wavelet_select_cl import select_rows_buffer

    material = brdf_stage.glossy_params("blinn_phong", {"gamma": 60})
    grid, level, refine = ViewGrid(128, 64), 4, 1
    views = brdf_stage.sampled_views(grid).reshape(grid.n_phi, grid.n_theta, 3)
    quarter = views[:grid.n_phi // 4 + 1].reshape(-1, 3)
    means = cl.read_only_buffer(brdf_stage.view_leaf_means(material, grid, level, refine))
    coefficients = forward_device(means, grid.size, level)
    out = {
        "leaf_means": _time(lambda: brdf_stage.kernel_leaf_means(material, quarter, level,
                                                                 refine)),
        "forward": _time(lambda: forward_device(means, grid.size, level)),
        "select": _time(lambda: select_rows_buffer(coefficients, 0, grid.size, 1, level,
                                                   1280, 0.01, 320)),
        "load_average": os.getloadavg()[0],
    }
    out["evaluations"] = int(len(quarter) * 20 * 4 ** (level + refine))
    return out


def compare(rev: str) -> dict[str, Any]:
    """This file in fresh processes on REV's code and this checkout's, alternating."""
    runs: dict[str, list[dict[str, Any]]] = {"before": [], "after": []}
    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.run(["git", "archive", rev], cwd=ROOT, check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        trees = {"before": Path(tmp), "after": ROOT}
        for _ in range(ROUNDS):
            for label, tree in trees.items():
                env = {**os.environ, "PYTHONPATH": str(tree)}
                out = subprocess.run([sys.executable, str(Path(__file__).resolve())],
                                     cwd=tree, env=env, check=True, capture_output=True,
                                     text=True).stdout
                runs[label].append(json.loads(out.strip().splitlines()[-1]))
                print(f"{label}: {runs[label][-1]}", flush=True)

    def median(label: str, step: str, key: str) -> float:
        return statistics.median(r[step][key] for r in runs[label])

    steps = ("leaf_means", "forward", "select")
    result: dict[str, Any] = {"rev_before": rev, "rounds": ROUNDS, "runs": runs}
    for label in runs:
        result[label] = {s: {k: median(label, s, k) for k in ("wall_s", "cpu_s")}
                         for s in steps}
    result["ratio_before_over_after"] = {
        s: {k: result["before"][s][k] / result["after"][s][k] for k in ("wall_s", "cpu_s")}
        for s in steps}
    return result


def main() -> None:
    if "--compare" in sys.argv:
        result = compare(sys.argv[sys.argv.index("--compare") + 1])
        result["load_average_at_end"] = os.getloadavg()
        path = ROOT / "benchmarks" / "results" / "triple_kernels.json"
        path.write_text(json.dumps(result, indent=1) + "\n")
        print(json.dumps(result["ratio_before_over_after"], indent=1))
        print(f"wrote {path}")
        return
    print(json.dumps(measure()))


if __name__ == "__main__":
    main()

"""Benchmark: the fit stage's batch (pipeline/stages/sg_fit.py ``fit_batch``) on a
connected patch of the coarse bunny — lobe counts from the tolerance, fit errors, flips
before and after the relaxation, and the time per vertex (transport and fit).

Run from the project root:
    python benchmarks/sg_fit_flips.py [--vertices 32] [--grid 55 110] [--tolerance 0.1]
Writes benchmarks/results/sg_fit_flips.json.

The patch: the first ``--vertices`` vertices of a breadth-first walk from vertex 0 over
the mesh of ${PRT_DATA}/meshes/bunny_6.6kf.obj (vertices merged by position): a
connected piece, as the stage's flood fill walks a batch; the scene and material are
benchmarks/sg_fit_stage.py's (Blinn–Phong γ 60, ρs 0.1, a ground plane). The stage's
default weights and sweeps.
os.getloadavg() is recorded: the machine is shared.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from sg_fit_stage import BUNNY, scene_arrays  # noqa: E402

from pipeline.executors import one_blas_thread  # noqa: E402
from pipeline.math import sg  # noqa: E402
from pipeline.stages import sg_fit as stage  # noqa: E402


def patch(count: int, faces: np.ndarray) -> np.ndarray:
    """The first ``count`` vertices of a breadth-first walk over the mesh from vertex 0."""
    _, neighbours = stage.flood_order(int(faces.max()) + 1,
                                      stage.batch_edges(faces, 0, int(faces.max()) + 1))
    seen, queue, out = {0}, [0], []
    while queue and len(out) < count:
        v = queue.pop(0)
        out.append(v)
        for u in neighbours[v]:
            if int(u) not in seen:
                seen.add(int(u))
                queue.append(int(u))
    return np.asarray(out, np.int64)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--vertices", type=int, default=32)
    ap.add_argument("--grid", type=int, nargs=2, default=[55, 110])
    ap.add_argument("--tolerance", type=float, default=0.1)
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/sg_fit_flips.json"))
    args = ap.parse_args()
    one_blas_thread()
    tracer, positions, normals, offset, vertex_count, faces = scene_arrays()
    chosen = patch(args.vertices, faces)
    local = np.full(vertex_count, -1)
    local[chosen] = np.arange(len(chosen))
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = local[e]
    edges = np.unique(np.sort(e[(e >= 0).all(axis=1)], axis=1), axis=0)
    d, omega = sg.latlong_directions(*args.grid)
    cfg = stage.settings({"sg.fit_tolerance": args.tolerance, "sg.fit_max_lobes": 3,
                          "sg.fit_mean_weight": 0.01, "sg.fit_sigma_weight": 0.01,
                          "sg.fit_spatial_weight": 0.1, "sg.fit_relaxation_sweeps": 4})
    start = time.perf_counter()
    lobes, report = stage.fit_batch(tracer, offset, positions[chosen], normals[chosen], edges,
                                    BUNNY, d.reshape(-1, 3), omega.ravel(), cfg)
    seconds = time.perf_counter() - start
    err = lobes.error[lobes.error >= 0]
    report.update(seconds_per_vertex=seconds / len(chosen), grid=args.grid,
                  tolerance=args.tolerance, load_end=os.getloadavg()[0],
                  error={"median": float(np.median(err)), "p90": float(np.percentile(err, 90)),
                         "max": float(err.max())},
                  whole_bunny_hours_one_core=seconds / len(chosen) * vertex_count / 3600)
    print(json.dumps(report))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()

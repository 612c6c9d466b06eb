"""Benchmark: the fit stage's batch (pipeline/methods/sg/stages/fit.py ``fit_batch``) on a
connected patch of bunny_sg's bunny — lobe counts from the tolerance, fit errors, flips
before and after the relaxation, and the time per vertex, transport (direct + indirect
glossy, the stage's own function) apart from the fit.

Run from the project root:
    python studies/sg_fit_flips.py [--vertices 32] [--tolerance 0.1] [--workdir W]
Writes benchmarks/results/sg_fit_flips.json.

The patch: the first ``--vertices`` vertices of a breadth-first walk from the bunny's
vertex 0 (benchmarks/sg/fit.py ``bunny_patch``; scenes/bunny_sg.yaml baked up to sg.diffuse in
``--workdir``, default .prt/bench_sg_fit), as the stage's flood fill walks a batch; the
stage's default params but ``--tolerance``. One BLAS thread (a bake runs one chunk per
core); os.getloadavg() is recorded: the machine is shared.
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

from benchmarks.sg.fit import bunny_patch  # noqa: E402
from pipeline.device.threads import one_blas_thread  # noqa: E402
from pipeline.methods.sg.stages import fit as stage  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--vertices", type=int, default=32)
    ap.add_argument("--tolerance", type=float, default=None,
                    help="sg.fit_tolerance [default: stages.yaml's]")
    ap.add_argument("--max-lobes", type=int, default=None,
                    help="sg.fit_max_lobes [default: stages.yaml's]")
    ap.add_argument("--workdir", default=str(ROOT / ".prt" / "bench_sg_fit"))
    ap.add_argument("--scene", default=str(ROOT / "scenes" / "bunny_sg.yaml"),
                    help="another sg scene (its --workdir apart), e.g. scenes/dragon_sg.yaml")
    ap.add_argument("--object", default="bunny", help="the object whose vertices to fit")
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/sg_fit_flips.json"))
    args = ap.parse_args()
    one_blas_thread()
    patch = bunny_patch(args.vertices, scene_file=Path(args.scene), obj_name=args.object,
                        workdir=Path(args.workdir))
    params = dict(patch.params)
    if args.tolerance is not None:
        params["sg.fit_tolerance"] = args.tolerance
    if args.max_lobes is not None:
        params["sg.fit_max_lobes"] = args.max_lobes
    cfg = stage.settings(params)
    transport_seconds = [0.0]

    def transport(group: np.ndarray) -> np.ndarray:
        t = time.perf_counter()
        out = patch.transport(group)
        transport_seconds[0] += time.perf_counter() - t
        return out

    load_start = os.getloadavg()[0]
    start = time.perf_counter()
    lobes, report = stage.fit_batch(transport, patch.normals, patch.edges, patch.brdf,
                                    patch.directions, patch.omega, cfg)
    seconds = time.perf_counter() - start
    err = lobes.error[lobes.error >= 0]
    per_vertex = seconds / len(patch.vertices)
    report.update(seconds_per_vertex=per_vertex,
                  transport_seconds_per_vertex=transport_seconds[0] / len(patch.vertices),
                  fit_seconds_per_vertex=(seconds - transport_seconds[0]) / len(patch.vertices),
                  grid=params["sg.fit_grid"], tolerance=cfg["tolerance"],
                  max_lobes=cfg["max_lobes"], load_start=load_start,
                  load_end=os.getloadavg()[0],
                  error={"median": float(np.median(err)), "p90": float(np.percentile(err, 90)),
                         "max": float(err.max())},
                  seconds_per_1000_vertices_one_core=1000 * per_vertex,
                  whole_bunny_minutes_one_core=per_vertex * patch.bunny_vertices / 60,
                  bunny_vertices=patch.bunny_vertices)
    print(json.dumps(report))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()

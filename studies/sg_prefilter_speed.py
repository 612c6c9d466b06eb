"""Benchmark: the SG-prefiltered environment stack (pipeline/methods/sg/prefilter.py, stage
``sg.env_prefilter`` of method sg) on real maps, against the brute-force reference.

Run from the project root:  python studies/sg_prefilter_speed.py [--repeats N]
Writes benchmarks/results/sg_prefilter_speed.json.

For grace_256x128.hdr and grace_latlong_1024x512.exr (${PRT_DATA}/envmaps): the level
ladder (sg.prefilter_levels, ratio 2^¼ to σ = 4 rad), the fast stack's time (median of
--repeats runs, one BLAS thread as a bake's worker has); and on the 256 × 128 map's every
4th row and column (32 × 64; the brute-force reference is O(texels²): hours for
1024 × 512) both paths' times and the worst difference per level relative to the
level's largest texel. Paper 003: 2 s for a
512 × 512 × 6 cube map in software (1.6 M texels; 1024 × 512 is 0.5 M).
os.getloadavg() is recorded with every timing: the machine is shared, re-run on a quiet
one for figures to quote.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from pipeline.device.threads import one_blas_thread
from pipeline.images import read_environment
from pipeline.math import sg
from pipeline.methods.sg import prefilter as sg_prefilter
from pipeline.scene.model import shared_data_dir

ROOT = Path(__file__).resolve().parent.parent
MAPS = ("grace_256x128.hdr", "grace_latlong_1024x512.exr")


def timed(fn, args: tuple, repeats: int) -> tuple[float, list[float], list[list[float]]]:
    """Median seconds of ``repeats`` calls ``fn(*args)``, each time and the load average
    with it."""
    times, loads = [], []
    for _ in range(repeats):
        start = time.perf_counter()
        fn(*args)
        times.append(time.perf_counter() - start)
        loads.append([round(x, 2) for x in os.getloadavg()])
    return statistics.median(times), times, loads


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    one_blas_thread()
    results = []
    for name in MAPS:
        rgb = read_environment(shared_data_dir() / "envmaps" / name).astype(np.float64)
        levels = sg.prefilter_levels(*rgb.shape[:2])
        median, times, loads = timed(sg_prefilter.prefilter, (rgb, levels),
                                     args.repeats)
        entry = {"map": name, "shape": list(rgb.shape[:2]), "levels": levels.count,
                 "stored_texels": int(sum(h * w for h, w in levels.shapes)),
                 "fast_seconds_median": median, "fast_seconds": times, "loadavg": loads}
        if rgb.shape[0] <= 128:
            small = rgb[::4, ::4]
            small_levels = sg.prefilter_levels(*small.shape[:2])
            fast_median, _, fast_loads = timed(
                sg_prefilter.prefilter, (small, small_levels), args.repeats)
            ref_median, _, ref_loads = timed(
                sg.prefilter_reference, (small, small_levels), 1)
            fast = sg_prefilter.prefilter(small, small_levels)
            ref = sg.prefilter_reference(small, small_levels)
            entry.update(small_shape=list(small.shape[:2]), small_fast_seconds=fast_median,
                         small_fast_loadavg=fast_loads, small_reference_seconds=ref_median,
                         small_reference_loadavg=ref_loads,
                         small_speedup=ref_median / fast_median,
                         worst_relative_difference_per_level=[
                             float(np.abs(a - b).max() / np.abs(b).max())
                             for a, b in zip(fast, ref, strict=True)])
        results.append(entry)
        print(json.dumps({k: v for k, v in entry.items()
                          if k != "worst_relative_difference_per_level"}))
    out = ROOT / "benchmarks" / "results" / "sg_prefilter_speed.json"
    out.write_text(json.dumps({"benchmark": "sg_prefilter_speed", "cpu": platform.processor()
                               or platform.machine(), "cores": os.cpu_count(),
                               "results": results}, indent=1) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()

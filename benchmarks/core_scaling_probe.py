"""Probe: do N processes at once run as fast as one? A pure-Python loop (core-bound) and a
NumPy streaming sum (memory-bound), each timed in 1, 2, 4, 8 and 16 processes started
together; prints per-process seconds (median) relative to one process. Explains a
LocalCluster's speedup on a machine whose cores are shared or hyperthreaded.

  python benchmarks/core_scaling_probe.py [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import statistics
import time

import numpy as np


def python_loop(_: int) -> float:
    start = time.perf_counter()
    total = 0
    for i in range(30_000_000):
        total += i * i % 7
    return time.perf_counter() - start


def numpy_stream(_: int) -> float:
    a = np.ones(16_000_000)  # 128 MB: past any per-core cache
    start = time.perf_counter()
    for _ in range(60):
        a.sum()
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out")
    args = parser.parse_args()
    cpus = os.cpu_count() or 1
    result = {"cpus": cpus}
    for probe in (python_loop, numpy_stream):
        one = None
        rows = {}
        for n in [n for n in (1, 2, 4, 8, 16) if n <= cpus]:
            with mp.get_context("spawn").Pool(n) as pool:
                seconds = statistics.median(pool.map(probe, range(n)))
            one = one or seconds
            rows[n] = {"s": round(seconds, 3), "slowdown": round(seconds / one, 2)}
            print(probe.__name__, n, rows[n], flush=True)
        result[probe.__name__] = rows
    if args.out:
        with open(args.out, "w") as f:
            json.dump(result, f, indent=1)


if __name__ == "__main__":
    main()

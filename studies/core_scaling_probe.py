"""Probe: do N processes at once run as fast as one? A pure-Python loop (core-bound), a
NumPy streaming sum (memory-bound) and NumPy temporaries of 1 MiB made and freed (as a
chunk's arithmetic does), the last twice: as glibc allocates by default, and with the
MALLOC_TRIM_THRESHOLD_=65536 that dask's nannies give their workers (each temporary
then mapped afresh and its pages faulted in and zeroed by the kernel; pipeline/
dask_executor.py ``heap_as_glibc_default``). Each is timed in 1, 2, 4, 8 and 16
processes started together; prints per-process seconds (median) relative to one
process. Explains a LocalCluster's speedup on a machine whose cores are shared or
hyperthreaded.

  python studies/core_scaling_probe.py [--out FILE]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import multiprocessing as mp
import os
import statistics
import time
from collections.abc import Iterator

import numpy as np

from pipeline.engine.executors.dask import MALLOC_TRIM


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


def numpy_temporaries(_: int) -> float:
    a = np.ones(1 << 17)  # 1 MiB
    start = time.perf_counter()
    for _ in range(10_000):
        (a * 2.0).sum()  # a 1 MiB temporary, filled, read, freed
    return time.perf_counter() - start


PROBES = [(python_loop, None), (numpy_stream, None), (numpy_temporaries, None),
          (numpy_temporaries, "65536")]  # (probe, MALLOC_TRIM_THRESHOLD_ of its processes)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out")
    args = parser.parse_args()
    cpus = os.cpu_count() or 1
    result = {"cpus": cpus}
    for probe, trim in PROBES:
        name = probe.__name__ + ("" if trim is None else f"_malloc_trim_{trim}")
        one = None
        rows = {}
        for n in [n for n in (1, 2, 4, 8, 16) if n <= cpus]:
            with malloc_trim(trim), mp.get_context("spawn").Pool(n) as pool:
                seconds = statistics.median(pool.map(probe, range(n)))
            one = one or seconds
            rows[n] = {"s": round(seconds, 3), "slowdown": round(seconds / one, 2)}
            print(name, n, rows[n], flush=True)
        result[name] = rows
    if args.out:
        with open(args.out, "w") as f:
            json.dump(result, f, indent=1)


@contextlib.contextmanager
def malloc_trim(value: str | None) -> Iterator[None]:
    """MALLOC_TRIM_THRESHOLD_ set to ``value`` (None: unset) for the processes started
    inside (glibc reads it when a process starts)."""
    before = os.environ.pop(MALLOC_TRIM, None)
    if value is not None:
        os.environ[MALLOC_TRIM] = value
    try:
        yield
    finally:
        os.environ.pop(MALLOC_TRIM, None)
        if before is not None:
            os.environ[MALLOC_TRIM] = before


if __name__ == "__main__":
    main()

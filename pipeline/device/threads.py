"""The threads this process's tasks may use, and the pools that honour that share:
``map_slices`` (NumPy loops, Embree ray batches), BLAS held at one thread, the OpenCL CPU
device's worker threads. The engine's executors set the share (``set_task_threads``,
``threads_per_task``); device code reads it (``task_threads``). No result depends on it.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any

# The OpenCL CPU devices' worker threads, read when OpenCL first starts in a process.
# PoCL: POCL_CPU_MAX_CU_COUNT since PoCL 4 (the old name still works there), the PoCL 3.0
# that pyopencl's wheel bundles reads only POCL_MAX_PTHREAD_COUNT; Intel's CPU runtime:
# its TBB pool's workers (measured: 1 worker, 0.9 cores busy in a kernel on 2 cores).
OPENCL_THREAD_VARIABLES = ("POCL_CPU_MAX_CU_COUNT", "POCL_MAX_PTHREAD_COUNT",
                           "CL_CONFIG_CPU_TBB_NUM_WORKERS")


def available_cpus() -> int:
    """The CPUs this process may run on: its affinity mask where the platform has one
    (a container or ``taskset`` may allow fewer than the machine has), else
    ``os.cpu_count()``; at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


# Threads a task of this process may use (None: ``available_cpus()``): set in worker
# processes by their initializer, around in-process tasks by the executors, and for the
# whole process by ``use_cores`` (the CLI). Read by ``map_slices`` and RayTracer.
_task_threads: int | None = None


def task_threads() -> int:
    """The threads a task (or a frame) of this process may use now."""
    return _task_threads or available_cpus()


@contextmanager
def threads_per_task(threads: int | None) -> Iterator[None]:
    """``task_threads()`` is ``threads`` inside the block (None: unchanged)."""
    global _task_threads
    before = _task_threads
    if threads is not None:
        _task_threads = threads
    try:
        yield
    finally:
        _task_threads = before


def cap_opencl_threads(threads: int, replace: bool = True) -> None:
    """Limit the OpenCL CPU device to ``threads`` worker threads in this process. Takes effect
    only if OpenCL has not started yet here (it reads its environment once); with
    ``replace`` False, a limit already in the environment (the user's) is kept."""
    for name in OPENCL_THREAD_VARIABLES:
        if replace or name not in os.environ:
            os.environ[name] = str(threads)


def set_task_threads(threads: int) -> None:
    """``task_threads()`` is ``threads`` for the rest of this process's life (a worker
    process; the CLI, once per command)."""
    global _task_threads
    _task_threads = threads


def one_blas_thread() -> None:
    """Limit BLAS (OpenBLAS: NumPy's, and SciPy's own when it loads) to one thread, for
    the rest of the process. Every bake and every CPU OpenCL context does this.

    Two reasons. Speed: OpenBLAS's worker threads spin for a while after each threaded
    call and take the cores from the pipeline's own workers (thread pools, PoCL, Embree);
    measured on the 400² d2i light-edit frame (medians of 25 frames, three runs each):
    156–189 ms with BLAS threads, 110–115 ms without. Determinism: a threaded BLAS
    reduces in another order, so an SVD (the brdf_basis stage) gave other bits depending
    on whether a CPU OpenCL context had been created earlier in the process; artifacts
    must be bit-identical however they are scheduled."""
    from threadpoolctl import threadpool_limits

    os.environ["OPENBLAS_NUM_THREADS"] = "1"  # BLAS loaded later (SciPy ships its own)
    threadpool_limits(limits=1, user_api="blas")  # BLAS already loaded (NumPy's)


def map_slices(fn: Callable[[slice], Any], n: int, size: int,
               threads: int | None = None) -> list[Any]:
    """``fn`` over consecutive slices of range(n), ``size`` long (the last shorter), on a
    pool of ``threads`` threads (default: ``task_threads()``, this task's share of the
    cores) for work that releases the GIL (NumPy's loops, Embree); results in slice
    order. One slice or one thread runs on the calling thread. The slices do not depend
    on the thread count, so neither do the results."""
    slices = [slice(s, min(s + size, n)) for s in range(0, n, size)]
    threads = min(threads or task_threads(), len(slices))
    if threads <= 1:
        return [fn(s) for s in slices]
    with ThreadPoolExecutor(threads) as pool:
        return list(pool.map(fn, slices))

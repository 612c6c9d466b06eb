"""Executors: run a list of independent chunk tasks, yielding results as they finish;
and ``map_slices``, the thread pool that the stages and renderers split arrays over.

Tasks are plain picklable values and the task function is a module-level function, so
the same task list runs in-process, on a local process pool, or (later) on a
dask.distributed cluster behind this same interface; artifacts come out bit-identical
whichever ran them, because each task's randomness is seeded from its own key.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import sys
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, ThreadPoolExecutor, wait
from typing import Any, Protocol


class Executor(Protocol):
    """Runs ``fn`` over ``tasks``; yields each result as soon as it is ready."""

    def map_unordered(self, fn: Callable[[Any], Any], tasks: Iterable[Any]) -> Iterator[Any]:
        ...


class InProcessExecutor:
    """One task after another in this process (the default)."""

    def map_unordered(self, fn: Callable[[Any], Any], tasks: Iterable[Any]) -> Iterator[Any]:
        for task in tasks:
            yield fn(task)


def _die_with_parent(parent: int) -> None:
    """Worker initializer: on Linux, ask the kernel to kill this worker when the run that
    started it dies (even by SIGKILL), so that no orphan keeps computing; exit at once if
    that run died while this worker was starting."""
    if sys.platform.startswith("linux"):
        import ctypes

        pr_set_pdeathsig = 1
        ctypes.CDLL(None, use_errno=True).prctl(pr_set_pdeathsig, int(signal.SIGKILL))
    if os.getppid() != parent:
        os._exit(1)


class LocalPoolExecutor:
    """``jobs`` worker processes on this machine (spawned, so no state leaks in; they die
    with the run that started them)."""

    def __init__(self, jobs: int) -> None:
        self.jobs = jobs

    def map_unordered(self, fn: Callable[[Any], Any], tasks: Iterable[Any]) -> Iterator[Any]:
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(self.jobs, mp_context=ctx,
                                 initializer=_die_with_parent,
                                 initargs=(os.getpid(),)) as pool:
            pending = {pool.submit(fn, task) for task in tasks}
            try:
                while pending:
                    done, pending = wait(pending, return_when=FIRST_COMPLETED)
                    for future in done:
                        yield future.result()
            finally:
                for future in pending:
                    future.cancel()


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
    pool of ``threads`` threads (default: one per CPU) for work that releases the GIL
    (NumPy's loops, Embree); results in slice order. One slice or one thread runs on the
    calling thread."""
    slices = [slice(s, min(s + size, n)) for s in range(0, n, size)]
    threads = min(threads or os.cpu_count() or 1, len(slices))
    if threads <= 1:
        return [fn(s) for s in slices]
    with ThreadPoolExecutor(threads) as pool:
        return list(pool.map(fn, slices))


def make_executor(jobs: int) -> Executor:
    """In-process for ``jobs`` <= 1, else a local pool of ``jobs`` processes."""
    return InProcessExecutor() if jobs <= 1 else LocalPoolExecutor(jobs)

"""Executors: run a list of independent chunk tasks, yielding results as they finish;
``map_slices``, the thread pool that the stages and renderers split arrays over; and
``Cores``, how many of the machine's cores a run uses (worker processes × threads per
task), which every one of those pools honours.

Tasks are plain picklable values and the task function is a module-level function, so
the same task list runs in-process, on a local process pool, or on a dask.distributed
cluster (pipeline/dask_executor.py) behind this same interface; artifacts come out bit-identical
whichever ran them, and however many threads each task had, because each task's
randomness is seeded from its own key and no result depends on how work is sliced.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import sys
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, ThreadPoolExecutor, wait
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Protocol

ENV_WORKERS = "PRT_JOBS"      # overrides the automatic number of worker processes
ENV_THREADS = "PRT_THREADS"   # overrides the automatic number of threads per task
THREADS_PER_WORKER = 2        # threads per task of the automatic choice above 3 cores
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


@dataclass(frozen=True)
class Cores:
    """How a run uses the cores: ``workers`` chunk tasks at once (worker processes; 1:
    in this process) × ``threads`` threads per task (``map_slices``, Embree's ray
    batches and the OpenCL CPU device within each task). BLAS runs on one thread whatever
    these are (``one_blas_thread``). Results do not depend on either number."""

    workers: int
    threads: int

    def __post_init__(self) -> None:
        if self.workers < 1 or self.threads < 1:
            raise ValueError(f"Cores needs workers and threads >= 1, got {self}")

    @property
    def total(self) -> int:
        """Threads running at once when every worker is busy: workers × threads."""
        return self.workers * self.threads

    @classmethod
    def auto(cls, cpus: int | None = None) -> Cores:
        """The default for ``cpus`` cores (default: ``available_cpus()``).

        Up to 3 cores: one worker process per core, one thread each. Above: workers of
        ``THREADS_PER_WORKER`` threads, as many as the cores hold (16 cores: 8 × 2).

        Why processes before threads: a chunk task has serial parts (its Python glue, a
        kernel launch per 128-pixel batch, compression blocks of one material's few rows)
        that no thread pool shares out, and separate processes overlap them. Measured on
        the 256² default scene, 16 cores: in-process with 16 threads per task the bake
        used ≈ 2 cores on average (134 s wall, 264 s user; transfer 99 s); 8 worker
        processes took 60 s (transfer 27 s, 3.7×). Why not one thread per worker on many
        cores: stages with fewer chunks than workers (gather and truncate have one, bounce
        has 8 at 16k gathers) and the last chunks of a stage leave workers idle, and a
        worker's own threads still help there; and each worker holds its own copy of the
        scene's ray-tracing structures and gather disks and its kernel batches'
        temporaries (a few hundred MB at 16k gathers). Measured on 2 cores (see
        benchmarks/results/cores.json): 2 workers × 1 thread against 1 × 2."""
        cpus = cpus or available_cpus()
        if cpus <= 3:
            return cls(cpus, 1)
        workers = cpus // THREADS_PER_WORKER
        return cls(workers, cpus // workers)

    @classmethod
    def resolve(cls, workers: int | None = None, threads: int | None = None,
                cpus: int | None = None) -> Cores:
        """The setting from what was given: each of ``workers`` and ``threads`` from the
        argument, else from ``$PRT_JOBS`` / ``$PRT_THREADS``, else chosen. With only one
        of them given, the other shares ``cpus`` (default: ``available_cpus()``) out
        (``--jobs 4`` on 16 cores: 4 × 4; ``--threads 1``: 16 × 1); with neither,
        ``Cores.auto``."""
        cpus = cpus or available_cpus()
        workers = workers or _env_count(ENV_WORKERS)
        threads = threads or _env_count(ENV_THREADS)
        if workers is None and threads is None:
            return cls.auto(cpus)
        if workers is None:
            workers = max(1, cpus // threads)
        if threads is None:
            threads = max(1, cpus // workers)
        return cls(workers, threads)

    def describe(self) -> str:
        """E.g. '2 workers × 1 thread'."""
        w, t = self.workers, self.threads
        return f"{w} worker{'s' * (w != 1)} × {t} thread{'s' * (t != 1)}"


def _env_count(name: str) -> int | None:
    """A positive integer from environment variable ``name``, None if unset or empty."""
    text = os.environ.get(name, "").strip()
    if not text:
        return None
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        from pipeline.errors import PrtError

        raise PrtError(None, f"{name}={text!r}: expected a positive integer")
    return value


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


def use_cores(cores: Cores) -> None:
    """Set this process's share for the rest of its life (the CLI, once per command):
    its thread pools use ``cores.total`` threads (tasks that run here, the frames) and,
    if fewer than the available CPUs, the OpenCL CPU device is limited to as many (unless the
    environment already limits it), when OpenCL has not started yet."""
    global _task_threads
    _task_threads = cores.total
    if cores.total < available_cpus():
        cap_opencl_threads(cores.total, replace=False)


class Executor(Protocol):
    """Runs ``fn`` over ``tasks``; yields each result as soon as it is ready."""

    def map_unordered(self, fn: Callable[[Any], Any], tasks: Iterable[Any]) -> Iterator[Any]:
        ...


class InProcessExecutor:
    """One task after another in this process, each with ``threads`` threads (None:
    this process's setting, ``task_threads()``)."""

    def __init__(self, threads: int | None = None) -> None:
        self.threads = threads

    def map_unordered(self, fn: Callable[[Any], Any], tasks: Iterable[Any]) -> Iterator[Any]:
        for task in tasks:
            with threads_per_task(self.threads):
                result = fn(task)
            yield result

    def close(self) -> None:
        """Nothing to release."""

    def __enter__(self) -> InProcessExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def search_dirs() -> tuple[list[str], list[str]]:
    """This process's kernel and schema folders (pipeline/searchpath.py), which include
    those that method plug-ins added when they were imported."""
    from pipeline.searchpath import kernel_dirs, schema_dirs

    return [str(p) for p in kernel_dirs()], [str(p) for p in schema_dirs()]


def _init_worker(parent: int, threads: int, search: tuple[list[str], list[str]]) -> None:
    """Worker initializer: die with the parent (``die_with_parent``), then
    ``prepare_worker``."""
    die_with_parent(parent)
    prepare_worker(threads, search)


def prepare_worker(threads: int, search: tuple[list[str], list[str]],
                   opencl_threads: int | None = None) -> None:
    """Make this (worker) process ready for chunk tasks: find kernels and schemas where
    the run's process does (``search``: the plug-ins' folders, which a worker would
    otherwise only learn by importing the plug-ins); ``threads`` threads per task for
    ``map_slices`` and Embree; the OpenCL CPU device limited to ``opencl_threads`` (default
    ``threads``; set before any OpenCL context exists here); BLAS and OpenMP at one
    thread."""
    from pathlib import Path

    from pipeline.searchpath import add_kernel_dir, add_schema_dir, kernel_dirs, schema_dirs

    for folders, have, add in ((search[0], kernel_dirs(), add_kernel_dir),
                               (search[1], schema_dirs(), add_schema_dir)):
        for folder in map(Path, folders):
            if folder not in have:
                add(folder)
    global _task_threads
    _task_threads = threads
    cap_opencl_threads(opencl_threads or threads)
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[name] = "1"
    one_blas_thread()


def die_with_parent(parent: int) -> None:
    """On Linux, ask the kernel to kill this worker when the run that started it dies
    (even by SIGKILL), so that no orphan keeps computing; exit at once if that run died
    while this worker was starting."""
    if sys.platform.startswith("linux"):
        import ctypes

        pr_set_pdeathsig = 1
        ctypes.CDLL(None, use_errno=True).prctl(pr_set_pdeathsig, int(signal.SIGKILL))
    if os.getppid() != parent:
        os._exit(1)


class LocalPoolExecutor:
    """``jobs`` worker processes on this machine, ``threads`` threads per task each
    (default: the available CPUs shared out between them). Workers are spawned, so no
    state leaks in, and die with the run that started them.

    Used as a context manager (``with make_executor(...) as executor``), one pool serves
    every stage of the block: workers start once per bake (≈ 0.7 s each, importing the
    stages and opening OpenCL) and keep what they built (Embree scenes, uploaded gather
    disks, kernels) from one stage to the next; without, each ``map_unordered`` starts
    and stops its own pool. A stage with a single task runs it in this process, with all
    ``jobs × threads`` threads, instead of on one worker's share."""

    def __init__(self, jobs: int, threads: int | None = None) -> None:
        self.jobs = jobs
        self.threads = threads or max(1, available_cpus() // jobs)
        self._pool: ProcessPoolExecutor | None = None
        self._entered = False

    def _new_pool(self) -> ProcessPoolExecutor:
        ctx = multiprocessing.get_context("spawn")
        return ProcessPoolExecutor(self.jobs, mp_context=ctx, initializer=_init_worker,
                                   initargs=(os.getpid(), self.threads, search_dirs()))

    def map_unordered(self, fn: Callable[[Any], Any], tasks: Iterable[Any]) -> Iterator[Any]:
        tasks = list(tasks)
        if len(tasks) <= 1:
            yield from InProcessExecutor(self.jobs * self.threads).map_unordered(fn, tasks)
            return
        if self._entered and self._pool is None:
            self._pool = self._new_pool()
        pool = self._pool or self._new_pool()
        pending = {pool.submit(fn, task) for task in tasks}
        try:
            while pending:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    yield future.result()
        finally:
            # an error, or the caller stopped early: cancel what has not started and wait
            # for what has (a chunk still running would otherwise write into the
            # artifact after the caller has dealt with the error)
            wait([future for future in pending if not future.cancel()])
            if pool is not self._pool:
                pool.shutdown()

    def close(self) -> None:
        """Stop the workers (after the tasks they are running)."""
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
            self._pool = None

    def __enter__(self) -> LocalPoolExecutor:
        self._entered = True
        return self

    def __exit__(self, *exc: object) -> None:
        self._entered = False
        self.close()


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


def make_executor(jobs: int | Cores | None = None, threads: int | None = None,
                  scheduler: str | None = None, quiet: bool = False) -> Any:
    """The executor for a ``Cores`` setting, or for ``jobs`` worker processes and
    ``threads`` per task (either None: ``Cores.resolve``): in-process for one worker,
    else a local pool; with ``scheduler`` (an address or ``local:N``), a dask cluster's
    workers (pipeline/dask_executor.py; ``jobs`` does not apply, ``threads`` is per
    chunk there; unless ``quiet``, the cluster and its dashboard are announced on
    stderr). Use it as a context manager so that a pool's workers serve every stage and
    are stopped at the end."""
    if scheduler is not None:
        from pipeline.dask_executor import DaskExecutor, announce_on_stderr

        if jobs is not None:
            from pipeline.errors import PrtError

            raise PrtError("--jobs", "does not apply with --scheduler (the cluster's "
                           "workers run the chunks; local:N sets their number)")
        return DaskExecutor(scheduler, threads, None if quiet else announce_on_stderr)
    cores = jobs if isinstance(jobs, Cores) else Cores.resolve(jobs, threads)
    if cores.workers <= 1:
        return InProcessExecutor(cores.threads)
    return LocalPoolExecutor(cores.workers, cores.threads)

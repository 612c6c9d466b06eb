"""Chunk tasks run here: in this process (:class:`InProcessExecutor`) or on a pool of
worker processes on this machine (:class:`LocalPoolExecutor`); and ``Cores``, how many
of the machine's cores a run uses (worker processes × threads per task), which every
pool honours (pipeline/device/threads.py). pipeline/engine/executors/dask.py runs the
same tasks on a dask.distributed cluster; both prepare a worker with ``prepare_worker``."""

from __future__ import annotations

import multiprocessing
import os
import signal
import sys
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from typing import Any

from pipeline.device.threads import (
    available_cpus,
    cap_opencl_threads,
    one_blas_thread,
    set_task_threads,
    threads_per_task,
)

ENV_WORKERS = "PRT_JOBS"      # overrides the automatic number of worker processes
ENV_THREADS = "PRT_THREADS"   # overrides the automatic number of threads per task
THREADS_PER_WORKER = 2        # threads per task of the automatic choice above 3 cores

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
        temporaries (a few hundred MB at 16k gathers). Measured on 2 cores
        (decision 0008): 2 workers × 1 thread against 1 × 2."""
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


def use_cores(cores: Cores) -> None:
    """Set this process's share for the rest of its life (the CLI, once per command):
    its thread pools use ``cores.total`` threads (tasks that run here, the frames) and,
    if fewer than the available CPUs, the OpenCL CPU device is limited to as many (unless the
    environment already limits it), when OpenCL has not started yet."""
    set_task_threads(cores.total)
    if cores.total < available_cpus():
        cap_opencl_threads(cores.total, replace=False)


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
    set_task_threads(threads)
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



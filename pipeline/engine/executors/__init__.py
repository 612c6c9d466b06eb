"""Executors: run a list of independent chunk tasks, yielding results as they finish —
in this process or on a local process pool (``local``), or on a dask.distributed cluster
(``dask``), all behind the one :class:`Executor` interface; ``make_executor`` picks one.

Tasks are plain picklable values and the task function is a module-level function, so
the same task list runs anywhere; artifacts come out bit-identical whichever ran them,
and however many threads each task had, because each task's randomness is seeded from
its own key and no result depends on how work is sliced (pipeline/device/threads.py).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from typing import Any, Protocol

from pipeline.engine.executors.local import Cores, InProcessExecutor, LocalPoolExecutor


class Executor(Protocol):
    """Runs ``fn`` over ``tasks``; yields each result as soon as it is ready."""

    def map_unordered(self, fn: Callable[[Any], Any], tasks: Iterable[Any]) -> Iterator[Any]:
        ...


def make_executor(jobs: int | Cores | None = None, threads: int | None = None,
                  scheduler: str | None = None, quiet: bool = False) -> Any:
    """The executor for a ``Cores`` setting, or for ``jobs`` worker processes and
    ``threads`` per task (either None: ``Cores.resolve``): in-process for one worker,
    else a local pool; with ``scheduler`` (an address or ``local:N``), a dask cluster's
    workers (pipeline/engine/executors/dask.py; ``jobs`` does not apply, ``threads`` is per
    chunk there; unless ``quiet``, the cluster and its dashboard are announced on
    stderr). Use it as a context manager so that a pool's workers serve every stage and
    are stopped at the end."""
    if scheduler is not None:
        from pipeline.engine.executors.dask import DaskExecutor, announce_on_stderr

        if jobs is not None:
            from pipeline.errors import PrtError

            raise PrtError("--jobs", "does not apply with --scheduler (the cluster's "
                           "workers run the chunks; local:N sets their number)")
        return DaskExecutor(scheduler, threads, None if quiet else announce_on_stderr)
    cores = jobs if isinstance(jobs, Cores) else Cores.resolve(jobs, threads)
    if cores.workers <= 1:
        return InProcessExecutor(cores.threads)
    return LocalPoolExecutor(cores.workers, cores.threads)

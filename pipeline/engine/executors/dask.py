"""Chunk tasks on a dask.distributed cluster: ``prt run --scheduler ADDRESS`` (a running
scheduler) or ``--scheduler local:N`` (a LocalCluster of N worker processes here).

The client (the ``prt run`` process) plans, submits one task per chunk and records
provenance; workers run :func:`pipeline.engine.runner.execute_chunk`, which reads the inputs and
writes the chunk straight into the shared work directory and then its record, as in a
local run. So:

* a worker killed in the middle of a chunk leaves that chunk unrecorded; the scheduler
  gives the task to another worker, which writes the whole chunk again (the same bytes:
  a chunk's randomness is seeded from its key);
* a client that dies leaves every recorded chunk in place; the next ``prt run`` plans
  the same keys and runs only the chunks without a record (a LocalCluster's workers die
  with it: they are its child processes and ask the kernel to be killed with it);
* the artifacts are bit-identical to an in-process bake (tests/test_dask_executor.py).

Workers must see the work directory, the scene's meshes and maps at the same absolute
paths as the client, and run the same prt installation (the chunk keys hold the client's
code version). A worker process is prepared on its first task as a local pool's is
(pipeline/engine/executors/local.py ``prepare_worker``): the client's kernel and schema folders, one
BLAS thread, the OpenCL CPU device capped to the process's share; and glibc's malloc
thresholds, which a nanny's MALLOC_TRIM_THRESHOLD_ pinned, set back
(``heap_as_glibc_default``). On a cluster of one thread per worker process (``dask
worker ADDRESS --nthreads 1``, the tested setting) each chunk gets ``threads`` threads
(default 1); several dask threads in one worker process run several chunks at once
there, each with ``threads`` threads.

**Chunks that trace on the GPU** (a stage whose ``bake.device`` resolved to ``device``,
decision 0047) need a process that owns one: on a running cluster they are submitted
with the dask resource ``GPU: 1``, so each runs on a worker started with ``--resources
GPU=1`` (one worker process per GPU), one at a time per GPU, and a cluster without such a
worker is refused before any chunk is submitted; with ``local:N`` (one machine, its GPU
held by this process) they run here, one after another (decision 0050).

dask is imported only here, and this module only for ``--scheduler``: ``prt status`` and
in-process runs never load it.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import sys
import uuid
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

from pipeline.device.threads import available_cpus, threads_per_task
from pipeline.engine.executors.local import (
    InProcessExecutor,
    die_with_parent,
    prepare_worker,
    search_dirs,
)
from pipeline.errors import PrtError

LOCAL_PREFIX = "local:"
GPU = "GPU"  # the dask worker resource of one GPU (dask worker ... --resources GPU=1)
CONNECT_TIMEOUT = "20s"  # how long to wait for a scheduler's address to answer
MALLOC_TRIM = "MALLOC_TRIM_THRESHOLD_"  # glibc's variable, which dask's nannies set
# A LocalCluster's workers without dask's periodic sampling: the 10 ms stack profiler, the
# 1 ms GIL monitor, the 20 ms event-loop tick, the system and memory monitors each take
# the GIL (and, with one core per worker, CPU) from the chunk running beside them.
# Measured on d2i.transfer at 128², 2 workers, two rounds alternating: the chunks' own
# seconds 45.3–45.6 against 49.3–50.3 with dask's defaults, the stage 25.1–25.2 s against
# 27.2–28.9 s (the local pool: 24.1–25.3 s; all of these with the nanny's malloc setting,
# before it was removed). The dashboard's profile page stays empty.
LEAN_WORKERS = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.system-monitor.gil.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.worker.memory.monitor-interval": "1s",
    # a stage's queued chunks handed out one per worker thread: the next when one ends
    "distributed.scheduler.worker-saturation": 1.0,
    # and without the nanny's MALLOC_TRIM_THRESHOLD_ (see heap_as_glibc_default)
    f"distributed.nanny.pre-spawn-environ.{MALLOC_TRIM}": None,
}

_prepared = False  # whether this worker process was prepared (run_on_worker)


def run_on_worker(fn: Callable[[Any], Any], task: Any, threads: int,
                  search: tuple[list[str], list[str]], parent: int | None) -> Any:
    """``fn(task)`` on a dask worker with ``threads`` threads, the process prepared on
    its first task (``parent``: the pid of the LocalCluster's process, which a local
    worker dies with; None on a remote cluster)."""
    global _prepared
    if not _prepared:
        from distributed import get_worker

        if parent is not None:
            die_with_parent(parent)
        heap_as_glibc_default()
        prepare_worker(threads, search, threads * get_worker().state.nthreads)
        _prepared = True
    with threads_per_task(threads):
        return fn(task)


def heap_as_glibc_default() -> bool:
    """Undo, in this worker process, the malloc setting that dask's nannies give the
    workers they start (``MALLOC_TRIM_THRESHOLD_=65536``, which dask sets so that idle
    workers hand memory back to the system); True if there was one to undo.

    With that variable set, glibc turns off its sliding mmap threshold: every block of
    128 KiB or more (a chunk's NumPy temporaries) is mapped fresh from the kernel and
    unmapped when freed, and every page of it is faulted in and zeroed again. A stage
    then runs 1.4 to 2.4 times as long (one process, with against without: d2i.transfer
    on the Cornell box at 128² 31.4 / 21.0 s, triple.visibility 49.6 / 35.6 s, sg.fit
    97.4 / 39.9 s). A LocalCluster's workers start without it (``LEAN_WORKERS``); a
    remote ``dask worker``'s nanny still sets it, so the thresholds glibc would have slid
    to are set here instead: blocks below 32 MiB from the heap, the heap's top trimmed
    past 64 MiB free (glibc's caps, DEFAULT_MMAP_THRESHOLD_MAX and twice it)."""
    if MALLOC_TRIM not in os.environ or not sys.platform.startswith("linux"):
        return False
    import ctypes

    m_trim_threshold, m_mmap_threshold = -1, -3  # malloc.h
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except AttributeError:  # a C library without mallopt
        return False
    return bool(mallopt(m_mmap_threshold, 32 << 20)) and bool(
        mallopt(m_trim_threshold, 64 << 20))


def parse_scheduler(text: str) -> tuple[str | None, int]:
    """``local:N`` -> (None, N); an address -> (address, 0); PrtError otherwise."""
    if text.startswith(LOCAL_PREFIX):
        count = text[len(LOCAL_PREFIX):]
        if not count.isdigit() or int(count) < 1:
            raise PrtError("--scheduler", f"{text!r}: expected local:N with N a positive "
                           "number of worker processes")
        return None, int(count)
    match = ADDRESS.fullmatch(text.strip())
    port = int(match["port"]) if match else 0
    if not match or not 0 < port < 65536:
        raise PrtError("--scheduler", f"{text!r}: expected [tcp://]HOST:PORT (a running dask "
                       "scheduler, e.g. tcp://10.0.0.5:8786) or local:N")
    return text.strip(), 0


ADDRESS = re.compile(r"(?:(?:tcp|tls|ws|wss|ucx)://)?(?P<host>\[[0-9a-fA-F:]+\]|[^\s:/\[\]]+)"
                     r":(?P<port>\d{1,5})")
"""A dask scheduler's address as ``Client`` takes it: an optional protocol, a host (a
name, IPv4 or bracketed IPv6) and a port."""


class DaskExecutor:
    """Chunk tasks as dask futures, results yielded as they finish (the
    pipeline/engine/executors/local.py ``Executor`` interface).

    ``scheduler``: an address, or ``local:N`` for a LocalCluster of N single-threaded
    worker processes, started at once in the background, beside the run's planning
    (each chunk then gets ``threads``, default the available CPUs / N; a stage with one
    chunk runs in this process with all of them, as the local pool does). ``announce``
    gets one line when the client connects (the cluster and its dashboard address). Use
    it as a context manager: the client, and a LocalCluster, are closed at the end."""

    def __init__(self, scheduler: str, threads: int | None = None,
                 announce: Callable[[str], None] | None = None) -> None:
        self.address, self.local_workers = parse_scheduler(scheduler)
        if self.local_workers:
            self.threads = threads or max(1, available_cpus() // self.local_workers)
        else:
            self.threads = threads or 1
        self.announce = announce
        self._client: Any = None
        self._cluster: Any = None
        self._starting: Future | None = None  # (client, cluster) of a LocalCluster
        if not self.local_workers:
            # reached now, before any stage is touched: an unreachable scheduler is one
            # error line, not a stage left half done
            self._client, self._cluster = self._connect()
        else:
            # Its start (about a second: N processes import dask) overlaps the run's
            # planning and any stage of one chunk, which run here.
            starter = ThreadPoolExecutor(1, thread_name_prefix="prt-dask-start")
            self._starting = starter.submit(self._connect)
            starter.shutdown(wait=False)

    def _connect(self) -> tuple[Any, Any]:
        """(client, LocalCluster or None): the cluster started, or the scheduler reached."""
        import dask
        from distributed import Client, LocalCluster

        if not self.local_workers:
            try:
                return Client(self.address, timeout=CONNECT_TIMEOUT), None
            except (OSError, ValueError) as exc:  # refused, timed out, a bad address
                raise PrtError("--scheduler", f"cannot reach the dask scheduler at "
                               f"{self.address}: {exc}") from None
        with dask.config.set(LEAN_WORKERS):  # the nannies hand it to the workers
            cluster = LocalCluster(n_workers=self.local_workers, threads_per_worker=1,
                                   processes=True, dashboard_address=":0",
                                   silence_logs=logging.ERROR)
        return Client(cluster), cluster

    def client(self) -> Any:
        """The dask client (a LocalCluster's start waited for on first use)."""
        if self._starting is not None:
            starting, self._starting = self._starting, None
            self._client, self._cluster = starting.result()
        if self.announce:
            announce, self.announce = self.announce, None  # once
            workers = self._client.scheduler_info().get("workers", {})
            link = self._client.dashboard_link or "none (install bokeh)"
            announce(f"dask: {self._client.scheduler.address}, {len(workers)} "
                     f"worker(s), {self.threads} thread(s) per chunk; dashboard {link}")
        return self._client

    def map_unordered(self, fn: Callable[[Any], Any], tasks: Iterable[Any]) -> Iterator[Any]:
        from distributed import as_completed, wait

        tasks = list(tasks)
        if not tasks:
            return
        on_gpu = [on_device(task) for task in tasks]
        if self.local_workers and (len(tasks) == 1 or all(on_gpu)):
            yield from InProcessExecutor(self.local_workers * self.threads).map_unordered(
                fn, tasks)
            return
        client = self.client()
        if any(on_gpu):
            offered = [w for w, info in client.scheduler_info().get("workers", {}).items()
                       if info.get("resources", {}).get(GPU, 0) >= 1]
            if not offered:
                stage = getattr(tasks[on_gpu.index(True)], "stage", "a stage")
                raise PrtError("--scheduler", f"{stage} traces its rays on the GPU "
                               f"(bake.device=device) but no worker of the dask cluster "
                               f"at {self.address} offers one: start one worker per GPU "
                               f"with --resources {GPU}=1, or bake it with --bake-device "
                               "embree")
        parent = os.getpid() if self.local_workers else None
        search = search_dirs()
        token = uuid.uuid4().hex
        futures = []
        for gpu in (False, True):
            chosen = [i for i, flag in enumerate(on_gpu) if flag == gpu]
            if chosen:
                futures += client.map(run_on_worker, [fn] * len(chosen),
                                      [tasks[i] for i in chosen], threads=self.threads,
                                      search=search, parent=parent, pure=False,
                                      key=[_key(tasks[i], i, token) for i in chosen],
                                      resources={GPU: 1} if gpu else None)
        pending = set(futures)
        try:
            for future in as_completed(futures):
                pending.discard(future)
                yield future.result()
        finally:
            if pending:  # an error, or the caller stopped early
                try:
                    running = {key for keys in client.processing().values() for key in keys}
                except Exception:  # the scheduler is gone: nothing to wait for
                    running = set()
                client.cancel([f for f in pending if f.key not in running])
                # a chunk still running would write into the artifact after the caller
                # has dealt with the error: wait for those
                wait([f for f in pending if f.key in running])

    def close(self) -> None:
        """Close the client and stop a LocalCluster's workers (once started, if no stage
        needed them)."""
        if self._starting is not None:
            starting, self._starting = self._starting, None
            with contextlib.suppress(Exception):  # a failed start left nothing to close
                self._client, self._cluster = starting.result()
        if self._client is not None:
            self._client.close()
            self._client = None
        if self._cluster is not None:
            self._cluster.close()
            self._cluster = None

    def __enter__(self) -> DaskExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def on_device(task: Any) -> bool:
    """Whether a chunk task traces its rays on the OpenCL device (its stage's
    ``bake.device`` param resolved to ``device``): it needs a process that owns a GPU."""
    return (getattr(task, "params", None) or {}).get("bake.device") == "device"


def _key(task: Any, index: int, token: str) -> tuple[str, str]:
    """A task's key: ``("STAGE-TOKEN", "CHUNK")`` for a chunk task. dask groups tasks by
    the key's first part less its token (``STAGE``, what the dashboard shows), so a
    stage's chunks form one group; a group of more than twice the cluster's threads,
    without dependencies, is queued on the scheduler and handed out as workers free up
    (``worker-saturation``), instead of being shared out among the workers in advance,
    where the worker with the slower chunks finishes last while the other waits."""
    stage, chunk = getattr(task, "stage", None), getattr(task, "chunk", None)
    if stage and chunk is not None:
        return f"{stage}-{token}", str(chunk.id)
    return f"task-{token}", str(index)


def announce_on_stderr(line: str) -> None:
    """Print ``line`` on stderr above any progress bar."""
    from tqdm import tqdm

    tqdm.write(line, file=sys.stderr)

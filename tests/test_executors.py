"""The Cores setting (workers × threads per task): its default, its overrides, and that
every pool honours it (map_slices, Embree batches, pool workers' threads, PoCL's CPU
device and BLAS in the workers)."""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest
from click.testing import CliRunner

from pipeline.device.raytrace import RayTracer
from pipeline.device.threads import (
    OPENCL_THREAD_VARIABLES,
    available_cpus,
    map_slices,
    task_threads,
    threads_per_task,
)
from pipeline.engine.executors import make_executor
from pipeline.engine.executors.local import Cores, InProcessExecutor, LocalPoolExecutor
from pipeline.errors import PrtError


@pytest.mark.parametrize("cpus, expected", [
    (1, (1, 1)), (2, (2, 1)), (3, (3, 1)), (4, (2, 2)), (6, (3, 2)), (16, (8, 2)),
    (17, (8, 2)), (64, (32, 2))])
def test_default_uses_the_cores(cpus, expected):
    cores = Cores.auto(cpus)
    assert (cores.workers, cores.threads) == expected
    assert cpus - 1 <= cores.total <= cpus


def test_resolve_explicit_then_environment_then_automatic(monkeypatch):
    monkeypatch.delenv("PRT_JOBS", raising=False)
    monkeypatch.delenv("PRT_THREADS", raising=False)
    assert Cores.resolve(cpus=16) == Cores.auto(16)
    assert Cores.resolve(4, cpus=16) == Cores(4, 4)           # threads share the cores out
    assert Cores.resolve(threads=1, cpus=16) == Cores(16, 1)  # and workers
    assert Cores.resolve(32, cpus=16) == Cores(32, 1)
    assert Cores.resolve(3, 5, cpus=16) == Cores(3, 5)
    monkeypatch.setenv("PRT_JOBS", "2")
    assert Cores.resolve(cpus=16) == Cores(2, 8)
    assert Cores.resolve(5, cpus=16) == Cores(5, 3)            # the argument wins
    monkeypatch.setenv("PRT_THREADS", "3")
    assert Cores.resolve(cpus=16) == Cores(2, 3)
    monkeypatch.setenv("PRT_JOBS", "zero")
    with pytest.raises(PrtError, match="PRT_JOBS"):
        Cores.resolve()
    with pytest.raises(ValueError):
        Cores(0, 1)


def test_make_executor_keeps_jobs_working():
    one = make_executor(1)
    assert isinstance(one, InProcessExecutor) and one.threads == available_cpus()
    two = make_executor(2, 1)
    assert isinstance(two, LocalPoolExecutor) and (two.jobs, two.threads) == (2, 1)
    assert isinstance(make_executor(Cores(1, 3)), InProcessExecutor)


def test_map_slices_and_ray_batches_take_the_tasks_share():
    callers = set()

    def record(s: slice) -> int:
        callers.add(threading.get_ident())
        return s.start

    with threads_per_task(1):
        assert task_threads() == 1
        assert map_slices(record, 100, 10) == list(range(0, 100, 10))
        assert callers == {threading.get_ident()}  # one thread: the calling one
        tracer = RayTracer(np.eye(3), np.array([[0, 1, 2]]))
        assert tracer.threads == 1
    with threads_per_task(3):
        assert tracer.threads == 3  # a cached tracer follows the task's share
    assert RayTracer(np.eye(3), np.array([[0, 1, 2]]), threads=2).threads == 2


def worker_state(_task: int) -> dict:
    """What a pool task sees of its share of the cores (module-level: picklable)."""
    import pyopencl as cl
    from threadpoolctl import threadpool_info

    cpu = [d for p in cl.get_platforms() for d in p.get_devices()
           if d.type & cl.device_type.CPU and "Portable" in d.platform.name]
    return {"pid": os.getpid(), "threads": task_threads(),
            "pocl_units": cpu[0].max_compute_units if cpu else None,
            "blas": [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"],
            "env": {k: os.environ.get(k) for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")},
            "opencl_env": {k: os.environ.get(k) for k in OPENCL_THREAD_VARIABLES}}


def test_pool_workers_get_the_per_task_share():
    """Two workers × one thread: each task's pools have one thread, PoCL's CPU device
    one compute unit and Intel's runtime one TBB worker (their variables set before
    OpenCL starts there), BLAS and OpenMP one thread. A stage of a single task runs in this
    process, with every thread of the pool (2 × 1)."""
    with LocalPoolExecutor(2, 1) as executor:
        states = list(executor.map_unordered(worker_state, range(4)))
        single = list(executor.map_unordered(worker_state, [0]))
    for state in states:
        assert state["pid"] != os.getpid()
        assert state["threads"] == 1
        assert state["pocl_units"] in (1, None)
        assert set(state["blas"]) <= {1}
        assert state["env"] == {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
        assert state["opencl_env"] == dict.fromkeys(OPENCL_THREAD_VARIABLES, "1")
    assert len({s["pid"] for s in states}) <= 2  # one pool for both calls' workers
    assert single[0]["pid"] == os.getpid() and single[0]["threads"] == 2


def test_in_process_executor_sets_threads_around_each_task():
    before = task_threads()
    seen = list(InProcessExecutor(threads=1).map_unordered(lambda _: task_threads(), [0, 1]))
    assert seen == [1, 1] and task_threads() == before


def test_cli_jobs_and_threads_options(tmp_path, monkeypatch):
    """--jobs and --threads exist on run and render, their help says what the default
    resolves to here, and a bad PRT_THREADS is an input error."""
    from pipeline.cli import cli, main

    for command in ("run", "render"):
        text = CliRunner().invoke(cli, [command, "--help"]).output
        assert "--threads" in text and "--jobs" in text
        assert f"{Cores.auto().workers} here" in " ".join(text.split())
    monkeypatch.setenv("PRT_THREADS", "-1")
    monkeypatch.setattr("sys.argv", ["prt", "run", "--until", "geometry", "--workdir",
                                     str(tmp_path / "w")])
    with pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code == 2


def kernel_folders(_task: int) -> list[str]:
    from pipeline.searchpath import kernel_dirs

    return [str(p) for p in kernel_dirs()]


def test_pool_workers_find_kernels_where_this_process_does(tmp_path, monkeypatch):
    """A folder a plug-in added (pipeline/searchpath.py) is searched in the workers too:
    they run the plug-in's stages without importing the plug-in."""
    from pipeline import searchpath

    monkeypatch.setitem(searchpath._EXTRA, "kernels", [tmp_path])
    with LocalPoolExecutor(2, 1) as executor:
        seen = list(executor.map_unordered(kernel_folders, range(2)))
    assert seen == [kernel_folders(0)] * 2 and str(tmp_path) in seen[0]

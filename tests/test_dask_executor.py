"""Chunk tasks on a dask.distributed LocalCluster (pipeline/engine/executors/dask.py): the same
bytes as an in-process bake, a worker killed mid-stage changes nothing, bad
``--scheduler`` values are refused in one line, and ``prt status`` never loads dask.
(A killed client: tests/test_crash_safety.py, ``local:2``.)"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

import pytest
from helpers import D2I_STAGES, TOY_STAGEFILE, artifact_bytes, small_scene_dict, write_scene

from pipeline import job
from pipeline.engine.executors.dask import MALLOC_TRIM, DaskExecutor, parse_scheduler
from pipeline.engine.runner import run
from pipeline.engine.stagefile import load_stagefile
from pipeline.engine.store import Workdir, read_record
from pipeline.errors import PrtError
from pipeline.scene.file import default_scene_path, load_scene


def test_default_scene_on_two_workers_is_bit_identical(tmp_path):
    """The embedded default scene (d2i), small, baked in-process and on a LocalCluster of
    2 worker processes: every artifact holds the same bytes and the same digest. Tiles
    and gather blocks small enough that the chunked stages have several chunks each."""
    scene = load_scene(default_scene_path()).with_image_size(24, 24).with_settings(
        {"gather.count": 1024, "transfer.tile": 8, "gbuffer.tile": 8, "bounce.block": 256})
    baked = {}
    for name, how in (("in_process", {"jobs": 1, "threads": 1}),
                      ("local2", {"scheduler": "local:2"})):
        workdir = job.workdir_for(scene, tmp_path / name)
        report = job.bake(scene, workdir, quiet=True, **how)
        assert len([r for r in report if r.name == "d2i.transfer"][0].ran_chunks) == 9
        baked[name] = ({s: read_record(workdir.artifact(s))["digest"] for s in D2I_STAGES},
                       artifact_bytes(workdir, D2I_STAGES))
    assert baked["in_process"] == baked["local2"]


def test_a_worker_killed_mid_stage_changes_nothing(tmp_path):
    """SIGKILL of the worker process running a tiles chunk (each sleeps 0.4 s): the
    scheduler gives its chunk to another worker (the nanny starts a new one), the bake
    completes, and every artifact equals an in-process bake's."""
    doc = small_scene_dict()
    doc["settings"] = {"toy.sleep": 0.4}
    scene = load_scene(write_scene(tmp_path, doc))
    stagefile = load_stagefile(TOY_STAGEFILE)
    reference = Workdir(tmp_path / "reference")
    run(scene, stagefile, reference, progress=False)

    workdir = Workdir(tmp_path / "killed")
    killed: list[int] = []  # the killed worker's pid
    with DaskExecutor("local:2") as executor:
        client = executor.client()
        pids = client.run(os.getpid)  # worker address -> pid

        def kill_a_tiles_worker() -> None:
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline:
                for address, keys in client.processing().items():
                    running = [k for k in keys if k[0].startswith("tiles-")]
                    if running:
                        time.sleep(0.1)  # into the chunk's sleep
                        os.kill(pids[address], signal.SIGKILL)
                        killed.append(pids[address])
                        return
                time.sleep(0.01)

        killer = threading.Thread(target=kill_a_tiles_worker)
        killer.start()
        report = run(scene, stagefile, workdir, executor=executor, progress=False)
        killer.join()
        assert killed, "no tiles chunk was seen running"
        assert killed[0] not in client.run(os.getpid).values()  # a new worker took over
    assert len([r for r in report if r.name == "tiles"][0].ran_chunks) == 9
    assert artifact_bytes(workdir) == artifact_bytes(reference)


def test_a_stages_chunks_are_handed_out_as_workers_free_up():
    """A stage's chunks form one dask task group, queued on the scheduler and handed
    out one per worker thread as each ends (not shared out among the workers in
    advance, which left one worker idle while the other ran its slower share): after
    the first of 12 chunks (0.3 s each) ends on 2 workers, each worker holds one."""
    from types import SimpleNamespace

    tasks = [SimpleNamespace(stage="demo", chunk=SimpleNamespace(id=f"c{i}"))
             for i in range(12)]
    with DaskExecutor("local:2") as executor:
        client = executor.client()
        results = executor.map_unordered(lambda t: time.sleep(0.3) or t.chunk.id, tasks)
        first = next(results)
        held = {worker: len(keys) for worker, keys in client.processing().items()}
        rest = list(results)
    assert sorted([first, *rest]) == sorted(t.chunk.id for t in tasks)
    assert len(held) == 2 and max(held.values()) == 1, held


def test_local_workers_start_without_the_nannys_malloc_setting(monkeypatch):
    """dask's nannies give their workers MALLOC_TRIM_THRESHOLD_=65536 and write it into
    the starting process's own environment too (where every later child, a local
    pool's workers or a one-process bake started from it, would inherit it): neither
    happens for a ``local:N`` cluster (``LEAN_WORKERS``)."""
    monkeypatch.delenv(MALLOC_TRIM, raising=False)
    with DaskExecutor("local:2") as executor:
        seen = executor.client().run(os.environ.get, MALLOC_TRIM)
    assert len(seen) == 2 and set(seen.values()) == {None}
    assert MALLOC_TRIM not in os.environ


def faults_per_array(_task=None) -> tuple[str | None, float]:
    """(this process's MALLOC_TRIM_THRESHOLD_, page faults per 1 MiB NumPy array made and
    freed: its pages touched when filled), over 20 arrays after a first one (for which
    the heap grows)."""
    import resource

    import numpy as np

    def faults():
        return resource.getrusage(resource.RUSAGE_SELF).ru_minflt

    np.ones(1 << 17)
    before = faults()
    for _ in range(20):
        np.ones(1 << 17)
    return os.environ.get(MALLOC_TRIM), (faults() - before) / 20


def undo_then_count(undo: bool) -> tuple[bool | None, float]:
    """(``heap_as_glibc_default``'s answer, or None without it; faults per array)."""
    from pipeline.engine.executors.dask import heap_as_glibc_default

    undone = heap_as_glibc_default() if undo else None
    return undone, faults_per_array()[1]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
@pytest.mark.parametrize("undo", [False, True])
def test_a_remote_workers_malloc_setting_is_undone(undo, monkeypatch):
    """A process started with the nanny's MALLOC_TRIM_THRESHOLD_=65536 (a remote ``dask
    worker``'s) maps every 1 MiB NumPy array afresh and faults in each of its 256 pages
    of 4 KiB (257 faults counted an array here); after ``heap_as_glibc_default`` it
    reuses the heap (no faults an array here; at most 32, an eighth of the pages,
    allowed for the allocator's bookkeeping). Arrays of 1 MiB, not larger: NumPy asks
    for huge pages from 4 MiB on, which would hide the faults. The process is spawned
    with the variable set (glibc reads it when a process starts)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    monkeypatch.setenv(MALLOC_TRIM, "65536")
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        undone, faults = pool.submit(undo_then_count, undo).result()
    if undo:
        assert undone is True and faults <= 32
    else:
        assert faults > 128  # the setting's effect, which the undo removes


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_chunks_on_a_cluster_of_dasks_defaults_run_without_its_malloc_setting():
    """A cluster started with dask's own settings, as a remote ``dask worker``'s nanny
    starts its worker (MALLOC_TRIM_THRESHOLD_=65536 in the worker's environment), given
    to DaskExecutor by its address: a task runs after the worker's preparation has undone
    the setting (no more faults per 1 MiB array than the undo test allows)."""
    import logging

    from distributed import LocalCluster

    try:
        with LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                          dashboard_address=None, silence_logs=logging.ERROR) as cluster, \
                DaskExecutor(cluster.scheduler_address) as executor:
            [(setting, faults)] = list(executor.map_unordered(faults_per_array, [None]))
    finally:
        os.environ.pop(MALLOC_TRIM, None)  # the nanny wrote it into this process too
    assert setting == "65536"
    assert faults <= 32


@pytest.mark.parametrize("text, expected", [("local:3", (None, 3)),
                                            ("tcp://10.0.0.5:8786", ("tcp://10.0.0.5:8786", 0))])
def test_scheduler_values(text, expected):
    assert parse_scheduler(text) == expected


@pytest.mark.parametrize("text", ["local:0", "local:x", "local:", " "])
def test_bad_scheduler_values_are_refused(text):
    with pytest.raises(PrtError, match="--scheduler"):
        parse_scheduler(text)


def test_unreachable_scheduler_is_one_line(monkeypatch):
    """A scheduler address nobody listens on: a one-line PrtError naming it, as the
    executor is made (before a run touches any stage)."""
    import pipeline.engine.executors.dask as dask_executor

    monkeypatch.setattr(dask_executor, "CONNECT_TIMEOUT", "2s")
    with pytest.raises(PrtError, match="cannot reach the dask scheduler at "
                                       "tcp://127.0.0.1:9") as info:
        DaskExecutor("tcp://127.0.0.1:9")
    assert "\n" not in str(info.value)


def test_jobs_and_scheduler_together_are_refused(tmp_path):
    result = subprocess.run([sys.executable, "-m", "pipeline", "run", "--workdir",
                             str(tmp_path / "w"), "--jobs", "2", "--scheduler", "local:2"],
                            capture_output=True, text=True)
    assert result.returncode != 0 and "--jobs" in result.stderr
    assert "does not apply with --scheduler" in result.stderr


def test_status_and_in_process_runs_do_not_load_dask(tmp_path):
    """``prt status`` and an in-process bake never import dask or distributed."""
    code = ("import sys; from pipeline.cli import cli; "
            f"cli(['status', '--workdir', {str(tmp_path / 'w')!r}], standalone_mode=False); "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in "
            "('dask', 'distributed')))")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip().splitlines()[-1] == "[]"


def test_a_worker_with_other_code_refuses_its_chunks(tmp_path):
    """A worker whose code differs from the client's (another checkout on a remote
    machine, or sources edited during a run) would store other bytes under the client's
    key: execute_chunk compares the stage's code version it computes with the one the
    key was made of and refuses, in one line, before writing anything. Simulated by an
    executor that hands the chunks over with another code part."""
    import dataclasses

    from pipeline.engine.executors.local import InProcessExecutor

    class OtherCode(InProcessExecutor):
        def map_unordered(self, fn, tasks):
            other = [dataclasses.replace(t, parts={**t.parts, "code": "0" * 16})
                     for t in tasks]
            return super().map_unordered(fn, other)

    scene = load_scene(write_scene(tmp_path, small_scene_dict()))
    workdir = Workdir(tmp_path / "w")
    with pytest.raises(PrtError, match="other code") as caught:
        run(scene, load_stagefile(TOY_STAGEFILE), workdir, executor=OtherCode(),
            progress=False)
    assert "\n" not in str(caught.value)
    record = read_record(workdir.artifact("geometry"))
    assert record["complete"] is False  # the stage's in-progress record, no chunk in it
    assert not any(workdir.marker("geometry", c).exists() for c in record["chunks"])
    run(scene, load_stagefile(TOY_STAGEFILE), workdir, progress=False)  # same code: runs
    assert read_record(workdir.artifact("geometry"))["complete"] is True


class _Task:
    """A chunk task as the executor sees it: its stage and params (bake.device)."""

    def __init__(self, stage: str, device: str) -> None:
        self.stage, self.params = stage, {"bake.device": device}


def _pid(task: _Task) -> int:
    return os.getpid()


def test_gpu_chunks_run_where_a_gpu_is(tmp_path):
    """Chunks of a stage that traces on the device (bake.device=device) run in the
    ``local:N`` client's own process, which holds the machine's GPU; Embree's on the
    workers. On a running cluster they go to workers that offer the GPU resource, and a
    cluster with none is refused in one PrtError naming the stage and the remedy, before
    anything is submitted."""
    from distributed import LocalCluster

    with DaskExecutor("local:2") as executor:
        here = list(executor.map_unordered(_pid, [_Task("s", "device")] * 3))
        there = list(executor.map_unordered(_pid, [_Task("s", "embree")] * 3))
    assert here == [os.getpid()] * 3
    assert os.getpid() not in there
    for resources, expect in (({"GPU": 1}, "ran"), (None, "refused")):
        with LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                          dashboard_address=":0", resources=resources) as cluster, \
                DaskExecutor(cluster.scheduler_address) as executor:
            if expect == "ran":
                pids = list(executor.map_unordered(_pid, [_Task("s", "device")] * 2))
                worker = next(iter(executor.client().run(os.getpid).values()))
                assert pids == [worker] * 2
            else:
                with pytest.raises(PrtError, match=r"s traces its rays on the GPU .* "
                                                   r"--resources GPU=1, or bake it with "
                                                   r"--bake-device embree"):
                    list(executor.map_unordered(_pid, [_Task("s", "device")]))

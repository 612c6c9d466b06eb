"""A run killed mid-stage loses nothing; resumed, serial and parallel runs agree bit for bit."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers import (
    D2I_STAGES,
    TOY_STAGEFILE,
    TOY_STAGES,
    artifact_bytes,
    small_scene_dict,
    write_scene,
)

from pipeline import job
from pipeline.engine.executors.local import InProcessExecutor, LocalPoolExecutor
from pipeline.engine.planning import plan
from pipeline.engine.runner import run
from pipeline.engine.stagefile import load_stagefile
from pipeline.engine.store import Workdir, open_artifact, read_record
from pipeline.errors import PrtError
from pipeline.scene.file import default_scene_path, load_scene

STAGEFILE = TOY_STAGEFILE
STAGES = TOY_STAGES


def cli(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "pipeline", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.parametrize("jobs", ["1", "2", "local:2"])
def test_sigkill_mid_stage_then_resume_is_bit_identical(tmp_path, jobs):
    """SIGKILL (of a serial run, of the parent of a 2-process pool, or of the client of
    a 2-worker dask LocalCluster) while the tiles stage runs: earlier artifacts stay
    valid, the next run reuses the finished chunks, and the result equals an
    uninterrupted serial run's."""
    doc = small_scene_dict()
    doc["settings"] = {"toy.sleep": 0.3}
    scene_path = write_scene(tmp_path, doc)
    stagefile = load_stagefile(STAGEFILE)

    reference = Workdir(tmp_path / "reference")
    run(load_scene(scene_path), stagefile, reference, progress=False)

    killed = Workdir(tmp_path / "killed")
    workers = ("--scheduler", jobs) if jobs.startswith("local:") else ("--jobs", jobs)
    args = ("run", str(scene_path), "--stages", str(STAGEFILE), "--workdir", str(killed.root),
            *workers, "-q")
    proc = cli(*args)
    pieces = killed.markers("tiles")
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if pieces.is_dir() and len(list(pieces.iterdir())) >= 3:
            break
        time.sleep(0.02)
    assert proc.poll() is None, f"run ended before it could be killed: {proc.communicate()}"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    time.sleep(0.5)  # let the kernel deliver SIGKILL to pool workers too (PDEATHSIG)
    finished_before_kill = sorted(p.stem for p in pieces.glob("*.json"))
    assert 3 <= len(finished_before_kill) < 9

    # Every earlier artifact is complete, readable and fresh; tiles is incomplete, and
    # refused by readers until a run finishes it.
    scene = load_scene(scene_path)
    states = {p.spec.name: (p.state, p.reason) for p in plan(scene, stagefile, killed)}
    assert {n: s for n, (s, _) in states.items()} == {
        "geometry": "fresh", "gbuffer": "fresh", "per_object": "fresh", "total": "fresh",
        "tiles": "stale"}
    assert states["tiles"][1].startswith("incomplete")
    for stage in STAGES[:-1]:
        open_artifact(killed.artifact(stage)).read_all()
    with pytest.raises(PrtError, match="incomplete"):
        open_artifact(killed.artifact("tiles"))

    report = run(scene, stagefile, killed, progress=False)
    tiles = [r for r in report if r.name == "tiles"][0]
    assert sorted(tiles.reused_chunks) == finished_before_kill
    assert len(tiles.ran_chunks) == 9 - len(finished_before_kill)
    assert {r.name for r in report if r.action == "ran"} == {"tiles"}
    assert artifact_bytes(killed) == artifact_bytes(reference)
    assert not any(Path(killed.tmp).iterdir())


@pytest.mark.parametrize("threads", [1, 2])
def test_two_jobs_equal_one_job(tmp_path, threads):
    """--jobs 2 (a process pool) with 1 or 2 threads per task writes the same bytes as
    the in-process executor with one thread."""
    scene = load_scene(write_scene(tmp_path, small_scene_dict()))
    stagefile = load_stagefile(STAGEFILE)
    serial, parallel = Workdir(tmp_path / "serial"), Workdir(tmp_path / "parallel")
    run(scene, stagefile, serial, executor=InProcessExecutor(threads=1), progress=False)
    with LocalPoolExecutor(2, threads) as executor:
        run(scene, stagefile, parallel, executor=executor, progress=False)
    assert artifact_bytes(serial) == artifact_bytes(parallel)
    for stage in STAGES:
        assert read_record(serial.artifact(stage))["key"] == \
            read_record(parallel.artifact(stage))["key"]


def outside_artifacts(workdir: Workdir) -> list[Path]:
    """Files of a work directory that are not inside an artifact (``*.zarr``)."""
    return [p for p in workdir.root.rglob("*") if p.is_file()
            and not any(part.endswith(".zarr") for part in p.relative_to(workdir.root).parts)]


def test_workdir_holds_one_copy_of_each_artifact(tmp_path):
    """Chunks are written in place: besides the artifacts, a work directory holds only
    the chunks' small JSON records and the lock, no second copy of any data."""
    workdir = Workdir(tmp_path / "w")
    run(load_scene(write_scene(tmp_path, small_scene_dict())), load_stagefile(STAGEFILE),
        workdir, progress=False)
    others = outside_artifacts(workdir)
    assert {p.suffix for p in others} <= {".json", ""} and \
        {p.name for p in others if p.suffix == ""} == {".lock"}
    assert sum(p.stat().st_size for p in others) < 64 * 1024




def test_d2i_bake_is_bit_identical_whatever_workers_and_threads(tmp_path):
    """Method d2i's stages (Embree visibility groups and compression blocks on thread
    pools, PoCL kernels) at 1 worker × 1 thread, 1 × 2 and 2 workers × 1 thread (whose
    PoCL device has one thread, not this process's two): the same bytes. Tiles and
    gather blocks small enough that every chunked stage has several chunks."""
    scene = load_scene(default_scene_path()).with_image_size(24, 24).with_settings(
        {"gather.count": 1024, "transfer.tile": 8, "gbuffer.tile": 8, "bounce.block": 256})
    digests = {}
    for jobs, threads in ((1, 1), (1, 2), (2, 1)):
        workdir = job.workdir_for(scene, tmp_path / f"{jobs}x{threads}")
        report = job.bake(scene, workdir, quiet=True, jobs=jobs,
                          threads=threads)
        assert len([r for r in report if r.name == "d2i.transfer"][0].ran_chunks) == 9
        digests[jobs, threads] = {
            stage: (read_record(workdir.artifact(stage))["digest"],
                    {n: a.tobytes() for n, a in
                     open_artifact(workdir.artifact(stage)).read_all().items()})
            for stage in D2I_STAGES}
    assert digests[1, 1] == digests[1, 2] == digests[2, 1]

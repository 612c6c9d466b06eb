"""The runner: stale chunks of every stage run (pipeline/engine/planning.py decides
which, and keys them), each writing its part of the artifact in place
(pipeline/engine/chunkwrite.py) on an executor (pipeline/engine/executors/); the
artifact is complete when every chunk is recorded; the record then also keeps the
results of the budgets ``finalize`` chose from a tolerance (pipeline/engine/tolerance.py),
which ``prt run`` reports.
"""

from __future__ import annotations

import datetime
import hashlib
import os
import shutil
import socket
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.device.threads import one_blas_thread
from pipeline.engine import chunkwrite
from pipeline.engine.chunk import Chunk
from pipeline.engine.chunkwrite import Block
from pipeline.engine.codeversion import code_version
from pipeline.engine.executors import Executor
from pipeline.engine.executors.local import InProcessExecutor
from pipeline.engine.graph import topological_order, with_upstream
from pipeline.engine.keys import digest
from pipeline.engine.planning import (
    PART_DIGEST,
    StagePlan,
    chunks_to_run,
    impl_target,
    load_impl,
    plan_stage,
    read_record_or_none,
    stage_context,
    stage_layout,
    stage_params,
)
from pipeline.engine.schema import load_schema
from pipeline.engine.stage import ChunkContext
from pipeline.engine.stagefile import StageFile, StageSpec
from pipeline.engine.store import Workdir, open_artifact, software_versions
from pipeline.errors import PrtError
from pipeline.scene.model import ENVIRONMENT_FILE, Scene


@dataclass
class StageRun:
    """What a run did with one stage."""

    name: str
    action: str  # "ran" or "skipped"
    ran_chunks: list[str] = field(default_factory=list)
    reused_chunks: list[str] = field(default_factory=list)
    seconds: float = 0.0
    reason: str = ""
    # the budgets the stage chose from a tolerance, as its record stores them (whether
    # it ran now or was fresh): pipeline/engine/tolerance.py
    tolerances: list[dict[str, Any]] = field(default_factory=list)


@dataclass(frozen=True)
class ChunkTask:
    """Everything one chunk needs, as plain picklable values."""

    stage: str
    impl: str
    chunk: Chunk
    key: str
    seed: int
    params: dict[str, Any]
    scene: dict[str, Any]
    inputs: dict[str, tuple[str, str]]  # input name -> (artifact path, schema kind)
    meshes: dict[str, tuple[str, Any]]  # object -> ("file", path) | ("primitive", spec)
    environment: str | None  # the environment map's path, if the stage declares its file
    output: tuple[str, str]  # (artifact path, schema kind) of the stage's own artifact
    marker: str  # where the chunk is recorded once written
    sizes: dict[str, int]  # symbolic zarr chunk sizes of the stage's layout
    parts: dict[str, str]  # what the key is made of, part by part (chunk_key_parts)
    kernels: tuple[str, ...] = ()  # the kernels the stage declares (its code version's)
    scene_path: str = ""  # the scene file, named by a stage's error that names no file




# ----------------------------------------------------------------------------- execution


def arrays_digest(arrays: dict[str, Any], attrs: dict[str, Any] | None = None) -> str:
    """SHA-256 of arrays (name, dtype, shape, bytes and, for a Block, where it goes; in
    name order) and attrs: equal output, equal digest, whatever produced it."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        value = arrays[name]
        start = value.start if isinstance(value, Block) else None
        a = np.ascontiguousarray(value.data if isinstance(value, Block) else value)
        h.update(f"{name}|{a.dtype.str}|{a.shape}|{start}|".encode())
        h.update(a.data)
    if attrs is not None:
        h.update(digest(attrs).encode())
    return h.hexdigest()


_ENVIRONMENT: dict[str, Any] = {}  # the last map read by this process: key and array


def _environment(path: str) -> np.ndarray:
    """The environment map at ``path``, read once per process while the file is unchanged
    (size and modification time), read-only: the chunks of a stage share one read (and
    what they derive from it, e.g. light_rotations' prefiltered map)."""
    from pipeline.images import read_environment

    stat = Path(path).stat()
    key = (path, stat.st_size, stat.st_mtime_ns)
    if _ENVIRONMENT.get("key") != key:
        rgb = read_environment(path)
        rgb.setflags(write=False)
        _ENVIRONMENT.update(key=key, map=rgb)
    return _ENVIRONMENT["map"]


def execute_chunk(task: ChunkTask) -> tuple[str, float]:
    """Run one chunk, write its arrays into the artifact in place and record it."""
    from pipeline.scene.meshio import primitive_mesh, read_mesh

    one_blas_thread()
    start, started = time.perf_counter(), time.time()
    try:
        _check_code(task)
        meshes = {name: read_mesh(Path(src)) if kind == "file" else primitive_mesh(src)
                  for name, (kind, src) in task.meshes.items()}
        inputs = {name: open_artifact(Path(path), kind) for name, (path, kind) in
                  task.inputs.items()}
        environment = _environment(task.environment) if task.environment else None
        ctx = ChunkContext(params=task.params, scene=task.scene, inputs=inputs,
                           chunk=task.chunk, key=task.key,
                           rng=np.random.default_rng(task.seed), meshes=meshes,
                           environment=environment)
        arrays = load_impl(task.impl).run_chunk(ctx)
        _check_finite(task, arrays)
    except PrtError as exc:
        exc.nothing_written = True  # the artifact is as it was: see _run_stage
        if exc.path is not None:
            raise
        named = PrtError(task.scene_path or task.output[0], f"stage {task.stage}: {exc.problem}")
        named.nothing_written = True
        raise named from None
    except Exception as exc:
        exc.nothing_written = True  # the artifact is as it was: see _run_stage
        raise
    path, kind = task.output
    chunkwrite.write_chunk(Path(path), load_schema(kind), task.chunk.id, arrays, task.sizes)
    seconds = time.perf_counter() - start
    chunkwrite.record_chunk(Path(task.marker), {
        "stage": task.stage, "chunk": task.chunk.id, "key": task.key,
        "digest": arrays_digest(arrays), "seconds": seconds, "meta": ctx.meta,
        "parts": task.parts,
        # where and when it ran (UNIX seconds): a run's timeline, per worker process
        "process": f"{socket.gethostname()}:{os.getpid()}", "started": started})
    return task.chunk.id, seconds


def _check_code(task: ChunkTask) -> None:
    """Refuse to run a chunk with other code than the client keyed it with (a dask
    worker with another checkout or version installed, or sources edited while a bake
    runs): it would store other bytes under the same key. Sources are parsed once per
    process while unchanged (pipeline/engine/codeversion.py), so this costs little per chunk."""
    here = code_version([impl_target(task.impl).partition(":")[0]], task.kernels)
    if here[:PART_DIGEST] != task.parts["code"]:
        raise PrtError(task.marker, f"stage {task.stage}: this process runs other code "
                       f"(version {here[:PART_DIGEST]}) than the run was planned with "
                       f"({task.parts['code']}): give every worker the same checkout or "
                       "installed version, and do not edit the sources during a run")


def _check_finite(task: ChunkTask, arrays: dict[str, Any]) -> None:
    """Refuse a chunk whose floating-point output holds NaN or Inf: stored, it would
    turn into garbage frames far from its cause."""
    for name, value in arrays.items():
        data = value.data if isinstance(value, Block) else np.asarray(value)
        if data.dtype.kind in "fc" and not np.isfinite(data).all():
            count = int(data.size - np.isfinite(data).sum())
            raise PrtError(task.output[0], f"stage {task.stage}, chunk {task.chunk.id}: array "
                           f"{name} has {count} NaN or Inf values; nothing was stored (check "
                           "the stage's inputs, parameters and scene)")


def _mesh_sources(spec: StageSpec, scene: Scene, chunk: Chunk) -> dict[str, tuple[str, Any]]:
    if "objects.*.mesh" not in spec.scene:
        return {}
    names = [chunk.object] if chunk.object else list(scene.objects)
    return {n: ("file", str(scene.objects[n].mesh)) if scene.objects[n].mesh is not None
            else ("primitive", scene.objects[n].primitive) for n in names}


def _environment_source(spec: StageSpec, scene: Scene) -> str | None:
    if ENVIRONMENT_FILE not in spec.scene:
        return None
    path = scene.environment_file()
    return None if path is None else str(path)


def run(scene: Scene, stagefile: StageFile, workdir: Workdir,
        until: str | tuple[str, ...] | None = None,
        force: tuple[str, ...] = (), executor: Executor | None = None,
        progress: bool = True, targets: set[str] | None = None) -> list[StageRun]:
    """Bring the artifacts of all stages (or of ``targets``, or ``until``, and their
    upstream) up to date; each stage is planned when its inputs are fresh."""
    executor = executor or InProcessExecutor()
    for name in force:
        if name not in stagefile.stages:
            raise PrtError(stagefile.path, f"--force: unknown stage {name!r}")
    if isinstance(until, str):
        until = (until,)
    wanted = targets if targets is not None else (set(until) if until else None)
    selected = with_upstream(stagefile, sorted(wanted)) if wanted is not None else None
    params_all = stage_params(stagefile, scene)
    report: list[StageRun] = []
    if not force and workdir.root.is_dir() and not workdir.writable():
        return _all_fresh(scene, stagefile, workdir, selected, params_all)
    with workdir.lock():
        one_blas_thread()
        for name in topological_order(stagefile):
            if selected is not None and name not in selected:
                continue
            p = plan_stage(stagefile.stages[name], scene, stagefile, workdir, params_all)
            if p.state == "fresh" and name not in force:
                record = read_record_or_none(workdir.artifact(name)) or {}
                report.append(StageRun(name, "skipped",
                                       tolerances=record.get("tolerances", [])))
                continue
            report.append(_run_stage(p, scene, stagefile, workdir, executor, progress,
                                     name in force))
    return report


def _all_fresh(scene: Scene, stagefile: StageFile, workdir: Workdir,
               selected: set[str] | None, params_all: dict[str, Any]) -> list[StageRun]:
    """The report of a run in a work directory this process cannot write (read-only
    folder or file system, another user's bake): nothing to bake when every stage is
    fresh, which needs no lock; else PrtError naming the first stage that is not."""
    report = []
    for name in topological_order(stagefile):
        if selected is not None and name not in selected:
            continue
        p = plan_stage(stagefile.stages[name], scene, stagefile, workdir, params_all)
        if p.state != "fresh":
            raise PrtError(workdir.root, f"work directory is not writable and stage {name} "
                           f"is {p.state} ({p.reason}); make it writable or give another "
                           "--workdir")
        report.append(StageRun(name, "skipped"))
    return report


def _run_stage(p: StagePlan, scene: Scene, stagefile: StageFile, workdir: Workdir,
               executor: Executor, progress: bool, forced: bool) -> StageRun:
    """Run the chunks of one stage that have no current record, in place, then finish
    its artifact (pipeline/engine/chunkwrite.py)."""
    from tqdm import tqdm

    start = time.perf_counter()
    spec, name = p.spec, p.spec.name
    impl = load_impl(spec.impl)
    schema = load_schema(spec.output)
    ctx = stage_context(p, stagefile, workdir)
    layout = stage_layout(impl, ctx)
    path = workdir.artifact(name)
    ids = [c.id for c in p.chunks]
    previous = read_record_or_none(path)
    rerun, _ = chunks_to_run(p, previous,
                             lambda: chunkwrite.layout_record(schema, layout.shapes,
                                                              layout.sizes),
                             lambda c: chunkwrite.read_marker(workdir.marker(name, c)),
                             forced)
    kept = chunkwrite.begin(workdir, path, schema, {
        "stage": name, "key": p.key, "chunk_keys": p.chunk_keys, "chunks": ids,
        "key_parts": p.key_parts}, layout.shapes, layout.sizes)
    if not kept:
        shutil.rmtree(workdir.markers(name), ignore_errors=True)
    rerun_ids = set(rerun)
    todo = longest_first([c for c in p.chunks if c.id in rerun_ids],
                         (previous or {}).get("chunk_seconds") or {})
    tasks = [ChunkTask(name, spec.impl, c, p.chunk_keys[c.id], p.seeds[c.id], p.params,
                       p.sections[c.id], {dep: (str(workdir.artifact(dep)),
                                                stagefile.stages[dep].output)
                                          for dep in spec.inputs},
                       _mesh_sources(spec, scene, c), _environment_source(spec, scene),
                       (str(path), spec.output),
                       str(workdir.marker(name, c.id)), layout.sizes, p.chunk_parts[c.id],
                       tuple(spec.kernels), str(scene.path))
             for c in todo]
    bar = tqdm(total=len(tasks), desc=name, unit="chunk", disable=not progress,
               file=sys.stderr, leave=False)
    try:
        for _ in executor.map_unordered(execute_chunk, tasks):
            bar.update()
    except Exception as exc:
        # A chunk failed before writing anything (bad input, say) and no other chunk
        # was written this run (the executor returns once every started task ended):
        # the artifact still holds exactly what its previous record says.
        written = [c for c in todo if (chunkwrite.read_marker(workdir.marker(name, c.id))
                                       or {}).get("key") == p.chunk_keys[c.id]]
        if kept and not written and getattr(exc, "nothing_written", False) \
                and previous is not None:
            chunkwrite.restore_record(path, previous)
        raise
    finally:
        bar.close()
    records = [chunkwrite.read_marker(workdir.marker(name, c)) for c in ids]
    lost = [c for c, r in zip(ids, records, strict=True)
            if r is None or r.get("key") != p.chunk_keys[c]]
    if lost:
        raise PrtError(workdir.marker(name, lost[0]), "chunk record missing after the run")
    output = impl.finalize(ctx, [(c, r["meta"]) for c, r in zip(p.chunks, records,
                                                                strict=True)])
    chunk_digests = {c: r["digest"] for c, r in zip(ids, records, strict=True)}
    seconds = time.perf_counter() - start
    tolerances = [t.as_record() for t in output.tolerances]
    chunkwrite.finish(path, schema, ids, output.arrays, output.attrs, {
        "chunk_digests": chunk_digests, "tolerances": tolerances,
        "digest": digest({"chunks": [chunk_digests[c] for c in ids],
                          "finalized": arrays_digest(output.arrays, output.attrs)}),
        "seconds": seconds, "chunk_seconds": {c: r["seconds"] for c, r in
                                              zip(ids, records, strict=True)},
        "software": software_versions(),
        "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")},
        layout.sizes)
    _drop_stale_markers(workdir, name, set(ids))
    done = {c.id for c in todo}
    return StageRun(name, "ran", [c for c in ids if c in done],
                    [c for c in ids if c not in done], seconds,
                    "forced" if forced else p.reason, tolerances)


def longest_first(chunks: list[Chunk], seconds: dict[str, float]) -> list[Chunk]:
    """``chunks`` in the order they are handed to the workers: those the stage's last
    bake timed (``seconds``, its record's ``chunk_seconds``) longest first, as a re-bake
    after an edit has them, so that the last to start are the short ones and no worker
    is left alone with a long chunk at the end; chunks without a time first, in plan
    order (a first bake runs in plan order). The artifact does not depend on the
    order."""
    untimed = [c for c in chunks if c.id not in seconds]
    timed = sorted((c for c in chunks if c.id in seconds), key=lambda c: -seconds[c.id])
    return untimed + timed


def _drop_stale_markers(workdir: Workdir, stage: str, keep: set[str]) -> None:
    kept = {workdir.marker(stage, chunk).name for chunk in keep}
    folder = workdir.markers(stage)
    if folder.is_dir():
        for child in folder.iterdir():
            if child.name not in kept:  # a file, or a chunk folder of an older prt
                shutil.rmtree(child) if child.is_dir() else child.unlink(missing_ok=True)

"""The runner: stages.yaml + scene -> keyed plan -> only the stale chunks run.

Keys (all SHA-256 of canonical JSON):

* chunk key = {stage, code, schema version, declared param values, declared scene
  sections resolved for the chunk, input artifact keys, chunk id};
* artifact key = {stage, chunk keys} (for an unchunked stage, its one chunk key);
* code = hash of the stage module's source and of the kernels it declares.

An artifact is fresh when its stored key equals the planned key. Otherwise its chunks
whose cached results carry the planned chunk key are reused and the rest run; then the
stage's ``assemble`` writes the artifact atomically. Planning reads only ``zarr.json``
files, never arrays.
"""

from __future__ import annotations

import datetime
import importlib
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pipeline.cl import kernel_dir
from pipeline.errors import PrtError
from pipeline.executors import Executor, InProcessExecutor
from pipeline.graph import topological_order, with_upstream
from pipeline.keys import digest, file_hash, module_source_hash, seed_from_key
from pipeline.scene import Scene
from pipeline.schema import load_schema
from pipeline.stagefile import StageFile, StageSpec
from pipeline.stages import REGISTRY, AssembleContext, Chunk, ChunkContext
from pipeline.store import (
    Workdir,
    open_artifact,
    open_group,
    read_record,
    software_versions,
    write_artifact,
    write_group,
)


@dataclass
class StagePlan:
    """A stage's planned keys and state. ``state`` is fresh, stale or missing; ``reason``
    says why it is not fresh; ``sections`` maps chunk id -> resolved scene sections."""

    spec: StageSpec
    key: str
    chunks: list[Chunk]
    chunk_keys: dict[str, str]
    key_parts: dict[str, Any]
    params: dict[str, Any]
    sections: dict[str, dict[str, Any]]
    state: str = "missing"
    reason: str = ""


@dataclass
class StageRun:
    """What a run did with one stage."""

    name: str
    action: str  # "ran" or "skipped"
    ran_chunks: list[str] = field(default_factory=list)
    reused_chunks: list[str] = field(default_factory=list)
    seconds: float = 0.0
    reason: str = ""


@dataclass(frozen=True)
class ChunkTask:
    """Everything one chunk needs, as plain picklable values."""

    stage: str
    impl: str
    chunk: Chunk
    key: str
    params: dict[str, Any]
    scene: dict[str, Any]
    inputs: dict[str, tuple[str, str]]  # input name -> (artifact path, schema kind)
    meshes: dict[str, tuple[str, Any]]  # object -> ("file", path) | ("primitive", spec)
    workdir: str


# ------------------------------------------------------------------------------ planning


def stage_params(stagefile: StageFile, scene: Scene) -> dict[str, Any]:
    """Parameter defaults from stages.yaml overridden by the scene's ``settings``."""
    unknown = sorted(set(scene.settings) - set(stagefile.params))
    if unknown:
        raise PrtError(scene.path, f"settings.{unknown[0]}: unknown parameter (known: "
                       f"{', '.join(sorted(stagefile.params))})")
    return {**stagefile.params, **scene.settings}


def resolve_sections(spec: StageSpec, scene: Scene, chunk: Chunk | None) -> dict[str, Any]:
    """Declared scene sections with ``*`` bound to the chunk's object or material (or,
    without a chunk, to every name)."""
    obj = chunk.object if chunk else None
    material = chunk.material if chunk else None
    if obj:
        material = scene.objects[obj].material
    out: dict[str, Any] = {}
    for pattern in spec.scene:
        if "*" not in pattern:
            out[pattern] = scene.section(pattern)
            continue
        head, _, tail = pattern.partition(".*")
        if head == "objects":
            names = [obj] if obj else list(scene.objects)
        elif head == "materials":
            names = [material] if material else list(scene.materials)
        else:
            raise PrtError(None, f"stage {spec.name}: scene section {pattern!r}: '*' is only "
                           "allowed after objects or materials")
        for name in names:
            out[f"{head}.{name}{tail}"] = scene.section(f"{head}.{name}{tail}")
    return out


def impl_module_name(impl: str) -> str:
    return REGISTRY.get(impl, impl).partition(":")[0]


def load_impl(impl: str) -> Any:
    """The module (or ``module:attribute`` object) implementing a stage."""
    target = REGISTRY.get(impl, impl)
    module_name, _, attr = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise PrtError(None, f"stage implementation {impl!r} cannot be imported ({exc})") \
            from None
    return getattr(module, attr) if attr else module


def code_version(spec: StageSpec) -> str:
    kernels = kernel_dir()
    parts = [module_source_hash(impl_module_name(spec.impl))]
    for name in spec.kernels:
        path = kernels / name
        if not path.is_file():
            raise PrtError(path, f"kernel file declared by stage {spec.name} not found")
        parts.append(file_hash(path))
    return digest(parts)


def stage_chunks(spec: StageSpec, scene: Scene, params: dict[str, Any]) -> list[Chunk]:
    if spec.chunking == "object":
        return [Chunk(name, object=name) for name in scene.objects]
    if spec.chunking == "material":
        return [Chunk(name, material=name) for name in scene.materials]
    if spec.chunking == "tile":
        tile = params[spec.tile_param]
        if not isinstance(tile, int) or tile < 1:
            raise PrtError(scene.path, f"{spec.tile_param}: expected a positive integer tile "
                           f"size, found {tile!r}")
        w, h = scene.camera.width, scene.camera.height
        return [Chunk(f"y{y:05d}_x{x:05d}", region=(y, min(y + tile, h), x, min(x + tile, w)))
                for y in range(0, h, tile) for x in range(0, w, tile)]
    if spec.chunking == "block":
        size, count = params[spec.tile_param], params[spec.count_param]
        for name, value in ((spec.tile_param, size), (spec.count_param, count)):
            if not isinstance(value, int) or value < 1:
                raise PrtError(scene.path, f"{name}: expected a positive integer, found "
                               f"{value!r}")
        return [Chunk(f"b{s:08d}", span=(s, min(s + size, count)))
                for s in range(0, count, size)]
    return [Chunk("all")]


def plan(scene: Scene, stagefile: StageFile, workdir: Workdir,
         targets: set[str] | None = None) -> list[StagePlan]:
    """Keys and states of the stages (``targets`` and their upstream; default all)."""
    params_all = stage_params(stagefile, scene)
    order = [n for n in topological_order(stagefile) if targets is None or n in targets]
    plans: dict[str, StagePlan] = {}
    for name in order:
        spec = stagefile.stages[name]
        params = {k: params_all[k] for k in spec.params}
        inputs = {dep: plans[dep].key for dep in spec.inputs}
        chunks = stage_chunks(spec, scene, params)
        per_chunk = spec.chunking in ("object", "material")
        shared = None if per_chunk else resolve_sections(spec, scene, None)
        sections = {c.id: resolve_sections(spec, scene, c) if per_chunk else shared
                    for c in chunks}
        base = {"stage": name, "code": code_version(spec),
                "schema_version": load_schema(spec.output).version,
                "params": params, "inputs": inputs}
        chunk_keys = {c.id: digest({**base, "scene": sections[c.id], "chunk": c.id})
                      for c in chunks}
        key = (chunk_keys["all"] if spec.chunking == "none"
               else digest({"stage": name, "chunks": chunk_keys}))
        scene_digests = {path: digest(value) for s in sections.values()
                         for path, value in s.items()}
        key_parts = {**base, "scene": dict(sorted(scene_digests.items())),
                     "chunks": sorted(chunk_keys)}
        p = StagePlan(spec, key, chunks, chunk_keys, key_parts, params, sections)
        p.state, p.reason = _state(workdir.artifact(name), key, key_parts)
        plans[name] = p
    return list(plans.values())


def _state(path: Path, key: str, parts: dict[str, Any]) -> tuple[str, str]:
    try:
        record = read_record(path)
    except PrtError as exc:
        return "stale", exc.problem
    if record is None:
        return "missing", "not built yet"
    if record.get("key") == key:
        return "fresh", ""
    return "stale", explain_change(record.get("key_parts") or {}, parts)


def explain_change(old: dict[str, Any], new: dict[str, Any]) -> str:
    """A short sentence naming what differs between two key_parts records."""
    reasons = []
    if old.get("code") != new["code"]:
        reasons.append("code changed")
    if old.get("schema_version") != new["schema_version"]:
        reasons.append(f"schema version {old.get('schema_version')} -> "
                       f"{new['schema_version']}")
    old_params, new_params = old.get("params", {}), new["params"]
    for k in sorted(set(old_params) | set(new_params)):
        if old_params.get(k) != new_params.get(k):
            reasons.append(f"param {k} changed ({old_params.get(k)!r} -> {new_params.get(k)!r})")
    old_scene, new_scene = old.get("scene", {}), new["scene"]
    changed = [p for p in sorted(set(old_scene) | set(new_scene))
               if old_scene.get(p) != new_scene.get(p)]
    if changed:
        more = f" and {len(changed) - 3} more" if len(changed) > 3 else ""
        reasons.append(f"scene section {', '.join(changed[:3])}{more} changed")
    old_inputs, new_inputs = old.get("inputs", {}), new["inputs"]
    for k in sorted(set(old_inputs) | set(new_inputs)):
        if old_inputs.get(k) != new_inputs.get(k):
            reasons.append(f"input {k} changed")
    if not reasons and old.get("chunks") != new["chunks"]:
        reasons.append("chunk layout changed")
    return "; ".join(reasons) or "key changed"


# ----------------------------------------------------------------------------- execution


def execute_chunk(task: ChunkTask) -> tuple[str, float]:
    """Run one chunk and store its result under the work directory's chunk cache."""
    from pipeline.meshio import primitive_mesh, read_mesh

    start = time.perf_counter()
    workdir = Workdir(task.workdir)
    meshes = {name: read_mesh(Path(src)) if kind == "file" else primitive_mesh(src)
              for name, (kind, src) in task.meshes.items()}
    inputs = {name: open_artifact(Path(path), kind) for name, (path, kind) in
              task.inputs.items()}
    import numpy as np

    ctx = ChunkContext(params=task.params, scene=task.scene, inputs=inputs, chunk=task.chunk,
                       key=task.key, rng=np.random.default_rng(seed_from_key(task.key)),
                       meshes=meshes)
    arrays = load_impl(task.impl).run_chunk(ctx)
    seconds = time.perf_counter() - start
    record = {"format": 1, "kind": "chunk", "stage": task.stage, "chunk": task.chunk.id,
              "key": task.key, "seconds": seconds}
    write_group(workdir, workdir.piece(task.stage, task.chunk.id), arrays, {"prt": record},
                chunks={}, dims={})
    return task.chunk.id, seconds


def _mesh_sources(spec: StageSpec, scene: Scene, chunk: Chunk) -> dict[str, tuple[str, Any]]:
    if "objects.*.mesh" not in spec.scene:
        return {}
    names = [chunk.object] if chunk.object else list(scene.objects)
    return {n: ("file", str(scene.objects[n].mesh)) if scene.objects[n].mesh is not None
            else ("primitive", scene.objects[n].primitive) for n in names}


def _piece_is_current(workdir: Workdir, stage: str, chunk: str, key: str) -> bool:
    try:
        record = read_record(workdir.piece(stage, chunk))
    except PrtError:
        return False
    return record is not None and record.get("key") == key


def run(scene: Scene, stagefile: StageFile, workdir: Workdir, until: str | None = None,
        force: tuple[str, ...] = (), executor: Executor | None = None,
        progress: bool = True) -> list[StageRun]:
    """Bring the artifacts of all stages (or of ``until`` and its upstream) up to date."""
    from tqdm import tqdm

    executor = executor or InProcessExecutor()
    for name in force:
        if name not in stagefile.stages:
            raise PrtError(stagefile.path, f"--force: unknown stage {name!r}")
    targets = with_upstream(stagefile, [until]) if until else None
    report: list[StageRun] = []
    with workdir.lock():
        for p in plan(scene, stagefile, workdir, targets):
            name = p.spec.name
            if p.state == "fresh" and name not in force:
                report.append(StageRun(name, "skipped"))
                continue
            start = time.perf_counter()
            forced = name in force
            todo = [c for c in p.chunks if forced or p.spec.chunking == "none"
                    or not _piece_is_current(workdir, name, c.id, p.chunk_keys[c.id])]
            tasks = [_task(p, scene, stagefile, workdir, c) for c in todo]
            bar = tqdm(total=len(tasks), desc=name, unit="chunk", disable=not progress,
                       file=sys.stderr, leave=False)
            for _ in executor.map_unordered(execute_chunk, tasks):
                bar.update()
            bar.close()
            _assemble(p, scene, stagefile, workdir, start)
            _drop_stale_pieces(workdir, name, {c.id for c in p.chunks})
            done = {c.id for c in todo}
            report.append(StageRun(name, "ran", [c.id for c in p.chunks if c.id in done],
                                   [c.id for c in p.chunks if c.id not in done],
                                   time.perf_counter() - start,
                                   "forced" if forced else p.reason))
    return report


def _task(p: StagePlan, scene: Scene, stagefile: StageFile, workdir: Workdir,
          chunk: Chunk) -> ChunkTask:
    inputs = {dep: (str(workdir.artifact(dep)), stagefile.stages[dep].output)
              for dep in p.spec.inputs}
    return ChunkTask(p.spec.name, p.spec.impl, chunk, p.chunk_keys[chunk.id], p.params,
                     p.sections[chunk.id], inputs, _mesh_sources(p.spec, scene, chunk),
                     str(workdir.root))


def _assemble(p: StagePlan, scene: Scene, stagefile: StageFile, workdir: Workdir,
              start: float) -> None:
    name = p.spec.name
    inputs = {dep: open_artifact(workdir.artifact(dep), stagefile.stages[dep].output)
              for dep in p.spec.inputs}
    all_sections: dict[str, Any] = {}
    for s in p.sections.values():
        all_sections.update(s)
    pieces = [(c, open_group(workdir.piece(name, c.id)).read_all()) for c in p.chunks]
    ctx = AssembleContext(params=p.params, scene=all_sections, inputs=inputs)
    output = load_impl(p.spec.impl).assemble(ctx, pieces)
    record = {"stage": name, "key": p.key, "chunk_keys": p.chunk_keys,
              "key_parts": p.key_parts, "seconds": time.perf_counter() - start,
              "software": software_versions(),
              "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")}
    write_artifact(workdir, workdir.artifact(name), load_schema(p.spec.output), output.arrays,
                   output.attrs, record, output.sizes)


def _drop_stale_pieces(workdir: Workdir, stage: str, keep: set[str]) -> None:
    import shutil

    folder = workdir.pieces(stage)
    if folder.is_dir():
        for child in folder.iterdir():
            if child.name not in keep:
                shutil.rmtree(child, ignore_errors=True)

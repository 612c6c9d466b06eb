"""The runner: stages.yaml + scene -> keyed plan -> only the stale chunks run.

Keys (SHA-256 of canonical JSON):

* a chunk's *data key* = {stage, declared param values, declared scene sections
  resolved for the chunk, the digests of the inputs it reads, chunk id}; it seeds the
  chunk's random numbers, so a refactor that leaves the numbers alone reproduces them;
* a chunk's *key* = {data key, code version, schema version}: the code version is the
  hash of the stage module's import closure and of the kernels it uses, includes
  followed (pipeline/codeversion.py);
* an input enters a chunk's key by its *output digest* (the hash of the bytes it
  wrote), not its key: when a re-run stage writes what it wrote before, its dependents
  stay fresh (early cut-off). An input listed in ``chunk_inputs`` enters only by the
  digests of the chunks the chunk reads (those of its object or materials): editing one
  material's ``gamma_range`` re-runs only the pixel tiles that see that material;
* an artifact's key = {stage, chunk keys}.

A stage is planned once its inputs are fresh (its chunks may depend on their
attributes, pipeline/chunking.py); before that ``prt status`` reports it as waiting for
them. An artifact is fresh when its stored key equals the planned key. Otherwise its
chunks whose records carry the planned chunk key are kept and the rest run, each
writing its part of the artifact in place (pipeline/chunkwrite.py); the artifact is
complete when every chunk is recorded; the record then also keeps the results of the
budgets ``finalize`` chose from a tolerance (pipeline/tolerance.py), which ``prt run``
reports. Planning reads only
``zarr.json`` files (and, for ``materials_from``, one small label image), never the
large arrays.
"""

from __future__ import annotations

import datetime
import hashlib
import importlib
import math
import os
import shutil
import socket
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pipeline import chunkwrite
from pipeline.chunk import Chunk
from pipeline.chunking import plan_chunks
from pipeline.chunkwrite import Block
from pipeline.codeversion import code_version
from pipeline.errors import PrtError
from pipeline.executors import Executor, InProcessExecutor, one_blas_thread
from pipeline.graph import topological_order, with_upstream
from pipeline.keys import digest, seed_from_key
from pipeline.scene import ENVIRONMENT_FILE, Scene
from pipeline.schema import load_schema
from pipeline.stagefile import StageFile, StageSpec
from pipeline.stages import AssembleContext, ChunkContext, Layout
from pipeline.store import Artifact, Workdir, open_artifact, read_record, software_versions

STAGE_PACKAGE = "pipeline.stages"


@dataclass
class StagePlan:
    """A stage's planned keys and state. ``state`` is fresh, stale or missing; ``reason``
    says why it is not fresh. ``chunks`` is None (and ``key`` empty) while an input is
    not fresh: such a stage is planned when it is its turn to run."""

    spec: StageSpec
    params: dict[str, Any]
    key: str = ""
    chunks: list[Chunk] | None = None
    chunk_keys: dict[str, str] = field(default_factory=dict)
    chunk_parts: dict[str, dict[str, str]] = field(default_factory=dict)
    seeds: dict[str, int] = field(default_factory=dict)
    key_parts: dict[str, Any] = field(default_factory=dict)
    sections: dict[str, dict[str, Any]] = field(default_factory=dict)
    stage_sections: dict[str, Any] = field(default_factory=dict)  # unbound: every object
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
    # the budgets the stage chose from a tolerance, as its record stores them (whether
    # it ran now or was fresh): pipeline/tolerance.py
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


# ------------------------------------------------------------------------------ planning


def stage_params(stagefile: StageFile, scene: Scene) -> dict[str, Any]:
    """Parameter defaults from stages.yaml overridden by the scene's ``settings``."""
    unknown = sorted(set(scene.settings) - set(stagefile.params))
    if unknown:
        raise PrtError(scene.path, f"settings.{unknown[0]}: unknown parameter (known: "
                       f"{', '.join(sorted(stagefile.params))})")
    for name, value in scene.settings.items():
        expected = _setting_kind(stagefile.params[name], value)
        if expected:
            raise PrtError(scene.path, f"settings.{name}: {value!r} is not {expected} (the "
                           f"default is {stagefile.params[name]!r})")
        low, high = stagefile.limits.get(name, (0.0, math.inf))
        numbers = value if isinstance(value, list) else [value]
        for x in numbers:
            if isinstance(x, (int, float)) and not isinstance(x, bool) \
                    and not (math.isfinite(x) and low <= x <= high):
                raise PrtError(scene.path, f"settings.{name}: {x!r} is outside "
                               f"{_bounds(low, high)} (the default is "
                               f"{stagefile.params[name]!r})")
    return {**stagefile.params, **scene.settings}


def _bounds(low: float, high: float) -> str:
    """``[low, high]`` as a reader writes it (``≥ 0`` without an upper bound)."""
    def text(x: float) -> str:
        return str(int(x)) if float(x).is_integer() else f"{x:g}"
    return f"≥ {text(low)}" if math.isinf(high) else f"{text(low)}..{text(high)}"


def _setting_kind(default: Any, value: Any) -> str | None:
    """What ``value`` should be to replace ``default`` (a stage parameter's), or None if
    it is of the default's kind: a boolean for a boolean, an integer for an integer, a
    number for a float, a list for a list, text for text."""
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if isinstance(default, bool):
        return None if isinstance(value, bool) else "true or false"
    if isinstance(default, int):
        return None if number and isinstance(value, int) else "an integer"
    if isinstance(default, float):
        return None if number else "a number"
    if isinstance(default, list):
        plural = {"an integer": "integers", "a number": "numbers"}
        element = plural.get(_setting_kind(default[0], "x") or "", "values") if default \
            else "values"
        wanted = f"a list of {len(default)} {element}"  # a grid's sizes: one per axis
        if not isinstance(value, list) or (default and len(value) != len(default)):
            return wanted if default else "a list"
        wrong = default and any(_setting_kind(default[0], x) for x in value)
        return wanted if wrong else None
    if isinstance(default, str):
        return None if isinstance(value, str) else "text"
    return None


def resolve_sections(spec: StageSpec, scene: Scene, chunk: Chunk | None) -> dict[str, Any]:
    """Declared scene sections with ``*`` bound to the chunk's object and materials
    (or, where the chunk has none, to every object or material)."""
    obj = chunk.object if chunk else None
    materials = chunk.materials if chunk else None
    if obj and materials is None:
        materials = (scene.objects[obj].material,)
    out: dict[str, Any] = {}
    for pattern in spec.scene:
        if "*" not in pattern:
            out[pattern] = scene.section(pattern)
            continue
        head, _, tail = pattern.partition(".*")
        if head == "objects":
            names = [obj] if obj else list(scene.objects)
        elif head == "materials":
            names = list(materials) if materials is not None else list(scene.materials)
        else:
            raise PrtError(None, f"stage {spec.name}: scene section {pattern!r}: '*' is only "
                           "allowed after objects or materials")
        for name in names:
            out[f"{head}.{name}{tail}"] = scene.section(f"{head}.{name}{tail}")
    return out


def impl_target(impl: str) -> str:
    """``gbuffer`` -> ``pipeline.stages.gbuffer``; dotted names stay as they are."""
    return impl if "." in impl.partition(":")[0] else f"{STAGE_PACKAGE}.{impl}"


def load_impl(impl: str) -> Any:
    """The module (or ``module:attribute`` object) implementing a stage."""
    module_name, _, attr = impl_target(impl).partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise PrtError(None, f"stage implementation {impl!r} cannot be imported ({exc})") \
            from None
    return getattr(module, attr) if attr else module


def stage_code(spec: StageSpec) -> str:
    """The stage's code version (pipeline/codeversion.py)."""
    return code_version([impl_target(spec.impl).partition(":")[0]], spec.kernels)


def _input_digests(spec: StageSpec, chunk: Chunk, records: dict[str, dict[str, Any]],
                   stagefile: StageFile) -> dict[str, Any]:
    """What each input contributes to a chunk's key: its output digest, or for a
    ``chunk_inputs`` input the digests of the chunks of the chunk's object/materials, or
    of its twin (the chunk with the same id) where the input is chunked alike, or of its
    parent tile where the chunk splits the input's tiles by material."""
    out: dict[str, Any] = {}
    for dep in spec.inputs:
        record = records[dep]
        if dep not in spec.chunk_inputs:
            out[dep] = record.get("digest")  # None: written by an older prt, re-runs
            continue
        chunking = stagefile.stages[dep].chunks
        by = chunking.by
        wanted = ((chunk.id,) if chunking == spec.chunks else  # chunked alike: its twin
                  (chunk.get("tile"),) if chunking == spec.chunks.parent() else
                  chunk.materials if by == "material" else
                  (chunk.object,) if by == "object" and chunk.object else None)
        if wanted is None:
            raise PrtError(stagefile.path, f"stages.{spec.name}.chunk_inputs: chunk "
                           f"{chunk.id} has no {by} to select the chunks of {dep} by")
        chunk_digests = record.get("chunk_digests", {})
        out[dep] = {w: chunk_digests.get(w) for w in sorted(wanted)}
    return out


PART_DIGEST = 16  # hex digits kept of each part's digest in a chunk's record


def chunk_key_parts(code: str, schema_version: int, params: dict[str, Any],
                    sections: dict[str, Any], inputs: dict[str, Any],
                    chunk: Chunk) -> dict[str, str]:
    """``chunk``'s key part by part, each a short digest, named as ``prt status`` says
    them: ``code``, ``schema``, ``chunk extent`` (its coordinates: a tile's region, a
    batch's span), ``param NAME``, ``scene SECTION``, ``input STAGE`` (or ``input
    STAGE[NAME]`` per chunk of a ``chunk_inputs`` input, ``input STAGE[twin]`` for its
    twin chunk). Recorded with each written chunk, so that a stale chunk's record says
    which parts changed."""
    chunk_id = chunk.id
    parts = {"code": code[:PART_DIGEST], "schema": str(schema_version),
             "chunk extent": digest(chunk.coords)[:PART_DIGEST]}
    parts.update({f"param {k}": digest(v)[:PART_DIGEST] for k, v in params.items()})
    parts.update({f"scene {k}": digest(v)[:PART_DIGEST] for k, v in sections.items()})
    for dep, value in inputs.items():
        if isinstance(value, dict):
            parts.update({f"input {dep}[{'twin' if w == chunk_id else w}]":
                          digest(d)[:PART_DIGEST] for w, d in value.items()})
        else:
            parts[f"input {dep}"] = digest(value)[:PART_DIGEST]
    return parts


def plan_stage(spec: StageSpec, scene: Scene, stagefile: StageFile, workdir: Workdir,
               params_all: dict[str, Any],
               input_records: dict[str, dict[str, Any]] | None = None) -> StagePlan:
    """Chunks, keys and state of one stage whose inputs are all fresh (or, with
    ``input_records``, keyed as if its inputs had those records: pipeline/rebake_plan.py
    forecasts a stage before its inputs have run so; the chunks are planned from the
    inputs as they are)."""
    params = {k: params_all[k] for k in spec.params}
    upstream = {dep: open_artifact(workdir.artifact(dep), stagefile.stages[dep].output)
                for dep in spec.inputs}
    records = {dep: (input_records or {}).get(dep, a.record) for dep, a in upstream.items()}
    chunks = plan_chunks(spec, scene, params, upstream)
    code = stage_code(spec)
    schema_version = load_schema(spec.output).version
    p = StagePlan(spec, params, chunks=chunks)
    shared = resolve_sections(spec, scene, None) if spec.chunks.by in ("none", "block") \
        else None
    input_parts = {}
    for c in chunks:
        sections = shared if shared is not None else resolve_sections(spec, scene, c)
        p.sections[c.id] = sections
        inputs = _input_digests(spec, c, records, stagefile)
        input_parts[c.id] = inputs
        data = digest({"stage": spec.name, "params": params, "scene": sections,
                       "inputs": inputs, "chunk": c.id})
        p.seeds[c.id] = seed_from_key(data)
        # the coordinates too: a chunker whose code changed may cut the same ids anew
        p.chunk_keys[c.id] = digest({"data": data, "code": code,
                                     "schema_version": schema_version, "coords": c.coords})
        p.chunk_parts[c.id] = chunk_key_parts(code, schema_version, params, sections, inputs,
                                              c)
    p.stage_sections = resolve_sections(spec, scene, None)
    p.key = digest({"stage": spec.name, "chunks": p.chunk_keys})
    if not chunks:
        # nothing to cut (no glossy pixel in view, say): the stage's artifact still holds
        # what its finalize derives from the params, scene and inputs, so they key it
        p.key = digest({"stage": spec.name, "chunks": {}, "params": params, "code": code,
                        "schema_version": schema_version, "scene": p.stage_sections,
                        "inputs": {dep: records[dep].get("digest") for dep in spec.inputs}})
    scene_digests = {path: digest(value) for s in p.sections.values()
                     for path, value in s.items()}
    # What each input contributes over all chunks, as a set: an input every chunk reads
    # whole (the geometry under texel tiles) does not seem changed when only the number
    # of chunks did (an atlas re-sized by a camera move).
    inputs_all = {dep: digest(sorted({digest(input_parts[c.id][dep]) for c in chunks}))
                  for dep in spec.inputs}
    p.key_parts = {"stage": spec.name, "code": code, "schema_version": schema_version,
                   "params": params, "inputs": inputs_all,
                   "scene": dict(sorted(scene_digests.items())),
                   "chunks": digest([[c.id, c.coords] for c in chunks])}  # ids, extents
    p.state, p.reason = _state(workdir.artifact(spec.name), p.key, p.key_parts)
    if p.reason.startswith("incomplete") and workdir.in_use():
        p.reason = "incomplete: another prt run is writing it now"
    return p


def plan(scene: Scene, stagefile: StageFile, workdir: Workdir,
         targets: set[str] | None = None) -> list[StagePlan]:
    """Keys and states of the stages (``targets`` and their upstream; default all),
    without running anything. A stage whose inputs are not all fresh is stale, waiting
    for them; its keys are known only once they have run."""
    params_all = stage_params(stagefile, scene)
    plans: dict[str, StagePlan] = {}
    for name in topological_order(stagefile):
        if targets is not None and name not in targets:
            continue
        spec = stagefile.stages[name]
        waiting = [dep for dep in spec.inputs if plans[dep].state != "fresh"]
        if waiting:
            p = StagePlan(spec, {k: params_all[k] for k in spec.params})
            missing = read_record_or_none(workdir.artifact(name)) is None
            p.state = "missing" if missing else "stale"
            p.reason = f"waits for {', '.join(waiting)}"
        else:
            p = plan_stage(spec, scene, stagefile, workdir, params_all)
        plans[name] = p
    return list(plans.values())


def read_record_or_none(path: Path) -> dict[str, Any] | None:
    try:
        return read_record(path)
    except PrtError:
        return None


def _state(path: Path, key: str, parts: dict[str, Any]) -> tuple[str, str]:
    try:
        record = read_record(path)
    except PrtError as exc:
        return "stale", exc.problem
    if record is None:
        return "missing", "not built yet"
    if record.get("complete") is False:
        return "stale", ("incomplete: an earlier run stopped before finishing it "
                         "(interrupted or failed); the next run resumes it")
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
    from pipeline.meshio import primitive_mesh, read_mesh

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
    process while unchanged (pipeline/codeversion.py), so this costs little per chunk."""
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


def stage_context(p: StagePlan, stagefile: StageFile, workdir: Workdir) -> AssembleContext:
    """What a stage's ``layout`` and ``finalize`` see: params, every chunk's scene
    sections (a stage cut into no chunks: its declared sections, unbound), inputs."""
    sections: dict[str, Any] = {} if p.sections else dict(p.stage_sections)
    for s in p.sections.values():
        sections.update(s)
    inputs: dict[str, Artifact] = {
        dep: open_artifact(workdir.artifact(dep), stagefile.stages[dep].output)
        for dep in p.spec.inputs}
    return AssembleContext(params=p.params, scene=sections, inputs=inputs)


def stage_layout(impl: Any, ctx: AssembleContext) -> Layout:
    """The layout a stage gives its artifact (its ``layout``, else the default)."""
    return impl.layout(ctx) if hasattr(impl, "layout") else Layout()


def _run_stage(p: StagePlan, scene: Scene, stagefile: StageFile, workdir: Workdir,
               executor: Executor, progress: bool, forced: bool) -> StageRun:
    """Run the chunks of one stage that have no current record, in place, then finish
    its artifact (pipeline/chunkwrite.py)."""
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
    kept = chunkwrite.begin(workdir, path, schema, {
        "stage": name, "key": p.key, "chunk_keys": p.chunk_keys, "chunks": ids,
        "key_parts": p.key_parts}, layout.shapes, layout.sizes)
    if not kept:
        shutil.rmtree(workdir.markers(name), ignore_errors=True)
    markers = {c: chunkwrite.read_marker(workdir.marker(name, c)) for c in ids}
    todo = [c for c in p.chunks if forced or spec.chunks.by == "none"
            or (markers[c.id] or {}).get("key") != p.chunk_keys[c.id]]
    todo = longest_first(todo, (previous or {}).get("chunk_seconds") or {})
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

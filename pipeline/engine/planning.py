"""Which chunks a run computes, and why: :func:`chunks_to_run`, the one rule that
``prt run`` (pipeline/engine/runner.py), ``prt status`` and ``prt run --dry-run``
(:func:`forecast`, stage by stage before anything runs) all apply.

A chunk runs when its stage is forced, when the stage's artifact is not built, when the
stage is one chunk, when the artifact's layout changes (its region arrays' shapes or
chunk sizes: the chunks written are dropped), or when the chunk's record holds another
key than the planned one; the record's key parts (``chunk_key_parts``) name what
changed. :func:`forecast` plans a stage whose inputs are fresh as the run plans it; a
stage whose inputs will re-run is forecast by keying it as if every input chunk that
re-runs wrote new bytes: its own chunks that read one of those re-run, the others are
kept. The forecast is an upper bound: a re-run input chunk that writes the bytes it
wrote before changes nothing downstream (early cut-off), and a re-run stage whose
artifact changes shape (a new image size, another atlas) re-runs every chunk of its
dependents. Chunks are planned from the inputs as they are on disk; where an input is
not built yet, or was left incomplete, its dependents wait and every chunk of theirs is
counted.

The rules behind the counts are the stage file's declarations: a chunk's key holds the
scene sections it declares (``materials.*`` bound to the chunk's materials, ``objects.*``
to its object), the parameters it declares, and each input either whole (its output
digest) or, for ``chunk_inputs``, only the chunks of the chunk's own material or object
(or its twin chunk, for an input chunked as the stage is).

Keys (SHA-256 of canonical JSON):

* a chunk's *data key* = {stage, declared param values, declared scene sections
  resolved for the chunk, the digests of the inputs it reads, chunk id}; it seeds the
  chunk's random numbers, so a refactor that leaves the numbers alone reproduces them;
* a chunk's *key* = {data key, code version, schema version}: the code version is the
  hash of the stage module's import closure and of the kernels it uses, includes
  followed (pipeline/engine/codeversion.py);
* an input enters a chunk's key by its *output digest* (the hash of the bytes it
  wrote), not its key: when a re-run stage writes what it wrote before, its dependents
  stay fresh (early cut-off). An input listed in ``chunk_inputs`` enters only by the
  digests of the chunks the chunk reads (those of its object or materials): editing one
  material's ``gamma_range`` re-runs only the pixel tiles that see that material;
* an artifact's key = {stage, chunk keys}.

Planning reads only ``zarr.json`` files (and, for ``materials_from``, one small label
image), never the large arrays.
"""

from __future__ import annotations

import importlib
import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pipeline.engine import chunkwrite
from pipeline.engine.chunk import Chunk
from pipeline.engine.chunking import plan_chunks
from pipeline.engine.codeversion import code_version
from pipeline.engine.graph import topological_order
from pipeline.engine.keys import digest, seed_from_key
from pipeline.engine.schema import load_schema
from pipeline.engine.stage import AssembleContext, Layout
from pipeline.engine.stagefile import StageFile, StageSpec
from pipeline.engine.store import Artifact, Workdir, open_artifact, read_record
from pipeline.errors import PrtError
from pipeline.scene.model import Scene

STAGE_PACKAGE = "pipeline.stages"
PART_DIGEST = 16  # hex digits kept of each part's digest in a chunk's record
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


def stage_params(stagefile: StageFile, scene: Scene) -> dict[str, Any]:
    """Parameter defaults from stages.yaml overridden by the scene's ``settings``, with
    ``bake.device: auto`` turned into this machine's choice (pipeline/device/
    bake_tracer.py), so that keys hold what a bake used."""
    from pipeline.device.bake_tracer import PARAM, resolve

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
    params = {**stagefile.params, **scene.settings}
    if PARAM in params:
        params[PARAM] = resolve(params[PARAM], scene.path, f"settings.{PARAM}")
    return params


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
    """The stage's code version (pipeline/engine/codeversion.py)."""
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
    ``input_records``, keyed as if its inputs had those records: pipeline/engine/planning.py
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


PENDING = "pending"  # the digest of an input chunk that will re-run


@dataclass
class StageForecast:
    """What the next run does with one stage: ``rerun`` of ``total`` chunks (None: not
    known until an input is built), those chunks' ids, ``reasons`` counting the key
    parts that changed over them, ``rule`` one sentence on how the set was decided."""

    name: str
    state: str
    total: int | None
    rerun: int | None
    chunks: list[str] | None = None
    reasons: dict[str, int] = field(default_factory=dict)
    rule: str = ""


def chunks_to_run(p: StagePlan, record: dict[str, Any] | None,
                  layout: Callable[[], dict[str, Any]],
                  markers: Callable[[str], dict[str, Any] | None],
                  forced: bool = False) -> tuple[list[str], Counter[str]]:
    """The ids of the chunks of planned stage ``p`` that a run computes, in plan order,
    and the key parts that changed over them (counted). ``record`` is the artifact's
    record as it stands (None: not built), ``layout()`` the layout record the run gives
    it (pipeline/engine/chunkwrite.py ``layout_record``), ``markers(id)`` a chunk's
    record (None: not written)."""
    ids = [c.id for c in p.chunks]
    reasons: Counter[str] = Counter()
    if forced:
        reasons["forced"] = len(ids)
        return ids, reasons
    if record is None:
        reasons["not built yet"] = len(ids)
        return ids, reasons
    if p.spec.chunks.by == "none":
        reasons.update(_changed_parts(markers(ids[0]), p.chunk_parts[ids[0]]))
        return ids, reasons
    if layout() != record.get("layout"):
        reasons["artifact layout changed"] = len(ids)
        return ids, reasons
    rerun = []
    for c in ids:
        marker = markers(c)
        if marker is None or marker.get("key") != p.chunk_keys[c]:
            rerun.append(c)
            reasons.update(_changed_parts(marker, p.chunk_parts[c]))
    return rerun, reasons


def forecast(scene: Scene, stagefile: StageFile, workdir: Workdir,
             targets: set[str] | None = None) -> list[StageForecast]:
    """The forecast of every stage (``targets`` and their upstream; default all)."""
    params_all = stage_params(stagefile, scene)
    records: dict[str, dict[str, Any]] = {}  # stage -> its record as forecast
    waiting: set[str] = set()                 # stages whose chunks cannot be planned
    out = []
    for name in topological_order(stagefile):
        if targets is not None and name not in targets:
            continue
        spec = stagefile.stages[name]
        blocked = [dep for dep in spec.inputs if dep in waiting]
        why = f"waits for {', '.join(blocked)}"
        planned = None
        if not blocked:
            try:
                p = plan_stage(spec, scene, stagefile, workdir, params_all, records)
            except PrtError as exc:  # an input left incomplete: readers refuse it
                why = exc.problem
            else:
                planned, after = _forecast(p, stagefile, workdir)
                if planned.state == "missing":  # nothing on disk to plan dependents by
                    waiting.add(name)
                else:
                    records[name] = after
        if planned is None:
            waiting.add(name)
            missing = read_record_or_none(workdir.artifact(name)) is None
            planned = StageForecast(name, "missing" if missing else "stale", None, None,
                                    None, {why: 0}, "planned once its inputs are built")
        out.append(planned)
    return out


def _forecast(p: StagePlan, stagefile: StageFile, workdir: Workdir
              ) -> tuple[StageForecast, dict[str, Any]]:
    """A planned stage's forecast, and its record as it will be after the run (the
    re-run chunks' digests, and the artifact's, replaced by PENDING)."""
    name, ids = p.spec.name, [c.id for c in p.chunks]
    record = read_record_or_none(workdir.artifact(name))
    if p.state == "fresh":
        return StageForecast(name, "fresh", len(ids), 0, []), record
    rerun, reasons = chunks_to_run(p, record, lambda: _layout(p, stagefile, workdir),
                                   lambda c: chunkwrite.read_marker(workdir.marker(name, c)))
    planned = StageForecast(name, p.state, len(ids), len(rerun), list(rerun),
                             dict(reasons.most_common()), _rule(p.spec, len(rerun), len(ids)))
    after = dict(record or {})
    after["chunk_digests"] = {**(after.get("chunk_digests") or {}),
                              **{c: f"{PENDING}:{c}" for c in rerun}}
    if rerun:
        after["digest"] = f"{PENDING}:{name}"
    return planned, after


def _layout(p: StagePlan, stagefile: StageFile, workdir: Workdir) -> dict[str, Any]:
    """The layout the run will give the stage's artifact (from its inputs as they are)."""
    layout = stage_layout(load_impl(p.spec.impl), stage_context(p, stagefile, workdir))
    return chunkwrite.layout_record(load_schema(p.spec.output), layout.shapes, layout.sizes)


def _changed_parts(marker: dict[str, Any] | None, parts: dict[str, str]) -> list[str]:
    """The key parts that differ between a chunk's record and its plan."""
    if marker is None:
        return ["chunk not built yet"]
    old = marker.get("parts")
    if old is None:
        return ["key changed (chunk recorded before key parts were kept)"]
    changed = [k for k in sorted(set(old) | set(parts)) if old.get(k) != parts.get(k)]
    return [f"{k} changed" if k in parts else f"{k} removed" for k in changed] \
        or ["key changed"]


def _rule(spec: Any, rerun: int, total: int) -> str:
    """How the stage's re-run set is decided, from its declarations."""
    if spec.chunks.by == "none":
        return "a single chunk"
    whole = [d for d in spec.inputs if d not in spec.chunk_inputs]
    if rerun == total and whole:
        return f"chunks by {spec.chunks.by}; each reads all of {', '.join(whole)}"
    own = [s for s in spec.scene if ".*." in s] + list(spec.chunk_inputs)
    if own:
        return (f"chunks by {spec.chunks.by}; each keyed by its own materials' or "
                f"object's sections{' and input chunks' if spec.chunk_inputs else ''}")
    return f"chunks by {spec.chunks.by}"

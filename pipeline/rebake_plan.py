"""What the next run will re-bake, stage by stage and chunk by chunk, and why, before
anything runs: ``prt status`` and ``prt run --dry-run``.

A stage whose inputs are fresh is planned as the run plans it (pipeline/runner.py): a
chunk re-runs when its record's key differs from the planned one, and the record's key
parts (``chunk_key_parts``) name what changed. A stage whose inputs will re-run is
forecast by keying it as if every input chunk that re-runs wrote new bytes: its own
chunks that read one of those re-run, the others are kept. The forecast is an upper
bound: a re-run input chunk that writes the bytes it wrote before changes nothing
downstream (early cut-off), and a re-run stage whose artifact changes shape (a new
image size, another atlas) re-runs every chunk of its dependents. Chunks are planned
from the inputs as they are on disk; where an input is not built yet, or was left
incomplete, its dependents wait and every chunk of theirs is counted.

The rules behind the counts are the stage file's declarations: a chunk's key holds the
scene sections it declares (``materials.*`` bound to the chunk's materials, ``objects.*``
to its object), the parameters it declares, and each input either whole (its output
digest) or, for ``chunk_inputs``, only the chunks of the chunk's own material or object
(or its twin chunk, for an input chunked as the stage is).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any

from pipeline import chunkwrite
from pipeline.errors import PrtError
from pipeline.graph import topological_order
from pipeline.runner import plan_stage, read_record_or_none, stage_params
from pipeline.scene import Scene
from pipeline.stagefile import StageFile
from pipeline.store import Workdir

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


def rebake_plan(scene: Scene, stagefile: StageFile, workdir: Workdir,
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
        forecast = None
        if not blocked:
            try:
                p = plan_stage(spec, scene, stagefile, workdir, params_all, records)
            except PrtError as exc:  # an input left incomplete: readers refuse it
                why = exc.problem
            else:
                forecast, after = _forecast(p, stagefile, workdir)
                if forecast.state == "missing":  # nothing on disk to plan dependents by
                    waiting.add(name)
                else:
                    records[name] = after
        if forecast is None:
            waiting.add(name)
            missing = read_record_or_none(workdir.artifact(name)) is None
            forecast = StageForecast(name, "missing" if missing else "stale", None, None,
                                     None, {why: 0}, "planned once its inputs are built")
        out.append(forecast)
    return out


def _forecast(p: Any, stagefile: StageFile, workdir: Workdir
              ) -> tuple[StageForecast, dict[str, Any]]:
    """A planned stage's forecast, and its record as it will be after the run (the
    re-run chunks' digests, and the artifact's, replaced by PENDING)."""
    name, ids = p.spec.name, [c.id for c in p.chunks]
    record = read_record_or_none(workdir.artifact(name))
    if p.state == "fresh":
        return StageForecast(name, "fresh", len(ids), 0, []), record
    reasons: Counter[str] = Counter()
    if record is None:
        rerun, reasons["not built yet"] = ids, len(ids)
    elif p.spec.chunks.by == "none":
        rerun = ids
        reasons.update(_changed_parts(chunkwrite.read_marker(workdir.marker(name, ids[0])),
                                      p.chunk_parts[ids[0]]))
    elif _layout(p, stagefile, workdir) != record.get("layout"):
        rerun, reasons["artifact layout changed"] = ids, len(ids)
    else:
        rerun = []
        for c in ids:
            marker = chunkwrite.read_marker(workdir.marker(name, c))
            if marker is None or marker.get("key") != p.chunk_keys[c]:
                rerun.append(c)
                reasons.update(_changed_parts(marker, p.chunk_parts[c]))
    forecast = StageForecast(name, p.state, len(ids), len(rerun), list(rerun),
                             dict(reasons.most_common()), _rule(p.spec, len(rerun), len(ids)))
    after = dict(record or {})
    after["chunk_digests"] = {**(after.get("chunk_digests") or {}),
                              **{c: f"{PENDING}:{c}" for c in rerun}}
    if rerun:
        after["digest"] = f"{PENDING}:{name}"
    return forecast, after


def _layout(p: Any, stagefile: StageFile, workdir: Workdir) -> dict[str, Any]:
    """The layout the run will give the stage's artifact (from its inputs as they are)."""
    from pipeline.runner import load_impl, stage_context, stage_layout
    from pipeline.schema import load_schema

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

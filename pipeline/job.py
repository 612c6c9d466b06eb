"""What the CLI commands do: bake, report status, render frames, inspect and clean.

Each function here is one floor-4 entry that a CLI command calls; it wires scenes,
the runner, the method registry (pipeline/method.py) and the renderers together and
returns plain results for the CLI to print. No method is named here.
"""

from __future__ import annotations

import functools
import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.engine.codeversion import code_version
from pipeline.engine.executors import make_executor
from pipeline.engine.keys import digest
from pipeline.engine.planning import StagePlan, plan
from pipeline.engine.runner import StageRun, run
from pipeline.engine.stagefile import StageFile, load_stagefile
from pipeline.engine.store import Artifact, Workdir, open_artifact, read_record
from pipeline.errors import PrtError
from pipeline.method import Method, resolve
from pipeline.registry import get_method, limit_warnings, scene_methods, stagefile_fragments
from pipeline.render import Frame, Renderer
from pipeline.scene.file import default_scene_path, load_scene
from pipeline.scene.model import Scene


def open_scene(path: str | Path | None, size: tuple[int, int] | None = None,
               bake_device: str | None = None) -> Scene:
    """The scene at ``path`` (default: the embedded Cornell box), optionally resized, and
    with ``bake_device`` (``--bake-device``: auto, device or embree) as its
    ``bake.device`` setting if given (pipeline/device/bake_tracer.py)."""
    from pipeline.device.bake_tracer import PARAM

    scene = load_scene(path or default_scene_path())
    if bake_device is not None:
        scene = scene.with_settings({PARAM: bake_device})
    return scene.with_image_size(*size) if size else scene


def workdir_for(scene: Scene, workdir: str | Path | None,
                stagefile: str | Path | None = None) -> Workdir:
    """``workdir`` or the default ``./.prt/<scene name>``. A scene resized at run time
    (``--size``, :attr:`Scene.view`) keeps its camera-dependent artifacts (those of the
    stage graph, ``stagefile`` or the project's) under ``views/<W>x<H>/`` there, and one
    lit by another map (``--env``, :attr:`Scene.environment_view`) its
    environment-dependent ones under ``views/env-<map>/``, so that a preview never
    replaces the bake of the scene file."""
    from pipeline.engine.graph import dependent_on

    root = workdir or Path(".prt") / scene.name
    views = [(name, section) for name, section in ((scene.view, "camera"),
                                                   (scene.environment_view, "environment"))
             if name is not None]
    if not views:
        return Workdir(root)
    graph = stages(stagefile)
    return Workdir(root, [(name, dependent_on(graph, section)) for name, section in views])


def bake_scene(method: Method, scene: Scene, file_scene: Scene) -> Scene:
    """The scene whose bake ``method`` renders ``scene``'s frames from (``file_scene``:
    the scene file as opened, before ``--size`` and the run-time edits). A method that
    follows the camera at run time (``camera`` among its edits: triple, sg) traces each
    frame's camera itself, so it renders any camera, moved (``--camera``) or resized
    (``--size``), from the bake of the file's camera: nothing is re-baked, and where
    that bake is too coarse for the frame its limits say so (decision 0045). Any other
    method bakes for the camera it renders (``scene`` itself)."""
    camera = file_scene.document["camera"]
    if "camera" not in method.edits or (scene.document["camera"] == camera
                                        and scene.resized_from is None):
        return scene
    return scene.edited("camera", camera, resized_from=None)


def resize_note(method: Method, scene: Scene, baked_for: Scene) -> str | None:
    """A note when ``method`` renders ``scene`` at another image size than the bake it
    reads was made for (:func:`bake_scene`) and some of what it reads depends on the
    camera (triple's atlas; sg reads nothing of it), else None."""
    from pipeline.engine.graph import dependent_on

    cam, base = scene.camera, baked_for.camera
    if (cam.width, cam.height) == (base.width, base.height):
        return None
    graph = stages()
    reads = sorted(set(method.reads) & dependent_on(graph, "camera"))
    if not reads:
        return None
    return (f"method {method.name} renders {cam.width}x{cam.height} from the "
            f"{', '.join(reads)} baked for the scene file's {base.width}x{base.height} "
            "camera (it traces the camera at run time; --size re-bakes nothing, "
            "decision 0045)")


def stages(stagefile: str | Path | None = None) -> StageFile:
    """The stage graph: ``stagefile`` alone (a custom graph), or the project's
    stages.yaml merged with the plug-ins' own stage files."""
    if stagefile is not None:
        return load_stagefile(stagefile)
    return load_stagefile(None, stagefile_fragments())


def baked_stages(scene: Scene, methods: list[Method] | None = None,
                 options: dict[str, Any] | None = None) -> set[str]:
    """The stages whose artifacts the frames of ``methods`` (default: the scene's) read
    with run-time ``options`` (parsed values; default: each option's default)."""
    methods = scene_methods(scene) if methods is None else methods
    return {name for m in methods for name in m.reads_for(options)}


def bake(scene: Scene, workdir: Workdir, until: str | tuple[str, ...] | None = None,
         force: tuple[str, ...] = (), jobs: int | None = None, quiet: bool = False,
         stagefile: str | Path | None = None,
         methods: list[Method] | None = None, threads: int | None = None,
         scheduler: str | None = None, options: dict[str, Any] | None = None
         ) -> list[StageRun]:
    """Run every stale stage that the scene's methods (or ``methods``) need for frames
    with run-time ``options`` (default: the defaults), or those
    ``until`` needs; a custom ``stagefile`` runs all of its stages. Chunks run on
    ``jobs`` worker processes (1: in this process) with ``threads`` threads each; either
    None: pipeline/engine/executors/local.py ``Cores.resolve`` (``$PRT_JOBS``,
    ``$PRT_THREADS``, else
    chosen from the available cores); or, with ``scheduler`` (a dask scheduler's
    address or ``local:N``), on a dask cluster's workers (pipeline/engine/executors/dask.py).
    The artifacts do not depend on any of these."""
    graph = stages(stagefile)
    targets = None if until or stagefile else baked_stages(scene, methods, options)
    with make_executor(jobs, threads, scheduler, quiet) as executor:
        return run(scene, graph, workdir, until=until, force=force, executor=executor,
                   progress=not quiet, targets=targets)


def tolerance_warnings(report: list[StageRun]) -> list[str]:
    """One line per budget a stage of ``report`` chose from a tolerance it did not reach
    (pipeline/engine/tolerance.py), whether the stage ran now or was fresh."""
    from pipeline.engine.tolerance import unmet, warning

    return [warning(r.name, t) for r in report for t in unmet({"tolerances": r.tolerances})]


def status(scene: Scene, workdir: Workdir, stagefile: str | Path | None = None
           ) -> list[StagePlan]:
    """The state (fresh, stale or missing) of every stage the scene's methods need (a
    custom ``stagefile``: all of its stages) and why, without running anything."""
    graph = stages(stagefile)
    return plan(scene, graph, workdir, _planned_stages(scene, graph, stagefile))


def rebake_forecast(scene: Scene, workdir: Workdir, stagefile: str | Path | None = None,
                    until: str | tuple[str, ...] | None = None) -> list[Any]:
    """What the next ``prt run`` (``until``: ``--until``) will re-bake, stage by stage,
    with chunk counts and reasons (pipeline/engine/planning.py), without running anything."""
    from pipeline.engine.planning import forecast

    graph = stages(stagefile)
    return forecast(scene, graph, workdir, _planned_stages(scene, graph, stagefile, until))


def _planned_stages(scene: Scene, graph: StageFile, stagefile: str | Path | None,
                    until: str | tuple[str, ...] | None = None) -> set[str] | None:
    """The stages ``prt status`` and a dry run plan: ``until`` (``--until``) and their
    upstream, else those the scene's methods read and their upstream; None (all) for a
    custom ``stagefile`` without ``until``."""
    from pipeline.engine.graph import with_upstream

    if isinstance(until, str):
        until = (until,)
    wanted = list(until) if until else None if stagefile else sorted(baked_stages(scene))
    return None if wanted is None else with_upstream(graph, wanted)


def chunk_progress(workdir: Workdir, stage: str) -> tuple[int, int] | None:
    """(chunks written, chunks planned) of a stage whose artifact is incomplete (a run
    was interrupted, or is running): the chunk markers that carry the key the record
    planned for them (pipeline/engine/chunkwrite.py). None when the artifact is complete or
    absent."""
    from pipeline.engine.chunkwrite import read_marker

    try:
        record = read_record(workdir.artifact(stage))
    except PrtError:
        return None
    if record is None or record.get("complete") is not False:
        return None
    keys = record.get("chunk_keys", {})
    done = sum((read_marker(workdir.marker(stage, c)) or {}).get("key") == keys.get(c)
               for c in record.get("chunks", []))
    return done, len(record.get("chunks", []))


def method_artifacts(method: Method, workdir: Workdir,
                     options: dict[str, Any] | None = None) -> dict[str, Artifact]:
    """The opened artifacts a method's frames with run-time ``options`` read, by stage
    name; PrtError naming the stage and the command that bakes it where one is not
    baked (an option that reads more than the bake's)."""
    graph = stages()
    wanted = method.reads_for(options)
    for name in wanted:
        if read_record(workdir.artifact(name)) is None:
            raise PrtError(workdir.artifact(name), f"not baked: method {method.name}'s "
                           f"frames with these options read stage {name} (prt render with "
                           "the same --option bakes it)")
    return {name: open_artifact(workdir.artifact(name), graph.stages[name].output)
            for name in wanted}


def frame_key(scene: Scene, workdir: Workdir, method: Method,
              options: dict[str, Any]) -> str:
    """What a frame depends on: the method, its renderer's code (import closure and
    kernels), the output digests of exactly the artifacts it reads, the camera, lights
    and materials, and the run-time options."""
    digests = {name: (read_record(workdir.artifact(name)) or {}).get("digest")
               for name in method.reads_for(options)}
    return digest({"method": method.name, "code": code_version([method.renderer_module()]),
                   "artifacts": digests, "options": options,
                   "scene": {s: scene.section(s) for s in ("camera", "lights", "materials")}})


@dataclass
class RenderResult:
    """A rendered (or already up-to-date) frame and where it was written."""

    exr: Path
    png: Path
    frame: Frame | None  # None when the frame on disk was already up to date
    baked: list[StageRun]
    warnings: list[str] = field(default_factory=list)  # the method's limits, at render time


def render(scene: Scene, workdir: Workdir, method: str, out: Path, jobs: int | None = None,
           quiet: bool = False, reuse: bool = False,
           options: dict[str, Any] | None = None, threads: int | None = None,
           exposure: float = 0.0,
           renderer_of: Callable[[], Renderer] | None = None,
           baked: list[StageRun] | None = None) -> RenderResult:
    """Bake what ``method`` needs (``jobs``, ``threads``: as for :func:`bake`), render
    one frame, write ``out`` (linear EXR), a PNG preview beside it (× 2^``exposure``,
    in stops; the EXR is never scaled) and its record ``out.json`` (see
    :func:`output_state`).

    With ``reuse``, a frame whose inputs (see :func:`frame_key`) are unchanged since it
    was written, and whose files are as written, is not rendered again.
    ``renderer_of``: where the renderer comes from (:func:`shared_renderer`, built with
    the same ``options``); default: one built for this frame. ``baked``: the report of
    the bake the caller has just run for this method (nothing is planned again); None:
    bake first."""
    from pipeline.images import check_writable, exposure_note
    from pipeline.registry import check_method_scene

    m = get_method(method)
    if out.suffix.lower() != ".exr":
        raise PrtError(out, "output must be an .exr file")
    check_method_scene(m, scene)
    check_writable(out)
    options = m.option_values({}) | (options or {})
    check_device()
    if baked is None:
        baked = bake(scene, workdir, jobs=jobs, quiet=quiet, methods=[m], threads=threads,
                     options=options)
    png, meta = out.with_suffix(".png"), out.with_suffix(".json")
    key = frame_key(scene, workdir, m, options)
    warnings = limit_warnings(m, scene, method_artifacts(m, workdir, options))
    if reuse and output_state(meta, key, exposure)[0] == "present":
        return RenderResult(out, png, None, baked, warnings)
    renderer = (renderer_of or shared_renderer(scene, workdir, method, options))()
    frame = checked_frame(renderer.frame(scene), out)
    write_frame(out, frame.rgb, exposure)
    dark = exposure_note(frame.rgb, exposure)
    if dark:
        frame.notes.append(dark)
    write_output_record(meta, key, [out, png], {"method": method, "exposure": exposure,
                                                **frame.timings})
    return RenderResult(out, png, frame, baked, warnings)


def write_frame(out: Path, rgb: np.ndarray, exposure: float) -> None:
    """``out`` (linear EXR) and its PNG preview × 2^``exposure`` (stops)."""
    from pipeline.images import write_exr, write_png

    write_exr(out, rgb)
    write_png(out.with_suffix(".png"), rgb, 2.0 ** exposure)


def write_output_record(record: Path, key: str, files: list[Path],
                        extra: dict[str, Any]) -> None:
    """The record of written frames: their key and every file's SHA-256 (by name, files
    beside the record), written last so that a run killed earlier leaves none."""
    from pipeline.scene.model import file_hash

    body = {"key": key, **extra, "files": {p.name: file_hash(p) for p in files}}
    tmp = record.with_name(f".{record.name}.tmp")
    tmp.write_text(json.dumps(body, indent=1))
    tmp.replace(record)


def output_state(record: Path, key: str, exposure: float | None = None
                 ) -> tuple[str, str]:
    """The state of the frames a record lists: ``("present", "")`` when the record's
    key is ``key`` (and its previews' exposure ``exposure``, unless None) and every file
    is there with the bytes it was written with; ``("missing", why)`` when the record or
    a file is absent; ``("stale", why)`` when the inputs changed or a file changed on
    disk (truncated, overwritten)."""
    from pipeline.scene.model import file_hash

    try:
        body = json.loads(record.read_text())
        files = dict(body["files"])
    except (OSError, ValueError, KeyError, TypeError):
        return "missing", "not rendered yet"
    lost = [name for name in files if not (record.parent / name).is_file()]
    if lost:
        return "missing", f"{len(lost)} of {len(files)} files missing ({lost[0]})"
    if body.get("key") != key:
        return "stale", "its inputs changed"
    if exposure is not None and body.get("exposure") != exposure:
        return "stale", f"preview exposure {body.get('exposure')} -> {exposure} EV"
    changed = [n for n, d in files.items() if file_hash(record.parent / n) != d]
    if changed:
        return "stale", f"{len(changed)} file(s) changed on disk ({changed[0]})"
    return "present", ""


def checked_frame(frame: Frame, out: Path) -> Frame:
    """``frame``, or PrtError naming ``out`` if any pixel is NaN or Inf (never a silent
    image)."""
    bad = int(frame.rgb.size - np.isfinite(frame.rgb).sum())
    if bad:
        raise PrtError(out, f"method {frame.method} rendered {bad} NaN or Inf values; "
                       "frame not written")
    return frame


def frame_renderer(scene: Scene, workdir: Workdir, method: str,
                   options: dict[str, Any] | None = None) -> Renderer:
    """A renderer of ``method``'s frames from the (already baked) artifacts in
    ``workdir``, loaded once; ``options`` are the method's run-time options, those not
    given at their declared defaults (what ``prt render`` renders). PrtError if what the
    method's factory gives is not a :class:`Renderer`."""
    m = get_method(method)
    options = m.option_values({}) | (options or {})
    renderer = resolve(m.renderer)(scene, method_artifacts(m, workdir, options), **options)
    if not isinstance(renderer, Renderer):
        raise PrtError(m.renderer, f"method {m.name}'s renderer has no frame(scene) and "
                       "edit_mode(kind, scene) (pipeline/render/__init__.py Renderer)")
    return renderer


def shared_renderer(scene: Scene, workdir: Workdir, method: str,
                    options: dict[str, Any] | None = None
                    ) -> Callable[[], Renderer]:
    """A factory of ``method``'s renderer (:func:`frame_renderer`) that builds it on
    its first call and returns the same one after: the frame and the sequences of one
    command share the artifacts it loaded (seconds on a large bake), and a command whose
    outputs are all up to date builds none. Sharing is safe because each call of a
    renderer renders from the scene it is given, and an edit mode sets up its own state
    on entry."""
    return functools.cache(lambda: frame_renderer(scene, workdir, method, options))


def render_frame(scene: Scene, workdir: Workdir, method: str,
                 options: dict[str, Any] | None = None) -> Frame:
    """One frame of ``method`` (see ``frame_renderer``)."""
    return frame_renderer(scene, workdir, method, options).frame(scene)


@dataclass
class SequencePlan:
    """A sequence of edits resolved against the baked artifacts: what ``prt run`` and
    ``prt render --frames`` write, and where its record lies."""

    spec: str
    kind: str
    scenes: list[Scene]
    edits: list[str]
    description: str
    exr: list[Path]
    record: Path
    key: str


@dataclass
class SequenceResult:
    """A sequence's frames (EXR files, PNG previews beside them), per-frame timings (none
    when it was up to date), the edit each frame shows and the path of the edit.
    ``skipped``: why a main sequence does not apply to the scene (no frames then)."""

    kind: str
    exr: list[Path]
    timings: list[dict[str, float]]
    edits: list[str]
    description: str = ""
    rendered: bool = True
    skipped: str = ""
    warnings: list[str] = field(default_factory=list)  # the method's limits, any frame's


def plan_sequence(scene: Scene, workdir: Workdir, method: str, spec: str, out: Path,
                  options: dict[str, Any] | None = None) -> SequencePlan:
    """Resolve ``spec`` (as the method's sequences read it) against the baked artifacts:
    frames ``out`` with the suffix ``_<kind>_<i>`` (EXR + PNG), record
    ``<out>_<kind>.json``. Raises PrtError (pipeline.method.NotApplicable when the scene
    has nothing the sequence edits) before anything is written."""
    m = get_method(method)
    if m.sequences is None:
        raise PrtError(None, f"--frames: method {method} has no edit sequences")
    options = m.option_values({}) | (options or {})
    kind, scenes, edits, *rest = resolve(m.sequences)(scene,
                                                      method_artifacts(m, workdir, options),
                                                      spec)
    exr = [out.with_name(f"{out.stem}_{kind}_{i:04d}.exr") for i in range(len(scenes))]
    key = digest({"frame": frame_key(scene, workdir, m, options), "spec": spec,
                  "edits": edits})
    return SequencePlan(spec, kind, scenes, edits, rest[0] if rest else "", exr,
                        sequence_record(out, kind), key)


def sequence_record(out: Path, kind: str) -> Path:
    """The record of the ``kind`` sequence (a sequence spec's head) beside frame ``out``."""
    return out.with_name(f"{out.stem}_{kind}.json")


def render_sequence(scene: Scene, workdir: Workdir, method: str, spec: str, out: Path,
                    options: dict[str, Any] | None = None, exposure: float = 0.0,
                    reuse: bool = False, plan: SequencePlan | None = None,
                    renderer_of: Callable[[], Renderer] | None = None
                    ) -> SequenceResult:
    """Render a sequence of edits (see :func:`plan_sequence`; ``plan`` if already made)
    from the baked artifacts, PNG previews × 2^``exposure``. A renderer with an
    ``edit_mode`` renders the sequence in that faster mode. With ``reuse``, a sequence
    whose record says its frames are present (:func:`output_state`) is not rendered
    again. ``renderer_of``: as for :func:`render`."""
    m = get_method(method)
    options = m.option_values({}) | (options or {})
    plan = plan or plan_sequence(scene, workdir, method, spec, out, options)
    artifacts = method_artifacts(m, workdir, options)
    warnings = list(dict.fromkeys(w for edited in plan.scenes
                                  for w in limit_warnings(m, edited, artifacts)))
    if reuse and output_state(plan.record, plan.key, exposure)[0] == "present":
        return SequenceResult(plan.kind, plan.exr, [], plan.edits, plan.description, False,
                              warnings=warnings)
    renderer = (renderer_of or shared_renderer(scene, workdir, method, options))()
    frame_of = renderer.edit_mode(plan.kind, scene)
    plan.record.unlink(missing_ok=True)
    timings = []
    for path, edited in zip(plan.exr, plan.scenes, strict=True):
        frame = checked_frame(frame_of(edited), path)
        write_frame(path, frame.rgb, exposure)
        timings.append(frame.timings)
    write_output_record(plan.record, plan.key,
                        [p for e in plan.exr for p in (e, e.with_suffix(".png"))],
                        {"method": method, "exposure": exposure, "spec": spec,
                         "edits": plan.edits, "path": plan.description})
    return SequenceResult(plan.kind, plan.exr, timings, plan.edits, plan.description,
                          warnings=warnings)


def main_frame_path(scene: Scene, method: Method, frames: Path) -> Path:
    """Where ``prt run`` writes the frame of ``method``: ``<frames>/<scene>_<method>.exr``,
    with ``_<W>x<H>`` added for a scene resized at run time (``--size``)."""
    view = f"_{scene.view}" if scene.view else ""
    return frames / f"{scene.name}_{method.name}{view}.exr"


def check_device() -> None:
    """Choose the OpenCL device now (pipeline/device/devices.py): where none works, one error
    line says so before any bake, not a traceback from the first kernel's chunk."""
    from pipeline.device import cl

    cl.device()


def main_job(scene: Scene, workdir: Workdir, frames: Path,
             until: str | tuple[str, ...] | None,
             force: tuple[str, ...], jobs: int | None, quiet: bool,
             stagefile: str | Path | None = None, threads: int | None = None,
             exposure: float = 0.0, scheduler: str | None = None
             ) -> tuple[list[StageRun], RenderResult | None, list[SequenceResult]]:
    """``prt run``: bake every stale stage of the scene's methods, then (unless
    ``until``, or with a custom stage file) bring the frame of the scene's first method
    and each of its main edit sequences in ``frames`` up to date: every frame missing,
    changed on disk or stale is rendered again. A main sequence that does not apply to
    the scene (pipeline.method.NotApplicable: e.g. no light that can move) is skipped,
    saying why, before any frame is written. ``scheduler``: bake on a dask cluster
    (``bake``); frames are rendered here."""
    from pipeline.method import NotApplicable

    check_device()
    report = bake(scene, workdir, until=until, force=force,
                  jobs=None if scheduler else jobs, quiet=quiet, stagefile=stagefile,
                  threads=threads, scheduler=scheduler)
    if until or stagefile:
        return report, None, []
    method = scene_methods(scene)[0]
    out = main_frame_path(scene, method, frames)
    plans: list[SequencePlan | SequenceResult] = []
    for spec in method.main_sequences:
        try:
            plans.append(plan_sequence(scene, workdir, method.name, spec, out))
        except NotApplicable as exc:
            plans.append(SequenceResult(spec.partition(":")[0], [], [], [],
                                        skipped=exc.problem))
    renderer_of = shared_renderer(scene, workdir, method.name, method.option_values({}))
    result = render(scene, workdir, method.name, out, quiet=quiet, reuse=True,
                    exposure=exposure, renderer_of=renderer_of, baked=report)
    sequences = [p if isinstance(p, SequenceResult) else
                 render_sequence(scene, workdir, method.name, p.spec, out, None, exposure,
                                 reuse=True, plan=p, renderer_of=renderer_of) for p in plans]
    return report, result, sequences


@dataclass
class OutputState:
    """One output ``prt run`` owns (its frame, or a sequence) and its state: present,
    missing, stale, or skipped (a sequence that does not apply to the scene)."""

    name: str
    path: Path
    state: str
    reason: str


def frame_states(scene: Scene, workdir: Workdir, frames: Path,
                 plans: list[StagePlan]) -> list[OutputState]:
    """The state of the frame and the main sequences ``prt run`` writes into ``frames``
    (``plans``: the stages' states, see :func:`status`), without rendering anything."""
    from pipeline.method import NotApplicable

    method = scene_methods(scene)[0]
    out = main_frame_path(scene, method, frames)
    waiting = sorted(p.spec.name for p in plans
                     if p.state != "fresh" and p.spec.name in method.reads_for())
    names = ["frame", *(f"sequence {spec}" for spec in method.main_sequences)]
    if waiting:
        # without the artifacts there is no key to compare with
        paths = [out, *(sequence_record(out, spec.partition(":")[0])
                        for spec in method.main_sequences)]
        return [OutputState(n, path, "stale" if path.is_file() else "missing",
                            f"waits for {', '.join(waiting)}")
                for n, path in zip(names, paths, strict=True)]
    options = method.option_values({})
    key = frame_key(scene, workdir, method, options)
    states = [OutputState("frame", out, *output_state(out.with_suffix(".json"), key))]
    for spec in method.main_sequences:
        try:
            p = plan_sequence(scene, workdir, method.name, spec, out, options)
        except NotApplicable as exc:
            states.append(OutputState(f"sequence {spec}", out, "skipped", exc.problem))
            continue
        state, reason = output_state(p.record, p.key)
        states.append(OutputState(f"sequence {spec}", p.exr[0], state, reason))
    return states


def load_geometry(scene: Scene, workdir: Workdir, quiet: bool = True) -> tuple[dict, str]:
    """Bake the geometry stage if stale; its arrays and names as a dict, and its output
    digest (the hash of its bytes: unchanged by a code edit that leaves them alone)."""
    bake(scene, workdir, until="geometry", quiet=quiet)
    artifact = open_artifact(workdir.artifact("geometry"), "geometry")
    arrays: dict[str, Any] = {n: artifact.read(n) for n in artifact.names}
    arrays["object_names"] = artifact.attrs["object_names"]
    arrays["material_names"] = artifact.attrs["material_names"]
    return arrays, artifact.record["digest"]


def clean(workdir: Workdir) -> int:
    """Delete a work directory; returns the bytes freed. PrtError if there is none."""
    root = workdir.root
    if not root.is_dir():
        raise PrtError(root, "no such work directory; nothing to remove")
    if not (root / ".lock").exists() and not any(root.glob("*.zarr")):
        raise PrtError(root, "does not look like a prt work directory; not deleting it")
    freed = sum(p.stat().st_size for p in root.rglob("*") if p.is_file())
    with workdir.lock():
        for child in root.iterdir():
            if child.name != ".lock":
                shutil.rmtree(child) if child.is_dir() else child.unlink()
    (root / ".lock").unlink(missing_ok=True)
    return freed


def inspect_artifact(path: Path) -> dict[str, Any]:
    """Schema kind and version, and per array its shape, dtype, chunks, stored bytes and
    statistics (min, max, mean over finite values; NaN count). A segmented array (one
    piece per chunk) reports its pieces and the zarr chunks of the largest."""
    path = Path(path)
    artifact = open_artifact(path)
    arrays = {}
    for name in artifact.names:
        pieces = artifact.pieces(name) if artifact.is_segmented(name) else None
        arr = max(pieces, key=lambda p: p.shape[0]) if pieces else artifact.array(name)
        data = artifact.read(name)
        stored = sum(p.stat().st_size for p in (path / name).rglob("*") if p.is_file())
        numeric = data.astype(np.float64) if data.size else np.zeros(1)
        finite = numeric[np.isfinite(numeric)]
        arrays[name] = {
            "shape": list(data.shape), "dtype": str(data.dtype), "chunks": list(arr.chunks),
            "pieces": None if pieces is None else len(pieces),
            "dims": list(arr.metadata.dimension_names or []),
            "stored_bytes": stored, "bytes": int(data.nbytes),
            "compression_ratio": round(data.nbytes / stored, 2) if stored else None,
            "min": float(finite.min()) if finite.size else None,
            "max": float(finite.max()) if finite.size else None,
            "mean": float(finite.mean()) if finite.size else None,
            "nan_count": int(np.isnan(numeric).sum()) if data.size else 0,
        }
    record = artifact.record
    return {"path": str(path), "kind": record.get("kind"),
            "schema_version": record.get("schema_version"), "stage": record.get("stage"),
            "key": record.get("key"), "seconds": record.get("seconds"),
            "software": record.get("software"), "arrays": arrays,
            "tolerances": record.get("tolerances", [])}


def is_workdir(path: Path) -> bool:
    """Whether ``path`` is a work directory (a folder of artifacts), not one artifact."""
    path = Path(path)
    return path.is_dir() and not (path / "zarr.json").exists()


def inspect_workdir(root: Path) -> dict[str, Any]:
    """A summary of every artifact under ``root`` (nested work directories, such as
    evaluate's sweeps and the reference cache, included), from the provenance records
    and file sizes only: kind, stage, complete or partial (chunks written / planned),
    stored bytes, seconds, the tolerance results (pipeline/engine/tolerance.py) and a warning
    per tolerance not reached."""
    from pipeline.engine.tolerance import unmet, warning

    root = Path(root)
    if not root.is_dir():
        raise PrtError(root, "no such work directory")
    rows = []
    for path in _artifact_folders(root):
        row: dict[str, Any] = {"artifact": str(path.relative_to(root)),
                               "stored_bytes": _bytes_under(path)}
        try:
            record = read_record(path) or {}
        except PrtError as exc:
            rows.append({**row, "state": "unreadable", "problem": exc.problem,
                         "warnings": [f"{row['artifact']}: {exc.problem}"]})
            continue
        stage = record.get("stage") or path.stem
        chunks = record.get("chunks")
        progress = chunk_progress(Workdir(path.parent), stage) \
            if record.get("complete") is False else None
        rows.append({**row, "kind": record.get("kind"),
                     "schema_version": record.get("schema_version"), "stage": stage,
                     "state": "complete" if progress is None else "partial",
                     "chunks": None if chunks is None else len(chunks),
                     "chunks_done": None if chunks is None else
                     (len(chunks) if progress is None else progress[0]),
                     "seconds": record.get("seconds"),
                     "tolerances": record.get("tolerances", []),
                     "warnings": [warning(stage, t) for t in unmet(record)]})
    if not rows:
        raise PrtError(root, "holds no prt artifacts")
    return {"path": str(root), "stored_bytes": sum(r["stored_bytes"] for r in rows),
            "artifacts": rows}


def _artifact_folders(root: Path) -> list[Path]:
    """Every ``*.zarr`` group under ``root`` (not inside another, nor in a hidden
    folder such as ``.tmp``)."""
    found, todo = [], [root]
    while todo:
        folder = todo.pop()
        for child in sorted(folder.iterdir()):
            if not child.is_dir() or child.name.startswith("."):  # .tmp, .chunks
                continue
            if child.suffix == ".zarr" and (child / "zarr.json").is_file():
                found.append(child)
            else:
                todo.append(child)
    return sorted(found, key=lambda p: (len(p.relative_to(root).parts), str(p)))


def _bytes_under(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


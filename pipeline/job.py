"""What the CLI commands do: bake, report status, render frames, inspect and clean.

Each function here is one floor-4 entry that a CLI command calls; it wires scenes,
the runner and the renderers together and returns plain results for the CLI to print.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.errors import PrtError
from pipeline.executors import make_executor
from pipeline.keys import digest, module_source_hash
from pipeline.render import Frame
from pipeline.runner import StagePlan, StageRun, plan, run
from pipeline.scene import Scene, default_scene_path, load_scene
from pipeline.stagefile import load_stagefile
from pipeline.store import Workdir

# Rendering methods: name -> (module, function, the stage whose artifact it needs).
# method -> (module, its renderer factory (scene, workdir, **options) -> frame function,
# the last stage it needs)
METHODS = {"direct": ("pipeline.render.direct", "direct_renderer", "gbuffer"),
           "d2i": ("pipeline.render.d2i", "d2i_renderer", "haar")}
# What `prt run` renders after baking: one frame of this method, and these sequences.
MAIN_METHOD = "d2i"
MAIN_SEQUENCES = ("light:8", "gamma:8")
# The artifacts each method's frame reads (its run-time storage).
METHOD_READS = {"direct": ("geometry", "gbuffer"),
                "d2i": ("geometry", "gbuffer", "gather", "brdf_basis", "haar")}


def open_scene(path: str | Path | None, size: tuple[int, int] | None = None) -> Scene:
    """The scene at ``path`` (default: the embedded Cornell box), optionally resized."""
    scene = load_scene(path or default_scene_path())
    return scene.with_image_size(*size) if size else scene


def workdir_for(scene: Scene, workdir: str | Path | None) -> Workdir:
    """``workdir`` or the default ``./.prt/<scene name>``."""
    return Workdir(workdir or Path(".prt") / scene.name)


def bake(scene: Scene, workdir: Workdir, until: str | None = None,
         force: tuple[str, ...] = (), jobs: int = 1, quiet: bool = False,
         stagefile: str | Path | None = None) -> list[StageRun]:
    """Run every stale stage (or those ``until`` needs)."""
    return run(scene, load_stagefile(stagefile), workdir, until=until, force=force,
               executor=make_executor(jobs), progress=not quiet)


def status(scene: Scene, workdir: Workdir, stagefile: str | Path | None = None
           ) -> list[StagePlan]:
    """Every stage's state (fresh, stale or missing) and why, without running anything."""
    return plan(scene, load_stagefile(stagefile), workdir)


@dataclass
class RenderResult:
    """A rendered (or already up-to-date) frame and where it was written."""

    exr: Path
    png: Path
    frame: Frame | None  # None when the frame on disk was already up to date
    baked: list[StageRun]


def render(scene: Scene, workdir: Workdir, method: str, out: Path, jobs: int = 1,
           quiet: bool = False, reuse: bool = False,
           options: dict[str, Any] | None = None) -> RenderResult:
    """Bake what ``method`` needs, render one frame, write ``out`` (EXR) and a PNG beside.

    With ``reuse``, a frame whose inputs (artifact keys, lights, materials, camera, code)
    are unchanged since it was written is not rendered again."""
    if method not in METHODS:
        raise PrtError(None, f"unknown method {method!r} (methods: {', '.join(METHODS)})")
    module_name, _, needs = METHODS[method]
    if out.suffix.lower() != ".exr":
        raise PrtError(out, "output must be an .exr file")
    baked = bake(scene, workdir, until=needs, jobs=jobs, quiet=quiet)
    png, meta = out.with_suffix(".png"), out.with_suffix(".json")
    key = digest({"method": method, "code": module_source_hash(module_name),
                  "artifacts": [p.key for p in status(scene, workdir)],
                  "scene": {s: scene.section(s) for s in ("camera", "lights", "materials")}})
    if reuse and out.is_file() and png.is_file() and _stored_key(meta) == key:
        return RenderResult(out, png, None, baked)
    from pipeline.images import write_exr, write_png

    frame = render_frame(scene, workdir, method, options)
    write_exr(out, frame.rgb)
    write_png(png, frame.rgb)
    meta.write_text(json.dumps({"key": key, "method": method, **frame.timings}, indent=1))
    return RenderResult(out, png, frame, baked)


def frame_renderer(scene: Scene, workdir: Workdir, method: str,
                   options: dict[str, Any] | None = None) -> Callable[[Scene], Frame]:
    """A function rendering frames of ``method`` from the (already baked) artifacts in
    ``workdir``, loaded once; ``options`` are the method's own keyword arguments (d2i:
    max_bounces, bounce_tolerance)."""
    import importlib

    module_name, factory, _ = METHODS[method]
    return getattr(importlib.import_module(module_name), factory)(scene, workdir,
                                                                  **(options or {}))


def render_frame(scene: Scene, workdir: Workdir, method: str,
                 options: dict[str, Any] | None = None) -> Frame:
    """One frame of ``method`` (see ``frame_renderer``)."""
    return frame_renderer(scene, workdir, method, options)(scene)


def _stored_key(meta: Path) -> str | None:
    try:
        return json.loads(meta.read_text()).get("key")
    except (OSError, ValueError):
        return None


SEQUENCE_KINDS = ("light", "gamma")


@dataclass
class SequenceResult:
    """A written frame sequence: its EXR files (PNG previews beside them), per-frame
    timings and the edit each frame shows."""

    kind: str
    exr: list[Path]
    timings: list[dict[str, float]]
    edits: list[str]


def parse_sequence(text: str) -> tuple[str, str | None, int]:
    """``light:N`` or ``gamma[:MATERIAL]:N`` -> (kind, material or None, N)."""
    parts = text.split(":")
    if parts[0] not in SEQUENCE_KINDS or len(parts) not in (2, 3) or \
            (parts[0] == "light" and len(parts) != 2) or not parts[-1].isdigit() \
            or int(parts[-1]) < 1:
        raise PrtError(None, f"--frames {text}: expected light:N or gamma[:MATERIAL]:N "
                       "(N ≥ 1 frames)")
    return parts[0], parts[1] if len(parts) == 3 else None, int(parts[-1])


def sequence_scenes(scene: Scene, workdir: Workdir, kind: str, material: str | None,
                    count: int) -> tuple[list[Scene], list[str]]:
    """The edited scenes of a sequence and a label for each. ``light``: the first light
    moved around a horizontal circle of radius 0.1 × the scene's diagonal about where it
    is (an emitter mesh tied to a quad light stays where it is). ``gamma``: the
    material's (default: the first glossy one) γ swept geometrically across its
    gamma_range."""
    from pipeline.scene_edits import with_light_offset, with_material_edits
    from pipeline.store import open_artifact

    if kind == "light":
        if not scene.lights:
            raise PrtError(scene.path, "a light sequence needs a light to move")
        geo = open_artifact(workdir.artifact("geometry"), "geometry").attrs
        radius = 0.1 * float(np.linalg.norm(np.subtract(geo["bbox_max"], geo["bbox_min"])))
        angles = 2 * np.pi * np.arange(count) / count
        offsets = [(radius * np.cos(a), 0.0, radius * np.sin(a)) for a in angles]
        return ([with_light_offset(scene, 0, o) for o in offsets],
                [f"light 0 moved by ({o[0]:.3g}, {o[1]:.3g}, {o[2]:.3g})" for o in offsets])
    glossy = [n for n, m in scene.materials.items() if m.model != "lambert"]
    name = material or (glossy[0] if glossy else None)
    if name not in glossy:
        raise PrtError(scene.path, f"a gamma sequence needs a glossy material (found "
                       f"{name!r}; glossy: {', '.join(glossy) or 'none'})")
    lo, hi = scene.materials[name].params["gamma_range"]
    gammas = np.geomspace(lo, hi, count) if count > 1 else \
        [scene.materials[name].params["gamma"]]
    edits = [f"{name}.gamma={g:.6g}" for g in gammas]
    return [with_material_edits(scene, [e]) for e in edits], edits


def render_sequence(scene: Scene, workdir: Workdir, spec: str, out: Path,
                    max_bounces: int = 32, bounce_tolerance: float = 1e-3) -> SequenceResult:
    """Render a d2i sequence (``light:N`` in light-edit mode, ``gamma[:M]:N`` in
    BRDF-edit mode) from the baked artifacts; frames go to ``out`` with the suffix
    ``_<kind>_<i>`` (EXR + PNG)."""
    from pipeline.images import write_exr, write_png
    from pipeline.render.d2i import D2iRenderer

    kind, material, count = parse_sequence(spec)
    scenes, edits = sequence_scenes(scene, workdir, kind, material, count)
    renderer = D2iRenderer(scene, workdir, max_bounces, bounce_tolerance)
    frame_of = renderer.light_edits(scene) if kind == "light" else renderer.brdf_edits(scene)
    paths, timings = [], []
    for i, edited in enumerate(scenes):
        frame = frame_of(edited)
        path = out.with_name(f"{out.stem}_{kind}_{i:04d}.exr")
        write_exr(path, frame.rgb)
        write_png(path.with_suffix(".png"), frame.rgb)
        paths.append(path)
        timings.append(frame.timings)
    return SequenceResult(kind, paths, timings, edits)


def main_job(scene: Scene, workdir: Workdir, frames: Path, until: str | None,
             force: tuple[str, ...], jobs: int, quiet: bool,
             stagefile: str | Path | None = None
             ) -> tuple[list[StageRun], RenderResult | None, list[SequenceResult]]:
    """``prt run``: bake every stale stage, then (unless ``until``, or with a custom
    stage file) bring the scene's frame and its edit sequences in ``frames`` up to date
    (the sequences are rendered again whenever the frame is)."""
    report = bake(scene, workdir, until=until, force=force, jobs=jobs, quiet=quiet,
                  stagefile=stagefile)
    if until or stagefile:
        return report, None, []
    result = render(scene, workdir, MAIN_METHOD, frames / f"{scene.name}_{MAIN_METHOD}.exr",
                    jobs=jobs, quiet=quiet, reuse=True)
    sequences = [] if result.frame is None else \
        [render_sequence(scene, workdir, spec, result.exr) for spec in MAIN_SEQUENCES]
    return report, result, sequences


REFERENCE_CODE = ("pipeline.reference", "pipeline.math.brdf", "pipeline.math.brdf_sampling",
                  "pipeline.math.envmap", "pipeline.math.lights", "pipeline.math.camera",
                  "pipeline.math.frames", "pipeline.raytrace")


def load_geometry(scene: Scene, workdir: Workdir, quiet: bool = True) -> tuple[dict, str]:
    """Bake the geometry stage if stale; its arrays and names as a dict, and its key."""
    from pipeline.store import open_artifact

    bake(scene, workdir, until="geometry", quiet=quiet)
    artifact = open_artifact(workdir.artifact("geometry"), "geometry")
    arrays: dict[str, Any] = {n: artifact.read(n) for n in artifact.names}
    arrays["object_names"] = artifact.attrs["object_names"]
    arrays["material_names"] = artifact.attrs["material_names"]
    return arrays, artifact.record["key"]


@dataclass
class ReferenceResult:
    """A reference image (from the cache or rendered now) and where it is stored."""

    image: Any  # pipeline.reference.ReferenceImage
    artifact: Path
    cached: bool


def reference(scene: Scene, workdir: Workdir, settings: Any, quiet: bool = False
              ) -> ReferenceResult:
    """The reference image for ``settings`` (a ReferenceSettings), rendered unless an
    artifact with the same key (scene camera, lights and materials, geometry, renderer
    code, settings) is stored under ``workdir/reference/``."""
    import dataclasses

    from pipeline import reference as ref
    from pipeline.schema import load_schema
    from pipeline.store import open_artifact, read_record, software_versions, write_artifact

    geometry, geometry_key = load_geometry(scene, workdir, quiet)
    parts = {"code": [module_source_hash(m) for m in REFERENCE_CODE],
             "geometry": geometry_key, "settings": dataclasses.asdict(settings),
             "scene": {s: scene.section(s) for s in ("camera", "lights", "materials")}}
    key = digest(parts)
    path = workdir.root / "reference" / f"{settings.transport}-{key[:16]}.zarr"
    record = read_record(path)
    if record is not None and record.get("key") == key:
        stored = open_artifact(path, "reference")
        a = stored.attrs
        image = ref.ReferenceImage(stored.read("mean"), stored.read("variance"), a["spp"],
                                   a["estimate"], a["seconds"], a["rays"],
                                   [tuple(h) for h in a["history"]])
        return ReferenceResult(image, path, True)
    image = ref.render(scene, geometry, settings, progress=not quiet)
    with workdir.lock():
        write_artifact(workdir, path, load_schema("reference"),
                       {"mean": image.mean, "variance": image.variance},
                       {"transport": settings.transport,
                        "settings": dataclasses.asdict(settings), "spp": image.spp,
                        "estimate": float(image.estimate), "seconds": image.seconds,
                        "rays": int(image.rays),
                        "history": [list(map(float, h)) for h in image.history]},
                       {"stage": "reference", "key": key, "key_parts": parts,
                        "seconds": image.seconds, "software": software_versions()},
                       {"tile": 64})
    return ReferenceResult(image, path, False)


def clean(workdir: Workdir) -> int:
    """Delete a work directory; returns the bytes freed."""
    root = workdir.root
    if not root.exists():
        return 0
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
    statistics (min, max, mean over finite values; NaN count)."""

    from pipeline.store import open_artifact, open_group

    path = Path(path)
    artifact = open_group(path)
    if artifact.record.get("kind") != "chunk":
        artifact = open_artifact(path)
    arrays = {}
    for name in artifact.names:
        arr = artifact.array(name)
        data = artifact.read(name)
        stored = sum(p.stat().st_size for p in (path / name).rglob("*") if p.is_file())
        numeric = data.astype(np.float64) if data.size else np.zeros(1)
        finite = numeric[np.isfinite(numeric)]
        arrays[name] = {
            "shape": list(data.shape), "dtype": str(data.dtype), "chunks": list(arr.chunks),
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
            "software": record.get("software"), "arrays": arrays}


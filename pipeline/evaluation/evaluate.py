"""``prt evaluate``: a method's error against its cost as its budgets vary.

For every budget of a sweep (the cartesian product of ``--sweep NAME=V1,V2,...``, plus
the method's default budget) it bakes what the method needs in the sweep's work
directory (``WORKDIR/sweep/METHOD``; only the stages a budget changes re-run), renders
``repeats`` frames after one warm-up and records:

* ``frame_ms``, ``kernel_ms``, ``setup_ms``: medians over full frames of one renderer
  (artifacts loaded once, before the warm-up frame; setup = everything but the OpenCL
  kernels: shadow rays, host work, transfers);
* ``storage_bytes``: bytes on disk of the artifacts a frame reads, or, where the
  renderer cuts them at run time (``Frame.read_bytes``: triple's ``render.budget``, rows
  cut on loading), the bytes of what the frame reads, uncompressed
  (``artifact_bytes``: on disk, always); ``bake_stages``: per
  stage of the chain that made them, its artifact key, compute seconds (summed over its
  chunks) and whether this budget's bake ran it; ``bake_s``: their sum;
* ``rel_rmse`` (headline), ``psnr_db``, ``flip`` against the reference renderer's image
  of the method's transport at the same size (pipeline/evaluation/reference.py, cached), and
  ``reference_rel_rmse``, that reference's own estimated error over the same pixels
  (``reference_rel_rmse_surfaces``: over the surfaces, as ``rel_rmse_surfaces``;
  charts draw it as a dotted line, pipeline/evaluation/charts.py): the reference is rendered at 64,
  256, 1024, ... paths per pixel (up to the cap) until that error is at most a third of
  the method's, so that the error measures the method, not the reference;
  ``rel_rmse_surfaces``: the same over the pixels that do not see an emitter;
* the *model error*: ``model_rel_rmse`` and ``model_rel_rmse_surfaces``, the same frame
  against ``full`` path tracing (what a user would see from a path tracer, tightened the
  same way; the same image where the method's transport is ``full``), with that
  reference's own error ``reference_model_rel_rmse(_surfaces)`` and spp
  ``model_reference_spp``; and ``transport_rel_rmse(_surfaces)``, the method transport's
  reference against ``full``: what the transport's simplification costs on the scene,
  the part of the model error no budget buys back;
* per component the method declares (d2i: ``indirect``; sg: ``glossy``, ``diffuse``):
  ``rel_rmse_<name>``, that image (the frame less the frame of the method the component
  subtracts, or the frame rendered with the component's options) against the
  component's reference transport and lobe on those pixels, tightened the same way, and
  ``<name>_mean_ratio`` (mean radiance over the reference's);
* ``kernel_gbs`` = ``kernel_bytes`` / the time of the kernels that moved them
  (``counted_kernel_ms``), and ``bandwidth_fraction`` of the memory-bandwidth probe run
  at the start (pipeline/device/bandwidth.py);
* ``warnings``: the method's limits that apply to the budget's scene (pipeline/method.py
  ``Limit``);
* what a user would do instead: ``pathtrace_ms_equal_error``, the wall time the reference
  renderer (a different seed, progressive) needs until its estimated error falls to the
  method's headline error (``Method.headline``, e.g. d2i's on the surfaces;
  ``pathtrace_rel_rmse``: its error then, measured against the reference), and
  ``mitsuba_ms_equal_error`` where Mitsuba 3 is installed and renders the scene's
  transport, lights and materials (spp doubled until its error is at most the method's).

Budget names: ``size`` (image width; the height follows the camera's aspect ratio, or
``WxH``), any stage parameter of stages.yaml (``brdf_basis.max_k``, ...), applied as a
scene setting, or ``render.OPTION``, a run-time option of the method. Without a sweep,
the method's own small sweep (``Method.evaluate_sweep``) runs with its reference cap
(``Method.evaluate_reference_spp``): a few minutes on two cores. Each step is printed
with an estimate of the time left, and :func:`summary_lines` tabulates the budgets.
Writes ``results.json`` (a list of records), ``probe.json`` (the bandwidth probe and
settings), charts ``error_vs_frame_time.png``, ``error_vs_storage.png``,
``error_vs_bake_time.png`` (pipeline/evaluation/charts.py) and, per budget, the frame and an error
heat map (per-pixel relative error, metrics.error_map, colour bar 0 to ``HEATMAP_MAX``)
under ``frames/`` (and the ``full`` reference with the frame's model-error heat map,
``_full.png`` and ``_model_error.png``).
"""

from __future__ import annotations

import itertools
import json
import statistics
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pipeline import job
from pipeline.engine.graph import with_upstream
from pipeline.engine.store import Workdir, read_record
from pipeline.errors import PrtError
from pipeline.evaluation import metrics, reference_cache
from pipeline.evaluation.charts import heatmap, write_charts
from pipeline.evaluation.reference import ReferenceSettings
from pipeline.images import write_exr, write_png
from pipeline.method import Component, Method
from pipeline.registry import check_method_scene, get_method, limit_warnings, scene_methods
from pipeline.scene.model import Scene

# Budgets named render.X are the method's run-time options X (d2i: render.max_bounces).
RENDER_PREFIX = "render."
HEATMAP_MAX = 0.2  # heat maps span relative errors 0 to 20 %
MITSUBA_MAX_SPP = 4096
REFERENCE_FIRST_SPP = 64  # references render at 64, 256, 1024, ... paths per pixel
MODEL_TRANSPORT = "full"  # the model error: against what a path tracer shows


@dataclass(frozen=True)
class EvaluateSettings:
    """``repeats`` timed frames per budget; the references' sample cap
    ``reference_max_spp``; the path tracer's ``pathtrace_max_spp``."""

    repeats: int = 5
    reference_max_spp: int = 4096
    pathtrace_max_spp: int = 4096


def default_plan(scene: Scene, method: Method, sweep: dict[str, list[Any]],
                 reference_max_spp: int | None, sized: bool
                 ) -> tuple[Scene, dict[str, list[Any]], int]:
    """The scene, sweep and reference cap to run: the given ones, or, when no sweep is
    given, the method's own bounded defaults (its sweep, on the scene resized to its
    ``evaluate_size`` unless ``sized``: the user chose the size)."""
    if sweep:
        return scene, sweep, reference_max_spp or 4096
    if method.evaluate_size and not sized:
        scene = apply_budget(scene, {"size": method.evaluate_size})
    return scene, dict(method.evaluate_sweep), \
        reference_max_spp or method.evaluate_reference_spp


def parse_sweep(items: list[str]) -> dict[str, list[Any]]:
    """``["NAME=V1,V2", ...]`` -> {NAME: [V1, V2]} with numbers parsed."""
    sweep: dict[str, list[Any]] = {}
    for item in items:
        name, eq, values = item.partition("=")
        if not eq or not name or not values:
            raise PrtError("--sweep", f"{item!r}: expected NAME=V1,V2,... e.g. size=64,128")
        sweep[name] = [_number(v) for v in values.split(",")]
    return sweep


def _number(text: str) -> Any:
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def sweep_names(scene: Scene, method: Method) -> dict[str, Any]:
    """Every budget ``method`` can sweep, with the scene's value: ``size``, its run-time
    options as ``render.OPTION``, and the parameters of the stages its frames read (with
    their upstream stages)."""
    from pipeline.engine.planning import stage_params

    graph = job.stages()
    params = stage_params(graph, scene)
    used = sorted({p for s in with_upstream(graph, list(method.every_read()))
                   for p in graph.stages[s].params})
    return {"size": scene.camera.width,
            **{f"{RENDER_PREFIX}{o.name}": o.default for o in method.options},
            **{name: params[name] for name in used}}


def default_budget(scene: Scene, method: Method, sweep: dict[str, list[Any]]
                   ) -> dict[str, Any]:
    """The scene's own value of each budget the sweep names; PrtError naming ``--sweep``
    for a name the method cannot sweep (listing those it can) or a value of the wrong
    kind, before anything runs."""
    known = sweep_names(scene, method)
    for name, values in sweep.items():
        if name not in known:
            raise PrtError("--sweep", f"method {method.name} has no budget {name!r} (its "
                           f"budgets: {', '.join(known)})")
        for value in values:
            _check_budget_value(method, name, value, known[name])
    return {name: known[name] for name in sorted(sweep)}


def _check_budget_value(method: Method, name: str, value: Any, default: Any) -> None:
    """PrtError unless ``value`` suits budget ``name`` (whose scene value is ``default``):
    a size is a width or WxH within MAX_IMAGE_SIDE; a run-time option parses as its
    type; a numeric stage parameter takes a finite number."""
    from pipeline.scene.model import MAX_IMAGE_SIDE

    if name == "size":
        w, sep, h = str(value).lower().partition("x")
        sides = [w, h] if sep else [w]
        if not all(s.isdigit() and 1 <= int(s) <= MAX_IMAGE_SIDE for s in sides):
            raise PrtError("--sweep", f"size={value}: expected a width or WIDTHxHEIGHT, "
                           f"positive integers up to {MAX_IMAGE_SIDE}")
        return
    if name.startswith(RENDER_PREFIX):
        option = next(o for o in method.options if RENDER_PREFIX + o.name == name)
        try:
            option.parse(str(value))
        except PrtError as exc:
            raise PrtError("--sweep", RENDER_PREFIX + exc.problem) from None
        return
    numeric = isinstance(default, int | float) and not isinstance(default, bool)
    if numeric and not (isinstance(value, int | float) and np.isfinite(value)):
        raise PrtError("--sweep", f"{name}={value}: expected a finite number (the scene's "
                       f"value is {default!r})")


def apply_budget(scene: Scene, budget: dict[str, Any]) -> Scene:
    """``scene`` with the budget's image size and stage-parameter settings."""
    settings = {}
    for name, value in budget.items():
        if name.startswith(RENDER_PREFIX):
            continue
        if name != "size":
            settings[name] = value
            continue
        if isinstance(value, str):
            w, _, h = value.lower().partition("x")
            width, height = int(w), int(h)
        else:
            width = int(value)
            height = max(1, round(width * scene.camera.height / scene.camera.width))
        scene = scene.with_image_size(width, height)
    return scene.with_settings(settings) if settings else scene


def _slug(budget: dict[str, Any]) -> str:
    return "_".join(f"{k.replace('.', '-')}-{v}" for k, v in sorted(budget.items())) or "default"


def _bytes_on_disk(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def _pathtrace_equal_error(scene: Scene, geometry: dict, transport: str, target: float,
                           reference: Any, mask: np.ndarray | None,
                           max_spp: int) -> dict[str, Any]:
    """Time the reference renderer (seed 1) needs until its estimated error over ``mask``
    (None: every pixel) is ``target``. It stops on its own estimate (over the pixels
    that do not see an emitter), which falls in proportion with the masked one (both as
    1/√spp): the target is scaled by their ratio in the converged ``reference``."""
    from pipeline.evaluation.reference import render

    pixels = np.ones(reference.mean.shape[:2], bool) if mask is None else mask
    scale = reference.estimate / max(_noise(reference, pixels), 1e-30)
    image = render(scene, geometry, ReferenceSettings(transport, tolerance=target * scale,
                                                      max_spp=max_spp, min_spp=1, seed=1))
    reached = image.estimate <= target * scale
    return {"pathtrace_ms_equal_error": image.seconds * 1e3 if reached else None,
            "pathtrace_spp": image.spp, "pathtrace_estimate": image.estimate / scale,
            "pathtrace_rel_rmse": metrics.relative_rmse(image.mean, reference.mean, mask)}


def _mitsuba_equal_error(scene: Scene, geometry: dict, transport: str, target: float,
                         reference: np.ndarray) -> dict[str, Any]:
    """Mitsuba 3's render time at the fewest spp (powers of 2) reaching ``target``, when
    Mitsuba is installed and has the scene's transport, lights and materials
    (pipeline/evaluation/mitsuba.py); None otherwise, with the reason."""
    try:
        from pipeline.evaluation import mitsuba

        mitsuba.scene_dict(scene, geometry, transport, 1, seed=1)
    except PrtError as exc:
        return {"mitsuba_ms_equal_error": None, "mitsuba_note": str(exc.problem)}
    spp, error, seconds = 1, np.inf, None
    while spp <= MITSUBA_MAX_SPP:
        result = mitsuba.render(scene, geometry, transport, spp, seed=1)
        error = metrics.relative_rmse(result.rgb, reference)
        if error <= target:
            seconds = result.render_s
            break
        spp *= 2
    return {"mitsuba_ms_equal_error": None if seconds is None else seconds * 1e3,
            "mitsuba_spp": spp, "mitsuba_rel_rmse": error,
            "mitsuba_note": "box pixel filter: its error includes edge aliasing against "
                            "the pixel-centre reference"}


def _step(text: str) -> None:
    """One line of progress on stderr (printed also under --quiet: a sweep runs long)."""
    print(text, file=sys.stderr, flush=True)


def evaluate(scene: Scene, workdir: Workdir, method: str | None, sweep: dict[str, list[Any]],
             out: Path, settings: EvaluateSettings = EvaluateSettings(),
             quiet: bool = False) -> list[dict[str, Any]]:
    """Run the sweep; write results.json, probe.json, charts and frames into ``out``."""
    from pipeline.device.bandwidth import probe

    m = get_method(method) if method else scene_methods(scene)[0]
    for note in check_method_scene(m, scene):
        _step(f"note: {note}")
    names = sorted(sweep)
    default = default_budget(scene, m, sweep)
    budgets = [dict(zip(names, values, strict=True))
               for values in itertools.product(*(sweep[n] for n in names))]
    if default not in budgets:
        budgets.append(default)
    out.mkdir(parents=True, exist_ok=True)
    bandwidth = probe()
    records = []
    start = time.perf_counter()
    for i, budget in enumerate(budgets):
        elapsed = time.perf_counter() - start
        left = f", about {elapsed / i * (len(budgets) - i) / 60:.1f} min left" if i else ""
        _step(f"[{i + 1}/{len(budgets)}] {m.name} {_slug(budget)}: bake, frames, "
              f"references{left}")
        records.append(_evaluate_budget(scene, workdir, m, budget, budget == default, out,
                                        settings, bandwidth, quiet))
        r = records[-1]
        _step(f"  {_slug(budget):<24} {r['headline']} {r[r['headline']]:.4f} (against "
              f"full {r['model_' + r['headline']]:.4f})  frame "
              f"{r['frame_ms']:.1f} ms  path tracer at equal error "
              f"{_ms(r['pathtrace_ms_equal_error'])}")
        for line in r["warnings"]:
            _step(f"  warning: {line}")
    (out / "results.json").write_text(json.dumps(records, indent=1))
    (out / "probe.json").write_text(json.dumps(
        {"bandwidth_probe": bandwidth, "settings": vars(settings), "method": m.name,
         "scene": str(scene.path), "transport": m.reference}, indent=1))
    write_charts(records, out)
    return records


def _ms(value: float | None) -> str:
    return "not reached" if value is None else f"{value:.0f} ms"


def _evaluate_budget(scene: Scene, workdir: Workdir, method: Method, budget: dict[str, Any],
                     is_default: bool, out: Path, settings: EvaluateSettings,
                     bandwidth: dict[str, Any], quiet: bool) -> dict[str, Any]:
    sc = apply_budget(scene, budget)
    options = method.option_values({}) | {k[len(RENDER_PREFIX):]: v for k, v in budget.items()
                                          if k.startswith(RENDER_PREFIX)}
    # one work directory for all budgets: a budget re-bakes only the stages whose keys
    # it changes (a truncate.tolerance sweep re-runs truncate, not transfer)
    wd = Workdir(workdir.root / "sweep" / method.name)
    report = job.bake(sc, wd, quiet=quiet, methods=[method], options=options)
    reads = list(method.reads_for(options))
    bake_stages = _bake_stages(wd, with_upstream(job.stages(), reads),
                               {r.name for r in report if r.action == "ran"})
    storage = sum(_bytes_on_disk(wd.artifact(name)) for name in reads)
    render = job.frame_renderer(sc, wd, method.name, options)  # loads the artifacts once
    render.frame(sc)  # warm-up: kernel builds, first use of the device buffers
    frames = [render.frame(sc) for _ in range(settings.repeats)]
    frame = frames[-1]

    def median(key: str) -> float:
        return statistics.median(f.timings[key] for f in frames)

    kernel_ms = median("kernel_ms")
    counted_ms = median("counted_kernel_ms") if "counted_kernel_ms" in frame.timings \
        else kernel_ms
    surfaces = ~emitter_pixels(sc, wd)
    transport = method.reference
    _step(f"  reference {transport} ({sc.camera.width}x{sc.camera.height})")
    ref = _converged_reference(sc, workdir, transport, frame.rgb, [None, surfaces], settings,
                               quiet)
    errors = metrics.image_metrics(frame.rgb, ref.mean)
    surface_error = metrics.relative_rmse(frame.rgb, ref.mean, surfaces)
    model, full = _model_record(sc, workdir, transport, ref, frame.rgb, surfaces, settings,
                                quiet)
    components: dict[str, Any] = {}
    for name, component in method.components.items():
        _step(f"  component {name}: reference {component.transport}")
        components.update(_component_record(sc, wd, workdir, method, options, name,
                                            component, frame.rgb, surfaces, settings, quiet))
    headline_mask = surfaces if method.headline == "rel_rmse_surfaces" else None
    headline = errors["rel_rmse"] if headline_mask is None else surface_error
    slug = _slug(budget)
    write_exr(out / "frames" / f"{slug}.exr", frame.rgb)
    write_png(out / "frames" / f"{slug}.png", frame.rgb)
    write_png(out / "frames" / f"{slug}_reference.png", ref.mean)
    heatmap(out / "frames" / f"{slug}_error.png", metrics.error_map(frame.rgb, ref.mean),
            HEATMAP_MAX, "relative error per pixel, |I - R| / |R| (RGB norms)",
            f"{method.name} {slug} against the {transport} reference", percent=True)
    if full is not ref:
        write_png(out / "frames" / f"{slug}_full.png", full.mean)
    heatmap(out / "frames" / f"{slug}_model_error.png",
            metrics.error_map(frame.rgb, full.mean), HEATMAP_MAX,
            "relative error per pixel, |I - R| / |R| (RGB norms)",
            f"{method.name} {slug} against {MODEL_TRANSPORT} path tracing", percent=True)
    geometry, _ = job.load_geometry(sc, wd)
    kernel_gbs = frame.kernel_bytes / (counted_ms * 1e-3) / 1e9 if counted_ms > 0 else None
    _step("  path tracer to equal error")
    return {
        "method": method.name, "headline": method.headline, "budget": budget,
        "default": is_default,
        "width": sc.camera.width, "height": sc.camera.height,
        "frame_ms": median("total_ms"), "kernel_ms": kernel_ms,
        "setup_ms": median("total_ms") - kernel_ms, "repeats": settings.repeats,
        "storage_bytes": storage if frame.read_bytes is None else frame.read_bytes,
        "artifact_bytes": storage,
        "bake_s": sum(v["seconds"] for v in bake_stages.values()), "bake_stages": bake_stages,
        **errors,
        "rel_rmse_surfaces": surface_error,
        # over the same pixels as rel_rmse (ref.estimate covers the surfaces only)
        "reference_rel_rmse": _noise(ref, np.ones(frame.rgb.shape[:2], bool)),
        "reference_rel_rmse_surfaces": _noise(ref, surfaces), "reference_spp": ref.spp,
        **model,
        **components,
        "kernel_bytes": frame.kernel_bytes, "counted_kernel_ms": counted_ms,
        "kernel_gbs": kernel_gbs,
        "bandwidth_fraction": None if kernel_gbs is None
        else kernel_gbs / bandwidth["opencl_copy_gbs"],
        **_pathtrace_equal_error(sc, geometry, transport, headline, ref, headline_mask,
                                 settings.pathtrace_max_spp),
        **_mitsuba_equal_error(sc, geometry, transport, errors["rel_rmse"], ref.mean),
        "heatmap_max": HEATMAP_MAX,
        "warnings": limit_warnings(method, sc, job.method_artifacts(method, wd, options)),
    }


def _model_record(scene: Scene, workdir: Workdir, transport: str, ref: Any,
                  image: np.ndarray, surfaces: np.ndarray, settings: EvaluateSettings,
                  quiet: bool) -> tuple[dict[str, Any], Any]:
    """``image`` against ``full`` path tracing (its converged reference, or ``ref``
    where ``transport`` is full): the model-error fields of a record (module docstring),
    and that reference."""
    if transport == MODEL_TRANSPORT:
        full = ref
    else:
        _step(f"  reference {MODEL_TRANSPORT} (the model error)")
        full = _converged_reference(scene, workdir, MODEL_TRANSPORT, image, [None, surfaces],
                                    settings, quiet)
    every = np.ones(image.shape[:2], bool)
    return {"model_transport": MODEL_TRANSPORT,
            "model_rel_rmse": metrics.relative_rmse(image, full.mean),
            "model_rel_rmse_surfaces": metrics.relative_rmse(image, full.mean, surfaces),
            "reference_model_rel_rmse": _noise(full, every),
            "reference_model_rel_rmse_surfaces": _noise(full, surfaces),
            "model_reference_spp": full.spp,
            "transport_rel_rmse": metrics.relative_rmse(ref.mean, full.mean),
            "transport_rel_rmse_surfaces": metrics.relative_rmse(ref.mean, full.mean,
                                                                 surfaces)}, full


def _bake_stages(workdir: Workdir, chain: list[str], ran: set[str]
                 ) -> dict[str, dict[str, Any]]:
    """Per stage of ``chain``: its artifact's key, its compute seconds (summed over its
    chunks, whichever run computed them: a stage re-run in part still counts in full)
    and whether this budget's bake ran it."""
    out = {}
    for name in chain:
        record = read_record(workdir.artifact(name)) or {}
        chunks = record.get("chunk_seconds")
        out[name] = {"key": record.get("key"), "ran": name in ran,
                     "seconds": sum(chunks.values()) if chunks
                     else record.get("seconds", 0.0)}
    return out


def summary_lines(records: list[dict[str, Any]]) -> list[str]:
    """A table with one line per budget: the headline error and the reference's own,
    frame time, storage, and bake time (of the stages this budget ran, and in all)."""
    lines = [f"  {'budget':<28} {'error':>8} {'ref.':>7} {'full':>8} {'frame ms':>9} "
             f"{'MB':>7} {'bake s':>7} {'ran':>7}"]
    for r in records:
        error = r.get("headline", "rel_rmse")
        ran = sum(v["seconds"] for v in r["bake_stages"].values() if v["ran"])
        name = _slug(r["budget"]) + (" *" if r["default"] else "")
        lines.append(f"  {name:<28} {r[error]:>8.4f} {r.get('reference_' + error, 0):>7.4f} "
                     f"{r['model_' + error]:>8.4f} "
                     f"{r['frame_ms']:>9.1f} {r['storage_bytes'] / 1e6:>7.2f} "
                     f"{r['bake_s']:>7.1f} {ran:>7.1f}")
    lines.append("  error: the headline relative RMSE against the method's transport; ref.: "
                 "that reference's own estimated error; full: the same against full path "
                 "tracing (the model error); ran: bake seconds of the stages this budget "
                 "ran; * the default")
    return lines


def _converged_reference(scene: Scene, workdir: Workdir, transport: str, image: np.ndarray,
                         masks: list[np.ndarray | None], settings: EvaluateSettings,
                         quiet: bool, lobe: str = "all") -> Any:
    """The reference image of ``transport`` whose estimated error, over each of ``masks``
    (None: every pixel), is at most a third of ``image``'s error there, or the one at
    the sample cap. A noisier reference would measure itself; the masks matter because
    the estimate over the whole image, dominated by an emitter's pixels, says little
    about the surfaces. References are rendered at fixed sample counts (64, 256, 1024,
    ... up to the cap) so that every budget of a sweep finds the same cached images."""
    spp = min(REFERENCE_FIRST_SPP, settings.reference_max_spp)
    while True:
        ref = reference_cache.reference(scene, workdir, ReferenceSettings(
            transport, tolerance=0.0, min_spp=spp, max_spp=spp, lobe=lobe),
            quiet=quiet).image
        full = np.ones(image.shape[:2], bool)
        ratios = [_noise(ref, full if m is None else m)
                  / max(metrics.relative_rmse(image, ref.mean, m), 1e-12) for m in masks]
        if max(ratios) <= 1 / 3 or spp >= settings.reference_max_spp:
            return ref
        spp = min(4 * spp, settings.reference_max_spp)


def _component_record(scene: Scene, wd: Workdir, workdir: Workdir, method: Method,
                      options: dict[str, Any], name: str, component: Component,
                      frame: np.ndarray, surfaces: np.ndarray, settings: EvaluateSettings,
                      quiet: bool) -> dict[str, Any]:
    """A component of the frame (pipeline/method.py Component: the frame less the frame
    of the method it subtracts, or the method's frame with the component's options on
    top of the budget's ``options``) against the component's reference, on
    ``surfaces``: ``rel_rmse_<name>``, that reference's noise, and the ratio of mean
    radiances ``<name>_mean_ratio``."""
    if component.subtract:
        other = get_method(component.subtract)
        job.bake(scene, wd, quiet=quiet, methods=[other])
        image = frame - job.render_frame(scene, wd, other.name).rgb
    else:
        image = job.render_frame(scene, wd, method.name,
                                 options | dict(component.options)).rgb
    ref = _converged_reference(scene, workdir, component.transport, image, [surfaces],
                               settings, quiet, component.lobe)
    return {f"rel_rmse_{name}": metrics.relative_rmse(image, ref.mean, surfaces),
            f"reference_rel_rmse_{name}": _noise(ref, surfaces),
            f"reference_spp_{name}": ref.spp,
            f"{name}_mean_ratio": float(image[surfaces].mean()
                                        / max(ref.mean[surfaces].mean(), 1e-30))}


def _noise(ref: Any, mask: np.ndarray) -> float:
    """The reference's estimated relative RMSE over the pixels in ``mask``."""
    norm = float(np.sum(np.square(ref.mean[mask], dtype=np.float64)))
    return float(np.sqrt(np.sum(ref.variance[mask], dtype=np.float64) / norm)) if norm > 0 \
        else float("inf")


def emitter_pixels(scene: Scene, workdir: Workdir) -> np.ndarray:
    """(height, width) True where the G-buffer's pixel sees an emitting object (a quad
    light's ``object``); such pixels show the light's radiance, which dwarfs everything
    else in ‖R‖ (the Cornell luminaire: 18 against ≈ 0.3), so the records also give
    ``rel_rmse_surfaces`` over the other pixels."""
    from pipeline.engine.store import open_artifact

    objects = [light.params["object"] for light in scene.lights
               if light.type == "quad" and "object" in light.params]
    if not objects:  # nothing emits (and methods like triple bake no G-buffer)
        return np.zeros((scene.camera.height, scene.camera.width), bool)
    gbuffer = open_artifact(workdir.artifact("gbuffer"), "gbuffer")
    names = open_artifact(workdir.artifact("geometry"), "geometry").attrs["object_names"]
    return np.isin(gbuffer.read("object_id"), [names.index(o) for o in objects])

"""The ``<method>.suite`` benchmarks: a method's error and cost on a suite of scenes, the
shipped ones and scenes it was not tuned on (other meshes and maps, a close-up camera, a
small bright source), each at 3–5 budgets.

Per scene and budget (``prt evaluate``'s record, pipeline/evaluation/evaluate.py, at the
error size ``--size``): the *method error* against the reference of the method's
transport, the *model error* against full path tracing, each reference's own noise,
storage and bake seconds; and, per ``--frame-sizes`` (256² and 1024×768 by default),
the median frame time of the budget at that size (``frame_ms_at``; d2i's per-pixel
bake is re-baked at each size, triple's and sg's serve any camera: see
:func:`frame_ms`; nothing is compared there, so no reference is rendered).
Writes the JSON, a chart per method (:func:`pipeline.evaluation.charts.suite_chart`:
error against frame time, a line per scene) and each scene's ``prt evaluate`` folder
beside it; ``python -m benchmarks table`` tabulates it.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from benchmarks.fixtures import CACHE, ROOT, load, result_path, write_result

FRAME_SIZES = "256,1024x768"
SUITE_SCENES = ROOT / "benchmarks" / "suite_scenes"  # the suites' own scene files
# the bunny scenes' camera (scenes/bunny_grace.yaml, bunny_sg.yaml) at half the distance
BUNNY_CLOSEUP = {"position": [0.25, 0.1, 1.7], "look_at": [0.0, -0.15, 0.0],
                 "up": [0, 1, 0], "fov": 32, "width": 64, "height": 64}


def tiny_preset(sweep: str) -> list[str]:
    """The options of a suite benchmark's smoke run: its tiny scene at 8², one budget
    ``sweep`` (``NAME=V``), 8-spp references, frames timed at 12²."""
    return ["--suite", "tiny", "--size", "8", "--frame-sizes", "12", "--repeats", "1",
            "--reference-max-spp", "8", "--sweep", sweep]


@dataclass(frozen=True)
class SuiteScene:
    """A scene of the suite, named ``name``: ``file`` with top-level sections replaced
    (``edits``: section -> value, as a scene file writes it; validated as the file is),
    and why it is in the suite."""

    name: str
    file: Path
    why: str
    edits: dict[str, Any] = field(default_factory=dict)

    def open(self) -> Any:
        from pipeline.scene.file import scene_from_document
        from pipeline.yamlfile import load_yaml

        path = self.file.resolve()
        return scene_from_document(path, {**load_yaml(path), **self.edits, "name": self.name})


def parse_sizes(text: str) -> list[tuple[int, int]]:
    """``"256,1024x768"`` -> [(256, 256), (1024, 768)] (a single number: square)."""
    sizes = []
    for item in text.split(","):
        w, _, h = item.lower().partition("x")
        sizes.append((int(w), int(h or w)))
    return sizes


def frame_ms(scene: Any, workdir: Path, method: str, budget: dict[str, Any],
             size: tuple[int, int], repeats: int, bake_per_size: bool) -> dict[str, Any]:
    """The median frame and kernel time (ms) of ``method`` on ``scene`` (as baked for
    the error measurement in ``workdir``) at ``budget``, rendered at ``size``, over
    ``repeats`` frames after one warm-up. ``bake_per_size``: the method bakes per pixel
    (d2i), so the budget is baked at ``size`` first (a view of ``workdir``); otherwise its
    artifacts serve any camera (triple's texels, sg's vertices) and the frame at ``size``
    is rendered from the error-size bake, the work per pixel being the same
    (``from_bake`` says which)."""
    from pipeline import job
    from pipeline.evaluation.evaluate import RENDER_PREFIX, apply_budget
    from pipeline.registry import get_method

    m = get_method(method)
    settings = {k: v for k, v in budget.items() if k != "size"}
    sized = apply_budget(scene.with_image_size(*size), settings)
    baked = sized if bake_per_size else apply_budget(scene, settings)
    options = m.option_values({}) | {k[len(RENDER_PREFIX):]: v for k, v in budget.items()
                                     if k.startswith(RENDER_PREFIX)}
    wd = job.workdir_for(baked, workdir)
    job.bake(baked, wd, quiet=True, methods=[m])
    renderer = job.frame_renderer(baked, wd, method, options)
    renderer.frame(sized)
    frames = [renderer.frame(sized) for _ in range(repeats)]
    if frames[0].rgb.shape[:2] != (size[1], size[0]):
        raise RuntimeError(f"{method} rendered {frames[0].width}x{frames[0].height} from its "
                           f"{baked.view or 'scene'} bake, not {size[0]}x{size[1]}: it "
                           "bakes per pixel (bake_per_size)")
    return {"frame_ms": statistics.median(f.timings["total_ms"] for f in frames),
            "kernel_ms": statistics.median(f.timings["kernel_ms"] for f in frames),
            "from_bake": f"{baked.camera.width}x{baked.camera.height}"}


def kept_rows(target: Path, scenes: tuple[SuiteScene, ...], chosen: tuple[SuiteScene, ...],
              args: argparse.Namespace) -> list[dict[str, Any]]:
    """The rows of the result at ``target`` for the suite's ``scenes`` not ``chosen``
    (a ``--scenes`` run replaces only its own), each stamped with that result's time and
    load unless it has its own; none if there is no result, or it was measured at another
    error size or frame sizes (its rows would not compare)."""
    if not target.exists():
        return []
    old = json.loads(target.read_text())
    sizes = [f"{w}x{h}" for w, h in parse_sizes(args.frame_sizes)]
    if old.get("size") != [args.size, args.size] or old.get("frame_sizes") != sizes:
        print(f"{target}: measured at {old.get('size')} / {old.get('frame_sizes')}, not "
              f"{[args.size, args.size]} / {sizes}: its other scenes are dropped")
        return []
    names = {s.name for s in scenes} - {s.name for s in chosen}
    return [{"finished": old["finished"], "load": old["load"], **row}
            for row in old["scenes"] if row["scene"] in names]


def scene_suite(name: str, method: str, suites: dict[str, tuple[SuiteScene, ...]],
                sweep: dict[str, list[Any]], argv: list[str] | None,
                bake_per_size: bool = False) -> dict[str, Any]:
    """Run one of ``suites`` (``--suite``: ``full``, the default, or ``tiny``, the smoke
    scene) of ``method`` over ``sweep`` (plus each scene's default budget);
    ``bake_per_size``: see :func:`frame_ms`; the module docstring says the rest."""
    from pipeline.engine.store import Workdir
    from pipeline.evaluation import evaluate
    from pipeline.evaluation.charts import suite_chart

    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {name} --",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=64,
                        help="image side of the error measurement [default: 64]")
    parser.add_argument("--frame-sizes", default=FRAME_SIZES,
                        help=f"sizes timed, WxH or W [default: {FRAME_SIZES}]")
    parser.add_argument("--suite", choices=sorted(suites), default="full")
    parser.add_argument("--scenes", default=None,
                        help="comma-separated suite scene names, run and replaced in the "
                             "existing result, whose other scenes are kept [default: all: "
                             f"{', '.join(s.name for s in suites['full'])}]")
    parser.add_argument("--sweep", action="append", default=[], metavar="NAME=V1,V2",
                        help="budgets [default: "
                             f"{'; '.join(f'{k}={v}' for k, v in sweep.items())}]")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--reference-max-spp", type=int, default=1024)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    scenes = suites[args.suite]
    chosen = scenes if args.scenes is None else \
        tuple(s for s in scenes if s.name in args.scenes.split(","))
    budgets = evaluate.parse_sweep(args.sweep) or sweep
    sizes = parse_sizes(args.frame_sizes)
    target = result_path(name, args.out)
    folder = target.with_suffix("")
    before = load()
    rows = kept_rows(target, scenes, chosen, args) if args.scenes else []
    for suite_scene in chosen:
        started = load()
        scene = suite_scene.open().with_image_size(args.size, args.size)
        workdir = CACHE / f"suite_{method}_{suite_scene.name}"
        records = evaluate.evaluate(
            scene, Workdir(workdir), method, budgets, folder / suite_scene.name,
            evaluate.EvaluateSettings(args.repeats, args.reference_max_spp,
                                      args.reference_max_spp), quiet=True)
        for record in records:
            record["frame_ms_at"] = {
                f"{w}x{h}": frame_ms(scene, workdir / "sweep" / method, method,
                                     record["budget"], (w, h), args.repeats, bake_per_size)
                for w, h in sizes}
        rows.append({"scene": suite_scene.name, "file": str(suite_scene.file),
                     "why": suite_scene.why, "edits": suite_scene.edits,
                     "finished": time.strftime("%Y-%m-%dT%H:%M:%S"),
                     "load": [started, load()], "budgets": records})
    order = [s.name for s in scenes]
    rows.sort(key=lambda row: order.index(row["scene"]))
    chart = suite_chart(rows, method, f"{sizes[0][0]}x{sizes[0][1]}",
                        folder / "error_vs_frame_time.png")
    return write_result(name, {"method": method, "size": [args.size, args.size],
                               "frame_sizes": [f"{w}x{h}" for w, h in sizes],
                               "load": [before, load()], "scenes": rows,
                               "chart": str(chart)}, args.out)

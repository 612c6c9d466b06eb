"""What every benchmark shares: where results go, the machine and its load, medians,
the memory-bandwidth probe, and scenes baked once into a cache folder.

Speed is reported as medians of repeats taken in one run (these machines are noisy),
with the load average before and after; ratios (against the bandwidth probe, a path
tracer, one worker) are taken in the same run.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"  # gitignored
# Scenes the benchmarks bake once and share, and their scratch folders ($PRT_BENCH_CACHE:
# elsewhere, e.g. the tests' temporary folder).
CACHE = Path(os.environ.get("PRT_BENCH_CACHE") or ROOT / ".prt" / "benchmarks")
SCENES = ROOT / "scenes"
TINY = ROOT / "benchmarks" / "scenes"  # each method's smoke scene (--tiny presets)


def result_path(name: str, out: str | Path | None = None) -> Path:
    """Where benchmark ``name`` (``suite.name``) writes its JSON: ``out`` if given, else
    ``benchmarks/results/<suite>/<name>.json``."""
    if out is not None:
        return Path(out)
    suite, _, short = name.partition(".")
    return RESULTS / suite / f"{short}.json"


def write_result(name: str, result: dict[str, Any], out: str | Path | None = None
                 ) -> dict[str, Any]:
    """``result`` with the benchmark's name, the machine and the time, written as JSON
    to :func:`result_path`; returned."""
    result = {"benchmark": name, "machine": machine(),
              "finished": time.strftime("%Y-%m-%dT%H:%M:%S"), **result}
    path = result_path(name, out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=1, default=_plain) + "\n")
    return result


def _plain(value: Any) -> Any:
    """JSON for NumPy scalars and arrays, paths."""
    if hasattr(value, "tolist"):
        return value.tolist()
    return str(value)


def machine() -> dict[str, Any]:
    """The machine a result was measured on: CPU, cores this process may use, Python,
    the OpenCL device (if OpenCL was started in this process)."""
    from pipeline.device.threads import available_cpus

    info = {"cpu": _cpu_name(), "cores": available_cpus(),
            "python": platform.python_version()}
    try:
        from pipeline.device import cl

        info["opencl_device"] = cl.device().name
    except Exception:  # noqa: BLE001 - a benchmark without OpenCL still reports the rest
        pass
    return info


def _cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def load() -> list[float]:
    """The 1, 5 and 15 minute load averages now."""
    return [round(x, 2) for x in os.getloadavg()]


def median(values: Iterable[float]) -> float:
    return float(statistics.median(list(values)))


def timed(fn: Callable[[], Any], repeats: int, warmup: int = 1) -> tuple[float, list[float]]:
    """Median wall seconds of ``fn()`` over ``repeats`` calls after ``warmup`` calls,
    and every timing."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return median(times), times


def medians(records: list[dict[str, float]]) -> dict[str, float]:
    """Per key, the median over ``records`` (frames' timings, say)."""
    return {k: median(r[k] for r in records) for k in records[0]}


def bandwidth_probe() -> dict[str, float]:
    """The memory-bandwidth probe on this process's OpenCL device
    (pipeline/device/bandwidth.py): what a kernel's bytes per second are measured
    against."""
    from pipeline.device.bandwidth import probe

    return probe()


def baked(scene_file: Any, size: int | None = None,
          settings: dict[str, Any] | None = None, workdir: Path | None = None,
          quiet: bool = True, until: str | tuple[str, ...] | None = None,
          rebake: bool = False) -> tuple[Any, Any]:
    """The scene (a scene file's, or a Scene; resized to ``size``² and with ``settings``
    applied, if given) and its work directory, baked for the scene's methods (or up to
    ``until``'s stages): under ``workdir`` or a cache folder per scene, size and settings
    that later runs reuse (only stale chunks re-run; ``rebake``: emptied first)."""
    from pipeline import job
    from pipeline.engine.keys import digest
    from pipeline.scene.model import Scene

    scene = scene_file if isinstance(scene_file, Scene) else job.open_scene(Path(scene_file))
    if size is not None:
        scene = scene.with_image_size(size, size)
    if settings:
        scene = scene.with_settings(settings)
    folder = workdir or CACHE / f"{scene.name}_{scene.camera.width}x{scene.camera.height}_" \
        f"{digest(settings or {})[:8]}"
    work = job.workdir_for(scene, folder)
    if rebake and work.root.is_dir():
        job.clean(work)
    job.bake(scene, work, until=until, quiet=quiet)
    return scene, work


def method_accuracy(name: str, method: str, argv: list[str] | None,
                    scene_file: Path) -> dict[str, Any]:
    """The ``<method>.accuracy`` benchmarks: ``prt evaluate``'s sweep of ``method`` on
    ``scene_file`` (pipeline/evaluation/evaluate.py: per budget its error against the
    reference of its transport, the reference's own noise, frame time, storage, bake
    seconds and the path tracer's time to equal error), with the method's own bounded
    sweep and size unless the options say otherwise. Charts and frames go beside the
    result's JSON."""
    import argparse

    from pipeline import job
    from pipeline.evaluation import evaluate
    from pipeline.registry import get_method

    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {name} --")
    parser.add_argument("--scene", type=Path, default=scene_file)
    parser.add_argument("--size", type=int, default=None,
                        help="image side [default: the method's evaluate size]")
    parser.add_argument("--sweep", action="append", default=[], metavar="NAME=V1,V2",
                        help="budgets [default: the method's own sweep]")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--reference-max-spp", type=int, default=None)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    m = get_method(method)
    scene = job.open_scene(args.scene)
    if args.size:
        scene = scene.with_image_size(args.size, args.size)
    scene, sweep, cap = evaluate.default_plan(scene, m, evaluate.parse_sweep(args.sweep),
                                              args.reference_max_spp, args.size is not None)
    target = result_path(name, args.out)
    folder = target.with_suffix("")
    workdir = job.workdir_for(scene, CACHE / f"{scene.name}_accuracy")
    before = load()
    records = evaluate.evaluate(scene, workdir, m.name, sweep, folder,
                                evaluate.EvaluateSettings(args.repeats, cap, cap), quiet=True)
    return write_result(name, {"method": method, "scene": str(args.scene),
                               "size": [scene.camera.width, scene.camera.height],
                               "load": [before, load()], "budgets": records,
                               "charts": str(folder)}, args.out)


def cpu_ms() -> float:
    """CPU time of this process so far, all its threads (Embree's, PoCL's), in ms; on a
    contended machine the difference over a step tells its work apart from its waiting."""
    import resource

    usage = resource.getrusage(resource.RUSAGE_SELF)
    return (usage.ru_utime + usage.ru_stime) * 1e3

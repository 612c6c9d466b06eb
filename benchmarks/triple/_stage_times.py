"""Times of method triple's table stages through their own ``run_chunk`` only (an API
that older checkouts share), for ``python -m benchmarks run triple.tables -- --compare
REV``: run as a script (``python benchmarks/triple/_stage_times.py [SCENE]``, SCENE
default scenes/bunny_grace.yaml) with PYTHONPATH set to the checkout to time, from its
root; it imports nothing from the benchmarks. Prints one JSON line: ``light_grid_s`` /
``light_grid_cpu_s`` (every chunk of triple.light_rotations, in a process that has built
the kernels but not seen the grid), ``brdf_table_s`` / ``brdf_table_cpu_s`` (the first
glossy material's table, median of 3), wall-clock and this process's CPU seconds, and
the load average. The parameters: the checkout's stage defaults (its stage graph where it
has ``pipeline.job.stages``, else its stages.yaml) with the scene's settings."""

from __future__ import annotations

import json
import os
import statistics
import sys
import time
from pathlib import Path

import yaml

from pipeline.images import read_environment
from pipeline.methods.triple.stages import brdf_tables as brdf_stage
from pipeline.methods.triple.stages import light_rotations as light_stage

try:  # the engine's modules moved; older checkouts have them at the top
    from pipeline.engine.chunk import make_chunk
    from pipeline.engine.stage import ChunkContext
except ImportError:
    from pipeline.chunk import make_chunk

    from pipeline.stages import ChunkContext
try:
    from pipeline.scene.file import load_scene
except ImportError:
    from pipeline.scene import load_scene


def _timed(fn) -> tuple[float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - wall, time.process_time() - cpu


def _params(scene) -> dict:
    """The stage defaults (the merged stage graph's, else stages.yaml's) and the scene's
    settings."""
    try:
        from pipeline.job import stages

        defaults = dict(stages().params)
    except (ImportError, AttributeError):
        defaults = yaml.safe_load(Path("stages.yaml").read_text())["params"]
    return {**defaults, **(getattr(scene, "settings", None) or {})}


def main() -> None:
    scene = load_scene(sys.argv[1] if len(sys.argv) > 1 else "scenes/bunny_grace.yaml")
    params = _params(scene)
    rgb = read_environment(scene.environment_file())
    size, block = light_stage.frame_grid(params).size, int(params["triple.light_block"])

    def light(first: int, end: int) -> None:
        for start in range(first, end, block):
            light_stage.run_chunk(ChunkContext(
                params=params, scene={}, inputs={}, environment=rgb,
                chunk=make_chunk("b", "block", span=(start, min(start + block, size)))))

    glossy = next(name for name, m in scene.materials.items() if m.model != "lambert")
    keys = ("model", *brdf_stage.SHAPE_KEYS)
    brdf_ctx = ChunkContext(params=params, scene={
        f"materials.{glossy}.{k}": scene.section(f"materials.{glossy}.{k}") for k in keys},
        inputs={}, chunk=make_chunk(glossy, "material", material=glossy, index=0))
    brdf_stage.run_chunk(brdf_ctx)  # builds the kernels
    light(0, block)
    cache = getattr(light_stage, "_sample_coords", None)  # absent in older checkouts
    if cache is not None:
        cache.cache_clear()
    getattr(light_stage, "_PREFILTERED", {}).clear()  # the prefiltered map, where kept
    light_wall, light_cpu = _timed(lambda: light(0, size))
    brdf = [_timed(lambda: brdf_stage.run_chunk(brdf_ctx)) for _ in range(3)]
    print(json.dumps({"light_grid_s": light_wall, "light_grid_cpu_s": light_cpu,
                      "brdf_table_s": statistics.median(b[0] for b in brdf),
                      "brdf_table_cpu_s": statistics.median(b[1] for b in brdf),
                      "load_average": os.getloadavg()[0]}))


if __name__ == "__main__":
    main()

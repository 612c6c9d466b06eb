"""Times of method triple's table stages through their own ``run_chunk`` only (an API
that older checkouts share), for ``bench_triple_tables.py --compare REV``: run with
PYTHONPATH set to the checkout to time, from its root. Prints one JSON line:
``light_grid_s`` / ``light_grid_cpu_s`` (every chunk of triple.light_rotations on
scenes/bunny_grace.yaml, in a process that has built the kernels but not seen the grid),
``brdf_table_s`` / ``brdf_table_cpu_s`` (the bunny's table, median of 3), wall-clock
and this process's CPU seconds, and the load average."""

from __future__ import annotations

import json
import os
import statistics
import time
from pathlib import Path

import yaml

from pipeline.chunk import make_chunk
from pipeline.images import read_environment
from pipeline.methods.triple.stages import brdf_tables as brdf_stage
from pipeline.methods.triple.stages import light_rotations as light_stage
from pipeline.scene import load_scene
from pipeline.stages import ChunkContext


def _timed(fn) -> tuple[float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - wall, time.process_time() - cpu


def main() -> None:
    params = yaml.safe_load(Path("stages.yaml").read_text())["params"]
    scene = load_scene("scenes/bunny_grace.yaml")
    rgb = read_environment(scene.environment_file())
    size, block = light_stage.frame_grid(params).size, int(params["triple.light_block"])

    def light(first: int, end: int) -> None:
        for start in range(first, end, block):
            light_stage.run_chunk(ChunkContext(
                params=params, scene={}, inputs={}, environment=rgb,
                chunk=make_chunk("b", "block", span=(start, min(start + block, size)))))

    keys = ("model", *brdf_stage.SHAPE_KEYS)
    brdf_ctx = ChunkContext(params=params, scene={
        f"materials.bunny.{k}": scene.section(f"materials.bunny.{k}") for k in keys},
        inputs={}, chunk=make_chunk("bunny", "material", material="bunny", index=0))
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

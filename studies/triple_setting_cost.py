"""What a finer rotation grid or visibility texture costs method triple's frame (issue 16).

The frame's per-pixel work does not depend on the grid's or the texture's resolution
(8 lighting rows, 4 texel rows, 9 BRDF rows per pixel either way); only the memory the
rows are spread over grows. This renders bunny_grace at ``--width`` × ``--height``
(default 1024×768, top-only ``--budget`` 80: the dense path) from tables baked at 128²
by studies/triple_accuracy.py (its default and its variants under ``--workdir``),
alternating the settings frame by frame (the camera's G-buffer cached, as in an
environment-rotation frame, whose turn changes only the lighting weights), and writes
the median frame and kernel times per setting, their ratios to the default, the
tables' bytes and the load averages to ``--out``.

    python studies/triple_setting_cost.py --workdir /tmp/h18acc/w \\
        --setting "frame grid 64x33x32+texels_per_pixel 3" \\
        --out benchmarks/results/triple_accuracy/third_session/setting_cost.json
"""

from __future__ import annotations

import json
import os
import statistics
import sys
import time
from pathlib import Path

import click

from pipeline import job
from pipeline.methods.triple.render import TripleRenderer
from pipeline.registry import get_method

SCENE = "scenes/bunny_grace.yaml"


@click.command()
@click.option("--workdir", type=click.Path(path_type=Path), required=True)
@click.option("--setting", "settings", multiple=True,
              help="Variants of triple_accuracy.VARIANTS joined by '+': the stages each "
              "changes are taken from its bake (repeatable).")
@click.option("--width", type=int, default=1024, show_default=True)
@click.option("--height", type=int, default=768, show_default=True)
@click.option("--budget", type=int, default=80, show_default=True)
@click.option("--frames", type=int, default=5, show_default=True)
@click.option("--out", type=click.Path(path_type=Path), required=True)
def main(workdir, settings, width, height, budget, frames, out):
    sys.path.insert(0, str(Path(__file__).parent))
    from triple_accuracy import VARIANTS, _baked

    method = get_method("triple")
    bake_scene = job.open_scene(SCENE, (128, 128))
    base = job.method_artifacts(method, job.workdir_for(bake_scene, workdir / "default"))
    scene = job.open_scene(SCENE, (width, height))
    renderers = {"default": TripleRenderer(scene, base, budget=budget)}
    nbytes = {}
    for setting in settings:
        artifacts = dict(base)
        for variant in setting.split("+"):
            baked = _baked(bake_scene, workdir, variant)
            stages = {"triple.frame_grid": ["triple.light_rotations"],
                      "triple.texels_per_pixel": ["triple.atlas", "triple.visibility"]}
            for param in VARIANTS[variant]:
                for stage in stages[param]:
                    artifacts[stage] = baked[stage]
        renderers[setting] = TripleRenderer(scene, artifacts, budget=budget)
    times: dict[str, list[dict]] = {name: [] for name in renderers}
    load0 = os.getloadavg()
    for i in range(frames + 1):  # the first round traces the camera (not counted)
        for name, render in renderers.items():
            frame = render.frame(scene)  # the map's turn changes only the weights: same work
            if i:
                times[name].append(frame.timings)
            nbytes[name] = frame.read_bytes
    report = {"size": [width, height], "budget": budget, "frames": frames,
              "loadavg": [load0, os.getloadavg()], "finished": time.ctime(), "settings": {}}
    base_ms = statistics.median(t["total_ms"] for t in times["default"])
    for name, ts in times.items():
        total = statistics.median(t["total_ms"] for t in ts)
        report["settings"][name] = {
            "total_ms": total, "shade_ms": statistics.median(t["shade_ms"] for t in ts),
            "ratio_to_default": total / base_ms, "read_bytes": nbytes[name]}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=1))
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()

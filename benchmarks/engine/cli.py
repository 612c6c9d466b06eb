"""CLI latency: `prt status`, a no-op `prt run`, start-up, and the frame's time split; medians.

Wall time of ``prt status`` and of a no-op ``prt run`` on the default scene, Python's
start-up, and the frame's time split (setup, shadow rays, kernel) from ``prt render
--json``.

Each is a ``prt`` command in a fresh process (Python start-up included, as a user would
see it), the work directory baked once by a first ``prt run``; medians over ``--repeats``
runs (these machines are noisy), the load average before and after.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.fixtures import TINY, load, median, medians, write_result

NAME = "engine.cli"
PRESETS = {"default": [],
           "tiny": ["--scene", str(TINY / "tiny_d2i.yaml"), "--repeats", "1"]}
SPLIT = ("setup_ms", "shadow_ms", "kernel_ms", "total_ms")


def wall(args: list[str], cwd: Path) -> float:
    """Wall seconds of ``prt ARGS`` in a new process."""
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "pipeline", *args], cwd=cwd, check=True,
                   capture_output=True)
    return time.perf_counter() - start


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME} --",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--scene", type=Path, default=None,
                        help="scene file [default: prt's default scene, the Cornell box]")
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    scene = [str(args.scene.resolve())] if args.scene else []
    before = load()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        work, frames = str(tmp / "work"), str(tmp / "frames")
        first = wall(["run", *scene, "--workdir", work, "--frames", frames, "-q"], tmp)
        status = [wall(["status", *scene, "--workdir", work], tmp) for _ in range(args.repeats)]
        noop = [wall(["run", *scene, "--workdir", work, "--frames", frames, "-q"], tmp)
                for _ in range(args.repeats)]
        python_start = [wall(["--version"], tmp) for _ in range(args.repeats)]
        renders = []
        for _ in range(args.repeats):
            out = subprocess.run([sys.executable, "-m", "pipeline", "render", *scene,
                                  "--workdir", work, "--out", str(tmp / "f.exr"), "--json",
                                  "-q"], cwd=tmp, check=True, capture_output=True,
                                 text=True).stdout
            renders.append(json.loads(out))
    from pipeline import job
    from pipeline.scene.file import default_scene_path

    opened = job.open_scene(args.scene or default_scene_path())
    split = medians([{k: r[k] for k in SPLIT} for r in renders])
    return write_result(NAME, {
        "scene": f"{opened.name}{'' if args.scene else ' (default)'}, "
                 f"{opened.camera.width}x{opened.camera.height}",
        "repeats": args.repeats,
        "load": [before, load()],
        "first_run_s": round(first, 3),
        "status_s_median": round(median(status), 3),
        "noop_run_s_median": round(median(noop), 3),
        "cli_startup_s_median": round(median(python_start), 3),
        "render_direct_ms_median": {k: round(v, 2) for k, v in split.items()},
    }, args.out)

"""Benchmark: wall time of `prt status` and of a no-op `prt run` on the default scene,
and the direct frame's time split (setup, shadow rays, kernel).

Run from the project root:  python benchmarks/bench_cli.py
Writes benchmarks/results/cli.json. Medians over repeated runs (these machines are noisy).
"""

from __future__ import annotations

import json
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPEATS = 9
ROOT = Path(__file__).resolve().parent.parent


def wall(args: list[str], cwd: Path) -> float:
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "pipeline", *args], cwd=cwd, check=True,
                   capture_output=True)
    return time.perf_counter() - start


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        work, frames = str(tmp / "work"), str(tmp / "frames")
        first = wall(["run", "--workdir", work, "--frames", frames, "-q"], tmp)
        status = [wall(["status", "--workdir", work], tmp) for _ in range(REPEATS)]
        noop = [wall(["run", "--workdir", work, "--frames", frames, "-q"], tmp)
                for _ in range(REPEATS)]
        python_start = [wall(["--version"], tmp) for _ in range(REPEATS)]
        renders = []
        for _ in range(REPEATS):
            out = subprocess.run([sys.executable, "-m", "pipeline", "render", "--workdir", work,
                                  "--out", str(tmp / "f.exr"), "--json", "-q"], cwd=tmp,
                                 check=True, capture_output=True, text=True).stdout
            renders.append(json.loads(out))
    result = {
        "machine": {"python": platform.python_version(), "cpu": platform.processor() or
                    platform.machine(), "cores": __import__("os").cpu_count()},
        "scene": "cornell_box (default), 256x256",
        "repeats": REPEATS,
        "first_run_s": round(first, 3),
        "status_s_median": round(statistics.median(status), 3),
        "noop_run_s_median": round(statistics.median(noop), 3),
        "cli_startup_s_median": round(statistics.median(python_start), 3),
        "render_direct_ms_median": {
            k: round(statistics.median(r[k] for r in renders), 2)
            for k in ("setup_ms", "shadow_ms", "kernel_ms", "total_ms")},
    }
    out = ROOT / "benchmarks" / "results" / "cli.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()

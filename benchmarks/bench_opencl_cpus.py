"""Benchmark: the two CPU OpenCL implementations against each other — PoCL (pyopencl's,
LLVM 14) and Intel's CPU runtime — where both work; the default order of
pipeline/devices.py ``CPU_ORDER`` follows the faster.

Per method, its default scene at ``--size`` (d2i: the Cornell box, triple: bunny_grace,
sg: bunny_sg):

* bake: ``prt run SCENE --size WxH`` from an empty work directory (each implementation
  its own), wall seconds, and the seconds of each stage from the stage records;
* frame: the method's frame rendered ``--frames`` times in one process after a warm-up
  (its artifacts loaded once, kernels built): the median of the frame's own total and
  of its kernels' milliseconds (event profiling).

Implementations alternate within each of ``--rounds`` rounds (bakes run once per
implementation: minutes each). Ratios are PoCL's time over Intel's (> 1: Intel faster),
of the medians. Each run is a separate process with ``PRT_CL_DEVICE`` naming the
implementation's platform.

Run from the project root, nothing else heavy running:
  python benchmarks/bench_opencl_cpus.py --workdir /tmp/bench_cpus
Writes benchmarks/results/opencl_cpus.json (``--out``).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
IMPLEMENTATIONS = {"pocl": "Portable", "intel-cpu": "Intel"}  # -> PRT_CL_DEVICE
SCENES = {"d2i": "cornell_box.yaml", "triple": "bunny_grace.yaml", "sg": "bunny_sg.yaml"}


def frame_times(scene: str, workdir: str, size: str, frames: int) -> dict:
    """In this process: ``frames`` renders of the scene's first method after one warm-up."""
    from pipeline import cl, job
    from pipeline.cli import parse_size
    from pipeline.devices import implementation

    sc = job.open_scene(Path(scene), parse_size(size))
    wd = job.workdir_for(sc, workdir)
    method = sc.methods[0]
    render = job.frame_renderer(sc, wd, method)
    render(sc)
    totals, kernels = [], []
    for _ in range(frames):
        start = time.perf_counter()
        frame = render(sc)
        totals.append((time.perf_counter() - start) * 1e3)
        kernels.append(frame.timings.get("kernel_ms", float("nan")))
    return {"method": method, "implementation": implementation(cl.device()),
            "device": cl.device().name.strip(), "frame_ms": totals, "kernel_ms": kernels}


def run_json(args: list[str], env: dict) -> dict:
    out = subprocess.run([sys.executable, *args], capture_output=True, text=True, env=env,
                         cwd=ROOT, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def bake(scene: Path, workdir: Path, size: str, env: dict) -> dict:
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "pipeline", "run", str(scene), "--size",
                           size, "--workdir", str(workdir), "--frames",
                           str(workdir / "frames"), "-q"], capture_output=True, text=True,
                          env=env, cwd=ROOT)
    if done.returncode:
        raise SystemExit(f"prt run failed: {done.stderr[-2000:]}")
    wall = time.perf_counter() - start
    from pipeline.errors import PrtError
    from pipeline.store import read_record

    stages = {}
    for artifact in workdir.rglob("*.zarr"):
        try:
            record = read_record(artifact)
        except PrtError:  # a group inside an artifact, or a reference image
            continue
        if record and "seconds" in record:
            stages[artifact.name.removesuffix(".zarr")] = record["seconds"]
    return {"wall_s": wall, "stage_s": stages}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--workdir", type=Path, required=True)
    parser.add_argument("--size", default="64x64")
    parser.add_argument("--frames", type=int, default=7)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--methods", default=",".join(SCENES))
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/opencl_cpus.json")
    parser.add_argument("--frame-worker", nargs=3, metavar=("SCENE", "WORKDIR", "SIZE"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.frame_worker:
        print(json.dumps(frame_times(*args.frame_worker, args.frames)))
        return
    from pipeline.devices import cpu_model

    result: dict = {"cpu": cpu_model(), "cores": os.cpu_count(), "size": args.size,
                    "frames": args.frames, "rounds": args.rounds, "methods": {}}
    for method in args.methods.split(","):
        scene = ROOT / "scenes" / SCENES[method]
        entry: dict = {"scene": SCENES[method], "bake": {}, "frame": {}}
        for impl, platform in IMPLEMENTATIONS.items():
            env = {**os.environ, "PRT_CL_DEVICE": platform}
            entry["bake"][impl] = bake(scene, args.workdir / method / impl, args.size, env)
            print(f"{method} bake on {impl}: {entry['bake'][impl]['wall_s']:.1f} s", flush=True)
        for _ in range(args.rounds):
            for impl, platform in IMPLEMENTATIONS.items():
                env = {**os.environ, "PRT_CL_DEVICE": platform}
                got = run_json([__file__, "--workdir", str(args.workdir), "--frames",
                                str(args.frames), "--frame-worker", str(scene),
                                str(args.workdir / method / impl), args.size], env)
                assert got["implementation"] == impl, got
                slot = entry["frame"].setdefault(impl, {"frame_ms": [], "kernel_ms": []})
                slot["frame_ms"] += got["frame_ms"]
                slot["kernel_ms"] += got["kernel_ms"]
        med = {impl: {k: statistics.median(v) for k, v in f.items()}
               for impl, f in entry["frame"].items()}
        entry["frame_median_ms"] = med
        entry["pocl_over_intel"] = {
            "bake_wall": entry["bake"]["pocl"]["wall_s"] / entry["bake"]["intel-cpu"]["wall_s"],
            "frame": med["pocl"]["frame_ms"] / med["intel-cpu"]["frame_ms"],
            "frame_kernels": med["pocl"]["kernel_ms"] / med["intel-cpu"]["kernel_ms"]}
        print(f"{method}: PoCL / Intel {entry['pocl_over_intel']}", flush=True)
        result["methods"][method] = entry
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()

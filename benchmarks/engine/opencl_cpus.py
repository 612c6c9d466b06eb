"""PoCL against Intel's CPU OpenCL runtime: each method's bake and frame on each, medians.

The two CPU OpenCL implementations against each other, PoCL and Intel's CPU runtime:
each method's bake and frame timed on each, medians and PoCL's time over Intel's.

PoCL is pyopencl's (LLVM 14), compared with Intel's CPU runtime where both work; the
default order of pipeline/device/devices.py ``CPU_ORDER`` follows the faster.

Per method, its default scene at ``--size`` (d2i: the Cornell box, triple: bunny_grace,
sg: bunny_sg; ``--scene METHOD=FILE`` another):

* bake: ``prt run SCENE --size WxH`` from an empty work directory (each implementation
  its own, emptied first), wall seconds, and the seconds of each stage from the stage
  records;
* frame: the method's frame rendered ``--frames`` times in one process after a warm-up
  (its artifacts loaded once, kernels built): the median of the frame's own total and
  of its kernels' milliseconds (event profiling).

Implementations alternate within each of ``--rounds`` rounds (bakes run once per
implementation: minutes each). Ratios are PoCL's time over Intel's (> 1: Intel faster),
of the medians, given only when both were measured (``--implementations``: which;
``available``: those this machine has). Each run is a separate process with
``PRT_CL_DEVICE`` naming the implementation's platform.

Run nothing else heavy beside it: ``python -m benchmarks run engine.opencl_cpus``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from benchmarks.fixtures import CACHE, ROOT, SCENES, TINY, load, median, write_result

NAME = "engine.opencl_cpus"
IMPLEMENTATIONS = {"pocl": "Portable", "intel-cpu": "Intel"}  # -> PRT_CL_DEVICE
METHOD_SCENES = {"d2i": "cornell_box.yaml", "triple": "bunny_grace.yaml",
                 "sg": "bunny_sg.yaml"}
PRESETS = {"default": [],
           "tiny": ["--methods", "d2i", "--scene", f"d2i={TINY / 'tiny_d2i.yaml'}", "--size",
                    "8x8", "--frames", "1", "--rounds", "1", "--implementations",
                    "available", "--workdir", str(CACHE / "engine.opencl_cpus_tiny")]}


def frame_times(scene: str, workdir: str, size: str, frames: int) -> dict:
    """In this process: ``frames`` renders of the scene's first method after one warm-up."""
    from pipeline import job
    from pipeline.cli import parse_size
    from pipeline.device import cl
    from pipeline.device.devices import implementation

    sc = job.open_scene(Path(scene), parse_size(size))
    wd = job.workdir_for(sc, workdir)
    method = sc.methods[0]
    render = job.frame_renderer(sc, wd, method)
    render.frame(sc)
    totals, kernels = [], []
    for _ in range(frames):
        start = time.perf_counter()
        frame = render.frame(sc)
        totals.append((time.perf_counter() - start) * 1e3)
        kernels.append(frame.timings.get("kernel_ms", float("nan")))
    return {"method": method, "implementation": implementation(cl.device()),
            "device": cl.device().name.strip(), "frame_ms": totals, "kernel_ms": kernels}


def run_json(args: list[str], env: dict) -> dict:
    """This module run as ``python -m`` with ``args`` (a frame worker): its last line."""
    out = subprocess.run([sys.executable, "-m", __spec__.name, *args], capture_output=True,
                         text=True, env=env, cwd=ROOT, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def available() -> list[str]:
    """The implementations of IMPLEMENTATIONS this machine's OpenCL loader finds."""
    from pipeline.device.devices import candidates

    found = {c.implementation for c in candidates()}
    return [impl for impl in IMPLEMENTATIONS if impl in found]


def bake(scene: Path, workdir: Path, size: str, env: dict) -> dict:
    """``prt run`` of ``scene`` in an emptied ``workdir``: wall and stage seconds."""
    shutil.rmtree(workdir, ignore_errors=True)
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "pipeline", "run", str(scene), "--size",
                           size, "--workdir", str(workdir), "--frames",
                           str(workdir / "frames"), "-q"], capture_output=True, text=True,
                          env=env, cwd=ROOT)
    if done.returncode:
        raise SystemExit(f"prt run failed: {done.stderr[-2000:]}")
    wall = time.perf_counter() - start
    from pipeline.engine.store import read_record
    from pipeline.errors import PrtError

    stages = {}
    for artifact in workdir.rglob("*.zarr"):
        try:
            record = read_record(artifact)
        except PrtError:  # a group inside an artifact, or a reference image
            continue
        if record and "seconds" in record:
            stages[artifact.name.removesuffix(".zarr")] = record["seconds"]
    return {"wall_s": wall, "stage_s": stages}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME} --",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--workdir", type=Path, default=CACHE / NAME,
                        help="folder for the bakes [default: %(default)s]")
    parser.add_argument("--size", default="64x64")
    parser.add_argument("--frames", type=int, default=7)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--methods", default=",".join(METHOD_SCENES))
    parser.add_argument("--scene", dest="scenes", action="append", default=[],
                        metavar="METHOD=FILE", help="a method's scene over its default")
    parser.add_argument("--implementations", default=",".join(IMPLEMENTATIONS),
                        help="comma-separated, of " + ", ".join(IMPLEMENTATIONS) +
                        ", or 'available': those found here [default: %(default)s]")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--frame-worker", nargs=3, metavar=("SCENE", "WORKDIR", "SIZE"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.frame_worker:
        got = frame_times(*args.frame_worker, args.frames)
        print(json.dumps(got))
        return got
    scenes = {m: SCENES / f for m, f in METHOD_SCENES.items()}
    scenes.update({m: Path(f).resolve() for m, _, f in (t.partition("=") for t in args.scenes)})
    impls = available() if args.implementations == "available" else \
        args.implementations.split(",")
    if not impls or set(impls) - set(IMPLEMENTATIONS):
        parser.error(f"--implementations: of {', '.join(IMPLEMENTATIONS)}, not {impls}")
    result: dict[str, Any] = {"size": args.size, "frames": args.frames, "rounds": args.rounds,
                              "implementations": impls, "load": [load()], "methods": {}}
    for method in args.methods.split(","):
        scene = scenes[method]
        entry: dict[str, Any] = {"scene": scene.name if scene.parent == SCENES else str(scene),
                                 "bake": {}, "frame": {}}
        for impl in impls:
            env = {**os.environ, "PRT_CL_DEVICE": IMPLEMENTATIONS[impl]}
            entry["bake"][impl] = bake(scene, args.workdir / method / impl, args.size, env)
            print(f"{method} bake on {impl}: {entry['bake'][impl]['wall_s']:.1f} s", flush=True)
        for _ in range(args.rounds):
            for impl in impls:
                env = {**os.environ, "PRT_CL_DEVICE": IMPLEMENTATIONS[impl]}
                got = run_json(["--frames", str(args.frames), "--frame-worker", str(scene),
                                str(args.workdir / method / impl), args.size], env)
                assert got["implementation"] == impl, got
                slot = entry["frame"].setdefault(impl, {"frame_ms": [], "kernel_ms": []})
                slot["frame_ms"] += got["frame_ms"]
                slot["kernel_ms"] += got["kernel_ms"]
        med = {impl: {k: median(v) for k, v in f.items()} for impl, f in entry["frame"].items()}
        entry["frame_median_ms"] = med
        if {"pocl", "intel-cpu"} <= set(impls):
            entry["pocl_over_intel"] = {
                "bake_wall": entry["bake"]["pocl"]["wall_s"]
                / entry["bake"]["intel-cpu"]["wall_s"],
                "frame": med["pocl"]["frame_ms"] / med["intel-cpu"]["frame_ms"],
                "frame_kernels": med["pocl"]["kernel_ms"] / med["intel-cpu"]["kernel_ms"]}
            print(f"{method}: PoCL / Intel {entry['pocl_over_intel']}", flush=True)
        result["methods"][method] = entry
        # after each method: a cut run keeps it
        written = write_result(NAME, {**result, "load": [*result["load"], load()]}, args.out)
    return written


if __name__ == "__main__":  # a frame worker (run_json)
    main()

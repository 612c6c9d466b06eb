"""Method triple's camera-move frame at 1024×768, top-only 80: NumPy G-buffer against the kernel.

Aim ≥ 5 fps on the CPU; the G-buffer's surface attributes in NumPy against the device
kernel, in one run. Issue 16: before and after the G-buffer's surface attributes moved
to the device (kernel ``triple_surface``). bunny_grace baked at its own 256² (the bake
of benchmarks/triple/frames.py, fixtures ``baked``) and rendered at
``--width``×``--height``:

* ``gbuffer``: the G-buffer of one camera, NumPy (``camera_gbuffer_numpy``, what every
  camera move ran before) against the kernel path (``camera_gbuffer``), alternated
  ``--repeats`` times; the kernel path split into camera rays, Embree trace, surface
  kernel (uploads and read-back included) and the rest, and the frame-grid angles
  (kernel ``triple_angles``, run once per camera);
* ``trace``: Embree's primary-ray rate (rays/s) as the G-buffer calls it (batches of
  32768 on the task's threads), in one call on one thread, and with the rays reordered
  into 8×8-pixel tiles (coherent batches); and the project's BVH kernel's
  (``device_bvh``, ``--option trace=device``; transfers included);
* ``frames``: camera-move frames through the renderer (the camera orbits 3° per frame),
  alternately with the NumPy G-buffer (before) and the kernel (after): medians of the
  frame's parts (renderer timings) and of the process's CPU time;
* ``identical``: one camera's frame shaded from both G-buffers: the largest difference
  of the shaded pixels, relative to the frame's largest value.

Timings on a shared machine are contended: the load average is recorded with each.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.fixtures import TINY, cpu_ms, load, median, medians, write_result
from benchmarks.triple.frames import SCENE, orbit, tracer_and_mesh, triple_bake

NAME = "triple.camera"
PRESETS = {"default": [],
           "tiny": ["--scene", str(TINY / "tiny_triple.yaml"), "--width", "16", "--height", "16",
                    "--frames", "1", "--repeats", "1", "--budget", "20"]}


def gbuffer_parts(tracer: Any, mesh: Any, atlas: Any, detail: Any, cam: Any,
                  tables: Any) -> dict[str, float]:
    """Milliseconds of the kernel path's parts (as ``camera_gbuffer`` runs them)."""
    from pipeline.methods.triple import render
    from pipeline.methods.triple.gbuffer import surface_attributes
    from pipeline.render.rays import aligned_image_rays

    t0 = time.perf_counter()
    origins, directions = aligned_image_rays(cam)
    t1 = time.perf_counter()
    hits = tracer.intersect(origins, directions)
    t2 = time.perf_counter()
    pixel = np.flatnonzero(hits.prim >= 0)
    surface_attributes(mesh, atlas.face_uv, hits, directions, pixel)
    t3 = time.perf_counter()
    whole = render.camera_gbuffer(tracer, mesh, atlas, detail, cam)
    t4 = time.perf_counter()
    _, angles_device_ms = whole.angles(tables.frames, tables.views)
    t5 = time.perf_counter()
    return {"camera_rays_ms": (t1 - t0) * 1e3, "trace_ms": (t2 - t1) * 1e3,
            "surface_kernel_ms": (t3 - t2) * 1e3, "camera_gbuffer_ms": (t4 - t3) * 1e3,
            "angles_ms": (t5 - t4) * 1e3, "angles_device_ms": angles_device_ms,
            "rays": cam.width * cam.height, "shaded": len(pixel), "load": load()[0]}


def trace_rates(tracer: Any, cam: Any, repeats: int, device: Any = None
                ) -> dict[str, Any]:
    """Primary rays per second: as the G-buffer traces them, one call on one thread,
    and reordered into 8×8 tiles (batches as the G-buffer's)."""
    from pipeline.math.camera import camera_rays

    o, d = camera_rays(cam.position, cam.look_at, cam.up, cam.fov, cam.width, cam.height)
    h, w = cam.height, cam.width
    tiles = np.arange(h * w).reshape(h // 8, 8, w // 8, 8).transpose(0, 2, 1, 3).reshape(-1)
    flat_o, flat_d = o.reshape(-1, 3), d.reshape(-1, 3)
    tiled_o, tiled_d = flat_o[tiles], flat_d[tiles]  # reordered outside the timing
    variants = {
        "batched": lambda: tracer.intersect(flat_o, flat_d),
        "one_call_one_thread": lambda: tracer.scene.run(flat_o, flat_d, output=1),
        "tiles_8x8_batched": lambda: tracer.intersect(tiled_o, tiled_d),
    }
    if device is not None:  # the project's BVH kernel (--option trace=device)
        variants["device_bvh"] = lambda: device.intersect(flat_o, flat_d)
    out: dict[str, Any] = {"threads": tracer.threads}
    for name, fn in variants.items():
        fn()  # warm-up
        times, loads = [], []
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
            loads.append(load()[0])
        out[name] = {"median_ms": median(times) * 1e3, "rays_per_s": len(flat_o) / median(times),
                     "load": loads}
    return out


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME} --",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--scene", type=Path, default=SCENE)
    parser.add_argument("--width", type=int, default=1024, help="a multiple of 8")
    parser.add_argument("--height", type=int, default=768, help="a multiple of 8")
    parser.add_argument("--frames", type=int, default=6)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--budget", type=int, default=80)
    parser.add_argument("--workdir", type=Path, default=None,
                        help="bake there [default: a cache folder per scene and size]")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)

    from pipeline.math.brdf import scene_brdfs
    from pipeline.methods.triple import render
    from pipeline.methods.triple.dense import DenseTables, dense_level
    from pipeline.methods.triple.gbuffer import LookupTables
    from pipeline.render.surface_detail import SceneDetail

    scene, artifacts = triple_bake(args.scene, workdir=args.workdir)
    big = scene.with_image_size(args.width, args.height)
    cam = big.camera
    names = artifacts["geometry"].attrs["material_names"]
    tables, atlas = render.load_tables(artifacts, names)
    tables = tables.truncated("top-only", args.budget)
    tracer, mesh = tracer_and_mesh(artifacts)
    detail = SceneDetail(scene, names)
    result: dict[str, Any] = {"scene": scene.name, "size": [args.width, args.height],
                              "budget": args.budget, "cpus": os.cpu_count(),
                              "load_average_start": load()[0]}

    # G-buffer: NumPy against the kernel path, alternated; the kernel path's parts.
    render.camera_gbuffer(tracer, mesh, atlas, detail, cam)  # warm-up: Embree, kernel build
    numpy_ms, kernel_ms, parts = [], [], []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        render.camera_gbuffer_numpy(tracer, mesh, atlas, detail, cam)
        t1 = time.perf_counter()
        render.camera_gbuffer(tracer, mesh, atlas, detail, cam)
        kernel_ms.append((time.perf_counter() - t1) * 1e3)
        numpy_ms.append((t1 - t0) * 1e3)
        parts.append(gbuffer_parts(tracer, mesh, atlas, detail, cam, tables))
    result["gbuffer"] = {"numpy_ms": median(numpy_ms), "kernel_ms": median(kernel_ms),
                         "ratio": median(numpy_ms) / median(kernel_ms),
                         "kernel_parts": medians(parts),
                         "all": {"numpy_ms": numpy_ms, "kernel_ms": kernel_ms,
                                 "parts": parts}}
    print("gbuffer", json.dumps({k: v for k, v in result["gbuffer"].items() if k != "all"},
                                default=float), flush=True)
    from pipeline.device.bvh import DeviceRayTracer

    geometry = artifacts["geometry"]
    result["trace"] = trace_rates(tracer, cam, args.repeats, DeviceRayTracer(
        geometry.read("vertices"), geometry.read("faces")))
    print("trace", json.dumps(result["trace"], default=float), flush=True)

    # Frames identical: one camera shaded from both G-buffers (dense top-only path).
    brdfs = scene_brdfs(scene, names)
    lookup = LookupTables.of(tables, atlas, np.array([b.albedo for b in brdfs]),
                             np.array([b.specular for b in brdfs]))
    dense = DenseTables.from_tables(tables, dense_level("top-only", args.budget))
    shaded = [render.shade_gbuffer(tables, dense, make(tracer, mesh, atlas, detail, cam),
                                   lookup, 0.3, {})[0]
              for make in (render.camera_gbuffer_numpy, render.camera_gbuffer)]
    difference, largest = np.abs(shaded[0] - shaded[1]), np.abs(shaded[0]).max()
    result["identical"] = {"max_abs": float(difference.max()), "max_value": float(largest),
                           "relative": float(difference.max() / largest),
                           "pixels_differing_1e-4": int((difference.max(1)
                                                         > 1e-4 * largest).sum())}
    print("identical", result["identical"], flush=True)

    # Camera-move frames through the renderer, alternating the G-buffer's path.
    renderer = render.TripleRenderer(scene, artifacts, args.budget, "top-only")
    kernel_gbuffer = render.camera_gbuffer
    paths = {"before_numpy": render.camera_gbuffer_numpy, "after_kernel": kernel_gbuffer}
    renderer.frame(orbit(big, 0.0))  # warm-up
    rows: dict[str, list[dict[str, float]]] = {k: [] for k in paths}
    try:
        for k in range(args.frames):
            for j, (name, fn) in enumerate(paths.items()):
                render.camera_gbuffer = fn  # the renderer looks it up at each new camera
                c0 = cpu_ms()
                frame = renderer.frame(orbit(big, 3.0 * (2 * k + j + 1)))
                rows[name].append({**frame.timings, "cpu_ms": cpu_ms() - c0,
                                   "load": load()[0]})
    finally:
        render.camera_gbuffer = kernel_gbuffer
    result["frames"] = {name: {"median": medians(rs), "all": rs} for name, rs in rows.items()}
    before, after = (result["frames"][n]["median"] for n in paths)
    result["frames"]["ratio_total"] = before["total_ms"] / after["total_ms"]
    result["frames"]["fps_after"] = 1e3 / after["total_ms"]
    for name in paths:
        m = result["frames"][name]["median"]
        print(name, {k: round(m[k], 1) for k in ("gbuffer_ms", "angles_ms", "shade_ms",
                                                  "background_ms", "total_ms", "cpu_ms",
                                                  "load")}, flush=True)
    result["load_average_end"] = load()[0]
    return write_result(NAME, result, args.out)

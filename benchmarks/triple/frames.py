"""Method triple's frame time per budget at 1024×768: frame parts, kernel bandwidth, sparse path.

The camera-move and environment-rotation frames, their parts, the dense kernel's
bandwidth and the sparse path's estimate, on bunny_grace. Issue 16, "Rendering" and
"Must show". bunny_grace baked at its own 256² (``--bake-size`` otherwise; fixtures
``baked``: a cache folder later runs reuse) and rendered at ``--width``×``--height``
(the atlas and visibility textures are sized for 256²: a 1024×768 bake would hold ~12×
the texels — visibility ~30 min of Embree on 2 quiet cores and ~360 MB — while the
kernel's per-pixel work does not depend on the texture's resolution: 4 texel rows either
way; a finer texture only spreads the rows a frame reads over more memory). Measured, in
one run on this machine, for each budget (top-only 20 / 80 / 320: the dense path; 0 = as
stored: the sparse path):

* camera-move frames (the camera orbits a few degrees each frame: G-buffer traced) and
  environment-rotation frames (camera unchanged: G-buffer cached), medians over
  ``--frames``, split into G-buffer (trace + surface interpolation + texel coordinates),
  lookups (device; 0 where fused into the dense kernel), shading kernel, background
  kernel and the rest of the frame (host assembly);
* the G-buffer's parts (trace, surface attributes, texel coordinates, upload) once;
* the dense kernel's bandwidth: the bytes it must move (the distinct table rows the
  frame's pixels read, the G-buffer, the output) over its median time, as a fraction
  of the memory-bandwidth probe (fixtures ``bandwidth_probe``);
* the general sparse kernel on the same top-only rows (80, 320) and as stored, timed on
  every ``--stride``-th G-buffer pixel (a full 1024×768 sparse frame takes minutes on
  this CPU) and scaled to the whole frame: an estimate, marked as such.

Timings on a shared machine are contended: the load average is recorded with each. The
chart (stacked bars per budget) is written beside the JSON (``.png``).

Also what the other triple benchmarks share: the scene, its bake, the traced geometry
and the orbiting camera.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.fixtures import (
    SCENES,
    TINY,
    baked,
    bandwidth_probe,
    cpu_ms,
    load,
    median,
    medians,
    result_path,
    write_result,
)

NAME = "triple.frames"
SCENE = SCENES / "bunny_grace.yaml"
PRESETS = {"default": [],
           "tiny": ["--scene", str(TINY / "tiny_triple.yaml"), "--width", "16", "--height", "16",
                    "--frames", "1", "--budgets", "20,0", "--stride", "4"]}
GBUFFER_ARRAYS = ("normal", "tangent", "view", "texel_xy", "object", "material_a",
                  "material_b", "blend")


def triple_bake(scene_file: Path, size: int | None = None, workdir: Path | None = None
                ) -> tuple[Any, dict[str, Any]]:
    """The scene (at ``size``² if given) baked once (fixtures ``baked``) and method
    triple's artifacts."""
    from pipeline import job
    from pipeline.registry import get_method

    scene, work = baked(scene_file, size, workdir=workdir)
    return scene, job.method_artifacts(get_method("triple"), work)


def tracer_and_mesh(artifacts: dict[str, Any]) -> tuple[Any, Any]:
    """Embree's tracer and the mesh of the baked geometry, as the renderer builds them."""
    from pipeline.device.raytrace import Mesh, RayTracer

    geo = artifacts["geometry"]
    arrays = {n: geo.read(n) for n in
              ("vertices", "normals", "uv", "faces", "face_object", "object_material")}
    return RayTracer(arrays["vertices"], arrays["faces"]), Mesh.from_arrays(arrays)


def orbit(scene: Any, degrees: float) -> Any:
    """``scene`` with its camera turned ``degrees`` about +y through its look-at point."""
    from pipeline.scene.edits import with_camera_position

    cam = scene.camera
    offset = np.subtract(cam.position, cam.look_at)
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    turned = (c * offset[0] + s * offset[2], offset[1], -s * offset[0] + c * offset[2])
    return with_camera_position(scene, tuple(np.add(cam.look_at, turned)))


def frame_series(renderer: Any, scenes: list[Any]) -> dict[str, Any]:
    """Timings of frames rendered in order: per key the median and every value
    (``cpu_ms``: the process's CPU time over the frame)."""
    rows = []
    for scene in scenes:
        c0 = cpu_ms()
        frame = renderer.frame(scene)
        rows.append({**frame.timings, "cpu_ms": cpu_ms() - c0,
                     "kernel_bytes": frame.kernel_bytes, "load": load()[0]})
    return {"median": medians([{k: v for k, v in r.items() if k != "load"} for r in rows]),
            "frames": rows, "load_average": [r["load"] for r in rows]}


def gbuffer_parts(renderer_inputs: dict[str, Any], cam: Any) -> dict[str, float]:
    """Milliseconds of the G-buffer's parts for one camera (as camera_gbuffer does)."""
    from pipeline.device import cl
    from pipeline.device.raytrace import surface_at
    from pipeline.math.camera import camera_rays

    tracer, mesh, atlas = (renderer_inputs[k] for k in ("tracer", "mesh", "atlas"))
    t0 = time.perf_counter()
    origins, directions = camera_rays(cam.position, cam.look_at, cam.up, cam.fov,
                                      cam.width, cam.height)
    origins, directions = origins.reshape(-1, 3), directions.reshape(-1, 3)
    t1 = time.perf_counter()
    hits = tracer.intersect(origins, directions)
    t2 = time.perf_counter()
    hit = hits.prim >= 0
    d = directions[hit].astype(np.float64)
    surface = surface_at(mesh, hits.select(hit), origins[hit].astype(np.float64), d)
    normal, tangent, obj = surface.normal, surface.tangent, surface.object_id
    t3 = time.perf_counter()
    texel = atlas.texel_xy(surface)
    t4 = time.perf_counter()
    for a in (normal, tangent, d, texel, obj):
        cl.read_only_buffer(np.ascontiguousarray(a, np.float32)).release()
    t5 = time.perf_counter()
    return {"camera_rays_ms": (t1 - t0) * 1e3, "trace_ms": (t2 - t1) * 1e3,
            "surface_ms": (t3 - t2) * 1e3, "texel_ms": (t4 - t3) * 1e3,
            "upload_ms": (t5 - t4) * 1e3, "rays": len(directions),
            "shaded_pixels": int(hit.sum()), "load": load()[0]}


def touched_bytes(dense: Any, lookups: Any) -> int:
    """Bytes of the distinct dense-table rows the pixels read (non-zero weights)."""
    total = 0
    for rows, weight, table in ((lookups.light_rows, lookups.light_weight, dense.light),
                                (lookups.vis_rows, lookups.vis_weight, dense.visibility),
                                (lookups.brdf_rows, np.abs(lookups.brdf_weight).sum(-1),
                                 dense.brdf)):
        distinct = np.unique(rows[weight != 0])
        total += len(distinct) * table[0].nbytes
    return int(total)


def kernel_only(tables: Any, dense: Any, gbuffer: Any, lookup: Any, repeats: int
                ) -> dict[str, Any]:
    """The dense kernel (lookups fused) and, apart, the lookups kernel alone, launched
    back to back on a cached G-buffer: median device ms and process CPU ms."""
    from pipeline.methods.triple.gbuffer import device_lookups
    from pipeline.methods.triple.render import shade_gbuffer

    static: dict[str, Any] = {}
    shade_gbuffer(tables, dense, gbuffer, lookup, 0.3, static)  # warm-up
    device_lookups(gbuffer, tables, lookup, 0.3, static)
    out: dict[str, list[float]] = {k: [] for k in ("kernel_ms", "kernel_cpu_ms",
                                                   "lookups_ms", "lookups_cpu_ms", "load")}
    for _ in range(repeats):
        c0 = cpu_ms()
        _, times, _ = shade_gbuffer(tables, dense, gbuffer, lookup, 0.3, static)
        c1 = cpu_ms()
        _, ms = device_lookups(gbuffer, tables, lookup, 0.3, static)
        out["kernel_ms"].append(times["kernel_ms"])
        out["kernel_cpu_ms"].append(c1 - c0)
        out["lookups_ms"].append(ms)
        out["lookups_cpu_ms"].append(cpu_ms() - c1)
        out["load"].append(load()[0])
    return {**{k: median(v) for k, v in out.items() if k != "load"}, "all": out}


def sparse_estimate(tables: Any, gbuffer: Any, lookup: Any, turn: float, stride: int,
                    repeats: int) -> dict[str, Any]:
    """The general sparse path (device lookups + merge kernel) on every ``stride``-th
    shaded pixel: median milliseconds (device; ``cpu_ms`` the process's CPU time, the
    angles included) and those × shaded / timed pixels (an estimate of the frame)."""
    from pipeline.methods.triple.render import shade_gbuffer

    pick = np.arange(0, gbuffer.count, stride)
    sub = dataclasses.replace(gbuffer, pixel=gbuffer.pixel[pick],
                              **{k: getattr(gbuffer, k)[pick] for k in GBUFFER_ARRAYS})
    lookup_ms, kernel_ms, cpu, loads = [], [], [], []
    for _ in range(repeats):
        c0 = cpu_ms()
        _, times, _ = shade_gbuffer(tables, None, sub, lookup, turn, {})
        cpu.append(cpu_ms() - c0)
        lookup_ms.append(times["lookup_ms"])
        kernel_ms.append(times["kernel_ms"])
        loads.append(load()[0])
    scale = gbuffer.count / len(pick)
    return {"pixels_timed": len(pick), "stride": stride, "repeats": repeats,
            "lookup_ms": median(lookup_ms), "kernel_ms": median(kernel_ms),
            "estimated_frame_kernel_ms": median(kernel_ms) * scale,
            "estimated_frame_lookup_ms": median(lookup_ms) * scale,
            "cpu_ms": median(cpu), "estimated_frame_cpu_ms": median(cpu) * scale,
            "kernel_ms_all": kernel_ms, "load_average": loads}


def chart(result: dict[str, Any], path: Path) -> None:
    """Stacked bars: per budget, rotation frame and camera-move frame."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    parts = [("gbuffer_ms", "G-buffer"), ("lookup_ms", "lookups"), ("shade_ms", "shading kernel"),
             ("background_ms", "background"), ("rest_ms", "rest (host)")]
    labels, bars, cpu, notes = [], [], [], []
    for name, entry in result["budgets"].items():
        for kind in ("rotation", "camera_move"):
            if kind not in entry:
                continue
            m = dict(entry[kind]["median"])
            m["rest_ms"] = max(m["total_ms"] - sum(m[k] for k, _ in parts[:-1]), 0.0)
            labels.append(f"{name}\n{'rotate' if kind == 'rotation' else 'camera'}")
            bars.append([m[k] for k, _ in parts])
            cpu.append(m["cpu_ms"] / 2.0)
        sparse = entry.get("sparse") or entry.get("sparse_same_rows")
        notes.append(f"{name}: sparse path ≈ {sparse['estimated_frame_kernel_ms'] / 1e3:.1f} s "
                     "kernel (estimate)")
    bars_arr = np.array(bars).reshape(len(bars), len(parts))
    fig, ax = plt.subplots(figsize=(9, 4.5))
    bottom = np.zeros(len(bars_arr))
    for j, (_, label) in enumerate(parts):
        ax.bar(range(len(bars_arr)), bars_arr[:, j], bottom=bottom, label=label)
        bottom += bars_arr[:, j]
    ax.scatter(range(len(cpu)), cpu, marker="D", color="k", zorder=3,
               label="process CPU time / 2 (a quiet 2-core estimate)")
    ax.text(0.99, 0.97, "\n".join(notes), transform=ax.transAxes, ha="right", va="top",
            fontsize=7)
    ax.axhline(200.0, color="k", ls="--", lw=1, label="5 fps")
    ax.set_xticks(range(len(labels)), labels, fontsize=8)
    ax.set_ylabel("ms per frame (median)")
    w, h = result["size"]
    ax.set_title(f"method triple, {result['scene']} {w}×{h}, dense top-only path: wall-clock "
                 f"medians at load average {result['load_average_start']:.1f}", fontsize=10)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME} --",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--scene", type=Path, default=SCENE)
    parser.add_argument("--width", type=int, default=1024)
    parser.add_argument("--height", type=int, default=768)
    parser.add_argument("--frames", type=int, default=5)
    parser.add_argument("--budgets", default="20,80,320,0")
    parser.add_argument("--stride", type=int, default=16,
                        help="sparse path: time every N-th pixel")
    parser.add_argument("--workdir", type=Path, default=None,
                        help="bake there [default: a cache folder per scene and size]")
    parser.add_argument("--bake-size", type=int, default=None,
                        help="bake at N×N instead of the scene's own size (a short GPU run: "
                             "the frame's per-pixel work does not depend on it)")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)

    from pipeline.math.brdf import scene_brdfs
    from pipeline.methods.triple import render
    from pipeline.methods.triple.dense import DenseTables, dense_level
    from pipeline.methods.triple.gbuffer import LookupTables, lookups_numpy
    from pipeline.render.surface_detail import SceneDetail
    from pipeline.scene.edits import with_environment_rotation

    scene, artifacts = triple_bake(args.scene, args.bake_size, args.workdir)
    big = scene.with_image_size(args.width, args.height)
    cam = big.camera
    rotations = [with_environment_rotation(big, 7.0 * (k + 1)) for k in range(args.frames)]
    moves = [orbit(big, 3.0 * (k + 1)) for k in range(args.frames)]
    result: dict[str, Any] = {
        "scene": scene.name, "bake_size": [scene.camera.width, scene.camera.height],
        "size": [args.width, args.height], "frames": args.frames,
        "load_average_start": load()[0], "budgets": {}}

    names = artifacts["geometry"].attrs["material_names"]
    tables_all, atlas = render.load_tables(artifacts, names)
    tracer, mesh = tracer_and_mesh(artifacts)
    inputs = {"tracer": tracer, "mesh": mesh, "atlas": atlas}
    gbuffer_parts(inputs, cam)  # warm-up (Embree scene build)
    result["gbuffer_parts"] = [gbuffer_parts(inputs, cam) for _ in range(3)]
    result["gbuffer_parts_median"] = medians(result["gbuffer_parts"])
    gbuffer = render.camera_gbuffer(tracer, mesh, atlas, SceneDetail(scene, names), cam)
    brdfs = scene_brdfs(scene, names)
    kd, rho_s = np.array([b.albedo for b in brdfs]), np.array([b.specular for b in brdfs])

    for budget in [int(b) for b in args.budgets.split(",")]:
        name = f"top-only {budget}" if budget else "as stored"
        t0 = time.perf_counter()
        renderer = render.TripleRenderer(scene, artifacts, budget, "top-only")
        entry: dict[str, Any] = {"renderer_load_s": time.perf_counter() - t0}
        level = dense_level("top-only", budget)
        tables = tables_all.truncated("top-only", budget) if budget else tables_all
        lookup = LookupTables.of(tables, atlas, kd, rho_s)
        if level is not None:
            renderer.frame(rotations[-1])  # first frame: kernel build, G-buffer, uploads
            entry["rotation"] = frame_series(renderer, rotations)
            entry["camera_move"] = frame_series(renderer, moves)
            dense = DenseTables.from_tables(tables, level)
            host = lookups_numpy(gbuffer, tables, lookup, 0.0)
            must = touched_bytes(dense, host) + sum(
                getattr(gbuffer, k).nbytes for k in GBUFFER_ARRAYS) + 12 * gbuffer.count
            shade_ms = entry["rotation"]["median"]["shade_ms"]
            entry["kernel_only"] = kernel_only(tables, dense, gbuffer, lookup, args.frames)
            entry["dense"] = {"level": level, "triangles": dense.triangles,
                              "table_mb": dense.nbytes / 1e6,
                              "bytes_must_move": must,
                              "effective_gbs": must / (shade_ms * 1e-3) / 1e9}
            entry["sparse_same_rows"] = sparse_estimate(tables, gbuffer, lookup, 0.0,
                                                        args.stride, 3)
        else:
            entry["sparse"] = sparse_estimate(tables, gbuffer, lookup, 0.0, args.stride, 3)
        entry["load_average_end"] = load()[0]
        result["budgets"][name] = entry
        print(name, json.dumps({k: v.get("median", v) if isinstance(v, dict) else v
                                for k, v in entry.items()}, default=float)[:900], flush=True)
        del renderer

    bandwidth = bandwidth_probe()
    result["bandwidth_probe"] = bandwidth
    for entry in result["budgets"].values():
        if "dense" in entry:
            entry["dense"]["bandwidth_fraction"] = \
                entry["dense"]["effective_gbs"] / bandwidth["opencl_copy_gbs"]
    result["load_average_end"] = load()[0]
    written = write_result(NAME, result, args.out)
    chart(result, result_path(NAME, args.out).with_suffix(".png"))
    return written

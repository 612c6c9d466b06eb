"""Method sg's frame time (issue 17): camera and map-rotation frames on synthetic tables.

The sg.fit and sg.diffuse stages were being built in parallel when this was written, so
the tables are synthetic but of the real size and layout (the artifact contract):
bunny_grace with the 6.6k-face bunny (3,301 vertices + the ground's 4, once welded: the
OBJ gives every face its own normal, so the geometry stage, through trimesh without
merging, keeps 3 vertices per face, 19,798 in all; both are measured), per vertex and
each of the 92 views 3 lobes of 7 floats, all 3 slots used on the bunny (the worst
case the kernel meets: it loops over the face's largest count), the ground diffuse
only (count 0). The lobes are plausible, not fitted: slot 0 along the mirror direction
of the view about the vertex normal (σ ≈ 4.7°), slot 1 tilted 10° from it (σ ≈ 10°),
slot 2 along the normal (σ ≈ 29°), weights 0 for views below the horizon; the
diffuse transfer is the unshadowed clamped-cosine one, kd/π Â_l Y_k(n), so the diffuse
term is kd/π times the irradiance. The map is Grace (1024 × 512), prefiltered here.
(``--scene``, ``--object``, ``--mesh``: another scene, its glossy object, that object's
mesh or ``scene``, the scene's own geometry.)

Measured in one run (the load averages recorded with each part):

* camera-move frames (the camera orbits 2° per frame: rays traced, view triangles
  looked up) and environment-rotation frames (10° per frame, camera kept), medians over
  ``--frames``, split into trace, view lookup, shading kernel, background kernel, SH
  rotation and the rest; for ``lambda_blend`` log and linear;
* the shading kernel's breakdown on the welded tables (camera fixed, kernels taking
  turns): every glossy vertex with 3, 2, 1 and 0 lobes (0: the diffuse SH term alone);
* the shading kernel's bandwidth: the bytes it loads and stores counting every
  gathered load (``render.sg.kernel_bytes``), and the distinct bytes (tables +
  per-pixel inputs + output), each over the median kernel time, as fractions of the
  memory-bandwidth probe (pipeline/device/bandwidth.py).

Run from the project root: python -m benchmarks run sg.frames [--tiny] [-- --width 1024
--height 768 --frames 7 --mesh ${PRT_DATA}/meshes/bunny_60kf.obj --variants welded].
The scene's geometry is baked once into benchmarks/fixtures.py's cache folder (or
``--workdir``); the frames (log blend, to look at) go to ``<result>/<variant>.png``
beside the result. Issue 17's frame-time point (512², a 10–50k-vertex model): ``--width
512 --height 512 --mesh ${PRT_DATA}/meshes/bunny_60kf.obj --variants welded``.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from benchmarks.fixtures import (
    SCENES,
    TINY,
    baked,
    bandwidth_probe,
    load,
    median,
    result_path,
    write_result,
)

PRESETS = {"default": [],
           "tiny": ["--scene", str(TINY / "tiny_sg.yaml"), "--object", "ball", "--mesh",
                    "scene", "--width", "16", "--height", "16", "--frames", "3"]}
SCENE = SCENES / "bunny_grace.yaml"
COARSE_MESH = "${PRT_DATA}/meshes/bunny_6.6kf.obj"
# clamped-cosine convolution per band l (Ramamoorthi & Hanrahan 2001): Â_l
COSINE_BANDS = (math.pi, 2.0 * math.pi / 3.0, math.pi / 4.0, 0.0, -math.pi / 24.0)


def synthetic_tables(geometry: dict, env: np.ndarray, obj: str = "bunny"
                     ) -> tuple[Any, float]:
    """Contract-shaped tables (module docstring), glossy on the vertices of ``obj``'s
    material, and the prefilter's seconds."""
    from pipeline.math import sg, sh
    from pipeline.methods.sg.prefilter import prefilter
    from pipeline.methods.sg.render import SgTables
    from pipeline.methods.sg.transport import view_directions

    normals = np.asarray(geometry["normals"], np.float64)
    vertices = len(normals)
    material = np.asarray(geometry["object_material"])[np.asarray(geometry["face_object"])]
    glossy = np.zeros(vertices, bool)
    shiny = np.asarray(geometry["object_material"])[list(geometry["object_names"]).index(obj)]
    glossy[np.asarray(geometry["faces"])[material == shiny].ravel()] = True
    views = view_directions()
    cos_nv = normals @ views.T  # (V, 92)
    mirror = 2.0 * cos_nv[..., None] * normals[:, None, :] - views[None]  # (V, 92, 3)
    tangent = np.cross(normals, [0.0, 1.0, 0.0]) + np.cross(normals, [1.0, 0.0, 0.0]) * 1e-3
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    tilt = np.radians(10.0)
    tilted = np.cos(tilt) * mirror + np.sin(tilt) * tangent[:, None, :]
    tilted /= np.linalg.norm(tilted, axis=2, keepdims=True)
    lobes = np.zeros((vertices, len(views), 3, 7), np.float32)
    for slot, (mu, sigma_deg, weight) in enumerate((
            (mirror, 4.7, [0.30, 0.30, 0.30]), (tilted, 10.0, [0.05, 0.04, 0.03]),
            (np.broadcast_to(normals[:, None, :], mirror.shape), 29.0, [0.01, 0.01, 0.01]))):
        lobes[:, :, slot, 3:6] = mu
        lobes[:, :, slot, 6] = 1.0 / np.radians(sigma_deg) ** 2
        lobes[:, :, slot, 0:3] = weight
    lobes[..., 0:3] *= ((cos_nv > 0) & glossy[:, None])[..., None, None]
    count = np.where(glossy, 3, 0).astype(np.uint8)
    albedo = np.where(glossy[:, None], [0.55, 0.45, 0.35], [0.5, 0.5, 0.5])
    bands = np.repeat(COSINE_BANDS, [2 * band + 1 for band in range(sh.ORDER)])
    transfer = (albedo / math.pi)[:, :, None] * (bands * sh.basis(normals))[:, None, :]
    levels = sg.prefilter_levels(*env.shape[:2])
    t0 = time.perf_counter()
    stack = [level.astype(np.float32) for level in prefilter(env, levels)]
    seconds = time.perf_counter() - t0
    return SgTables.from_dense(lobes, count, transfer, stack, levels,
                               slots=count), seconds


def scene_and_geometry(scene_file: Path, obj: str, width: int, height: int,
                       mesh: str = COARSE_MESH, workdir: Path | None = None
                       ) -> tuple[Any, dict]:
    """``scene_file`` at ``width`` × ``height``, its object ``obj`` given ``mesh``
    (``scene``: its own), method direct only, named after the mesh (its cache folder);
    and its geometry, baked (benchmarks/fixtures.py ``baked``)."""
    from pipeline import job
    from pipeline.scene.file import scene_from_document

    scene_file = Path(scene_file).resolve()
    doc = yaml.safe_load(scene_file.read_text())
    if mesh != "scene":
        spec = doc["objects"][obj]
        spec.pop("primitive", None)
        spec["mesh"] = mesh
        doc["name"] = f"{doc['name']}_{re.sub(r'[^A-Za-z0-9_-]', '_', Path(mesh).stem)}"
    doc["camera"].update(width=width, height=height)
    doc["methods"] = ["direct"]
    scene, work = baked(scene_from_document(scene_file, doc), workdir=workdir,
                        until="geometry")
    geometry, _ = job.load_geometry(scene, work)
    return scene, geometry


def welded(geometry: dict) -> dict:
    """The geometry with vertices at equal positions merged and area-weighted normals
    recomputed (as the geometry stage computes them)."""
    unique, inverse = np.unique(np.asarray(geometry["vertices"]), axis=0, return_inverse=True)
    faces = inverse.ravel()[np.asarray(geometry["faces"])]
    corner = unique[faces]
    cross = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])
    normals = np.zeros_like(unique)
    for i in range(3):
        np.add.at(normals, faces[:, i], cross)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return {**geometry, "vertices": unique.astype(np.float32), "faces": faces,
            "normals": normals}


def run_frames(renderers: dict[str, Any], scenes: list[Any]) -> dict[str, dict[str, Any]]:
    """Per renderer, medians of the frames' timings; the renderers take turns frame by
    frame, so that the machine's load falls on each alike."""
    before = load()
    timings: dict[str, list[dict]] = {name: [] for name in renderers}
    for s in scenes:
        for name, frames_of in renderers.items():
            timings[name].append(frames_of.frame(s).timings)
    after = load()
    keys = ("total_ms", "trace_ms", "view_lookup_ms", "shade_ms", "background_ms", "sh_ms")
    out = {}
    for name, rows in timings.items():
        entry: dict[str, Any] = {k: median([t[k] for t in rows]) for k in keys}
        entry["rest_ms"] = entry["total_ms"] - sum(entry[k] for k in keys[1:])
        entry.update(frames=len(rows), load_before=before, load_after=after)
        out[name] = entry
    return out


def breakdown(tables: Any, geometry: dict, scene: Any, repeats: int) -> dict[str, Any]:
    """Median ``sg_shade`` milliseconds with the glossy vertices' count set to 3..0."""
    import dataclasses

    from pipeline.math import sh
    from pipeline.methods.sg import render

    gbuffer = render.camera_gbuffer(render.RayTracer(geometry["vertices"], geometry["faces"]),
                                    geometry["vertices"],
                                    np.asarray(geometry["faces"]), scene.camera)
    devices = {n: render.SgDevice(dataclasses.replace(
        tables, count=np.minimum(tables.count, n).astype(np.uint8))) for n in (3, 2, 1, 0)}
    before, times = load(), {n: [] for n in devices}
    for _ in range(repeats + 1):  # the first round builds the kernels
        for n, device in devices.items():
            light = device.vertex_diffuse(np.zeros((sh.ORDER ** 2, 3)))
            times[n].append(device.shade(gbuffer.buffers(), len(gbuffer.pixel), light, None,
                                         1.0)[1])
    return {"pixels": int(len(gbuffer.pixel)), "load_before": before, "load_after": load(),
            **{f"lobes_{n}_ms": median(t[1:]) for n, t in times.items()}}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    from pipeline.images import read_environment, write_png
    from pipeline.methods.sg import render
    from pipeline.scene.edits import with_camera_position, with_environment_rotation

    parser = argparse.ArgumentParser(prog="python -m benchmarks run sg.frames --",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--scene", type=Path, default=SCENE,
                        help="lit by an environment map alone")
    parser.add_argument("--object", default="bunny",
                        help="the glossy object (its material's vertices get the lobes)")
    parser.add_argument("--mesh", default=COARSE_MESH,
                        help="the object's mesh ('scene': the scene file's own)")
    parser.add_argument("--width", type=int, default=1024)
    parser.add_argument("--height", type=int, default=768)
    parser.add_argument("--frames", type=int, default=7)
    parser.add_argument("--workdir", type=Path, default=None,
                        help="bake here [default: benchmarks/fixtures.py's cache folder]")
    parser.add_argument("--variants", nargs="+", default=["welded", "as_baked"],
                        choices=["welded", "as_baked"])
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)

    scene, baked_geometry = scene_and_geometry(args.scene, args.object, args.width,
                                               args.height, args.mesh, args.workdir)
    images = result_path("sg.frames", args.out).with_suffix("")
    env_file = next(light for light in scene.lights if light.type == "environment")
    env = read_environment(env_file.params["file"])
    record: dict[str, Any] = {
        "scene": str(args.scene), "object": args.object, "frames": args.frames,
        "size": [args.width, args.height], "mesh": args.mesh,
        "faces": int(len(baked_geometry["faces"])), "images": str(images), "variants": {}}

    cam = scene.camera
    offset = np.subtract(cam.position, cam.look_at)
    orbit = []
    for i in range(args.frames + 1):
        a = np.radians(2.0 * (i + 1))
        turned = (np.cos(a) * offset[0] + np.sin(a) * offset[2], offset[1],
                  -np.sin(a) * offset[0] + np.cos(a) * offset[2])
        orbit.append(with_camera_position(scene, tuple(np.add(cam.look_at, turned))))
    rotations = [with_environment_rotation(scene, 10.0 * i) for i in range(args.frames + 1)]
    for variant, geometry in (("welded", welded(baked_geometry)),
                              ("as_baked", baked_geometry)):
        if variant not in args.variants:
            continue
        tables, prefilter_s = synthetic_tables(geometry, env, args.object)
        entry: dict[str, Any] = {
            "vertices": int(len(tables.count)), "table_mb": tables.lobes.nbytes / 1e6,
            "transfer_mb": tables.transfer.nbytes / 1e6,
            "stack_mb": sum(level.nbytes for level in tables.stack) / 1e6,
            "prefilter_s": prefilter_s, "prefilter_load": load(), "blends": {},
            "distinct_bytes": tables.nbytes + args.width * args.height * (48 + 12)}
        record["variants"][variant] = entry
        if variant == "welded":
            record["breakdown"] = breakdown(tables, geometry, scene, args.frames)
            say("breakdown", json.dumps(record["breakdown"]))
        renderers = {blend: render.SgRenderer(tables, geometry["vertices"], geometry["faces"],
                                             env, blend) for blend in render.LAMBDA_BLENDS}
        for blend, frames_of in renderers.items():
            first = frames_of.frame(scene)  # kernels built, camera traced
            if blend == "log":
                images.mkdir(parents=True, exist_ok=True)
                write_png(images / f"{variant}.png", first.rgb, exposure=6.0)
        camera = run_frames(renderers, orbit[1:])
        for frames_of in renderers.values():
            frames_of.frame(rotations[0])
        rotation = run_frames(renderers, rotations[1:])
        for blend, frames_of in renderers.items():
            entry["blends"][blend] = {"camera_move": camera[blend],
                                      "env_rotation": rotation[blend],
                                      "kernel_bytes": frames_of.frame(rotations[1]).kernel_bytes}
            say(variant, blend, json.dumps(entry["blends"][blend]))

    probe = bandwidth_probe()
    probe["load"] = load()
    record["bandwidth_probe"] = probe
    gbs = float(probe["opencl_copy_gbs"])
    for variant in record["variants"].values():
        for entry in variant["blends"].values():
            ms = entry["env_rotation"]["shade_ms"]
            entry["gathered_gbs"] = entry["kernel_bytes"] / (ms * 1e-3) / 1e9
            entry["gathered_fraction_of_probe"] = entry["gathered_gbs"] / gbs
            entry["distinct_gbs"] = variant["distinct_bytes"] / (ms * 1e-3) / 1e9
            entry["distinct_fraction_of_probe"] = entry["distinct_gbs"] / gbs
    return write_result("sg.frames", record, args.out)


def say(*parts: str) -> None:
    print(*parts, file=sys.stderr, flush=True)

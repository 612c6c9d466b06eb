"""Method d2i's frame times, storage and shadow rays: light and BRDF edits on one bake.

At paper 000's Cornell setting (400², 16k gathers).

Measures, in one run on this machine:

* bake time per stage, and where the transfer stage's time goes (visibility rays,
  the transfer kernel, Haar compression; D only: T is d2i.transfer_t's), timed on a
  sample of its tiles;
* storage of T (d2i.truncate_t), D (d2i.truncate; pixel ids included) and Ms
  (d2i.truncate_ms)
  (bytes on disk and raw CSR bytes), beside
  paper 000 Table 5 (152, 60, 20 MB);
* frame times, medians of ``--repeats``: light-edit frames with a point light at the
  luminaire's centre (moved each frame) and with the scene's 16-sample area light;
  BRDF-edit frames (the floor's γ changed each frame); split into shadow rays, bounces
  and per-pixel work;
* the effective bandwidth of the per-pixel product kernels of a light-edit frame (the
  bytes they must move: rows, the radiance vector once per launch, the products; over
  their kernel time) as a fraction of the memory-bandwidth probe (pipeline/device/bandwidth.py),
  run in the same process: timed back to back like the probe (median of ``--repeats``),
  and as they ran inside the frames; on the GPU layout (a work-group per row), the same
  products with each work-group size of ``GROUP_SWEEP`` (their time, and how far their
  sums stray from the renderer's own size's: only the order of the additions differs);

* shadow rays of the scene's lights from every pixel and gather sample: Embree's rate
  against the device kernel's (pipeline/device/bvh.py) on the same rays, and how many differ.

Run from the project root: python -m benchmarks run d2i.frames [--tiny] [-- --size 400
--gathers 16384 --shadows auto|device|embree --layout auto|gpu|cpu --skip-breakdown]; on a
GPU, PRT_CL_DEVICE=gpu (the frames then trace their shadows on the device). The scene
(``--scene``: a Cornell box, whose first light is its luminaire's quad) is baked once
into benchmarks/fixtures.py's cache folder (or ``--workdir``); later runs reuse the
bake unless ``--rebake``.
"""

from __future__ import annotations

import argparse
import datetime
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.fixtures import (
    SCENES,
    baked,
    bandwidth_probe,
    load,
    median,
    medians,
    timed,
    write_result,
)
from pipeline import job
from pipeline.device import cl
from pipeline.engine.planning import stage_params
from pipeline.engine.rows import Rows
from pipeline.math.brdf import scene_brdfs
from pipeline.methods.d2i.render import GATHER_ID_OFFSET, D2iRenderer
from pipeline.registry import get_method
from pipeline.scene.edits import with_light_offset, with_material_edits

PRESETS = {"default": [],
           "tiny": ["--size", "24", "--gathers", "256", "--skip-breakdown",
                    "--repeats", "3"]}
REPEATS = 25
PAPER_TABLE5_MB = {"T": 152, "D": 60, "Ms": 20}
PROFILED_TILES = 13
GROUP_SWEEP = (8, 16, 32, 64, 128)  # work-items per row of the grouped products


def transfer_breakdown(scene, workdir) -> dict[str, float]:
    """Seconds of visibility, kernel and compression over a few transfer tiles, run again
    in this process (the stage's own run is not instrumented)."""
    import pipeline.methods.d2i.stages.transfer as stage
    from pipeline.engine.chunking import plan_chunks
    from pipeline.engine.planning import plan
    from pipeline.engine.stage import ChunkContext
    from pipeline.engine.store import open_artifact

    spent = {"visibility": 0.0, "kernel": 0.0, "compress": 0.0}

    def instrumented(name, fn):
        def wrapper(*args, **kwargs):
            start = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[name] += time.perf_counter() - start
        return wrapper

    originals = (stage.center_visibility, stage.compress_rows, stage.TransferKernel.__call__)
    stage.center_visibility = instrumented("visibility", stage.center_visibility)
    stage.compress_rows = instrumented("compress", stage.compress_rows)
    stage.TransferKernel.__call__ = instrumented("kernel", stage.TransferKernel.__call__)
    try:
        stagefile = job.stages()
        p = next(p for p in plan(scene, stagefile, workdir) if p.spec.name == "d2i.transfer")
        params = stage_params(stagefile, scene)
        inputs = {n: open_artifact(workdir.artifact(n)) for n in p.spec.inputs}
        chunks = plan_chunks(p.spec, scene, {k: params[k] for k in p.spec.params}, inputs)
        picks = [chunks[i] for i in np.linspace(0, len(chunks) - 1, PROFILED_TILES).astype(int)]
        start = time.perf_counter()
        for chunk in picks:
            stage.run_chunk(ChunkContext(params=p.params, scene=p.sections[chunk.id],
                                         inputs=inputs, chunk=chunk))
        total = time.perf_counter() - start
    finally:
        stage.center_visibility, stage.compress_rows, stage.TransferKernel.__call__ = originals
    return {**{k: v / total for k, v in spent.items()}, "seconds_per_tile": total / len(picks),
            "tiles_profiled": len(picks)}


def storage(workdir) -> dict[str, dict[str, float]]:
    from pipeline.engine.store import open_artifact

    out = {}
    for label, prefix, stage in (("T", "t_", "d2i.truncate_t"), ("D", "d_", "d2i.truncate"),
                                 ("Ms", "ms_", "d2i.truncate_ms")):
        art, root = open_artifact(workdir.artifact(stage)), workdir.artifact(stage)
        names = [n for n in art.names if n.startswith(prefix)]
        disk = sum(f.stat().st_size for n in names for f in (root / n).rglob("*") if f.is_file())
        raw = sum(art.read(n).nbytes for n in names)
        entries = int(art.read(prefix + "value").shape[0])
        rows = int(art.read(prefix + "count").shape[0])
        out[label] = {"disk_mb": disk / 1e6, "raw_mb": raw / 1e6, "rows": rows,
                      "coefficients": entries, "per_row": entries / max(rows, 1),
                      "paper_mb": PAPER_TABLE5_MB[label]}
    return out


def point_light_scene(scene):
    """The scene with its area light replaced by a point light of equal power 5 mm below
    the luminaire's centre (a Lambertian emitter of radiance L and area A has power πLA,
    a point light of intensity I has 4πI: I = LA/4). For timing: it lights the ceiling
    too, which the one-sided luminaire does not."""
    quad = scene.lights[0].params
    corner, u, v = (np.asarray(quad[k], float) for k in ("corner", "edge_u", "edge_v"))
    area = float(np.linalg.norm(np.cross(u, v)))
    centre = corner + 0.5 * (u + v) - np.array([0.0, 5.0, 0.0])
    intensity = [float(r) * area / 4.0 for r in quad["radiance"]]
    return scene.edited("lights", [{"type": "point", "position": centre.tolist(),
                                    "intensity": intensity}])


def shadow_rates(scene, workdir) -> dict[str, float]:
    """Shadow rays of the scene's own lights (the area light's 16 samples) from every
    pixel and gather sample: Embree (render/shadows.light_visibility, its thread pool)
    against the device kernel on the same rays (medians of 5; the device time is its
    kernel's), in millions of rays per second; and how many answers differ."""
    import pyopencl

    from pipeline.device import cl
    from pipeline.math.lights import total_samples
    from pipeline.render.shadows import DeviceShadows, light_visibility

    renderer = D2iRenderer(scene, job.method_artifacts(get_method("d2i"), workdir),
                           shadows="embree")
    direct = renderer.direct
    packed, _ = direct.packed_lights(scene)
    position = np.concatenate([direct.hit_position, renderer.gather_position]).astype(np.float32)
    normal = np.concatenate([direct.hit_normal, renderer.gather_normal]).astype(np.float32)
    ids = np.concatenate([direct.hit, np.arange(len(renderer.gather_position))
                          + GATHER_ID_OFFSET]).astype(np.uint32)
    rays = len(position) * total_samples(packed)
    embree, _ = timed(lambda: light_visibility(direct.tracer, position, normal, ids, packed,
                                               direct.diagonal), 5, warmup=0)
    expected = light_visibility(direct.tracer, position, normal, ids, packed, direct.diagonal)
    shadows = DeviceShadows(*(renderer_geometry(workdir)))
    buffers = [cl.read_only_buffer(a) for a in (position, normal, ids)]
    kernel = []
    for _ in range(6):
        out, ms = shadows.visibility(*buffers, len(position), packed, direct.diagonal)
        kernel.append(ms)
    got = np.empty_like(expected)
    pyopencl.enqueue_copy(cl.queue(), got, out)
    return {"rays": rays, "embree_mrays_s": rays / embree / 1e6,
            "device_mrays_s": rays / median(kernel[1:]) / 1e3,
            "device": cl.device().name, "differ": int((got != expected).sum()),
            "bvh_mb": shadows.bvh.nbytes / 1e6}


def renderer_geometry(workdir) -> tuple[np.ndarray, np.ndarray]:
    from pipeline.engine.store import open_artifact

    geo = open_artifact(workdir.artifact("geometry"))
    return geo.read("vertices"), geo.read("faces")


def frame_times(scene, workdir, shadows: str = "auto", layout: str = "auto",
                repeats: int = REPEATS
                ) -> tuple[dict[str, dict[str, float]], dict[str, float]]:
    """Median frame timings per mode over ``repeats`` frames (after one), and the product
    kernels' measurement."""
    renderer = D2iRenderer(scene, job.method_artifacts(get_method("d2i"), workdir),
                           shadows=shadows, layout=layout)
    renderer.frame(scene)  # builds kernels
    results = {}
    for label, sc in (("light_edit_point", point_light_scene(scene)),
                      ("light_edit_area16", scene)):
        frame_of = renderer.light_edits(sc)
        frames = [frame_of(with_light_offset(sc, 0, (30.0 * np.cos(a), 0.0, 30.0 * np.sin(a))))
                  for a in np.linspace(0, 2 * np.pi, repeats + 1)]
        results[label] = medians([f.timings for f in frames[1:]])
    frame_of = renderer.brdf_edits(scene)
    glossy = next(n for n, m in scene.materials.items() if m.model != "lambert")
    frames = [frame_of(with_material_edits(scene, [f"{glossy}.gamma={g:.4g}"]))
              for g in np.geomspace(3, 300, repeats + 1)]
    results["brdf_edit"] = medians([f.timings for f in frames[1:]])
    return results, product_kernels(renderer, point_light_scene(scene),
                                    results["light_edit_point"]["product_kernel_ms"], repeats)


def product_kernels(renderer: D2iRenderer, scene, in_frame_ms: float,
                    repeats: int = REPEATS) -> dict[str, Any]:
    """The light-edit frame's product kernels (D rows, frozen T rows) on the point-light
    frame's radiance: the bytes they must move at least (``product_bytes``), their median
    time over ``repeats`` back-to-back launches (as the probe is timed) and in a frame."""
    frozen = renderer.freeze(renderer.coefficients(scene))
    renderer.trace_lights(scene)
    renderer.gather_radiance(np.array([p.albedo for p in scene_brdfs(
        scene, renderer.material_names)]))
    back_to_back = median(renderer.products(frozen)[2] for _ in range(repeats))
    return {"bytes": float(product_bytes(renderer, frozen)), "ms": back_to_back,
            "ms_in_frame": in_frame_ms, "group_sweep": group_sweep(renderer, frozen, repeats)}


def group_sweep(renderer: D2iRenderer, frozen: Rows, repeats: int = REPEATS
                ) -> dict[str, dict[str, float]] | None:
    """The light-edit frame's two grouped product launches (D rows, frozen T rows) with
    each work-group size of ``GROUP_SWEEP``, on the radiance vector the renderer holds:
    their median kernel ms over ``repeats`` and the largest deviation of any product from
    the renderer's own size's, relative to the launch's largest |product| (the sums are
    added in another order only, so float32 rounding: ≲ 1e-6). None on the CPU layout
    (a work-item per row)."""
    if not renderer.grouped_products:
        return None
    launches = (("d", renderer.d), ("frozen", frozen))
    own = renderer.sparse_group
    reference = {name: renderer._sparse(name, rows)[0] for name, rows in launches}
    sweep = {}
    try:
        for group in GROUP_SWEEP:
            renderer.sparse_group = group  # read at each launch
            times, deviation = [], 0.0
            for _ in range(repeats):
                ms = 0.0
                for name, rows in launches:
                    values, kernel_ms = renderer._sparse(name, rows)
                    ms += kernel_ms
                    scale = max(float(np.abs(reference[name]).max()), 1e-30)
                    deviation = max(deviation,
                                    float(np.abs(values - reference[name]).max()) / scale)
                times.append(ms)
            sweep[str(group)] = {"ms": median(times), "deviation": deviation}
    finally:
        renderer.sparse_group = own
    return sweep


def product_bytes(renderer: D2iRenderer, frozen: Rows) -> int:
    """Bytes a light-edit frame's two product kernels (D rows, frozen T rows) must move
    at least: every row's offsets, indices and values, the float4 radiance vector once
    per launch (it stays in cache while the rows stream past), the float4 outputs."""
    launches = (renderer.d, frozen)
    return sum(rows.nbytes + 16 * renderer.size + 16 * rows.count for rows in launches)


def stages_ran_since(scene, workdir, since: float) -> list[str]:
    """The stages of the scene's methods whose artifact was written at or after the wall
    time ``since`` (their records' ``created``, to the second): those the bake ran now."""
    from pipeline.engine.store import read_record

    since_utc = datetime.datetime.fromtimestamp(int(since), datetime.UTC)
    ran = []
    for p in job.status(scene, workdir):
        record = read_record(workdir.artifact(p.spec.name))
        if record and datetime.datetime.fromisoformat(record["created"]) >= since_utc:
            ran.append(p.spec.name)
    return ran


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog="python -m benchmarks run d2i.frames --",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", type=Path, default=SCENES / "cornell_box.yaml",
                        help="a Cornell box: its first light the luminaire's quad")
    parser.add_argument("--size", type=int, default=400)
    parser.add_argument("--gathers", type=int, default=16384)
    parser.add_argument("--repeats", type=int, default=REPEATS,
                        help="frames per mode, product launches (medians)")
    parser.add_argument("--workdir", type=Path, default=None,
                        help="bake here [default: benchmarks/fixtures.py's cache folder]")
    parser.add_argument("--rebake", action="store_true")
    parser.add_argument("--shadows", default="auto", choices=["auto", "device", "embree"],
                        help="the frames' shadow rays (auto: the device's BVH on a GPU)")
    parser.add_argument("--layout", default="auto", choices=["auto", "gpu", "cpu"],
                        help="the products' layout (auto: by the device's type)")
    parser.add_argument("--skip-breakdown", action="store_true",
                        help="leave out the transfer stage's breakdown (a GPU run)")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    before = load()
    since, start = time.time(), time.perf_counter()
    scene, workdir = baked(args.scene, args.size, {"gather.count": args.gathers},
                           args.workdir, rebake=args.rebake)
    bake_wall = time.perf_counter() - start
    from pipeline.engine.store import read_record

    stage_seconds = {p.spec.name: read_record(workdir.artifact(p.spec.name))["seconds"]
                     for p in job.status(scene, workdir)
                     if workdir.artifact(p.spec.name).exists()}
    bandwidth = bandwidth_probe()
    times, products = frame_times(scene, workdir, args.shadows, args.layout, args.repeats)
    gbs = products["bytes"] / (products["ms"] * 1e-3) / 1e9
    gbs_in_frame = products["bytes"] / (products["ms_in_frame"] * 1e-3) / 1e9
    result = {
        "scene": str(args.scene), "size": args.size, "gathers": args.gathers,
        "repeats": args.repeats, "workdir": str(workdir.root),
        "stages_ran_now": stages_ran_since(scene, workdir, since),
        "bake_wall_s_now": bake_wall, "stage_seconds": stage_seconds,
        "bake_s_total": sum(stage_seconds.values()),
        "transfer_breakdown": None if args.skip_breakdown
        else transfer_breakdown(scene, workdir),
        "device": cl.device().name, "shadows": args.shadows, "layout": args.layout,
        "shadow_rays": shadow_rates(scene, workdir),
        "storage": storage(workdir), "frames": times, "bandwidth_probe": bandwidth,
        "product_kernels": products, "product_kernel_gbs": gbs,
        "product_kernel_bandwidth_fraction": gbs / bandwidth["opencl_copy_gbs"],
        "product_kernel_bandwidth_fraction_in_frame": gbs_in_frame
        / bandwidth["opencl_copy_gbs"],
    }
    result["load"] = [before, load()]
    summary(result)
    return write_result("d2i.frames", result, args.out)


def summary(result: dict[str, Any]) -> None:
    """The frames, storage and product kernels' bandwidth, on stderr."""
    def say(line: str) -> None:
        print(line, file=sys.stderr)

    for label, t in result["frames"].items():
        say(f"{label:<20} total {t['total_ms']:.1f} ms  (shadow {t['shadow_ms']:.1f}, "
            f"bounce {t.get('bounce_ms', 0):.1f}, pixels {t['pixel_ms']:.1f})")
    for label, s in result["storage"].items():
        say(f"{label:<3} {s['disk_mb']:.1f} MB on disk, {s['raw_mb']:.1f} MB raw, "
            f"{s['per_row']:.0f} coefficients per row (paper {s['paper_mb']} MB)")
    products, probe = result["product_kernels"], result["bandwidth_probe"]["opencl_copy_gbs"]
    say(f"product kernels {result['product_kernel_gbs']:.2f} GB/s = "
        f"{result['product_kernel_bandwidth_fraction']:.0%} of the probe back to back, "
        f"{result['product_kernel_bandwidth_fraction_in_frame']:.0%} in a frame")
    for group, run in (products["group_sweep"] or {}).items():
        fraction = products["bytes"] / (run["ms"] * 1e-3) / 1e9 / probe
        say(f"  {group:>3} work-items per row: {run['ms']:.3f} ms = {fraction:.0%} of the "
            f"probe (sums within {run['deviation']:.1e} of the renderer's)")

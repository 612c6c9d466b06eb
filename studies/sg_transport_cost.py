"""Benchmark: what method sg's transport costs per vertex on scenes/bunny_sg.yaml — the
glossy transport the fit stage computes in its chunks (pipeline/methods/sg/transport.py:
direct visibility rays over the sphere grid, the direct glossy table, the indirect
glossy paths) and the whole sg.diffuse stage (pipeline/methods/sg/diffuse.py: the direct
pass with its gather matrix, then the bounces).

Run from the project root:  python studies/sg_transport_cost.py [--workdir W]
[--vertices 32] [--samples 64] [--repeats 3]
Writes benchmarks/results/sg_transport_cost.json. Bakes the scene's geometry (and the
sg.diffuse stage, whose transfer the indirect part reads) into the work directory first.

Glossy transport: ``--vertices`` bunny vertices spread over the mesh, one call at a
time in batches of 8 (as a fit chunk would), on the fit's 55 × 110 lat-long grid (6050
directions), ``--samples`` indirect paths per (vertex, view above the horizon). Parts
timed separately (medians over ``--repeats``): visibility (Embree, 6050 rays per vertex
of which about half above the horizon), the direct table (NumPy), the indirect SH
vectors (sampling + 92 × samples rays per vertex + blending), and its evaluation on the
grid. sg.diffuse: the whole scene (7526 vertices) at the stage's defaults. Every timing
records os.getloadavg(): the machine may be shared; quote medians and the ratios of one
run, and re-run on a quiet machine for absolute figures.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pipeline.engine.planning import stage_params  # noqa: E402
from pipeline.engine.runner import run  # noqa: E402
from pipeline.engine.store import Workdir, open_artifact  # noqa: E402
from pipeline.images import read_environment  # noqa: E402
from pipeline.math import sg, sh  # noqa: E402
from pipeline.math.brdf import BrdfParams, scene_brdfs  # noqa: E402
from pipeline.math.envmap import EnvironmentMap  # noqa: E402
from pipeline.math.frames import tangent_from_normal  # noqa: E402
from pipeline.methods.sg import diffuse as sg_diffuse  # noqa: E402
from pipeline.methods.sg.transport import (  # noqa: E402
    direct_glossy,
    indirect_glossy_sh,
    on_grid,
    scene_visibility,
    view_directions,
)
from pipeline.methods.sg.vertex_scene import VertexScene  # noqa: E402
from pipeline.scene.file import load_scene  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
BATCH = 8  # vertices per transport call


def timed(call) -> tuple[float, object, list[float]]:
    load = list(os.getloadavg())
    start = time.perf_counter()
    out = call()
    return time.perf_counter() - start, out, load


def glossy_parts(scene: VertexScene, vertices: np.ndarray, directions: np.ndarray,
                 transfer: np.ndarray, samples: int, seed: int) -> dict[str, float]:
    """Seconds of each part of glossy_transport for ``vertices``, in batches."""
    views = view_directions()
    rng = np.random.default_rng(seed)
    y = sh.basis(directions)
    parts = {"visibility": 0.0, "direct_table": 0.0, "indirect_paths": 0.0,
             "indirect_on_grid": 0.0}
    loads = []
    for s in range(0, len(vertices), BATCH):
        batch = vertices[s:s + BATCH]
        normal = scene.normals[batch]
        material = scene.materials[int(scene.vertex_material[batch[0]])]
        seconds, visible, load = timed(lambda b=batch: scene_visibility(scene, b, directions))
        parts["visibility"] += seconds
        loads.append(load)
        seconds, _, _ = timed(lambda n=normal, v=visible, m=material: direct_glossy(
            n, tangent_from_normal(n), m, views, directions, v))
        parts["direct_table"] += seconds
        seconds, a, _ = timed(lambda b=batch: indirect_glossy_sh(
            scene, b, views, transfer, samples, rng))
        parts["indirect_paths"] += seconds
        seconds, _, _ = timed(lambda a=a: [on_grid(x, y) for x in a])
        parts["indirect_on_grid"] += seconds
    out = {k: v / len(vertices) for k, v in parts.items()}
    out["load"] = loads[len(loads) // 2]
    return out


def indirect_shares(scene: VertexScene, vertices: np.ndarray, directions: np.ndarray,
                    omega: np.ndarray, transfer: np.ndarray, environment: EnvironmentMap,
                    coefficients: np.ndarray, samples: int) -> dict[str, float]:
    """Where the glossy lobes of ``vertices`` go, and what indirect glossy adds under the
    map, summed over the vertices and their views above the horizon (channel means):
    ``blocked``: the share of the lobe's weight E[f cos / p] whose paths hit a surface,
    ``on_glossy``: the share that hits a glossy (non-Lambertian) object — the light the
    glossy–glossy approximation drops comes from there; ``indirect_over_direct``: the
    indirect glossy radiance (paths through the stored diffuse transfer) over the direct.
    The shares use indirect_glossy_sh itself with indicator transfers (coefficient 0 = 1
    on the chosen vertices), so they are the estimator's own paths."""
    views = view_directions()
    glossy_vertex = np.array([scene.materials[m].model != "lambert"
                              for m in scene.vertex_material])
    unit = np.zeros((len(scene.positions), 3, 25))
    unit[:, :, 0] = 1.0               # A[..., 0] = ρs E[w · 1(path hits)] (t_0 = 1 at hits)
    on_glossy = unit * glossy_vertex[:, None, None]
    rng = np.random.default_rng(0)
    hit = indirect_glossy_sh(scene, vertices, views, unit, samples, rng)[..., 0]
    hit_glossy = indirect_glossy_sh(scene, vertices, views, on_glossy, samples, rng)[..., 0]
    indirect = indirect_glossy_sh(scene, vertices, views, transfer, samples, rng)
    normal = scene.normals[vertices]
    tangent = tangent_from_normal(normal)
    total = direct_glossy(normal, tangent, scene.materials[int(scene.vertex_material[
        vertices[0]])], views, directions, (normal @ directions.T) > 0)      # V ≡ 1
    lobe = np.einsum("pksc,s->pkc", total, omega)                            # E[w] ρs
    visible = scene_visibility(scene, vertices, directions)
    direct = direct_glossy(normal, tangent, scene.materials[int(scene.vertex_material[
        vertices[0]])], views, directions, visible)
    radiance = environment.radiance(directions)                              # (S, 3)
    direct_radiance = np.einsum("pksc,sc,s->", direct, radiance, omega)
    indirect_radiance = np.einsum("pkcn,nc->", indirect, coefficients)
    return {"blocked": float(hit.sum() / lobe.sum()),
            "on_glossy": float(hit_glossy.sum() / lobe.sum()),
            "indirect_over_direct": float(indirect_radiance / direct_radiance)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--workdir", default="/tmp/sg_transport_cost")
    parser.add_argument("--vertices", type=int, default=32)
    parser.add_argument("--samples", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    os.environ.setdefault("PRT_DATA", str(ROOT.parent / "shared" / "data"))
    scene_path = ROOT / "scenes" / "bunny_sg.yaml"
    from pipeline import job

    scene, stagefile = load_scene(scene_path), job.stages()
    workdir = Workdir(Path(args.workdir))
    run(scene, stagefile, workdir, until="sg.diffuse", progress=False)
    geometry = open_artifact(workdir.artifact("geometry"))
    arrays = {n: geometry.read(n) for n in
              ("vertices", "normals", "faces", "object_ranges", "object_material")}
    names = list(geometry.attrs["material_names"])
    vscene = VertexScene.from_arrays(arrays, scene_brdfs(scene, names))
    transfer = open_artifact(workdir.artifact("sg.diffuse")).read("transfer").astype(np.float64)
    bunny = np.arange(*arrays["object_ranges"][names.index("bunny")][:2])
    vertices = bunny[np.linspace(0, len(bunny) - 1, args.vertices).astype(int)]
    directions = sg.latlong_directions(55, 110)[0].reshape(-1, 3)

    light = next(x for x in scene.lights if x.type == "environment")
    rgb = read_environment(light.params["file"])
    rotation = light.params.get("rotation", 0.0)
    grid, omega = sg.latlong_directions(55, 110)
    shares = indirect_shares(vscene, vertices, grid.reshape(-1, 3), omega.ravel(), transfer,
                             EnvironmentMap(rgb, rotation), sh.project_latlong(rgb, rotation),
                             args.samples)
    glossy = [glossy_parts(vscene, vertices, directions, transfer, args.samples, seed)
              for seed in range(args.repeats)]
    glossy_median = {k: statistics.median(g[k] for g in glossy)
                     for k in glossy[0] if k != "load"}
    glossy_median["total"] = sum(glossy_median.values())

    params = stage_params(stagefile, scene)
    samples, bounces = int(params["sg.diffuse_samples"]), int(params["sg.diffuse_bounces"])
    lambert = VertexScene(vscene.tracer, vscene.positions, vscene.normals, vscene.faces,
                          vscene.vertex_material,
                          [BrdfParams("lambert", m.albedo) for m in vscene.materials],
                          vscene.offset)
    everything = np.arange(len(vscene.positions))
    diffuse = []
    for seed in range(args.repeats):
        rng = np.random.default_rng(seed)
        t_direct, (t0, gather), load = timed(
            lambda r=rng: sg_diffuse.direct_and_gather(lambert, everything, samples, r))
        t_bounce, _, _ = timed(lambda t0=t0, g=gather: sg_diffuse.with_bounces(
            g, lambert.diffuse_albedo(), t0, bounces))
        diffuse.append({"direct_and_gather_s": t_direct, "bounces_s": t_bounce,
                        "gather_nnz": int(gather.nnz), "load": load})
    result = {
        "machine": platform.processor() or platform.machine(),
        "cpus": os.cpu_count(),
        "scene": "scenes/bunny_sg.yaml",
        "vertices_total": int(len(vscene.positions)),
        "glossy_transport": {
            "vertices_timed": args.vertices, "grid": [55, 110],
            "indirect_samples_per_view": args.samples,
            "seconds_per_vertex_median": glossy_median,
            "runs": glossy,
            "bunny_vertices": int(len(bunny)),
            "estimated_bunny_seconds": glossy_median["total"] * len(bunny),
            "lobe_shares": shares},
        "sg_diffuse": {
            "samples": samples, "bounces": bounces, "runs": diffuse,
            "median_s": statistics.median(d["direct_and_gather_s"] + d["bounces_s"]
                                          for d in diffuse),
            "per_vertex_ms": 1e3 * statistics.median(
                d["direct_and_gather_s"] + d["bounces_s"] for d in diffuse)
            / len(vscene.positions)},
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "sg_transport_cost.json").write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps({"glossy_per_vertex": glossy_median, "lobe_shares": shares,
                      "diffuse_median_s": result["sg_diffuse"]["median_s"]}, indent=1))


if __name__ == "__main__":
    main()

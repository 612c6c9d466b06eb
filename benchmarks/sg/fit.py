"""Method sg's fit on real transport lobes: speed and error of each fit path, the stage's cost.

The fast path (each function on its support cap, pipeline/methods/sg/support.py) against
the whole-grid batched fit of the second session and the paper-faithful trf path
(pipeline/methods/sg/fit.py), same functions, same start rule; and the stage's
per-vertex cost (pipeline/methods/sg/stages/fit.py: N chosen from the tolerance,
alignment, coupled refit, view filling).

Run from the project root: python -m benchmarks run sg.fit [--tiny] [-- --vertices 12
--trf 24 --grid 55 110].

Data: ``--scene`` (scenes/bunny_sg.yaml) baked up to sg.diffuse, once, into
benchmarks/fixtures.py's cache folder (or ``--workdir``); ``--vertices`` vertices of its
object ``--object`` (the bunny) from a breadth-first walk; their glossy transport,
direct + indirect, by the stage's own function, for the 92 views on the lat-long grid
``--grid``; the functions with data (views above the horizon, T ≠ 0) are fitted after
dividing by their norm (as the stage does). Reported per path and N = 1, 2, 3:
milliseconds per function (median of ``--repeats`` repeats of the whole set; trf: on the
first ``--trf`` functions, one repeat), the relative L² error on the whole grid (median,
90th percentile, max) and the error ratio of each path to the whole-grid fit on the
same functions; then the stage's fit_group per vertex (median over groups) and its
extrapolation to the object's vertex count. The load averages before and after every
timing; one BLAS thread (a bake runs one chunk per core). The machine is shared: quote
ratios taken in one run, re-run on a quiet machine for absolute times.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.fixtures import SCENES, TINY, baked, load, median, timed, write_result

PRESETS = {"default": [],
           "tiny": ["--scene", str(TINY / "tiny_sg.yaml"), "--object", "ball",
                    "--vertices", "4", "--trf", "4", "--grid", "9", "18", "--repeats", "1"]}
SCENE = SCENES / "bunny_sg.yaml"


@dataclass
class BunnyPatch:
    """A connected patch of the bunny's vertices, as the stage's flood fill sees a batch."""

    transport: Callable[[np.ndarray], np.ndarray]  # local indices (G,) -> T (G, 92, S, 3)
    normals: np.ndarray      # (P, 3) unit
    edges: np.ndarray        # (E, 2) local indices
    vertices: np.ndarray     # (P,) global vertex indices
    brdf: object             # the bunny's glossy BrdfParams
    directions: np.ndarray   # (S, 3) the fit grid
    omega: np.ndarray        # (S,) its solid angles
    params: dict             # the stage's params (stages.yaml defaults)
    bunny_vertices: int      # vertices of the whole bunny object


def breadth_first(count: int, neighbours: list[np.ndarray], root: int) -> np.ndarray:
    """The first ``count`` vertices of a breadth-first walk from ``root``."""
    seen, queue, out = {root}, [root], []
    while queue and len(out) < count:
        v = queue.pop(0)
        out.append(v)
        for u in neighbours[v]:
            if int(u) not in seen:
                seen.add(int(u))
                queue.append(int(u))
    return np.asarray(out, np.int64)


def bunny_patch(count: int, settings: dict | None = None, seed: int = 0,
                scene_file: Path = SCENE, obj_name: str = "bunny", root: int = 0,
                workdir: Path | None = None) -> BunnyPatch:
    """Bake ``geometry`` and ``sg.diffuse`` of bunny_sg (or ``scene_file``) into the
    fixtures' cache folder or ``workdir`` (once; later calls find them fresh) and return
    ``count`` vertices of object ``obj_name`` from a breadth-first walk from its vertex
    ``root``, with the stage's transport function on the fit grid and its params:
    stages.yaml's defaults updated by ``settings``."""
    from pipeline import job
    from pipeline.engine.planning import resolve_sections, stage_params
    from pipeline.engine.stage import ChunkContext
    from pipeline.engine.store import open_artifact
    from pipeline.methods.sg.stages import fit as stage

    scene, wd = baked(scene_file, workdir=workdir, until="sg.diffuse")
    graph = job.stages()
    params = {**stage_params(graph, scene), **(settings or {})}
    spec = graph.stages["sg.fit"]
    inputs = {name: open_artifact(wd.artifact(name), graph.stages[name].output)
              for name in spec.inputs}
    ctx = ChunkContext(params=params, scene=resolve_sections(spec, scene, None),
                       inputs=inputs, rng=np.random.default_rng(seed))
    geometry = inputs["geometry"]
    obj = geometry.attrs["object_names"].index(obj_name)
    material = geometry.attrs["material_names"][int(geometry.read("object_material")[obj])]
    first, end = (int(x) for x in geometry.read("object_ranges")[obj, :2])
    faces = geometry.read("faces")
    _, neighbours = stage.flood_order(end - first, stage.batch_edges(faces, first, end))
    local = breadth_first(count, neighbours, root)
    vertices = first + local
    position = np.full(end - first, -1)
    position[local] = np.arange(len(local))
    e = position[stage.batch_edges(faces, first, end)]
    edges = e[(e >= 0).all(axis=1)]
    directions, omega = stage.grid(params)
    whole = stage.chunk_transport(ctx, first, directions)
    normals = geometry.read("normals")[vertices].astype(np.float64)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return BunnyPatch(lambda g: whole(local[g]), normals, np.sort(edges, axis=1), vertices,
                      stage.material_brdf(ctx, material), directions, omega, params,
                      end - first)


def measured(fn: Callable[[], Any], repeats: int) -> tuple[Any, float, list[list[float]]]:
    """(the last call's result, median seconds, load averages before and after) of
    ``repeats`` calls (no warm-up: the fits build nothing)."""
    results, before = [], load()
    seconds, _ = timed(lambda: results.append(fn()), repeats, warmup=0)
    return results[-1], seconds, [before, load()]


def error_summary(err: np.ndarray) -> dict:
    return {"median": float(np.median(err)), "p90": float(np.percentile(err, 90)),
            "max": float(err.max())}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    from pipeline.device.threads import one_blas_thread
    from pipeline.methods.sg import coherence as sg_coherence
    from pipeline.methods.sg import fit as sg_fit
    from pipeline.methods.sg import support as sg_support
    from pipeline.methods.sg.stages import fit as stage
    from pipeline.methods.sg.transport import view_directions

    ap = argparse.ArgumentParser(prog="python -m benchmarks run sg.fit --",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--scene", type=Path, default=SCENE)
    ap.add_argument("--object", default="bunny", help="the glossy object to take vertices of")
    ap.add_argument("--vertices", type=int, default=12)
    ap.add_argument("--trf", type=int, default=24)
    ap.add_argument("--grid", type=int, nargs=2, default=[55, 110])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--workdir", type=Path, default=None,
                    help="bake here [default: benchmarks/fixtures.py's cache folder]")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    one_blas_thread()
    patch = bunny_patch(args.vertices, {"sg.fit_grid": args.grid}, scene_file=args.scene,
                        obj_name=args.object, workdir=args.workdir)
    directions, omega, normals = patch.directions, patch.omega, patch.normals
    vertex_count = patch.bunny_vertices
    views = view_directions()
    transport_before, t_start = load(), time.perf_counter()
    t = patch.transport(np.arange(args.vertices))
    transport_s = time.perf_counter() - t_start
    strength = np.einsum("gvsc,s->gv", t.astype(np.float64) ** 2, omega)
    g_idx, v_idx = np.nonzero(strength > 0)
    values = t[g_idx, v_idx].astype(np.float64) / np.sqrt(strength[g_idx, v_idx])[:, None, None]
    values32 = values.astype(np.float32)   # as the stage holds them
    f = len(values)
    report = {"scene": f"{args.scene}, object {args.object}, direct + indirect glossy "
                       "(the stage's)",
              "grid": args.grid, "directions": len(directions), "vertices": args.vertices,
              "functions": f, "transport_seconds": transport_s,
              "transport_load": [transport_before, load()], "paths": {}}
    say(f"{f} functions from {args.vertices} vertices; transport {transport_s:.2f} s")
    for n in (1, 2, 3):
        base = sg_fit.FitOptions(lobes=n)
        fast = sg_fit.FitOptions(lobes=n, fields=stage.FIELDS_DTYPE, tolerance=stage.STOP)
        runs = {
            "whole_grid": lambda o=base: sg_fit.fit(directions, omega, values, o),
            "support": lambda o=base: sg_support.fit(directions, omega, values32, o)[0],
            "support_fast": lambda o=fast: sg_support.fit(directions, omega, values32, o)[0],
        }
        row = {}
        errors = {}
        for name, fn in runs.items():
            result, seconds, loads = measured(fn, args.repeats)
            err = sg_support.relative_error(directions, omega, values, result)
            errors[name] = err
            row[name] = {"ms_per_function": 1e3 * seconds / f, "load": loads,
                         "error": error_summary(err),
                         "iterations_median": float(np.median(result.iterations)),
                         "not_converged": int((~result.converged).sum())}
        m = min(args.trf, f)
        sub = np.linspace(0, f - 1, m).astype(np.int64)
        result, seconds, loads = measured(
            lambda sub=sub, base=base: sg_fit.fit_trf(directions, omega, values[sub], base), 1)
        err = sg_support.relative_error(directions, omega, values[sub], result)
        errors["trf"] = err
        row["trf"] = {"ms_per_function": 1e3 * seconds / m, "load": loads, "functions": m,
                      "error": error_summary(err)}
        for name in ("support", "support_fast"):
            ratio = errors[name] / errors["whole_grid"]
            row[name]["error_ratio_to_whole_grid"] = error_summary(ratio)
            row[name]["speedup_over_whole_grid"] = (row["whole_grid"]["ms_per_function"]
                                                    / row[name]["ms_per_function"])
            row[name]["speedup_over_trf"] = (row["trf"]["ms_per_function"]
                                             / row[name]["ms_per_function"])
        ratio = errors["whole_grid"][sub] / errors["trf"]
        row["whole_grid"]["error_ratio_to_trf_on_subset"] = error_summary(ratio)
        row["support"]["error_ratio_to_trf_on_subset"] = error_summary(
            errors["support"][sub] / errors["trf"])
        for name in row:  # one fit of every function of 1,000 vertices at this N
            row[name]["seconds_per_1000_vertices"] = (row[name]["ms_per_function"] * f
                                                      / args.vertices)
        report["paths"][f"N={n}"] = row
        say(f"N={n}: " + ", ".join(f"{k} {v['ms_per_function']:.2f} ms "
                                   f"err {v['error']['median']:.4f}" for k, v in row.items()))
    # the stage's fit of whole vertices (N from the tolerance, alignment, coupled refit)
    cfg = stage.settings({"sg.fit_tolerance": 0.1, "sg.fit_max_lobes": 3,
                          "sg.fit_mean_weight": 0.01, "sg.fit_sigma_weight": 0.01,
                          "sg.fit_spatial_weight": 0.1, "sg.fit_relaxation_sweeps": 4,
                          "sg.fit_match_integral": True})
    lobes = stage.Lobes(args.vertices, len(views), stage.mirror(views, normals))
    view_nbs = sg_coherence.view_neighbours(views)
    nbs = [np.array([], np.int64)] * args.vertices
    done = np.zeros(args.vertices, bool)
    per_vertex, before = [], load()
    for g0 in range(0, args.vertices, stage.GROUP):
        group = np.arange(g0, min(g0 + stage.GROUP, args.vertices))
        start = time.perf_counter()
        stage.fit_group(lobes, group, t[group], views, view_nbs, nbs, done, directions,
                        omega, cfg)
        per_vertex.append((time.perf_counter() - start) / len(group))
    seconds = median(per_vertex)
    report["stage_fit"] = {
        "seconds_per_vertex_median": seconds, "load": [before, load()],
        "counts": np.bincount(lobes.count, minlength=4).tolist(),
        "error_median": float(np.median(lobes.error[lobes.error >= 0])),
        "bunny_vertices": vertex_count,
        "whole_bunny_fit_minutes_one_core": seconds * vertex_count / 60,
        "transport_seconds_per_vertex": transport_s / args.vertices}
    say(f"stage fit {seconds:.3f} s per vertex; the whole object "
        f"{report['stage_fit']['whole_bunny_fit_minutes_one_core']:.1f} min on one core")
    return write_result("sg.fit", report, args.out)


def say(line: str) -> None:
    print(line, file=sys.stderr)

"""Method triple's visibility bake on bunny_grace: stage seconds, rays/s against plain Embree.

Stages triple.atlas and triple.visibility at the default settings: leaf level 4, 4 rays
per leaf (the stages' defaults). Measured in one run, on this machine:

- the two stages' seconds (from a fresh work directory unless ``--keep``; the geometry
  stage before them is not counted; the bake as ``prt`` runs it, fixtures ``baked``) and
  the visibility stage's occlusion rays per second;
- Embree's plain rate: the same scene's occlusion rays from random points of its
  surface in random upper-hemisphere directions (``RayTracer.occluded`` on this
  process's threads, ``--plain-rays`` rays). A shared machine's load drifts over a bake
  of minutes, so the ratio stage / plain is measured on equal terms: ``--pairs`` times,
  the busiest tile of ``--object``'s texture (its chunk, run_chunk, in process) then as
  many plain rays, back to back; the median of the ratios compares the stage with
  incoherent rays; the same tile's own rays (recorded, then traced alone in batches,
  ``ratio_own``) say what the stage spends besides tracing;
- the texture size chosen per object, the texel counts (covered / dilated / empty),
  stored coefficients per non-empty texel (median, 90th percentile, max) and the
  visibility artifact's storage (MB on disk, compressed, and the raw bytes of its
  arrays).

It also writes one PNG per object beside the JSON (``<name>_<object>.png``): the
texel-wise visible fraction ∫ V max(cos θ, 0) dω / π from the stored rows (grey; empty
texels magenta), to look for seams, flipped normals and empty texels.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.fixtures import CACHE, SCENES, TINY, baked, load, median, result_path, write_result

NAME = "triple.visibility"
PRESETS = {"default": [],
           "tiny": ["--scene", str(TINY / "tiny_triple.yaml"), "--object", "ball",
                    "--plain-rays", "65536", "--pairs", "1"]}


def plain_embree_rate(geometry: Any, rays: int) -> float:
    """Occlusion rays per second from random surface points in random directions of the
    upper hemisphere of their face (one run of ``rays`` rays)."""
    from pipeline.stages.geometry import traced_geometry

    traced = traced_geometry(geometry)
    tracer, face_normal, epsilon = traced.tracer, traced.mesh.face_normal, traced.epsilon
    vertices, faces = geometry.read("vertices").astype(np.float64), geometry.read("faces")
    rng = np.random.default_rng(1)
    face = rng.integers(0, len(faces), rays)
    u, v = rng.random((2, rays))
    flip = u + v > 1
    u, v = np.where(flip, 1 - u, u), np.where(flip, 1 - v, v)
    corner = vertices[faces[face]]
    point = corner[:, 0] + u[:, None] * (corner[:, 1] - corner[:, 0]) \
        + v[:, None] * (corner[:, 2] - corner[:, 0])
    direction = rng.normal(size=(rays, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    direction *= np.sign(np.sum(direction * face_normal[face], axis=1))[:, None]
    origin = point + epsilon * face_normal[face]
    far = np.full(rays, np.inf, np.float32)
    start = time.perf_counter()
    tracer.occluded(origin, direction, far)
    return rays / (time.perf_counter() - start)


def paired_rates(geometry: Any, atlas: Any, visibility: Any, params: dict, obj: str,
                 pairs: int) -> list[dict[str, float]]:
    """``pairs`` × (the busiest tile of ``obj``'s chunk, then plain rays of the same
    count)."""
    from pipeline.engine.chunk import make_chunk
    from pipeline.engine.stage import ChunkContext
    from pipeline.methods.triple.stages import visibility as stage
    from pipeline.stages.geometry import traced_geometry

    sizes = atlas.attrs["texture_sizes"]
    tile = visibility.attrs["texel_tile"]
    offsets = dict(zip(sizes, atlas.read("texture_offsets").tolist(), strict=True))
    height, width = sizes[obj]
    state = atlas.read("texel_state")[offsets[obj]:offsets[obj] + height * width]
    state = state.reshape(height, width)
    filled = [(int(np.sum(state[y:y + tile, x:x + tile] != 0)), y, x)
              for y in range(0, height, tile) for x in range(0, width, tile)]
    _, y, x = max(filled)
    chunk = make_chunk(f"{obj}/y{y:05d}_x{x:05d}", "texel_tile", object=obj,
                       region=(y, min(y + tile, height), x, min(x + tile, width)))
    tracer = traced_geometry(geometry).tracer
    own = tile_rays(tracer, ChunkContext(params=params, scene={}, chunk=chunk, inputs={
        "geometry": geometry, "triple.atlas": atlas}), stage)
    out = []
    for _ in range(pairs):
        ctx = ChunkContext(params=params, scene={}, chunk=chunk,
                           inputs={"geometry": geometry, "triple.atlas": atlas})
        start = time.perf_counter()
        stage.run_chunk(ctx)
        stage_rate = ctx.meta["rays"] / (time.perf_counter() - start)
        plain = plain_embree_rate(geometry, ctx.meta["rays"])
        start = time.perf_counter()
        tracer.occluded(*own)
        traced = ctx.meta["rays"] / (time.perf_counter() - start)
        out.append({"stage_rays_per_s": stage_rate, "plain_rays_per_s": plain,
                    "ratio": stage_rate / plain, "own_rays_traced_per_s": traced,
                    "ratio_own": stage_rate / traced})
    return out


def tile_rays(tracer: Any, ctx: Any, stage: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The occlusion rays (origins, directions, distances) one run of the chunk casts,
    recorded by wrapping the tracer's ``occluded``."""
    calls, original = [], tracer.occluded

    def recording(origins, directions, distances, threads=None):
        calls.append((origins, directions, distances))
        return original(origins, directions, distances, threads)

    tracer.occluded = recording
    try:
        stage.run_chunk(ctx)
    finally:
        del tracer.occluded
    return tuple(np.concatenate([c[i] for c in calls]) for i in range(3))


def visible_fraction(visibility: Any, level: int) -> np.ndarray:
    """∫ V max(cos θ, 0) dω / π per row: the rows' dot product with the coefficients of
    max(cos θ, 0)/π (orthonormal basis), each a sum over the row's entries."""
    from pipeline.math.sphwavelet import leaf_means, wavelet_basis

    basis = wavelet_basis(level)
    cosine = basis.forward(leaf_means(lambda w: np.maximum(w[:, 2], 0.0) / np.pi, level, 2))
    count = visibility.read("count")
    row_of = np.repeat(np.arange(len(count)), count)
    products = visibility.read("value") * cosine[visibility.read("index")]
    return np.bincount(row_of, weights=products, minlength=len(count))


def write_png(path: Path, fraction: np.ndarray, empty: np.ndarray, height: int,
              width: int) -> None:
    """Grey visible fraction (1 = white), magenta where the texel is empty; row 0 at top."""
    import matplotlib.image

    rgb = np.repeat(np.clip(fraction, 0, 1)[:, None], 3, axis=1)
    rgb[empty] = [1.0, 0.0, 1.0]
    matplotlib.image.imsave(path, rgb.reshape(height, width, 3))


def folder_mb(path: Path) -> float:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file()) / 1e6


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME} --",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--scene", type=Path, default=SCENES / "bunny_grace.yaml")
    parser.add_argument("--workdir", type=Path, default=None,
                        help="bake there [default: a cache folder <scene>_visibility]")
    parser.add_argument("--keep", action="store_true",
                        help="keep a finished bake in the work directory (stage seconds "
                             "from its record)")
    parser.add_argument("--object", default="bunny",
                        help="the object whose busiest texel tile the paired rates run")
    parser.add_argument("--plain-rays", type=int, default=1 << 22)
    parser.add_argument("--pairs", type=int, default=5)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)

    from pipeline import job
    from pipeline.engine.executors.local import Cores
    from pipeline.engine.planning import stage_params
    from pipeline.engine.store import open_artifact

    scene = job.open_scene(args.scene)
    folder = args.workdir or CACHE / f"{scene.name}_visibility"
    before = load()
    _, workdir = baked(scene, workdir=folder, until="geometry", rebake=not args.keep)
    baked(scene, workdir=folder, until="triple.visibility")
    geometry = open_artifact(workdir.artifact("geometry"))
    atlas = open_artifact(workdir.artifact("triple.atlas"))
    visibility = open_artifact(workdir.artifact("triple.visibility"))
    params = {k: v for k, v in stage_params(job.stages(), scene).items()
              if k.startswith("triple.") or k == "bake.device"}
    pairs = paired_rates(geometry, atlas, visibility, params, args.object, args.pairs)
    plain = median(plain_embree_rate(geometry, args.plain_rays) for _ in range(3))

    attrs = visibility.attrs
    seconds = visibility.record["seconds"]
    count = visibility.read("count")
    state = atlas.read("texel_state")
    rows = visibility.read("texel_row")
    stored = count[rows[state != 0]]
    fraction = visible_fraction(visibility, attrs["leaf_level"])[rows]
    offsets = dict(zip(atlas.attrs["texture_sizes"], atlas.read("texture_offsets").tolist(),
                       strict=True))
    target = result_path(NAME, args.out)
    target.parent.mkdir(parents=True, exist_ok=True)
    pngs = {}
    for obj, (height, width) in atlas.attrs["texture_sizes"].items():
        part = slice(offsets[obj], offsets[obj] + height * width)
        path = target.with_name(f"{target.stem}_{obj}.png")
        write_png(path, fraction[part], state[part] == 0, height, width)
        pngs[obj] = path.name
    raw_bytes = sum(visibility.read(n).nbytes for n in ("count", "start", "residual",
                                                         "index", "value", "texel_row"))
    result = {
        "scene": args.scene.name,
        "bake_cores": Cores.resolve().describe(),
        "load_avg_at_start": before, "load_avg_at_end": load(),
        "settings": {k: attrs[k] for k in ("leaf_level", "coefficients", "visibility_refine",
                                           "selection", "keep_first", "store_tolerance",
                                           "store_budget", "texel_tile")},
        "atlas": {"seconds": atlas.record["seconds"],
                  "texture_sizes": atlas.attrs["texture_sizes"],
                  "screen_pixels": atlas.attrs["screen_pixels"],
                  "texel_counts": atlas.attrs["texel_counts"]},
        "visibility": {"seconds": seconds, "rays": attrs["rays"],
                       "rays_per_s": attrs["rays"] / seconds,
                       "rays_per_texel": attrs["rays"] / attrs["texels"],
                       "texels": attrs["texels"],
                       "texels_per_s": attrs["texels"] / seconds},
        "embree_plain_rays_per_s_at_end": plain,
        "paired": {"object": args.object, "runs": pairs,
                   "median_ratio": median(p["ratio"] for p in pairs),
                   "median_stage_rays_per_s": median(p["stage_rays_per_s"] for p in pairs),
                   "median_plain_rays_per_s": median(p["plain_rays_per_s"] for p in pairs),
                   "median_ratio_own": median(p["ratio_own"] for p in pairs),
                   "median_own_rays_traced_per_s": median(
                       p["own_rays_traced_per_s"] for p in pairs)},
        "coefficients_per_texel": {"median": float(np.median(stored)),
                                   "p90": float(np.percentile(stored, 90)),
                                   "max": int(stored.max()), "mean": float(stored.mean())},
        "worst_residual": float(visibility.read("residual").max()),
        "storage_mb": {"on_disk": folder_mb(workdir.artifact("triple.visibility")),
                       "raw": raw_bytes / 1e6,
                       "atlas_on_disk": folder_mb(workdir.artifact("triple.atlas"))},
        "visible_fraction": {"mean_covered": float(fraction[state == 1].mean()),
                             "min": float(fraction[state != 0].min()),
                             "max": float(fraction[state != 0].max())},
        "pngs": pngs,
    }
    return write_result(NAME, result, args.out)

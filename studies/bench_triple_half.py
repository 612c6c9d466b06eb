"""Benchmark: the rendered error that float16 storage of method triple's lighting and
BRDF tables adds (schema v2: float16 values over a float32 scale per row).

From a finished bake (``prt run SCENE --size WxH --workdir W``), one frame rendered from
the tables as stored, and one from the same rows with the values the stages computed
before the float16 rounding (the stages' own run_chunk, re-run here with
``wavelet_rows.to_half`` replaced by a float32 pass-through; the rows' entries are
checked to be the stored ones). Over the pixels that see the scene, reported: the
relative L2 difference of the two frames, the largest pixel difference relative to
that pixel, and the same per table when only that table's values are exchanged, with
the twin bound 2^-11 per value; against the 1 % store tolerance. Visibility rows are
float32 in both.

Run from the project root (bakes must be guarded: the bake's process pool spawns):
  python studies/bench_triple_half.py --workdir /tmp/bake64 [--size 64x64]
Writes benchmarks/results/triple_half.json.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from pipeline import job
from pipeline.cli import parse_size
from pipeline.device.raytrace import RayTracer
from pipeline.engine.chunk import make_chunk
from pipeline.engine.stage import ChunkContext
from pipeline.images import read_environment
from pipeline.math.camera import camera_rays
from pipeline.methods.triple import render as render_triple
from pipeline.methods.triple.stages import brdf_tables as brdf_stage
from pipeline.methods.triple.stages import light_rotations as light_stage
from pipeline.methods.triple.tables import WaveletRows
from pipeline.registry import get_method

ROOT = Path(__file__).resolve().parent.parent
PARAMS = job.stages().params  # the project's stages and every method's


def _float32(count: np.ndarray, value: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """to_half's stand-in: the values unrounded, scale 1."""
    return np.asarray(value, np.float32), np.ones(len(count), np.float32)


def unrounded_rows(scene: Any, artifacts: dict) -> dict[str, WaveletRows]:
    """The lighting and BRDF rows as the stages computed them before float16."""
    light_stage.to_half = brdf_stage.to_half = _float32
    try:
        light_art = artifacts["triple.light_rotations"]
        grid = light_stage.frame_grid(PARAMS)
        block = int(PARAMS["triple.light_block"])
        rgb = read_environment(scene.environment_file())
        parts = [light_stage.run_chunk(ChunkContext(
            params=PARAMS, scene={}, inputs={}, environment=rgb,
            chunk=make_chunk("b", "block", span=(s, min(s + block, grid.size)))))
            for s in range(0, grid.size, block)]
        brdf_art = artifacts["triple.brdf_tables"]
        keys = ("model", *brdf_stage.SHAPE_KEYS)
        brdf_parts = [brdf_stage.run_chunk(ChunkContext(
            params=PARAMS, scene={f"materials.{n}.{k}": scene.section(f"materials.{n}.{k}")
                                  for k in keys}, inputs={},
            chunk=make_chunk(n, "material", material=n, index=i)))
            for i, n in enumerate(brdf_art.attrs["material_names"])]
    finally:
        from pipeline.methods.triple.wavelet_rows import to_half
        light_stage.to_half = brdf_stage.to_half = to_half
    out = {}
    for name, art, chunks in (("light", light_art, parts), ("brdf", brdf_art, brdf_parts)):
        rows = {k: np.concatenate([p[k] for p in chunks]) for k in ("count", "index", "value")}
        if not (np.array_equal(rows["count"], art.read("count"))
                and np.array_equal(rows["index"], art.read("index"))):
            raise SystemExit(f"{name}: the re-run rows' entries differ from the stored ones "
                             "(was the bake made with these settings and this code?)")
        out[name] = WaveletRows.from_counts(rows["count"], rows["index"], rows["value"])
    return out


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--workdir", required=True)
    parser.add_argument("--size", default="64x64")
    args = parser.parse_args()
    scene = job.open_scene(str(ROOT / "scenes" / "bunny_grace.yaml"), parse_size(args.size))
    workdir = job.workdir_for(scene, args.workdir, None)
    method = get_method("triple")
    artifacts = job.method_artifacts(method, workdir)
    exact = unrounded_rows(scene, artifacts)
    stored_rows = render_triple._rows

    def render(swap: set[str]) -> np.ndarray:
        def rows(artifact: Any) -> WaveletRows:
            kind = artifact.record["kind"]
            if kind == "triple_lighting" and "light" in swap:
                return exact["light"]
            if kind == "triple_brdf" and "brdf" in swap:
                return exact["brdf"]
            return stored_rows(artifact)

        render_triple._rows = rows
        try:
            return render_triple.TripleRenderer(scene, artifacts).frame(scene).rgb
        finally:
            render_triple._rows = stored_rows

    half = render(set())
    cam, geo = scene.camera, artifacts["geometry"]
    origins, directions = camera_rays(cam.position, cam.look_at, cam.up, cam.fov,
                                      cam.width, cam.height)
    hits = RayTracer(geo.read("vertices"), geo.read("faces")).intersect(
        origins.reshape(-1, 3), directions.reshape(-1, 3))
    hit = (hits.prim >= 0).reshape(cam.height, cam.width)  # the background is the map
    result: dict[str, Any] = {"workdir": args.workdir, "size": args.size,
                              "load_average": os.getloadavg(), "tolerance": 0.01,
                              "float16_bound_per_value": 2.0 ** -11}
    for label, swap in (("both", {"light", "brdf"}), ("light_only", {"light"}),
                        ("brdf_only", {"brdf"})):
        ref = render(swap)
        diff = np.linalg.norm(half[hit] - ref[hit]) / np.linalg.norm(ref[hit])
        pixel = np.linalg.norm(half - ref, axis=-1) / np.maximum(
            np.linalg.norm(ref, axis=-1), 1e-12)
        result[label] = {"rel_l2": float(diff), "max_pixel_rel": float(pixel[hit].max()),
                         "pixels": int(hit.sum())}
        print(label, result[label])
    path = ROOT / "benchmarks" / "results" / "triple_half.json"
    path.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()

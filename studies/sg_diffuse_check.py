"""Scene-level check of method sg's diffuse SH transfer (stage sg.diffuse) against the
path-traced reference: scenes/bunny_sg.yaml with the bunny made Lambertian (same kd),
so that the full transport is all diffuse and the transfer should carry all of it.

Run from the project root:  python studies/sg_diffuse_check.py [--size 64]
[--spp 8192] [--workdir W]
Writes benchmarks/results/sg_diffuse_check/{results.json, compare.png} (left to right:
the SH frame, the control without SH, the reference, |SH − reference| in red; one
exposure, the surfaces' mean at 0.3).

Per vertex, radiance = Σ_k transfer[v, c, k] L_k (L = sh.project_latlong of the map, its
rotation and scale); a frame is the barycentric blend of it at each pixel's first hit
through the pixel centre (as the reference's ``center`` filter), which is what the sg
renderer's diffuse term will do. Compared with ``prt reference --transport full`` on
the surface pixels (background excluded): relative RMSE ‖I − R‖ / ‖R‖ and the mean
ratio ΣI / ΣR, for the whole surface, the bunny and the ground, at 0…4 bounces (the
stage's artifact at its default; the others from the same rays, sg_diffuse.with_bounces).
A control without SH (the map looked up per ray, the same gather matrix and bounces)
separates the order-5 truncation from the rest (rays, bounces, vertex interpolation).
The reference's own relative error estimate is recorded beside (its noise adds to the
RMSE; the mean ratio is hardly affected by it).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pipeline.engine.planning import stage_params  # noqa: E402
from pipeline.engine.runner import run  # noqa: E402
from pipeline.engine.stage import AssembleContext  # noqa: E402
from pipeline.engine.store import Workdir, open_artifact  # noqa: E402
from pipeline.images import read_environment, read_exr, write_png  # noqa: E402
from pipeline.math import sh  # noqa: E402
from pipeline.math.camera import camera_rays  # noqa: E402
from pipeline.math.envmap import EnvironmentMap  # noqa: E402
from pipeline.methods.sg import diffuse as sg_diffuse  # noqa: E402
from pipeline.methods.sg.stages.diffuse import vertex_scene  # noqa: E402
from pipeline.scene.file import load_scene  # noqa: E402

OUT = ROOT / "benchmarks" / "results" / "sg_diffuse_check"


def lambert_scene(workdir: Path) -> Path:
    """bunny_sg with the bunny's material Lambertian (same albedo), paths expanded."""
    doc = yaml.safe_load((ROOT / "scenes" / "bunny_sg.yaml").read_text())
    bunny = doc["materials"]["bunny"]
    doc["materials"]["bunny"] = {"model": "lambert", "albedo": bunny["albedo"]}
    doc["name"] = "bunny_sg_lambert"
    text = yaml.safe_dump(doc).replace("${PRT_DATA}", os.environ["PRT_DATA"])
    path = workdir / "bunny_sg_lambert.yaml"
    path.write_text(text)
    return path


def radiance_without_sh(scene, gather, environment: EnvironmentMap, samples: int,
                        bounces: int, rng: np.random.Generator) -> np.ndarray:
    """The control: per-vertex radiance (V, 3) of the same transport with the map looked
    up per ray instead of through SH: r_0 = kd/N Σ_j V_j L(ω_j) over fresh cosine
    directions, r_b = kd ⊙ (G r_{b−1}) with the stage's gather matrix G."""
    kd = scene.diffuse_albedo()
    direct = np.zeros((len(scene.positions), 3))
    for start in range(0, len(scene.positions), 1024):
        v = np.arange(start, min(start + 1024, len(scene.positions)))
        d = sg_diffuse.cosine_directions(scene.normals[v], samples, rng).reshape(-1, 3)
        o = np.repeat(scene.positions[v] + scene.offset * scene.normals[v], samples, axis=0)
        escaped = (scene.intersect(o, d).prim < 0)[:, None]
        light = (environment.radiance(d) * escaped).reshape(len(v), samples, 3)
        direct[v] = kd[v] * light.mean(axis=1)
    return sg_diffuse.with_bounces(gather, kd, direct[:, :, None], bounces)[:, :, 0]


def metrics(image: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> dict[str, float]:
    diff = image[mask] - reference[mask]
    return {"rel_rmse": float(np.linalg.norm(diff) / np.linalg.norm(reference[mask])),
            "mean_ratio": float(image[mask].sum() / reference[mask].sum()),
            "pixels": int(mask.sum())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--spp", type=int, default=8192)
    parser.add_argument("--workdir", default="/tmp/sg_diffuse_check")
    args = parser.parse_args()
    os.environ.setdefault("PRT_DATA", str(ROOT.parent / "shared" / "data"))
    root = Path(args.workdir)
    root.mkdir(parents=True, exist_ok=True)
    scene_path = lambert_scene(root)
    reference_exr = root / f"reference_{args.size}_{args.spp}.exr"
    if not reference_exr.exists():
        subprocess.run([sys.executable, "-m", "pipeline", "reference", str(scene_path),
                        "--transport", "full", "--size", f"{args.size}x{args.size}",
                        "--max-spp", str(args.spp), "--tolerance", "0.0",
                        "--out", str(reference_exr), "--workdir", str(root / "work"),
                        "--json", "-q"], check=True)
    record = json.loads(reference_exr.with_suffix(".json").read_text()) \
        if reference_exr.with_suffix(".json").exists() else {}
    reference = read_exr(reference_exr)[..., :3]

    from pipeline import job

    scene, stagefile = load_scene(scene_path), job.stages()
    workdir = Workdir(root / "work")
    run(scene, stagefile, workdir, until="sg.diffuse", progress=False)
    geometry = open_artifact(workdir.artifact("geometry"))
    stored = open_artifact(workdir.artifact("sg.diffuse"))
    params = stage_params(stagefile, scene)
    sections = {f"materials.{n}.albedo": scene.section(f"materials.{n}.albedo")
                for n in scene.materials}
    vscene = vertex_scene(AssembleContext(params, sections, {"geometry": geometry}))

    light = next(x for x in scene.lights if x.type == "environment")
    order = int(stored.attrs["order"])
    coefficients = sh.project_latlong(read_environment(light.params["file"]),
                                      light.params.get("rotation", 0.0), order)  # (n², 3)
    scale = light.params.get("scale", 1.0)
    cam = scene.camera
    origins, directions = camera_rays(cam.position, cam.look_at, cam.up, cam.fov,
                                      args.size, args.size)
    hits = vscene.tracer.intersect(origins.reshape(-1, 3), directions.reshape(-1, 3))
    names = list(geometry.attrs["object_names"])
    ranges = geometry.read("object_ranges")
    face_object = np.searchsorted(ranges[:, 3], np.maximum(hits.prim, 0), side="right")
    surface = (hits.prim >= 0).reshape(args.size, args.size)
    masks = {"surfaces": surface}
    for i, name in enumerate(names):
        masks[name] = surface & (face_object == i).reshape(args.size, args.size)

    def frame(transfer: np.ndarray) -> np.ndarray:
        radiance = np.einsum("vck,kc->vc", transfer, coefficients) * scale
        image = vscene.at_hits(radiance, hits).reshape(args.size, args.size, 3)
        return np.where(surface[..., None], image, reference)

    rng = np.random.default_rng(0)
    everything = np.arange(len(vscene.positions))
    direct, gather = sg_diffuse.direct_and_gather(vscene, everything,
                                                  int(params["sg.diffuse_samples"]), rng,
                                                  order)
    results = {"size": args.size, "reference": record, "stored_bounces":
               int(stored.attrs["bounces"]), "samples": int(stored.attrs["samples"]),
               "load": list(os.getloadavg()), "bounces": {}}
    stored_frame = frame(stored.read("transfer").astype(np.float64))
    control = radiance_without_sh(vscene, gather, EnvironmentMap(
        read_environment(light.params["file"]), light.params.get("rotation", 0.0), scale),
        int(params["sg.diffuse_samples"]), int(stored.attrs["bounces"]), rng)
    control_frame = np.where(surface[..., None], vscene.at_hits(control, hits).reshape(
        args.size, args.size, 3), reference)
    results["without_sh"] = {k: metrics(control_frame, reference, m) for k, m in masks.items()}
    results["stored"] = {k: metrics(stored_frame, reference, m) for k, m in masks.items()}
    for bounces in range(5):
        transfer = sg_diffuse.with_bounces(gather, vscene.diffuse_albedo(), direct, bounces)
        results["bounces"][bounces] = {k: metrics(frame(transfer), reference, m)
                                       for k, m in masks.items()}
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "results.json").write_text(json.dumps(results, indent=1) + "\n")
    error = np.abs(stored_frame - reference).mean(axis=-1, keepdims=True)
    heat = np.concatenate([error, 0.25 * error, 0.25 * error], axis=-1)
    exposure = 0.3 / float(reference[surface].mean())   # the surfaces' mean at 0.3
    write_png(OUT / "compare.png", np.concatenate([stored_frame, control_frame, reference,
                                                   heat], axis=1), exposure=exposure)
    print(json.dumps({"stored": results["stored"], "without_sh": results["without_sh"],
                      "surfaces_by_bounces": {b: r["surfaces"] for b, r in
                                              results["bounces"].items()}}, indent=1))


if __name__ == "__main__":
    main()

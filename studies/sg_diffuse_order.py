"""Study: how much of the shadowed direct diffuse light the SH order keeps under the
scene's map (method sg's sg.diffuse, pipeline/methods/sg/diffuse.py), on bunny_sg.

Run from the project root:  python studies/sg_diffuse_order.py [--workdir W]
Writes benchmarks/results/sg_diffuse_order.json.

For 40 vertices of each object (evenly spread in index), the direct diffuse radiance
kd/N Σ_j V_j L(ω_j) over N = 4096 cosine directions, the map looked up per ray (the
truth up to noise), against the SH product Σ_k t_k L_k from the same rays at orders 5
(paper 003), 8, 12, 16. Reported per object and channel: Σ SH / Σ truth and the relative
RMS over the vertices. The transfer is exact for the given rays, so what differs is the
truncation of the product at order n.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pipeline.engine.runner import run  # noqa: E402
from pipeline.engine.store import Workdir, open_artifact  # noqa: E402
from pipeline.images import read_environment  # noqa: E402
from pipeline.math import sh  # noqa: E402
from pipeline.math.brdf import BrdfParams  # noqa: E402
from pipeline.math.envmap import EnvironmentMap  # noqa: E402
from pipeline.methods.sg import diffuse as sg_diffuse  # noqa: E402
from pipeline.methods.sg.vertex_scene import VertexScene  # noqa: E402
from pipeline.scene.file import load_scene  # noqa: E402

SAMPLES = 4096
ORDERS = (5, 8, 12, 16)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--workdir", default="/tmp/sg_diffuse_order")
    args = parser.parse_args()
    os.environ.setdefault("PRT_DATA", str(ROOT.parent / "shared" / "data"))
    scene = load_scene(ROOT / "scenes" / "bunny_sg.yaml")
    workdir = Workdir(Path(args.workdir))
    from pipeline import job

    run(scene, job.stages(), workdir, until="geometry",
        progress=False)
    geometry = open_artifact(workdir.artifact("geometry"))
    arrays = {n: geometry.read(n) for n in
              ("vertices", "normals", "faces", "object_ranges", "object_material")}
    names = list(geometry.attrs["material_names"])
    vscene = VertexScene.from_arrays(arrays, [BrdfParams("lambert", scene.materials[n].albedo)
                                              for n in names])
    light = next(x for x in scene.lights if x.type == "environment")
    rgb = read_environment(light.params["file"])
    rotation = light.params.get("rotation", 0.0)
    environment = EnvironmentMap(rgb, rotation)
    result = {"samples": SAMPLES, "load": list(os.getloadavg()), "objects": {}}
    for index, name in enumerate(geometry.attrs["object_names"]):
        start, end = arrays["object_ranges"][index][:2]
        vertices = np.linspace(start, end - 1, 40).astype(int)
        rng = np.random.default_rng(0)
        directions = sg_diffuse.cosine_directions(vscene.normals[vertices], SAMPLES, rng)
        origins = np.repeat(vscene.positions[vertices]
                            + vscene.offset * vscene.normals[vertices], SAMPLES, axis=0)
        escaped = (vscene.intersect(origins, directions.reshape(-1, 3)).prim < 0
                   ).reshape(len(vertices), SAMPLES)
        kd = vscene.diffuse_albedo()[vertices]
        light_in = environment.radiance(directions.reshape(-1, 3)).reshape(
            len(vertices), SAMPLES, 3)
        truth = kd * (light_in * escaped[..., None]).mean(axis=1)
        rows = {}
        for order in ORDERS:
            y = np.zeros((len(vertices), SAMPLES, order * order))
            y[escaped] = sh.basis(directions[escaped], order)
            transfer = kd[:, :, None] * y.mean(axis=1)[:, None, :]
            radiance = np.einsum("vck,kc->vc", transfer, sh.project_latlong(rgb, rotation, order))
            rows[order] = {
                "sum_ratio": (radiance.sum(0) / truth.sum(0)).tolist(),
                "rel_rms": (np.linalg.norm(radiance - truth, axis=0)
                            / np.linalg.norm(truth, axis=0)).tolist()}
        result["objects"][name] = rows
    out = ROOT / "benchmarks" / "results" / "sg_diffuse_order.json"
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result["objects"], indent=1))


if __name__ == "__main__":
    main()

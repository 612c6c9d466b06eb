"""d2i accuracy against the reference path tracer, split the way paper 000 is judged.

Bakes the default scene (or ``--scene``) with ``--set`` stage parameters, renders the d2i
frame and the direct frame (their difference is d2i's indirect image, without noise:
both share one direct shader), and compares with the reference renderer at ``--spp``:

* full image and surfaces (pixels not seeing an emitter) against ``--transport first-glossy``;
* the indirect-only image against ``--transport first-glossy-indirect`` (the reference's
  indirect light alone, so its noise is the indirect light's only);
* per object, the indirect image's error and its mean radiance over the reference's (on
  a glossy object, the glossy indirect error of paper 000 Fig. 2).

Every error is also given with the reference's own noise taken out in quadrature
(√(e² − noise²)), the estimate of d2i's error against the converged answer.
``--material-edit OBJECT.gamma=V`` edits materials at run time (same bake) and renders
the references with that edit. Writes JSON (``--out``) and PNGs beside it: the two
indirect images (×4 exposure) and the per-pixel indirect error heat map (0 to 50 %).

    python studies/d2i_accuracy.py --workdir W --spp 1024 --out results/acc.json
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import click
import numpy as np

from pipeline import job
from pipeline.evaluation import metrics, reference_cache
from pipeline.evaluation.charts import heatmap
from pipeline.evaluation.evaluate import emitter_pixels
from pipeline.evaluation.reference import ReferenceSettings
from pipeline.images import write_png
from pipeline.scene.edits import with_material_edits
from pipeline.scene.file import default_scene_path, load_scene


def _noise(variance: np.ndarray, mean: np.ndarray, mask: np.ndarray) -> float:
    return math.sqrt(float(variance[mask].sum()) / float(np.square(mean[mask]).sum()))


def _corrected(error: float, noise: float) -> float:
    return math.sqrt(max(error * error - noise * noise, 0.0))


@click.command()
@click.option("--scene", "scene_path", type=click.Path(path_type=Path))
@click.option("--workdir", type=click.Path(path_type=Path), required=True)
@click.option("--reference-dir", type=click.Path(path_type=Path),
              help="Where references are cached [default: the work directory]; share one "
                   "across bakes of other stage parameters.")
@click.option("--spp", type=int, default=1024, show_default=True)
@click.option("--set", "settings", multiple=True, help="Stage parameter NAME=VALUE.")
@click.option("--material-edit", "edits", multiple=True, help="Run-time OBJECT.PARAM=V.")
@click.option("--bounces", type=int, default=32, show_default=True)
@click.option("--one-bounce", is_flag=True,
              help="Indirect light of one bounce only: d2i without its bounce loop, the "
                   "references cut after the second vertex (max_depth 2).")
@click.option("--size", type=int, help="Square image side [default: the scene camera's].")
@click.option("--out", type=click.Path(path_type=Path), required=True)
def main(scene_path, workdir, reference_dir, spp, settings, edits, bounces, one_bounce, size,
         out):
    base = load_scene(scene_path or default_scene_path())
    if size:
        base = base.with_image_size(size, size)
    params = {}
    for item in settings:
        name, _, value = item.partition("=")
        params[name] = json.loads(value)
    baked = base.with_settings(params) if params else base
    wd = job.workdir_for(baked, workdir)
    job.bake(baked, wd, quiet=True)
    scene = with_material_edits(baked, list(edits)) if edits else baked
    if one_bounce:
        bounces = 0
    frame = job.render_frame(scene, wd, "d2i", {"max_bounces": bounces}).rgb
    direct = job.render_frame(scene, wd, "direct").rgb
    ref_wd = job.workdir_for(scene, reference_dir) if reference_dir else wd
    refs = {t: reference_cache.reference(scene, ref_wd, ReferenceSettings(
        t, tolerance=0.0, min_spp=spp, max_spp=spp, max_depth=2 if one_bounce else -1),
        quiet=True).image
            for t in ("first-glossy", "first-glossy-indirect")}
    full, indirect_ref = refs["first-glossy"], refs["first-glossy-indirect"]
    surfaces = ~emitter_pixels(scene, wd)
    indirect = frame - direct
    result = {"settings": params, "edits": list(edits), "spp": spp, "bounces": bounces,
              "one_bounce": one_bounce}
    for name, image, ref, mask in (("full", frame, full, np.ones_like(surfaces)),
                                   ("surfaces", frame, full, surfaces),
                                   ("indirect", indirect, indirect_ref, surfaces)):
        error = metrics.relative_rmse(image, ref.mean, mask)
        noise = _noise(ref.variance, ref.mean, mask)
        result[name] = {"rel_rmse": error, "reference_noise": noise,
                        "noise_corrected": _corrected(error, noise)}
    result["indirect"]["mean_ratio"] = float(indirect[surfaces].mean()
                                             / indirect_ref.mean[surfaces].mean())
    geometry, _ = job.load_geometry(scene, wd)
    from pipeline.engine.store import open_artifact

    object_id = open_artifact(wd.artifact("gbuffer"), "gbuffer").read("object_id")
    result["per_object_indirect"] = {}
    for i, name in enumerate(geometry["object_names"]):
        mask = object_id == i
        if not mask.any() or not surfaces[mask].all():
            continue
        error = metrics.relative_rmse(indirect, indirect_ref.mean, mask)
        noise = _noise(indirect_ref.variance, indirect_ref.mean, mask)
        result["per_object_indirect"][name] = {
            "mean_ratio": float(indirect[mask].mean() / indirect_ref.mean[mask].mean()),
            "rel_rmse": error, "reference_noise": noise,
            "noise_corrected": _corrected(error, noise)}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    stem = out.with_suffix("")
    write_png(Path(f"{stem}_indirect.png"), indirect, 4.0)
    write_png(Path(f"{stem}_indirect_reference.png"), indirect_ref.mean, 4.0)
    heatmap(Path(f"{stem}_indirect_error.png"), metrics.error_map(indirect, indirect_ref.mean),
            0.5, "relative error per pixel of the indirect image, |I - R| / |R|")
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()

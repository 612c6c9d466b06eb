"""Where method d2i breaks down (issue 6): three studies on variants of the default
Cornell box at a small size, each against the reference renderer's ``first-glossy-indirect``
transport (the indirect image is what d2i approximates; its direct term is exact).

``gathers``     a small glossy object: the small box made Blinn-Phong (γ = 100), gather
                counts swept; the indirect error on the box's pixels and on the rest.
``gamma``       γ across and beyond what a truncated PCA basis fits: a mostly glossy
                floor (kd 0.05, ρs 0.2, so that its indirect light is mostly the glossy
                term), γ swept over its range with the default basis and with k forced
                to 1 and 2; the floor's indirect error next to the basis's own error.
``truncation``  a sharp indirect shadow: a narrow spot light (the only light) lights a
                low patch of the back wall behind the small box, which casts that
                patch's indirect shadow on the floor in front of it. The proportional
                budgets (the default rule) swept together — D's per pixel, T's b0 and
                Ms's per row, as multiples of the defaults; the floor's indirect error.

Each study writes ``d2i_breakdown_<study>.json`` and a chart (PNG) into ``--out``, and
the indirect images (×4) of its extremes for viewing.

    python studies/d2i_breakdown.py gathers --out benchmarks/results --workdir W
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import click
import numpy as np
import yaml

from pipeline import job
from pipeline.engine.stagefile import load_stagefile
from pipeline.engine.store import open_artifact
from pipeline.evaluation import metrics, reference_cache
from pipeline.evaluation.reference import ReferenceSettings
from pipeline.images import write_png
from pipeline.math.brdf import scene_brdfs
from pipeline.methods.d2i.brdf_pca import read_basis
from pipeline.scene.edits import with_material_edits
from pipeline.scene.file import default_scene_path, load_scene
from pipeline.scene.model import Scene


def _variant(folder: Path, name: str, edit) -> Scene:
    """The default scene with ``edit(doc)`` applied, written into ``folder``."""
    source = default_scene_path()
    doc = yaml.safe_load(source.read_text())
    for obj in doc["objects"].values():
        if "mesh" in obj:
            obj["mesh"] = str((source.parent / obj["mesh"]).resolve())
    doc["name"] = name
    edit(doc)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return load_scene(path)


def _indirect_errors(scene: Scene, baked: Scene, workdir: Path, spp: int,
                     objects: list[str]) -> dict[str, Any]:
    """Bake ``baked`` (stage settings), render ``scene`` (run-time edits of it) and
    compare its indirect image with the first-glossy-indirect reference, per object in
    ``objects`` and over all surfaces; noise-corrected errors alongside."""
    wd = job.workdir_for(baked, workdir / "bake")
    job.bake(baked, wd, quiet=True)
    frame = job.render_frame(scene, wd, "d2i")
    indirect = frame.rgb - job.render_frame(scene, wd, "direct").rgb
    ref = reference_cache.reference(scene, job.workdir_for(scene, workdir / "reference"),
                        ReferenceSettings("first-glossy-indirect", tolerance=0.0, min_spp=spp,
                                          max_spp=spp), quiet=True).image
    geometry, _ = job.load_geometry(scene, wd)
    names = geometry["object_names"]
    object_id = open_artifact(wd.artifact("gbuffer"), "gbuffer").read("object_id")
    emitters = [names.index(n) for n in names if n == "luminaire"]
    masks = {"surfaces": (object_id >= 0) & ~np.isin(object_id, emitters)}
    masks.update({o: object_id == names.index(o) for o in objects})
    out: dict[str, Any] = {"bounces": frame.timings["bounces"],
                           "gather_count": int(open_artifact(wd.artifact("d2i.gather"), "gather")
                                               .attrs["count"])}
    gather_object = open_artifact(wd.artifact("d2i.gather"), "gather").read("object_id")
    for o in objects:
        out[f"gathers_on_{o}"] = int(np.sum(gather_object == names.index(o)))
    for key, mask in masks.items():
        error = metrics.relative_rmse(indirect, ref.mean, mask)
        norm = float(np.square(ref.mean[mask]).sum())
        noise = math.sqrt(float(ref.variance[mask].sum()) / norm)
        out[key] = {"rel_rmse": error, "reference_noise": noise,
                    "noise_corrected": math.sqrt(max(error ** 2 - noise ** 2, 0.0)),
                    "mean_ratio": float(indirect[mask].mean() / ref.mean[mask].mean())}
    out["images"] = (indirect, ref.mean)
    return out


def _save(out: Path, study: str, rows: list[dict[str, Any]], x: str, series: list[str],
          xlabel: str, logx: bool = True) -> None:
    """JSON of ``rows`` (images dropped) and a chart of each series' noise-corrected
    error against ``x``; the indirect images of the first and last rows."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    for tag, row in (("first", rows[0]), ("last", rows[-1])):
        indirect, reference = row["images"]
        write_png(out / f"d2i_breakdown_{study}_{tag}.png", indirect, 4.0)
        write_png(out / f"d2i_breakdown_{study}_{tag}_reference.png", reference, 4.0)
    clean = [{k: v for k, v in r.items() if k != "images"} for r in rows]
    (out / f"d2i_breakdown_{study}.json").write_text(json.dumps(clean, indent=1))
    fig, ax = plt.subplots(figsize=(5.5, 4.0), dpi=120)
    for label in series:
        pts = [(r[x], r[label]["noise_corrected"]) for r in clean if label in r]
        ax.plot(*zip(*pts, strict=True), "o-", label=label)
    if logx:
        ax.set_xscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("indirect rel. RMSE (reference noise removed)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / f"d2i_breakdown_{study}.png")
    plt.close(fig)


def _gathers(out: Path, workdir: Path, size: int, spp: int) -> None:
    def glossy_small_box(doc):
        doc["materials"]["glossy_box"] = {"model": "blinn_phong",
                                          "albedo": [0.3, 0.2, 0.6], "specular": 0.1,
                                          "gamma": 100, "gamma_range": [3, 300]}
        doc["objects"]["smallbox"]["material"] = "glossy_box"

    scene = _variant(workdir, "cornell_glossy_smallbox", glossy_small_box)
    scene = scene.with_image_size(size, size)
    rows = []
    for count in (256, 1024, 4096, 16384):
        baked = scene.with_settings({"gather.count": count})
        row = _indirect_errors(baked, baked, workdir, spp, ["smallbox", "floor"])
        rows.append({"gather.count": count, **row})
        click.echo(f"gathers {count}: small box {row['smallbox']['noise_corrected']:.3f} "
                   f"({row['gathers_on_smallbox']} gathers on it), floor "
                   f"{row['floor']['noise_corrected']:.3f}")
    _save(out, "gathers", rows, "gather.count", ["smallbox", "floor", "surfaces"],
          "gather samples")


def _gamma(out: Path, workdir: Path, size: int, spp: int) -> None:
    def mostly_glossy_floor(doc):
        doc["materials"]["glossy_floor"].update(albedo=[0.05, 0.05, 0.05], specular=0.2)

    scene = _variant(workdir, "cornell_glossier_floor", mostly_glossy_floor)
    scene = scene.with_image_size(size, size)
    rows = []
    for max_k in (None, 2, 1):
        baked = scene.with_settings({"gather.count": 4096,
                                     **({"brdf_basis.max_k": max_k} if max_k else {})})
        for gamma in (3, 10, 20, 50, 100, 200, 300):
            edited = with_material_edits(baked, [f"glossy_floor.gamma={gamma}"])
            row = _indirect_errors(edited, baked, workdir, spp, ["floor"])
            basis = open_artifact(job.workdir_for(baked, workdir / "bake")
                                  .artifact("brdf_basis"), "brdf_basis")
            b = read_basis(basis, "glossy_floor", scene_brdfs(edited, ["glossy_floor"])[0])
            rows.append({"gamma": gamma, "max_k": max_k or "default", "k": int(b.k),
                         "basis_rel_rms": float(np.interp(gamma, b.gamma_test,
                                                          b.rel_rms[b.k])),
                         f"floor, k = {b.k}": row["floor"], **row})
            click.echo(f"k={b.k} gamma {gamma}: floor {row['floor']['noise_corrected']:.3f} "
                       f"basis rel. RMS {rows[-1]['basis_rel_rms']:.3f}")
    _save(out, "gamma", rows, "gamma", sorted({k for r in rows for k in r
                                               if k.startswith("floor, k")}), "floor γ")


def _truncation(out: Path, workdir: Path, size: int, spp: int) -> None:
    def spot_on_back_wall(doc):
        position, target = np.array([278.0, 500, 0]), np.array([150.0, 80, 559])
        doc["lights"] = [{"type": "spot", "position": position.tolist(),
                          "direction": (target - position).tolist(),
                          "intensity": [2e6, 2e6, 2e6], "angle": 10.0, "falloff": 0.2}]
        del doc["objects"]["luminaire"]

    scene = _variant(workdir, "cornell_spot", spot_on_back_wall).with_image_size(size, size)
    defaults = load_stagefile().params
    budgets = ("truncate.d_coefficients", "truncate.coefficients", "truncate.ms_coefficients")
    rows = []
    for factor in (2.0, 1.0, 0.5, 0.25, 0.125, 0.0625):
        settings = {name: max(1, round(factor * int(defaults[name]))) for name in budgets}
        baked = scene.with_settings({"gather.count": 4096, "truncate.budget": "proportional",
                                     **settings})
        row = _indirect_errors(baked, baked, workdir, spp, ["floor"])
        rows.append({**settings, **row})
        click.echo(f"budgets ×{factor} (D {settings[budgets[0]]} per pixel): floor "
                   f"{row['floor']['noise_corrected']:.3f}")
    _save(out, "truncation", rows, budgets[0], ["floor", "surfaces"],
          "D coefficients per pixel (T's and Ms's budgets scaled alike)")


STUDIES = {"gathers": _gathers, "gamma": _gamma, "truncation": _truncation}


@click.command()
@click.argument("study", type=click.Choice(list(STUDIES)))
@click.option("--out", type=click.Path(path_type=Path), default=Path("benchmarks/results"),
              show_default=True)
@click.option("--workdir", type=click.Path(path_type=Path), required=True)
@click.option("--size", type=int, default=64, show_default=True)
@click.option("--spp", type=int, default=1024, show_default=True)
def main(study: str, out: Path, workdir: Path, size: int, spp: int) -> None:
    out.mkdir(parents=True, exist_ok=True)
    STUDIES[study](out, workdir, size, spp)


if __name__ == "__main__":
    main()

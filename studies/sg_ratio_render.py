"""Study (issue 42, item 4; decision 0042): method sg's rendered image with each
``normal`` option, rendered from one bake against one set of references, so that a
render-time change is measured without the re-fit ``prt evaluate`` would start (its
keys cover the method's package).

Run from the project root, after ``prt evaluate SCENE --method sg --size 128x128
--workdir W --out …`` has baked W and cached its references:
    python studies/sg_ratio_render.py SCENE --workdir W [--size 128]
        [--spp FULL GLOSSY] [--options vertex pixel ratio] [--model-spp N]
        [--out benchmarks/results/sg_ratio_render_<scene>.json]

Per option: the full frame against the first-glossy reference and the glossy component
(``component=glossy``) against the first-glossy ``--lobe glossy`` reference, relative
RMSE over the surface pixels (evaluate.py's mask), the mean ratio, and each reference's
own estimated noise, and the shading kernel's median milliseconds over 5 frames (the
G-buffer cached). With ``--model-spp N`` also the full frame against the ``full``
transport's reference at N paths per pixel (the model error: what a path tracer would
show; rendered and cached in W if not there). The references are read from W's cache at
the paths per pixel ``--spp`` gives (those prt evaluate's stopping rule settled on).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pipeline import job  # noqa: E402
from pipeline.engine.store import Workdir  # noqa: E402
from pipeline.evaluation import metrics, reference_cache  # noqa: E402
from pipeline.evaluation.evaluate import _noise, apply_budget, emitter_pixels  # noqa: E402
from pipeline.evaluation.reference import ReferenceSettings  # noqa: E402


def cached_reference(scene, workdir: Workdir, lobe: str, spp: int,
                     transport: str = "first-glossy"):
    """The ``transport`` reference of ``lobe`` at ``spp`` paths per pixel (cached by prt
    evaluate; rendered and cached if not)."""
    settings = ReferenceSettings(transport, tolerance=0.0, min_spp=spp, max_spp=spp,
                                 lobe=lobe)
    return reference_cache.reference(scene, workdir, settings, quiet=True).image


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("--workdir", required=True)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--options", nargs="+", default=["vertex", "pixel", "ratio"])
    ap.add_argument("--spp", type=int, nargs=2, default=[1024, 1024],
                    help="paths per pixel of the full and the glossy reference (the ones "
                    "prt evaluate settled on: its results.json's reference_spp, "
                    "reference_spp_glossy)")
    ap.add_argument("--model-spp", type=int, default=0,
                    help="paths per pixel of a full-transport reference to measure the "
                    "full frame against too (0: not measured)")
    ap.add_argument("--out", default="")
    args = ap.parse_args()
    scene = apply_budget(job.open_scene(Path(args.scene)), {"size": args.size})
    workdir = Workdir(Path(args.workdir))
    wd = Workdir(workdir.root / "sweep" / "sg")
    surfaces = ~emitter_pixels(scene, wd)
    refs = {lobe: cached_reference(scene, workdir, lobe, spp)
            for lobe, spp in zip(("all", "glossy"), args.spp, strict=True)}
    full = cached_reference(scene, workdir, "all", args.model_spp, "full") \
        if args.model_spp else None
    rows = {}
    for normal in args.options:
        row = {}
        for lobe, component in (("all", "all"), ("glossy", "glossy")):
            ref = refs[lobe]
            renderer = job.frame_renderer(scene, wd, "sg",
                                          {"normal": normal, "component": component})
            renderer.frame(scene)  # warm-up
            frames = [renderer.frame(scene) for _ in range(5)]
            frame = frames[-1]
            row[f"{lobe}_shade_ms"] = statistics.median(f.timings["shade_ms"] for f in frames)
            row[f"{lobe}_rel_rmse"] = metrics.relative_rmse(frame.rgb, ref.mean, surfaces)
            row[f"{lobe}_mean_ratio"] = float(frame.rgb[surfaces].sum()
                                              / ref.mean[surfaces].sum())
            row[f"{lobe}_reference_noise"] = _noise(ref, surfaces)
            row[f"{lobe}_reference_spp"] = ref.spp
            if lobe == "all" and full is not None:
                row["model_rel_rmse"] = metrics.relative_rmse(frame.rgb, full.mean, surfaces)
                row["model_reference_noise"] = _noise(full, surfaces)
        rows[normal] = row
        print(f"{scene.name} normal={normal:7s} full {100 * row['all_rel_rmse']:5.1f} % "
              f"(ratio {row['all_mean_ratio']:.3f}, noise "
              f"{100 * row['all_reference_noise']:.1f} % at {row['all_reference_spp']})  "
              f"glossy {100 * row['glossy_rel_rmse']:5.1f} % (ratio "
              f"{row['glossy_mean_ratio']:.3f}, noise "
              f"{100 * row['glossy_reference_noise']:.1f} % at "
              f"{row['glossy_reference_spp']})  shade {row['glossy_shade_ms']:.1f} ms"
              + (f"  against full {100 * row['model_rel_rmse']:.1f} % (noise "
                 f"{100 * row['model_reference_noise']:.1f} %)" if full is not None else ""),
              flush=True)
    out = Path(args.out or ROOT / "benchmarks" / "results" / f"sg_ratio_render_{scene.name}.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"scene": scene.name, "size": args.size, "rows": rows},
                              indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()

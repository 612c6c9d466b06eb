"""Fine against coarse bunny under method sg, side by side (issue 17: paper 003's point
is that a coarse mesh keeps sharp, non-cross-fading glossy highlights).

Run from the project root, after ``prt evaluate`` of both scenes at the same size (the
fine scene's records: benchmarks/results/evaluate_sg_integral, made of two evaluate
runs, one budget each, of scenes/bunny_sg.yaml with ``settings: {sg.fit_tolerance: T}``
for T = 1 and 0.3, ``--size 128x128 --workdir .prt/eval_sg``):
    prt evaluate scenes/bunny_sg_coarse.yaml --method sg --sweep sg.fit_tolerance=1 \
        --size 128x128 --out benchmarks/results/evaluate_sg_coarse --workdir .prt/eval_sg_coarse
    python studies/sg_fine_coarse.py [--budget sg-fit_tolerance-1] [--exposure 3]
Writes benchmarks/results/sg_fine_coarse.png (rows: the 6.6k-face bunny, the 948-face
one; columns: method sg, its first-glossy reference (the best cached one), the error
heat map evaluate wrote)
and sg_fine_coarse.json (each row's errors, whole and split into glossy and diffuse,
frame time, storage, bake seconds, from the evaluate records).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from PIL import Image  # noqa: E402

from pipeline.engine.store import open_artifact  # noqa: E402
from pipeline.images import read_exr, srgb_encode  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
# label: (evaluate's output folder, its work directory: the references are cached there)
ROWS = {"fine (bunny_6.6kf, 3,301 vertices)": (RESULTS / "evaluate_sg_integral",
                                               ROOT / ".prt/eval_sg"),
        "coarse (bunny_948f, 453 vertices)": (RESULTS / "evaluate_sg_coarse",
                                              ROOT / ".prt/eval_sg_coarse")}
KEYS = ("rel_rmse_surfaces", "rel_rmse_glossy", "rel_rmse_diffuse", "glossy_mean_ratio",
        "diffuse_mean_ratio", "reference_rel_rmse_surfaces", "reference_rel_rmse_glossy",
        "reference_rel_rmse_diffuse", "frame_ms", "artifact_bytes", "bake_s")


def to_8bit(linear: np.ndarray, exposure: float) -> np.ndarray:
    """8-bit sRGB of linear radiance × 2^exposure (as the PNG previews)."""
    return np.round(srgb_encode(linear, 2.0 ** exposure) * 255.0).astype(np.uint8)


def best_reference(workdir: Path, shape: tuple[int, ...]) -> np.ndarray:
    """The cached first-glossy reference (all lobes) of ``shape`` with the most paths."""
    best, spp = None, -1
    for path in (workdir / "reference").glob("first-glossy-*.zarr"):
        if path.name.startswith(("first-glossy-glossy-", "first-glossy-diffuse-",
                                 "first-glossy-indirect-")):
            continue
        artifact = open_artifact(path, "reference")
        mean = artifact.read("mean")
        if mean.shape == shape and artifact.attrs["spp"] > spp:
            best, spp = mean, artifact.attrs["spp"]
    return best


def fitted(image: np.ndarray, height: int) -> np.ndarray:
    """``image`` (8-bit RGB) scaled to ``height`` rows (nearest neighbour)."""
    width = round(image.shape[1] * height / image.shape[0])
    return np.asarray(Image.fromarray(image).resize((width, height), Image.NEAREST))


def slug_of(budget: dict) -> str:
    """A budget's file name in evaluate's frames folder (pipeline/evaluation/evaluate.py)."""
    return "_".join(f"{k.replace('.', '-')}-{v}" for k, v in sorted(budget.items()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget", default=None,
                    help="the budget's slug [default: each evaluation's default budget]")
    ap.add_argument("--exposure", type=float, default=2.0)
    args = ap.parse_args()
    tiles, summary = [], {}
    for label, (folder, workdir) in ROWS.items():
        records = json.loads((folder / "results.json").read_text())
        record = next(r for r in records if (r["default"] if args.budget is None else
                                             slug_of(r["budget"]) == args.budget))
        frames = folder / "frames"
        frame = read_exr(frames / f"{slug_of(record['budget'])}.exr")
        heat = np.asarray(Image.open(frames / f"{slug_of(record['budget'])}_error.png")
                          .convert("RGB"))
        height = 2 * frame.shape[0]  # frames doubled (nearest), the heat map fitted
        row = [fitted(to_8bit(frame, args.exposure), height),
               fitted(to_8bit(best_reference(workdir, frame.shape), args.exposure), height),
               fitted(heat, height)]
        tiles.append(np.concatenate(row, axis=1))
        summary[label] = {"budget": record["budget"], **{k: record.get(k) for k in KEYS}}
    width = max(t.shape[1] for t in tiles)
    image = np.concatenate([np.pad(t, ((0, 0), (0, width - t.shape[1]), (0, 0)))
                            for t in tiles], axis=0)
    Image.fromarray(image).save(RESULTS / "sg_fine_coarse.png")
    (RESULTS / "sg_fine_coarse.json").write_text(json.dumps(summary, indent=1))
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()

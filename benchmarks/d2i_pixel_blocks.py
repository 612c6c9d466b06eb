"""Study: D's truncation per pixel row (paper 000) against per block of b × b pixels
(pipeline/stages/truncate.py cut_pixel_blocks, the rows transformed across the block first),
at equal budgets per pixel. From a baked scene's transfer rows (the near-lossless rows
before the cut) and the radiance vector of its full frame (direct light and every
bounce, as the renderer's products read it), per budget and block size: entries kept,
D L's relative RMS error over the pixels with a row and its mean ratio, against D L of
the transfer rows. No reference renderer: this isolates the cut (the end-to-end errors
are d2i_accuracy.py's).

  python benchmarks/d2i_pixel_blocks.py --workdir W [--size 128] [--budgets 500,250,125,64]
Writes benchmarks/results/d2i_pixel_blocks_<size>.json (``--out``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import scipy.sparse as sp

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pipeline import job  # noqa: E402
from pipeline.math import haar  # noqa: E402
from pipeline.method import get_method  # noqa: E402
from pipeline.render.d2i import D2iRenderer  # noqa: E402
from pipeline.rows import expand_values  # noqa: E402
from pipeline.scene import default_scene_path, load_scene  # noqa: E402
from pipeline.stages.truncate import cut_pixel_blocks  # noqa: E402
from pipeline.store import open_artifact  # noqa: E402


def products(count: np.ndarray, index: np.ndarray, value: np.ndarray, radiance: np.ndarray
             ) -> np.ndarray:
    """Each CSR row's product with ``radiance`` (size, 3), float64."""
    offsets = np.concatenate([[0], np.cumsum(count)]).astype(np.int64)
    rows = sp.csr_matrix((value.astype(np.float64), index, offsets),
                         shape=(len(count), len(radiance)))
    return rows @ radiance


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--workdir", type=Path, required=True)
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--budgets", default="500,250,125,64")
    parser.add_argument("--blocks", default="1,2,4,8")
    parser.add_argument("--scene", type=Path, help="scene file [default: the Cornell box]")
    parser.add_argument("--pooled", action="store_true",
                        help="also cut with the budget pooled over each transfer tile "
                        "(truncate.shared_budget chunk; otherwise per block)")
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    scene = load_scene(args.scene or default_scene_path()).with_image_size(args.size, args.size)
    workdir = job.workdir_for(scene, args.workdir)
    job.bake(scene, workdir, quiet=True)
    renderer = D2iRenderer(scene, job.method_artifacts(get_method("d2i"), workdir),
                           layout="cpu")
    renderer(scene)
    vector = np.empty((renderer.size, 4), np.float32)
    renderer.pcl.enqueue_copy(renderer.queue, vector, renderer.radiance_buffer)
    radiance = vector[:, :3].astype(np.float64)

    transfer = open_artifact(workdir.artifact("d2i.transfer"))
    haar_length = int(transfer.attrs["haar_length"])
    columns = haar_length + int(transfer.attrs["gather_count"])
    tiles = [{n: transfer.read_piece(n, c) for n in transfer.names if n.startswith("d_")}
             for c in transfer.record["chunks"]]
    width = height = args.size
    exact = np.zeros((width * height, 3))
    for tile in tiles:
        exact[tile["d_pixel"]] = products(tile["d_count"], tile["d_index"], tile["d_value"],
                                          radiance)
    seen = np.zeros(width * height, bool)
    for tile in tiles:
        seen[tile["d_pixel"][tile["d_count"] > 0]] = True
    result = {"size": args.size, "pixels_with_rows": int(seen.sum()),
              "transfer_entries": int(sum(t["d_count"].sum() for t in tiles)), "cuts": []}
    for budget in (int(b) for b in args.budgets.split(",")):
        params = {"truncate.budget": "proportional", "truncate.d_coefficients": budget,
                  "truncate.tolerance": 0.0}
        variants = [(int(b), False) for b in args.blocks.split(",")]
        variants += [(b, True) for b, _ in variants if args.pooled]
        for block, pooled in variants:
            blocks = -(-width // block) * -(-height // block)
            stored = np.zeros((blocks * block * block, 3))
            entries = 0
            for tile in tiles:
                params["truncate.shared_budget"] = "chunk" if pooled else "block"
                cut = cut_pixel_blocks(params, tile, haar_length, columns, width, block)
                value = expand_values(cut["d_count"], cut["d_value"], cut["d_scale"])
                stored[cut["d_row"]] = products(cut["d_count"], cut["d_index"], value,
                                                radiance)
                entries += int(cut["d_count"].sum())
            ids, slot = haar.pixel_blocks(np.arange(width * height), width, block)
            got = haar.unblock(stored, ids, slot, haar.block_transform(block))
            error = np.sqrt(np.mean((got[seen] - exact[seen]) ** 2) / np.mean(exact[seen] ** 2))
            row = {"budget": budget, "block": block, "pooled": pooled, "entries": entries,
                   "entries_per_pixel": entries / seen.sum(), "rel_rmse": float(error),
                   "mean_ratio": float(got[seen].sum() / exact[seen].sum())}
            result["cuts"].append(row)
            print(json.dumps(row), flush=True)
    out = args.out or ROOT / "benchmarks" / "results" / f"d2i_pixel_blocks_{args.size}.json"
    out.write_text(json.dumps(result, indent=1))
    print(f"wrote {out}", file=sys.stderr)


if __name__ == "__main__":
    main()

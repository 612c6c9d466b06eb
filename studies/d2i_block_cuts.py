"""Study: d2i's D and Ms cut per row (paper 000) against cut across blocks of neighbours
(pipeline/methods/d2i/stages/truncate.py cut_blocks: D across b × b pixel blocks, Ms across n
consecutive gather samples), at equal budgets per row. From a baked scene's
near-lossless rows (the transfer and bounce stages', before any cut) and the radiance
vector of its full frame (direct light and every bounce, as the renderer's products read
it), per budget and block size: entries kept, the product's relative RMS error over the
rows that have entries (D L per pixel, Ms L per gather sample) and its mean ratio,
against the product of the uncut rows. No reference renderer: this isolates the cut
(the end-to-end errors are d2i_accuracy.py's). ``--pooled`` adds the budget shared by
all the blocks of a chunk (truncate.shared_budget chunk: a transfer tile, a bounce block).

  python studies/d2i_block_cuts.py --workdir W [--size 128] [--scene S] [--pooled]
Writes benchmarks/results/d2i_block_cuts_<scene>_<size>.json (``--out``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pipeline import job  # noqa: E402
from pipeline.engine.rows import expand_values  # noqa: E402
from pipeline.engine.store import open_artifact  # noqa: E402
from pipeline.math import haar  # noqa: E402
from pipeline.methods.d2i import blocks  # noqa: E402
from pipeline.methods.d2i.render import D2iRenderer  # noqa: E402
from pipeline.methods.d2i.stages.truncate import cut_blocks  # noqa: E402
from pipeline.registry import get_method  # noqa: E402
from pipeline.scene.file import default_scene_path, load_scene  # noqa: E402

FIELDS = ("count", "index", "value", "residual")


def products(count: np.ndarray, index: np.ndarray, value: np.ndarray, radiance: np.ndarray
             ) -> np.ndarray:
    """Each CSR row's product with ``radiance`` (size, 3), float64."""
    offsets = np.concatenate([[0], np.cumsum(count)]).astype(np.int64)
    rows = sp.csr_matrix((value.astype(np.float64), index, offsets),
                         shape=(len(count), len(radiance)))
    return rows @ radiance


def pieces(artifact: Any, prefix: str, item: str) -> list[dict[str, np.ndarray]]:
    """Each chunk's rows (``count``, ``index``, ``value``, ``residual``) and the item
    (pixel or gather sample) of each row, ``item``."""
    out = []
    start = 0
    for chunk in artifact.record["chunks"]:
        rows = {k: artifact.read_piece(f"{prefix}_{k}", chunk) for k in FIELDS}
        rows["item"] = artifact.read_piece(f"{prefix}_pixel", chunk) if item == "pixel" \
            else start + np.arange(len(rows["count"]))
        start += len(rows["count"])
        out.append(rows)
    return out


def study(chunks: list[dict[str, np.ndarray]], items: int, radiance: np.ndarray,
          haar_length: int, budgets: list[int], grouping: dict[int, Any],
          pooled_too: bool) -> list[dict[str, Any]]:
    """Errors of every (budget, block size, pooled) cut of ``chunks``' rows;
    ``grouping[size]`` maps item ids to (block, slot, transform)."""
    exact = np.zeros((items, 3))
    seen = np.zeros(items, bool)
    for rows in chunks:
        exact[rows["item"]] = products(rows["count"], rows["index"], rows["value"], radiance)
        seen[rows["item"][rows["count"] > 0]] = True
    out = []
    for budget in budgets:
        for size in grouping:
            for pooled in (False, True) if pooled_too else (False,):
                params = {"truncate.budget": "proportional", "truncate.tolerance": 0.0}
                all_block, all_slot, transform = grouping[size](np.arange(items))
                stored = np.zeros(((int(all_block.max()) + 1) * len(transform), 3))
                entries = 0
                for rows in chunks:
                    block, slot, _ = grouping[size](rows["item"])
                    cut = cut_blocks(params, rows, block, slot, transform, haar_length,
                                     len(radiance), budget, pooled)
                    value = expand_values(cut["count"], cut["value"], cut["scale"])
                    stored[cut["row"]] = products(cut["count"], cut["index"], value,
                                                  radiance)
                    entries += int(cut["count"].sum())
                got = blocks.unblock(stored, all_block, all_slot, transform)
                error = np.sqrt(np.mean((got[seen] - exact[seen]) ** 2)
                                / np.mean(exact[seen] ** 2))
                row = {"budget": budget, "block": size, "pooled": pooled, "entries": entries,
                       "entries_per_row": entries / seen.sum(), "rel_rmse": float(error),
                       "mean_ratio": float(got[seen].sum() / exact[seen].sum())}
                out.append(row)
                print(json.dumps(row), flush=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--workdir", type=Path, required=True)
    parser.add_argument("--scene", type=Path, help="scene file [default: the Cornell box]")
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--budgets", default="500,250,125,64")
    parser.add_argument("--pixel-blocks", default="1,2,4,8", help="D: block edges b")
    parser.add_argument("--gather-blocks", default="1,4,16,64", help="Ms: block lengths n")
    parser.add_argument("--pooled", action="store_true")
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    scene = load_scene(args.scene or default_scene_path()).with_image_size(args.size, args.size)
    workdir = job.workdir_for(scene, args.workdir)
    job.bake(scene, workdir, quiet=True)
    renderer = D2iRenderer(scene, job.method_artifacts(get_method("d2i"), workdir),
                           layout="cpu")
    renderer.frame(scene)
    vector = np.empty((renderer.size, 4), np.float32)
    renderer.pcl.enqueue_copy(renderer.queue, vector, renderer.radiance_buffer)
    radiance = vector[:, :3].astype(np.float64)
    budgets = [int(b) for b in args.budgets.split(",")]
    width = height = args.size

    def pixel_grouping(b: int):
        return lambda pixel: (*blocks.pixel_blocks(pixel, width, b), blocks.block_transform(b))

    def gather_grouping(n: int):
        return lambda gather: (gather // n, gather % n, haar.matrix(n))

    transfer = open_artifact(workdir.artifact("d2i.transfer"))
    bounce = open_artifact(workdir.artifact("d2i.bounce"))
    result = {"scene": scene.name, "size": args.size, "D": study(
        pieces(transfer, "d", "pixel"), width * height, radiance,
        int(transfer.attrs["haar_length"]), budgets,
        {int(b): pixel_grouping(int(b)) for b in args.pixel_blocks.split(",")}, args.pooled)}
    result["Ms"] = study(
        pieces(bounce, "ms", "gather"), int(bounce.attrs["gather_count"]), radiance,
        haar.padded_length(int(bounce.attrs["gather_count"])), budgets,
        {int(n): gather_grouping(int(n)) for n in args.gather_blocks.split(",")}, args.pooled)
    out = args.out or ROOT / "benchmarks" / "results" / \
        f"d2i_block_cuts_{scene.name}_{args.size}.json"
    out.write_text(json.dumps(result, indent=1))
    print(f"wrote {out}", file=sys.stderr)


if __name__ == "__main__":
    main()

"""Where a γ-range re-bake's time would go with finer transfer chunks (issue 18): a
least-squares fit of each d2i.transfer tile's seconds (its chunk record) to its pixel
counts per material kind (Lambertian, and each glossy material), from a work directory
baked by benchmarks/engine/rebake.py (two glossy materials: glossy_floor, smallbox_ward).

Run: python studies/rebake_cost_model.py WORKDIR [--tile 32]
Prints the seconds per pixel of each kind and the share of the transfer stage that the
edited material's pixels (smallbox_ward) cost, against the share its tiles cost now.
"""

from __future__ import annotations

import argparse
import glob
import json
from pathlib import Path

import numpy as np

from pipeline.engine.store import open_artifact


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("workdir", type=Path)
    parser.add_argument("--tile", type=int, default=32)
    parser.add_argument("--edited", default="smallbox_ward")
    parser.add_argument("--other-glossy", default="glossy_floor")
    args = parser.parse_args()
    gbuffer = open_artifact(args.workdir / "gbuffer.zarr")
    height, width = gbuffer.attrs["height"], gbuffer.attrs["width"]
    material = gbuffer.read("material_id").reshape(height, width)
    names = open_artifact(args.workdir / "geometry.zarr").attrs["material_names"]
    edited, other = names.index(args.edited), names.index(args.other_glossy)
    seconds, counts = [], []
    for path in sorted(glob.glob(str(args.workdir / ".chunks" / "d2i.transfer" / "*.json"))):
        record = json.loads(Path(path).read_text())
        y, x = int(record["chunk"][1:6]), int(record["chunk"][8:13])
        tile = material[y:y + args.tile, x:x + args.tile]
        seconds.append(record["seconds"])
        counts.append([np.sum(tile >= 0) - np.sum(tile == edited) - np.sum(tile == other),
                       np.sum(tile == other), np.sum(tile == edited)])
    sec, c = np.array(seconds), np.array(counts, float)
    design = np.c_[c, np.ones(len(sec))]
    coef, *_ = np.linalg.lstsq(design, sec, rcond=None)
    fit = np.sqrt(np.mean((design @ coef - sec) ** 2)) / sec.mean()
    print(f"seconds per pixel: Lambertian {coef[0]:.4f}, {args.other_glossy} {coef[1]:.4f}, "
          f"{args.edited} {coef[2]:.4f}; per tile {coef[3]:.3f} (fit {fit:.0%} RMS)")
    print(f"transfer {sec.sum():.1f} s over {len(sec)} tiles; {args.edited}: "
          f"{int(c[:, 2].sum())} pixels, their cost {coef[2] * c[:, 2].sum() / sec.sum():.1%} "
          f"of the stage; the {int((c[:, 2] > 0).sum())} tiles that hold them "
          f"{sec[c[:, 2] > 0].sum() / sec.sum():.1%}")


if __name__ == "__main__":
    main()

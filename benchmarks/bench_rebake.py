"""Benchmark: re-bake after a scene edit against the full bake (issue 18, aim < 10 % for
one material's γ-range edit in a two-glossy-material scene), and after moving a small
object.

The scene is the default Cornell box with a second glossy material: the small box in
Ward (α 0.2, range [0.1, 0.5]) beside the Blinn–Phong floor, at ``--size``² with
transfer tiles of ``--tile`` pixels. One run:

1. the full bake from scratch (``prt run --until d2i.truncate --until d2i.truncate_t
   --until d2i.truncate_ms``: every stage, no frames), wall seconds;
2. the small box's ``gamma_range`` edited to [0.15, 0.5]: the forecast (``prt run
   --dry-run --json``), then the re-bake, its wall seconds and the stages and chunks
   that ran; with ``--repeats N``, N re-bakes, the range toggled between [0.15, 0.5]
   and [0.1, 0.5] (each a new basis: the same chunks re-run), and their median. Each
   repeat records the box's basis size k: the narrower range needs k = 4 where the full
   bake's needs 5, so its T chunks have 5 rows per pixel instead of 6 (at 400²: 14.4
   against 17.6 s). A basis of a new size means new transfer kernels (ROWS = k + 1),
   compiled once per process; until the fourteenth session PoCL also compiled them once
   per launch size, which made the first re-bake after the full bake 2–9 s slower than
   the same edit repeated (NOTES.md, fourteenth session);
3. the small box moved 20 mm along x: the same.

Each step is a ``prt`` command (Python start-up included in its seconds, as a user
would see it), started when the machine is quiet (benchmarks/bench_cores.py
``quiet_prt``). Run from the project root:
  python benchmarks/bench_rebake.py --workdir /tmp/bench_rebake
Writes benchmarks/results/rebake.json (``--out``).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml
from bench_cores import ROOT, prt, quiet_prt, scene_file

# every stage the d2i frames read, no frames
UNTIL = ("--until", "d2i.truncate", "--until", "d2i.truncate_t", "--until", "d2i.truncate_ms")


def two_glossy_scene(folder: Path, size: int, tile: int, gathers: int | None
                     ) -> dict[str, Any]:
    """The Cornell box with its small box in a glossy Ward material, as a dictionary
    (``gathers``: its gather count, None for the scene's)."""
    doc = yaml.safe_load(scene_file(folder, size).read_text())
    doc["materials"]["smallbox_ward"] = {"model": "ward", "albedo": [0.45, 0.30, 0.90],
                                         "specular": 0.08, "gamma": 0.2,
                                         "gamma_range": [0.1, 0.5]}
    doc["objects"]["smallbox"]["material"] = "smallbox_ward"
    doc["settings"] = {"transfer.tile": tile}
    if gathers is not None:
        doc["settings"]["gather.count"] = gathers
    return doc


def write(folder: Path, doc: dict[str, Any], name: str) -> Path:
    path = folder / name
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def rebake(scene: Path, workdir: Path, run: Callable[[list[str]], dict]) -> dict[str, Any]:
    """The forecast, then the re-bake (by ``run``): seconds, stages and chunk counts."""
    base = ["run", str(scene), *UNTIL, "--workdir", str(workdir)]
    plan = prt([*base, "--dry-run"])["report"]["dry_run"]
    r = run(base)
    stages = r["report"]["stages"]
    return {"wall_s": r["wall_s"], "cpu_s": r["cpu_s"], "noisy": r["noisy"],
            "stage_s": sum(s["seconds"] for s in stages),
            "ran": {s["name"]: {"chunks": len(s["ran_chunks"]),
                                "of": len(s["ran_chunks"]) + len(s["reused_chunks"]),
                                "seconds": s["seconds"]}
                    for s in stages if s["action"] == "ran"},
            "forecast": {p["name"]: {"rerun": p["rerun"], "total": p["total"],
                                     "reasons": p["reasons"], "rule": p["rule"]}
                         for p in plan if p["state"] != "fresh"}}


def basis_k(work: Path) -> int:
    """The small box's basis size k (its T rows per pixel: k + 1) in the work directory."""
    from pipeline.store import open_artifact

    basis = open_artifact(work / "brdf_basis.zarr")
    return int(basis.read("k")[list(basis.attrs["material_names"]).index("smallbox_ward")])


def gamma_range(doc: dict[str, Any]) -> list[float]:
    return doc["materials"]["smallbox_ward"]["gamma_range"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--workdir", type=Path, required=True)
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--tile", type=int, default=16, help="transfer tile edge")
    parser.add_argument("--repeats", type=int, default=1,
                        help="γ-range re-bakes (the range toggled), median reported")
    parser.add_argument("--gathers", type=int, default=None,
                        help="gather count [default: the scene's]")
    parser.add_argument("--no-quiet", action="store_true",
                        help="run each step at once, neither waiting for a quiet machine "
                        "nor repeating noisy runs (a smoke test: timings not comparable)")
    parser.add_argument("--out", type=Path,
                        default=ROOT / "benchmarks" / "results" / "rebake.json")
    args = parser.parse_args()
    folder = args.workdir
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    doc = two_glossy_scene(folder, args.size, args.tile, args.gathers)
    work = folder / "work"
    run = (lambda a: {**prt(a), "noisy": None}) if args.no_quiet else quiet_prt
    full = run(["run", str(write(folder, doc, "scene.yaml")), *UNTIL, "--workdir",
                      str(work)])
    result: dict[str, Any] = {"cpus": os.cpu_count(), "size": args.size,
                              "transfer_tile": args.tile,
                              "full_bake": {"wall_s": full["wall_s"], "cpu_s": full["cpu_s"],
                                            "noisy": full["noisy"],
                                            "stage_s": sum(s["seconds"] for s in
                                                           full["report"]["stages"]),
                                            "stages": {s["name"]: s["seconds"] for s in
                                                       full["report"]["stages"]}}}
    k_full = basis_k(work)
    gamma = json.loads(json.dumps(doc))
    walls = []
    for repeat in range(args.repeats):
        gamma["materials"]["smallbox_ward"]["gamma_range"] = [0.15 if repeat % 2 == 0 else
                                                              0.1, 0.5]
        edit = rebake(write(folder, gamma, "gamma.yaml"), work, run)
        result.setdefault("gamma_range_edit", edit)
        walls.append((edit["wall_s"], edit["stage_s"], gamma_range(gamma), basis_k(work)))
    result["gamma_range_edit"]["full_bake_k"] = k_full
    result["gamma_range_edit"]["repeats"] = [
        {"wall_s": w, "stage_s": st, "gamma_range": r, "k": k} for w, st, r, k in walls]
    result["gamma_range_edit"]["median_ratio_to_full"] = (
        statistics.median(w for w, *_ in walls) / full["wall_s"])
    result["gamma_range_edit"]["median_stage_ratio_to_full"] = (
        statistics.median(st for _, st, *_ in walls) / result["full_bake"]["stage_s"])
    moved = json.loads(json.dumps(gamma))
    moved["objects"]["smallbox"]["transform"] = {"translate": [20.0, 0.0, 0.0]}
    result["moved_small_box"] = rebake(write(folder, moved, "moved.yaml"), work, run)
    for edit in ("gamma_range_edit", "moved_small_box"):
        result[edit]["ratio_to_full"] = result[edit]["wall_s"] / full["wall_s"]
        result[edit]["stage_ratio_to_full"] = (result[edit]["stage_s"]
                                               / result["full_bake"]["stage_s"])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1))
    print(json.dumps({k: (v if not isinstance(v, dict) else
                          {kk: vv for kk, vv in v.items() if kk in ("wall_s", "ratio_to_full",
                                                                    "stage_ratio_to_full",
                                                                    "median_ratio_to_full",
                                                                    "ran")})
                      for k, v in result.items()}, indent=1))


if __name__ == "__main__":
    main()

"""Re-bake after a γ-range edit and after a moved box against the full bake: prt run seconds.

Re-bake after a scene edit against the full bake (issue 18, aim < 10 % for one
material's γ-range edit in a two-glossy-material scene), and after moving a small object:
wall seconds of each ``prt run`` and the stages and chunks it re-ran.

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
   compiled once per process (PoCL no longer compiles them once per launch size, which
   made the first re-bake after the full bake 2–9 s slower than the same edit repeated;
   decision 0016);
3. the small box moved 20 mm along x: the same.

Each step is a ``prt`` command (Python start-up included in its seconds, as a user
would see it), started when the machine is quiet (benchmarks/engine/cores.py
``quiet_prt``; ``--no-quiet``: at once). The work directory (``--workdir``) is emptied
first.
"""

from __future__ import annotations

import argparse
import json
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

from benchmarks.engine.cores import prt, quiet_prt, scene_file
from benchmarks.fixtures import CACHE, load, median, write_result

NAME = "engine.rebake"
# The Cornell box (the edits name its small box) at its smallest useful size: 24², tiles
# of 8 (9 chunks, so that an edit re-runs some of them), 256 gathers (tests/
# test_benchmarks.py's settings), one γ-range re-bake.
PRESETS = {"default": [],
           "tiny": ["--size", "24", "--tile", "8", "--gathers", "256", "--repeats", "2",
                    "--no-quiet", "--workdir", str(CACHE / "engine.rebake_tiny")]}

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
    from pipeline.engine.store import open_artifact

    basis = open_artifact(work / "brdf_basis.zarr")
    return int(basis.read("k")[list(basis.attrs["material_names"]).index("smallbox_ward")])


def gamma_range(doc: dict[str, Any]) -> list[float]:
    return doc["materials"]["smallbox_ward"]["gamma_range"]


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME} --",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--workdir", type=Path, default=CACHE / NAME,
                        help="scratch folder, emptied first [default: %(default)s]")
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--tile", type=int, default=16, help="transfer tile edge")
    parser.add_argument("--repeats", type=int, default=1,
                        help="γ-range re-bakes (the range toggled), median reported")
    parser.add_argument("--gathers", type=int, default=None,
                        help="gather count [default: the scene's]")
    parser.add_argument("--no-quiet", action="store_true",
                        help="run each step at once, neither waiting for a quiet machine "
                        "nor repeating noisy runs (a smoke test: timings not comparable)")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    folder = args.workdir
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    doc = two_glossy_scene(folder, args.size, args.tile, args.gathers)
    work = folder / "work"

    def run(a: list[str]) -> dict[str, Any]:
        return quiet_prt(a, quiet=not args.no_quiet)

    before = load()
    full = run(["run", str(write(folder, doc, "scene.yaml")), *UNTIL, "--workdir", str(work)])
    result: dict[str, Any] = {"size": args.size,
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
        median(w for w, *_ in walls) / full["wall_s"])
    result["gamma_range_edit"]["median_stage_ratio_to_full"] = (
        median(st for _, st, *_ in walls) / result["full_bake"]["stage_s"])
    moved = json.loads(json.dumps(gamma))
    moved["objects"]["smallbox"]["transform"] = {"translate": [20.0, 0.0, 0.0]}
    result["moved_small_box"] = rebake(write(folder, moved, "moved.yaml"), work, run)
    for edit in ("gamma_range_edit", "moved_small_box"):
        result[edit]["ratio_to_full"] = result[edit]["wall_s"] / full["wall_s"]
        result[edit]["stage_ratio_to_full"] = (result[edit]["stage_s"]
                                               / result["full_bake"]["stage_s"])
    result["load"] = [before, load()]
    print(json.dumps({k: (v if not isinstance(v, dict) else
                          {kk: vv for kk, vv in v.items() if kk in ("wall_s", "ratio_to_full",
                                                                    "stage_ratio_to_full",
                                                                    "median_ratio_to_full",
                                                                    "ran")})
                      for k, v in result.items()}, indent=1))
    return write_result(NAME, result, args.out)

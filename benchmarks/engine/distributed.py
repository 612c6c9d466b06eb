"""Each method's heaviest stage in one process against dask local:2 and --jobs 2; re-runs.

The heaviest stage of each method in-process against a dask LocalCluster of 2 worker
processes (``prt run --scheduler local:2``; issue 18, aim ≥ 1.8×), with the local process
pool (``--jobs 2``) beside it, and the scheduler's cost per task: forced re-runs, medians.

Per case, the scene is baked once up to the stage, then the stage is re-run with
``prt run SCENE --until STAGE --force STAGE`` per configuration, configurations
alternating over ``--rounds`` rounds (each run started on a quiet machine and repeated
when others used the cores meanwhile: benchmarks/engine/cores.py ``quiet_prt``;
``--no-quiet``: at once):

* d2i: ``d2i.transfer``, the default Cornell box at 128² (16 tiles of 32²; ``--size
  d2i=256``: 64 tiles);
* triple: ``triple.visibility``, bunny_grace at 64² (texel tiles of its atlas; ``--size
  triple=128``: about 4× the texels);
* sg: ``sg.fit``, bunny_sg_coarse (453 glossy vertices in 4 batches of 113; the ground's
  34 batches are Lambertian: nothing to fit).

``--scene METHOD=FILE`` replaces a case's scene (the smoke run: the tiny d2i scene).

Configurations: ``1x1`` (in-process, one thread: the baseline of the aim), ``1x2``
(in-process, both cores as threads), ``local:2`` and ``2x1`` (the local pool). The
stage's seconds are the run's own (its chunks and the assembly of its artifact; for
local:2 also what remains of the cluster's start after the run's planning, ≈ 1 s on 2
cores, which a first stage waits for); each run's
artifact digest is recorded: they must all be equal. Speed-ups are given as the ratio of
the medians and as the median of each round's own ratio (``..._per_round_median``: on a
machine whose speed drifts between rounds, the pairs of one round are comparable).

Each run's ``timeline`` comes from its chunk records (which process ran each chunk, when
it started, its seconds): per worker process the first chunk's seconds against the
median of its others (what a fresh process pays once: imports, opening the inputs,
building its kernels), the stage's span from the first chunk's start to the last one's
end, and the seconds the processes sat idle in it (waiting for work, or at the tail).

``overhead``: the scheduler's round trip per task on a LocalCluster of 2 workers, from
``--tasks`` no-op tasks submitted at once (what a chunk pays besides its work), for the
written estimate of paper 000's Interior scene on 32 workers (decision 0009); None with
``--tasks 0`` (the smoke run: a cluster's start is seconds).

Run nothing else heavy beside it: ``python -m benchmarks run engine.distributed``. The
result is written after each case (a cut run keeps the cases it finished).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import yaml

from benchmarks.engine.cores import prt, quiet_prt, scene_copy, stage_seconds
from benchmarks.fixtures import CACHE, SCENES, TINY, load, median, write_result
from pipeline.engine.chunkwrite import read_marker
from pipeline.engine.executors.dask import LEAN_WORKERS
from pipeline.engine.store import read_record
from pipeline.scene.file import default_scene_path

NAME = "engine.distributed"
CONFIGS = ["1x1", "1x2", "local:2", "2x1"]
PRESETS = {"default": [],
           "tiny": ["--only", "d2i", "--scene", f"d2i={TINY / 'tiny_d2i.yaml'}", "--size",
                    "d2i=16", "--configs", "1x1,local:2", "--rounds", "1", "--tasks", "0",
                    "--no-quiet", "--workdir", str(CACHE / "engine.distributed_tiny")]}


def config_args(config: str) -> list[str]:
    """``JxT`` -> --jobs J --threads T; ``local:N`` -> --scheduler local:N."""
    if config.startswith("local:"):
        return ["--scheduler", config]
    jobs, threads = config.split("x")
    return ["--jobs", jobs, "--threads", threads]


def cases(folder: Path, settings: dict[str, Any], sizes: dict[str, int] | None = None,
          scenes: dict[str, Path] | None = None) -> list[dict[str, Any]]:
    """The method, scene arguments and heaviest stage of each case; ``settings``: stage
    parameters over the scenes' own (smaller chunks for many workers, say); ``sizes``:
    image edges over the defaults (d2i 128, triple 64: the work grows with the pixels,
    and triple's with the texels, about 3 a pixel) — a bake large enough for many
    workers to share; ``scenes``: scene files over the defaults (per method)."""
    sizes = {"d2i": 128, "triple": 64, **(sizes or {})}
    scenes = {"d2i": default_scene_path(), "triple": SCENES / "bunny_grace.yaml",
              "sg": SCENES / "bunny_sg_coarse.yaml", **(scenes or {})}
    edge = sizes["d2i"]
    cornell = scene_copy(scenes["d2i"], folder / f"{scenes['d2i'].stem}_{edge}.yaml", edge,
                         settings)
    grace = scene_copy(scenes["triple"], folder / scenes["triple"].name, settings=settings)
    sg = scene_copy(scenes["sg"], folder / scenes["sg"].name, settings=settings)
    return [
        {"method": "d2i", "scene": [str(cornell)], "stage": "d2i.transfer"},
        {"method": "triple", "scene": [str(grace), "--size", f"{sizes['triple']}x"
                                                             f"{sizes['triple']}"],
         "stage": "triple.visibility"},
        {"method": "sg", "scene": [str(sg)], "stage": "sg.fit"},
    ]


def parse_setting(text: str) -> tuple[str, Any]:
    """``NAME=VALUE`` -> (NAME, VALUE read as YAML: 16 -> int)."""
    name, _, value = text.partition("=")
    return name, yaml.safe_load(value)


def noop(x: int) -> int:
    return x


def scheduler_overhead(tasks: int, workers: int) -> dict[str, float]:
    """Milliseconds per task of ``tasks`` no-op tasks on a LocalCluster of ``workers``
    set up as ``prt run --scheduler local:N`` sets up its own (submitted at once,
    gathered as they complete), median of 5 batches. With dask's defaults the nannies
    would also write MALLOC_TRIM_THRESHOLD_ into this process's environment, and every
    run after this one, the one-process baseline too, would inherit it (1.4 to 2.4 times
    as slow; pipeline/engine/executors/dask.py ``heap_as_glibc_default``)."""
    import logging

    import dask
    from distributed import Client, LocalCluster, as_completed

    with dask.config.set(LEAN_WORKERS), \
            LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                         dashboard_address=":0", silence_logs=logging.ERROR) as cluster, \
            Client(cluster) as client:
        client.gather(client.map(noop, range(4), pure=False))  # warm-up
        per_task = []
        for _ in range(5):
            start = time.perf_counter()
            for future in as_completed(client.map(noop, range(tasks), pure=False)):
                future.result()
            per_task.append((time.perf_counter() - start) / tasks * 1e3)
    return {"tasks": tasks, "workers": workers, "ms_per_task_median": median(per_task),
            "ms_per_task": per_task}


def timeline(artifact: Path, stage: str) -> dict[str, Any]:
    """The last run of ``stage``'s chunks (its ``artifact``), from their records
    (pipeline/engine/runner.py ``execute_chunk``, beside the artifact as pipeline/engine/store.py
    ``Workdir.markers`` lays them out): per process, the chunk count, its first chunk's
    seconds and the median of its others; the span (first start to last end) and the
    idle process seconds in it (span × processes − busy)."""
    markers = (read_marker(p) for p in (artifact.parent / ".chunks" / stage).glob("*.json"))
    chunks = [m for m in markers if m is not None]
    by_process: dict[str, list[dict[str, Any]]] = {}
    for c in sorted(chunks, key=lambda c: c["started"]):
        by_process.setdefault(c["process"], []).append(c)
    start = min(c["started"] for c in chunks)
    span = max(c["started"] + c["seconds"] for c in chunks) - start
    processes = {
        name: {"chunks": len(own), "first_s": own[0]["seconds"],
               "others_median_s": median(c["seconds"] for c in own[1:])
               if len(own) > 1 else None,
               "first_start_s": own[0]["started"] - start}
        for name, own in by_process.items()}
    excess = [p["first_s"] - p["others_median_s"] for p in processes.values()
              if p["others_median_s"] is not None]
    return {"processes": len(processes), "span_s": span,
            "idle_s": span * len(processes) - sum(c["seconds"] for c in chunks),
            "first_chunk_excess_s_median": median(excess) if excess else None,
            "per_process": processes}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME} --",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--workdir", type=Path, default=CACHE / NAME,
                        help="folder for the bakes (one work directory per case) "
                        "[default: %(default)s]")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--only", choices=["d2i", "triple", "sg"], action="append",
                        help="run only these cases (repeatable) [default: all]")
    parser.add_argument("--tasks", type=int, default=400,
                        help="no-op tasks per batch of the overhead (0: not measured)")
    parser.add_argument("--configs", default=",".join(CONFIGS),
                        help=f"comma-separated configurations [default: {','.join(CONFIGS)}]")
    parser.add_argument("--set", dest="settings", action="append", default=[],
                        metavar="NAME=VALUE", help="stage parameter over the scenes' own "
                        "(repeatable), e.g. transfer.tile=16 for more chunks than workers")
    parser.add_argument("--size", dest="sizes", action="append", default=[],
                        metavar="METHOD=EDGE", help="image edge of a case (d2i, triple) "
                        "over its default (128, 64), e.g. d2i=256 for 16 workers")
    parser.add_argument("--scene", dest="scenes", action="append", default=[],
                        metavar="METHOD=FILE", help="scene file of a case over its default")
    parser.add_argument("--max-wait", type=float, default=1800.0,
                        help="longest wait for a quiet machine before a run, seconds")
    parser.add_argument("--no-quiet", action="store_true",
                        help="run each step at once, neither waiting for a quiet machine "
                        "nor repeating noisy runs (a smoke test: timings not comparable)")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    args.workdir.mkdir(parents=True, exist_ok=True)

    configs = args.configs.split(",")
    settings = dict(parse_setting(t) for t in args.settings)
    sizes = {method: int(edge) for method, _, edge in (t.partition("=") for t in args.sizes)}
    if set(sizes) - {"d2i", "triple"}:
        parser.error(f"--size: a case of d2i or triple, not {sorted(set(sizes))}")
    scenes = {method: Path(file).resolve()
              for method, _, file in (t.partition("=") for t in args.scenes)}
    if set(scenes) - {"d2i", "triple", "sg"}:
        parser.error(f"--scene: a case of d2i, triple or sg, not {sorted(set(scenes))}")
    result: dict[str, Any] = {"configs": configs, "cases": {}, "settings": settings,
                              "sizes": sizes, "scenes": {m: str(f) for m, f in scenes.items()},
                              "load_average_start": load()}
    workers = max([int(c.split(":")[1]) for c in configs if c.startswith("local:")] or [2])
    result["overhead"] = scheduler_overhead(args.tasks, workers) if args.tasks else None
    print("overhead", json.dumps(result["overhead"]), flush=True)
    for case in cases(args.workdir, settings, sizes, scenes):
        if args.only and case["method"] not in args.only:
            continue
        workdir = args.workdir / case["method"]
        base = ["run", *case["scene"], "--until", case["stage"], "--workdir", str(workdir)]
        prt(base)  # the stages before it, once
        runs: dict[str, list[dict[str, Any]]] = {c: [] for c in configs}
        for round_ in range(args.rounds):
            for config in configs:
                r = quiet_prt([*base, "--force", case["stage"], *config_args(config)],
                              max_wait_s=args.max_wait, quiet=not args.no_quiet)
                artifact = next(workdir.rglob(f"{case['stage']}.zarr"))
                record = read_record(artifact)
                runs[config].append({
                    "round": round_, "stage_s": stage_seconds(r["report"], case["stage"]),
                    "wall_s": r["wall_s"], "cpu_s": r["cpu_s"],
                    "other_cpu_s": r["other_cpu_s"], "noisy": r["noisy"],
                    "chunks": len(record["chunk_digests"]),
                    "chunk_seconds_sum": sum(record["chunk_seconds"].values()),
                    "digest": record["digest"], "timeline": timeline(artifact, case["stage"])})
                shown = {k: v for k, v in runs[config][-1].items() if k != "timeline"}
                t = runs[config][-1]["timeline"]
                shown["timeline"] = {k: v for k, v in t.items() if k != "per_process"}
                print(case["method"], config, json.dumps(shown), flush=True)
        stage_s = {c: median(r["stage_s"] for r in rs) for c, rs in runs.items()}
        digests = {r["digest"] for rs in runs.values() for r in rs}
        ratios = {f"speedup_{c}_vs_1x1": stage_s["1x1"] / stage_s[c] for c in configs
                  if c != "1x1" and "1x1" in stage_s}
        # the same from each round's own pair (robust to a machine that drifts between
        # rounds: one worker and the configuration ran minutes apart, not an hour)
        ratios.update({f"speedup_{c}_vs_1x1_per_round_median": median(
            a["stage_s"] / b["stage_s"] for a, b in zip(runs["1x1"], runs[c], strict=True))
            for c in configs if c != "1x1" and "1x1" in runs})
        result["cases"][case["method"]] = {
            "stage": case["stage"], "scene": case["scene"], "stage_s_median": stage_s,
            **ratios, "identical_digests": len(digests) == 1, "runs": runs}
        print(case["method"], json.dumps({k: v for k, v in result["cases"][case["method"]]
                                          .items() if k != "runs"}), flush=True)
        result["load_average_end"] = load()
        write_result(NAME, result, args.out)  # after each case: a cut run keeps it
    result["load_average_end"] = load()
    return write_result(NAME, result, args.out)


if __name__ == "__main__":
    main()

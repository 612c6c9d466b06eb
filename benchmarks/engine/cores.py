"""How the bake scales with cores (--jobs × --threads): a forced d2i.transfer per setting.

How the bake scales with the cores it is given (``--jobs`` worker processes ×
``--threads`` per task; pipeline/engine/executors/local.py ``Cores``): a forced
d2i.transfer (and with ``--full`` a bake from scratch) per configuration, medians.

Two measurements, each a few runs with the configurations alternating (so that a slow
spell of a shared machine hits them all), reported as medians:

- transfer: the default scene (``--scene``) at ``--size`` (128²) baked once up to
  d2i.transfer, then ``prt run --until d2i.transfer --force d2i.transfer`` per
  configuration. Two times: ``transfer_s``, the stage's seconds as the run reports them
  (its chunks, the workers' start when a pool runs, and the assembly of its artifact in
  the parent, which is the same serial work whatever the configuration), and
  ``chunks_s``, from the command's start to the last chunk stored (the CLI's start-up and
  planning, ≈ 0.5 s, the workers' start and the chunks); chunks/s and pixels/s are over
  ``chunks_s``.
- full (``--full``): the same scene at 256² baked from scratch up to d2i.truncate,
  wall seconds per configuration (every stage, Python start-up included).

A configuration is ``JxT`` (``--jobs J --threads T``) or ``auto`` (neither flag: what
the machine's cores resolve to). Each run records its CPU seconds (user + system, from
the children's rusage) and the CPU seconds everything else on the machine took meanwhile
(/proc/stat's busy time less ours): other engineers' tests running beside a timing show
up there. A run starts only once the machine has been quiet for 5 s (others below
QUIET_CORES; ``--no-quiet``: at once, a smoke test), and is repeated when the others
took more than NOISY_CORES on average (kept, flagged ``noisy``, after RETRIES repeats).
Every run's artifact digest is recorded: they must all be equal.

Run nothing else heavy beside it:
  python -m benchmarks run engine.cores -- --full
Every run is also appended to WORKDIR/runs.jsonl as it ends, and ``--resume`` (same
arguments) keeps those runs after an interruption. The helpers that run ``prt`` on a
quiet machine (:func:`prt`, :func:`quiet_prt`, :func:`scene_copy`) serve
benchmarks/engine/rebake.py and benchmarks/engine/distributed.py too.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import yaml

from benchmarks.fixtures import CACHE, ROOT, TINY, load, median, write_result
from pipeline.engine.chunkwrite import read_marker
from pipeline.engine.executors.local import Cores
from pipeline.engine.store import Workdir, read_record
from pipeline.scene.file import default_scene_path

NAME = "engine.cores"
PRESETS = {"default": [],
           "tiny": ["--scene", str(TINY / "tiny_d2i.yaml"), "--size", "16", "--runs", "1",
                    "--configs", "1x1,2x1", "--no-quiet",
                    "--workdir", str(CACHE / "engine.cores_tiny")]}


def scene_copy(source: Path, path: Path, size: int | None = None,
               settings: dict[str, Any] | None = None) -> Path:
    """``source`` rewritten to ``path``: mesh and light file paths made absolute, the
    image ``size``² if given, ``settings`` (stage parameters) over the file's own."""
    doc = yaml.safe_load(source.read_text())
    if size is not None:
        doc["camera"]["width"] = doc["camera"]["height"] = size
    for obj in doc["objects"].values():
        if "mesh" in obj and "$" not in obj["mesh"]:
            obj["mesh"] = str((source.parent / obj["mesh"]).resolve())
    for light in doc.get("lights") or []:  # environment maps
        if "file" in light and "$" not in light["file"]:
            light["file"] = str((source.parent / light["file"]).resolve())
    if settings:
        doc["settings"] = {**(doc.get("settings") or {}), **settings}
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def scene_file(folder: Path, size: int, source: Path | None = None) -> Path:
    """``source`` (the default scene) at ``size``² as a file in ``folder`` (mesh paths
    made absolute)."""
    source = source or default_scene_path()
    return scene_copy(source, folder / f"{source.stem}_{size}.yaml", size)


def cores_args(config: str) -> list[str]:
    """``JxT`` -> ['--jobs', J, '--threads', T]; ``auto`` -> []."""
    if config == "auto":
        return []
    jobs, threads = config.split("x")
    return ["--jobs", jobs, "--threads", threads]


def resolved(config: str) -> str:
    """The configuration as workers × threads."""
    if config == "auto":
        return Cores.resolve().describe()
    jobs, threads = (int(v) for v in config.split("x"))
    return Cores(jobs, threads).describe()


def busy_jiffies() -> int | None:
    """Busy CPU time of the whole machine so far (clock ticks), None off Linux."""
    try:
        fields = [int(v) for v in Path("/proc/stat").read_text().split("\n")[0].split()[1:]]
    except OSError:
        return None
    idle = fields[3] + (fields[4] if len(fields) > 4 else 0)
    return sum(fields[:8]) - idle


QUIET_CORES = 0.2   # a run starts when the rest of the machine uses less than this
NOISY_CORES = 0.25  # a run during which the rest used more (on average) is repeated
RETRIES = 3         # repeats of a noisy run before it is kept as it is (flagged)


def wait_quiet(max_wait_s: float = 1800.0, window_s: float = 5.0) -> float:
    """Wait until the machine's busy time over ``window_s`` is below QUIET_CORES cores
    (or ``max_wait_s`` passed); returns the seconds waited."""
    start = time.perf_counter()
    while True:
        busy0 = busy_jiffies()
        time.sleep(window_s)
        busy1 = busy_jiffies()
        if busy0 is None or busy1 is None:
            return 0.0
        cores = (busy1 - busy0) / os.sysconf("SC_CLK_TCK") / window_s
        waited = time.perf_counter() - start
        if cores < QUIET_CORES or waited > max_wait_s:
            return waited


def quiet_prt(args: list[str], fresh: Path | None = None,
              max_wait_s: float = 1800.0, quiet: bool = True) -> dict:
    """``prt`` started on a quiet machine, repeated (up to RETRIES times) when the rest
    of the machine used more than NOISY_CORES cores meanwhile; ``fresh``: a work
    directory deleted before each attempt; ``max_wait_s``: the longest wait for quiet.
    ``quiet`` False: started at once, never repeated, ``noisy`` None (a smoke test)."""
    if not quiet:
        if fresh is not None:
            shutil.rmtree(fresh, ignore_errors=True)
        return {**prt(args), "waited_s": 0.0, "attempt": 0, "noisy": None}
    for attempt in range(RETRIES + 1):
        waited = wait_quiet(max_wait_s)
        if fresh is not None:
            shutil.rmtree(fresh, ignore_errors=True)
        r = prt(args)
        noisy = r["other_cpu_s"] is not None and r["other_cpu_s"] > NOISY_CORES * r["wall_s"]
        r.update(waited_s=round(waited, 1), attempt=attempt, noisy=noisy)
        if not noisy:
            return r
        print(f"noisy run repeated: {r['other_cpu_s']:.1f} CPU s of others in "
              f"{r['wall_s']:.1f} s", file=sys.stderr, flush=True)
    return r


def prt(args: list[str]) -> dict:
    """Run ``prt ARGS --json -q``; its report, wall seconds, CPU seconds and the CPU
    seconds the rest of the machine used meanwhile."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    busy0, start, started = busy_jiffies(), time.perf_counter(), time.time()
    out = subprocess.run([sys.executable, "-m", "pipeline", *args, "--json", "-q"],
                         check=True, capture_output=True, text=True, cwd=ROOT).stdout
    wall = time.perf_counter() - start
    busy1 = busy_jiffies()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    other = None
    if busy0 is not None and busy1 is not None:
        other = max(0.0, (busy1 - busy0) / os.sysconf("SC_CLK_TCK") - cpu)
    return {"report": json.loads(out), "wall_s": wall, "cpu_s": cpu, "other_cpu_s": other,
            "started": started}


def chunk_records(workdir: Workdir, stage: str) -> list[dict[str, Any]]:
    """The records of ``stage``'s chunks (pipeline/engine/runner.py ``execute_chunk``:
    its seconds, when it started), in completion order."""
    records = (read_marker(m) for m in workdir.markers(stage).glob("*.json"))
    return sorted((r for r in records if r is not None),
                  key=lambda r: r["started"] + r["seconds"])


def last_piece_time(workdir: Workdir, stage: str) -> float:
    """When the last chunk of ``stage`` was stored (the latest end of a chunk in its
    records; seconds since the epoch)."""
    return max(r["started"] + r["seconds"] for r in chunk_records(workdir, stage))


def chunk_seconds(workdir: Workdir, stage: str) -> list[float]:
    """Each stored chunk's own seconds (its record), in completion order: whether chunks
    run slower side by side (their sum grows) and how long the last ones ran."""
    return [round(r["seconds"], 2) for r in chunk_records(workdir, stage)]


def stage_seconds(report: dict, name: str) -> float:
    return next(s["seconds"] for s in report["stages"] if s["name"] == name)


class Journal:
    """Every run's record, appended to a JSON-lines file as soon as it is taken, so that
    an interrupted benchmark resumes (``--resume``) with the runs it has."""

    def __init__(self, path: Path, resume: bool) -> None:
        self.path = path
        if not resume:
            path.unlink(missing_ok=True)
        self.records = [json.loads(line) for line in path.read_text().splitlines()
                        if line.strip()] if path.is_file() else []

    def done(self, part: str, round_: int, config: str) -> dict | None:
        return next((r for r in self.records if (r["part"], r["round"], r["config"])
                     == (part, round_, config)), None)

    def add(self, record: dict) -> None:
        self.records.append(record)
        with self.path.open("a") as f:
            f.write(json.dumps(record) + "\n")
        print(json.dumps(record), flush=True)


def transfer_runs(scene: Path, workdir: Path, configs: list[str], runs: int,
                  size: int, journal: Journal, **quiet: Any) -> list[dict]:
    """``runs`` rounds of a forced d2i.transfer per configuration, alternating;
    ``quiet``: :func:`quiet_prt`'s ``max_wait_s`` and ``quiet``."""
    bake = workdir / "transfer"
    prt(["run", str(scene), "--until", "d2i.transfer", "--workdir", str(bake)])
    records = []
    for round_ in range(runs):
        order = configs if round_ % 2 == 0 else configs[::-1]
        for config in order:
            if (old := journal.done("transfer", round_, config)) is not None:
                records.append(old)
                continue
            r = quiet_prt(["run", str(scene), "--until", "d2i.transfer", "--force",
                           "d2i.transfer", "--workdir", str(bake), *cores_args(config)],
                          **quiet)
            stage = next(s for s in r["report"]["stages"] if s["name"] == "d2i.transfer")
            seconds = stage["seconds"]
            chunks = len(stage["ran_chunks"])
            chunk_phase = last_piece_time(Workdir(bake), "d2i.transfer") - r["started"]
            each = chunk_seconds(Workdir(bake), "d2i.transfer")
            records.append({
                "part": "transfer", "round": round_, "config": config,
                "transfer_s": round(seconds, 3),
                "chunks_s": round(chunk_phase, 3), "assemble_s": round(seconds - chunk_phase, 3),
                "chunk_seconds_sum": round(sum(each), 2), "chunk_seconds": each,
                "chunks": chunks, "chunks_per_s": round(chunks / chunk_phase, 4),
                "pixels_per_s": round(size * size / chunk_phase, 1),
                "wall_s": round(r["wall_s"], 3), "cpu_s": round(r["cpu_s"], 2),
                "other_cpu_s": None if r["other_cpu_s"] is None else round(r["other_cpu_s"], 2),
                "noisy": r["noisy"], "attempts": r["attempt"] + 1,
                "digest": read_record(Workdir(bake).artifact("d2i.transfer"))["digest"]})
            journal.add(records[-1])
    return records


def full_runs(scene: Path, workdir: Path, configs: list[str], runs: int,
              journal: Journal, **quiet: Any) -> list[dict]:
    """``runs`` rounds of a bake from scratch to d2i.truncate per configuration."""
    records = []
    for round_ in range(runs):
        order = configs if round_ % 2 == 0 else configs[::-1]
        for config in order:
            if (old := journal.done("full", round_, config)) is not None:
                records.append(old)
                continue
            bake = workdir / f"full_{config}"
            r = quiet_prt(["run", str(scene), "--until", "d2i.truncate", "--until",
                           "d2i.truncate_t", "--until", "d2i.truncate_ms", "--workdir",
                           str(bake), *cores_args(config)], fresh=bake, **quiet)
            records.append({
                "part": "full", "round": round_, "config": config,
                "wall_s": round(r["wall_s"], 2),
                "cpu_s": round(r["cpu_s"], 1),
                "other_cpu_s": None if r["other_cpu_s"] is None else round(r["other_cpu_s"], 1),
                "noisy": r["noisy"], "attempts": r["attempt"] + 1,
                "stages_s": {s["name"]: round(s["seconds"], 2) for s in r["report"]["stages"]},
                "digest": read_record(Workdir(bake).artifact("d2i.truncate"))["digest"]})
            journal.add(records[-1])
            shutil.rmtree(bake, ignore_errors=True)
    return records


def config_medians(records: list[dict], configs: list[str], field: str) -> dict[str, float]:
    """Per configuration, the median of ``field`` over its runs."""
    return {c: round(median(r[field] for r in records if r["config"] == c), 3)
            for c in configs}


def paired_ratios(records: list[dict], base: str, other: str, field: str) -> list[float]:
    """Per round, ``base``'s ``field`` over ``other``'s (a speed-up when field is time)."""
    rounds = sorted({r["round"] for r in records})
    value = {(r["round"], r["config"]): r[field] for r in records}
    return [round(value[(k, base)] / value[(k, other)], 3) for k in rounds
            if (k, base) in value and (k, other) in value]


def summary(records: list[dict], configs: list[str], field: str) -> dict:
    """Medians per configuration, and each configuration's speed-up over 1x1 (ratio of
    the medians, and the median of the per-round ratios)."""
    med = config_medians(records, configs, field)
    out = {"field": field, "median_s": med, "resolved": {c: resolved(c) for c in configs},
           "other_cpu_s_median": config_medians(records, configs, "other_cpu_s")
           if all(r["other_cpu_s"] is not None for r in records) else None,
           "digests_equal": len({r["digest"] for r in records}) == 1}
    if "1x1" in configs:
        out["speedup_over_1x1"] = {c: round(med["1x1"] / med[c], 3) for c in configs
                                   if c != "1x1"}
        out["speedup_over_1x1_paired_median"] = {
            c: median(paired_ratios(records, "1x1", c, field))
            for c in configs if c != "1x1"}
    return out


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME} --",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--workdir", type=Path, default=CACHE / NAME,
                        help="scratch folder [default: %(default)s]")
    parser.add_argument("--scene", type=Path, default=None,
                        help="scene file [default: prt's default scene, the Cornell box]")
    parser.add_argument("--size", type=int, default=128, help="image edge of the transfer runs")
    parser.add_argument("--runs", type=int, default=3, help="rounds per measurement")
    parser.add_argument("--configs", default="1x1,1x2,auto,2x2",
                        help="configurations of the transfer runs (JxT or auto)")
    parser.add_argument("--full", action="store_true",
                        help="also bake the scene at 256² from scratch, 1x1 against auto")
    parser.add_argument("--full-configs", default="1x1,auto")
    parser.add_argument("--no-quiet", action="store_true",
                        help="run each step at once, neither waiting for a quiet machine "
                        "nor repeating noisy runs (a smoke test: timings not comparable)")
    parser.add_argument("--max-wait", type=float, default=1800.0,
                        help="longest wait for a quiet machine before a run, seconds")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--resume", action="store_true",
                        help="keep the runs already in WORKDIR/runs.jsonl (same arguments)")
    argv = sys.argv[1:] if argv is None else argv
    args = parser.parse_args(argv)
    args.workdir.mkdir(parents=True, exist_ok=True)
    journal = Journal(args.workdir / "runs.jsonl", args.resume)
    configs, full_configs = args.configs.split(","), args.full_configs.split(",")
    quiet = {"quiet": not args.no_quiet, "max_wait_s": args.max_wait}

    result: dict[str, Any] = {
        "auto": Cores.auto().describe(), "os_cpus": os.cpu_count(),
        "command": " ".join(["python -m benchmarks run", NAME, "--", *argv]),
        "load": [load()]}
    records = transfer_runs(scene_file(args.workdir, args.size, args.scene), args.workdir,
                            configs, args.runs, args.size, journal, **quiet)
    result["transfer"] = {
        "what": f"{(args.scene or default_scene_path()).stem} at {args.size}x{args.size}: "
                "prt run --until d2i.transfer --force d2i.transfer [--jobs J --threads T]; "
                "the stage's seconds",
        **summary(records, configs, "transfer_s"),
        "chunk_phase": summary(records, configs, "chunks_s"),
        "chunk_seconds_sum_median": config_medians(records, configs, "chunk_seconds_sum"),
        "chunks_per_s_median": config_medians(records, configs, "chunks_per_s"),
        "pixels_per_s_median": config_medians(records, configs, "pixels_per_s"),
        "runs": records}
    if args.full:
        full = full_runs(scene_file(args.workdir, 256, args.scene), args.workdir, full_configs,
                         args.runs, journal, **quiet)
        result["full_bake"] = {
            "what": f"{(args.scene or default_scene_path()).stem} at 256x256 from scratch: "
                    "prt run --until d2i.truncate* [--jobs J --threads T]; wall seconds of "
                    "the command",
            **summary(full, full_configs, "wall_s"),
            "stages_s_median": {c: {name: round(median(
                r["stages_s"][name] for r in full if r["config"] == c), 2)
                for name in full[0]["stages_s"]} for c in full_configs},
            "runs": full}
    result["load"].append(load())
    print(json.dumps({k: {kk: vv for kk, vv in v.items() if kk != "runs"}
                      for k, v in result.items() if isinstance(v, dict) and "runs" in v},
                     indent=1))
    return write_result(NAME, result, args.out)

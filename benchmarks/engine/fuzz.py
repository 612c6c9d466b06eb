"""The scene fuzzer's long run (tests/scene_fuzz.py): generated cases through prt render.

``--count`` generated scenes and command lines for one ``--seed``, each through ``prt
render``, counted by outcome.

Each case is checked against the invariant (exit 0 with a finite frame, or exit 2 with
one ``error:`` line, the work directory still answering ``prt status``). One JSON line per
case goes to ``seed_<S>.jsonl`` in the folder beside the result's JSON (the JSON's path
without ``.json``: ``benchmarks/results/engine/fuzz/``), and the result counts exit 0 /
exit 2 / anything else; a case of the last kind is kept (scene and files) under
``found/<seed>_<n>/`` in that folder to become a regression test (tests/
test_fuzz_findings.py). One process per seed:

    python -m benchmarks run engine.fuzz -- --seed 2 --count 1000
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from collections import Counter
from pathlib import Path
from typing import Any

from benchmarks.fixtures import ROOT, load, median, result_path, write_result

NAME = "engine.fuzz"
PRESETS = {"default": [], "tiny": ["--count", "2"]}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME} --",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--count", type=int, default=1000)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    # The one sys.path change of the suite: the fuzzer's strategies live with the tests
    # that run its fixed-seed budget (tests/scene_fuzz.py, with tests/helpers.py and
    # tests/tiny_scenes.py), and tests/ is no package.
    tests = str(ROOT / "tests")
    if tests not in sys.path:
        sys.path.insert(0, tests)
    from hypothesis import HealthCheck, given, seed, settings
    from scene_fuzz import Case, cases, record, run_case

    folder = result_path(NAME, args.out).with_suffix("")
    folder.mkdir(parents=True, exist_ok=True)
    log_path = folder / f"seed_{args.seed}.jsonl"
    counts: Counter[str] = Counter()
    seconds: list[float] = []
    found: list[str] = []
    before = load()

    with log_path.open("w") as log:
        @seed(args.seed)
        @settings(max_examples=args.count, deadline=None, database=None,
                  suppress_health_check=list(HealthCheck), phases=["generate"])
        @given(cases())
        def one(case: Case) -> None:
            n = sum(counts.values())
            with tempfile.TemporaryDirectory(prefix="prt-fuzz-") as tmp:
                outcome = run_case(case, Path(tmp))
                if outcome.kind == "else":
                    keep = folder / "found" / f"{args.seed}_{n}"
                    shutil.copytree(tmp, keep, ignore=shutil.ignore_patterns("w"),
                                    dirs_exist_ok=True)
                    found.append(str(keep))
            counts[outcome.kind] += 1
            seconds.append(outcome.seconds)
            log.write(record(case, outcome) + "\n")
            log.flush()
            if n % 50 == 0:
                print(f"seed {args.seed}: {n} cases, {dict(counts)}", flush=True)

        one()
    print(f"seed {args.seed}: {sum(counts.values())} cases: exit 0 {counts['exit0']}, "
          f"exit 2 {counts['exit2']}, anything else {counts['else']}")
    return write_result(NAME, {
        "seed": args.seed, "count": args.count, "cases": sum(counts.values()),
        "counts": {k: counts[k] for k in ("exit0", "exit2", "else")},
        "case_seconds_median": median(seconds) if seconds else None,
        "load": [before, load()], "log": str(log_path), "found": found}, args.out)

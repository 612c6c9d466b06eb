"""The scene fuzzer's long run (tests/scene_fuzz.py): N generated scenes and command
lines per seed, each run through ``prt render`` and checked against the invariant
(exit 0 with a finite frame, or exit 2 with one ``error:`` line, the work directory
still answering ``prt status``). Writes one JSON line per case to
``benchmarks/results/fuzz/seed_<S>.jsonl`` and prints the counts of exit 0 / exit 2 /
anything else; a case of the last kind is kept (scene and files) under
``benchmarks/results/fuzz/found/<seed>_<n>/`` to become a regression test.

    python benchmarks/fuzz_scenes.py --seed 1 --count 1000   # one process per seed
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from hypothesis import HealthCheck, given, seed, settings  # noqa: E402
from scene_fuzz import Case, cases, record, run_case  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--count", type=int, default=1000)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "fuzz")
    a = parser.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    log = open(a.out / f"seed_{a.seed}.jsonl", "w")  # noqa: SIM115 - closed below
    counts: Counter[str] = Counter()

    @seed(a.seed)
    @settings(max_examples=a.count, deadline=None, database=None,
              suppress_health_check=list(HealthCheck), phases=["generate"])
    @given(cases())
    def one(case: Case) -> None:
        n = sum(counts.values())
        with tempfile.TemporaryDirectory(prefix="prt-fuzz-") as tmp:
            outcome = run_case(case, Path(tmp))
            if outcome.kind == "else":
                shutil.copytree(tmp, a.out / "found" / f"{a.seed}_{n}",
                                ignore=shutil.ignore_patterns("w"), dirs_exist_ok=True)
        counts[outcome.kind] += 1
        log.write(record(case, outcome) + "\n")
        log.flush()
        if n % 50 == 0:
            print(f"seed {a.seed}: {n} cases, {dict(counts)}", flush=True)

    one()
    log.close()
    print(f"seed {a.seed}: {sum(counts.values())} cases: exit 0 {counts['exit0']}, "
          f"exit 2 {counts['exit2']}, anything else {counts['else']}")


if __name__ == "__main__":
    main()

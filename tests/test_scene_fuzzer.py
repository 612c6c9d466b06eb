"""The scene fuzzer's CI budget (tests/scene_fuzz.py): a fixed-seed set of generated
scenes and command lines, each of which must exit 0 with a finite frame or exit 2 with
one ``error:`` line, leaving a work directory that still answers ``prt status``. The
long run is benchmarks/engine/fuzz.py; what it finds becomes a regression test."""

from __future__ import annotations

import itertools

from hypothesis import HealthCheck, given, seed, settings
from scene_fuzz import Case, cases, record, run_case

EXAMPLES = 80  # 2–3 minutes on 2 cores: a case bakes a tiny scene in seconds, or stops
_COUNT = itertools.count()


@seed(40)
@settings(max_examples=EXAMPLES, deadline=None, database=None, derandomize=True,
          suppress_health_check=list(HealthCheck))
@given(cases())
def test_every_generated_scene_renders_or_is_refused_in_one_line(tmp_path_factory,
                                                                 case: Case) -> None:
    folder = tmp_path_factory.mktemp(f"fuzz{next(_COUNT)}")
    outcome = run_case(case, folder)
    assert outcome.kind in ("exit0", "exit2"), record(case, outcome)

"""What the scene fuzzer's long run found (benchmarks/fuzz_scenes.py), each case cut
down to the mutation that broke the invariant and kept as a regression test: it must
now exit 0 with a finite frame or exit 2 with one error line (tests/scene_fuzz.py)."""

from __future__ import annotations

from typing import Any

import pytest
from scene_fuzz import _base, run_case


def _tiny_up(doc: dict[str, Any]) -> None:
    """seed 1, cases 115–116: an ``up`` of subnormal components passed validation and the
    camera frame divided a cross product of 1e-311 by itself (ValueError, exit 1)."""
    doc["camera"]["up"] = [-2.225073858507e-311, -2.225073858507e-311, 1e-300]


def _empty_grid(doc: dict[str, Any]) -> None:
    """seed 1, case 630: ``triple.frame_grid: []`` was a list as the default is, and
    Intel's OpenCL compiler crashed on the kernel it defined (exit −11). A list setting
    now has its default's length and element kind."""
    doc["settings"]["triple.frame_grid"] = []


FOUND = {"tiny_up": ("triple", _tiny_up, "exit0"),
         "empty_grid": ("triple", _empty_grid, "exit2")}


@pytest.mark.parametrize("name", sorted(FOUND))
def test_a_fuzzer_finding_keeps_the_invariant(tmp_path, name: str) -> None:
    method, change, expected = FOUND[name]
    case = _base(method, 6)
    change(case.doc)
    outcome = run_case(case, tmp_path)
    assert (outcome.kind, outcome.problem) == (expected, ""), outcome

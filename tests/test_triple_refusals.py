"""Method triple refuses a bad environment map up front (pipeline/methods/triple/hooks.py
``check_scene``), through the CLI: ``prt run`` with the map in the scene file and ``prt
render --env FILE`` each exit 2 with one line naming the file, before anything is baked.
(``prt reference`` is tested in tests/test_integrity.py, the lighting stage itself in
tests/test_triple_tables.py.)"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from helpers import small_scene_dict, write_scene

from pipeline.images import write_exr


def _map(path, problem: str):
    """An 8 × 16 map of ones with texel (x 5, y 3) spoiled, or an 8 × 8 one."""
    rgb = np.ones((8, 8 if problem == "shape" else 16, 3), np.float32)
    if problem != "shape":
        rgb[3, 5, 1] = {"nan": np.nan, "inf": np.inf, "negative": -1.0, "huge": 1e30}[problem]
    write_exr(path, rgb)
    return path


@pytest.mark.parametrize(("command", "problem"), [("run", "nan"), ("run", "shape"),
                                                  ("render --env", "negative"),
                                                  ("render --env", "inf"),
                                                  ("run", "huge")])
def test_a_bad_map_is_refused_before_any_bake(tmp_path, command, problem):
    """"huge" is issue 40's case 2: a finite 1e30 texel squared to +inf energies and the
    lighting stage wrote past its buffer (a segfault under PoCL)."""
    good = tmp_path / "good.exr"
    write_exr(good, np.ones((8, 16, 3), np.float32))
    bad = _map(tmp_path / "bad.exr", problem)
    doc = small_scene_dict(8)
    doc["methods"] = ["triple"]
    doc["lights"] = [{"type": "environment", "file": str(good if "env" in command else bad)}]
    scene = write_scene(tmp_path, doc)
    args = (["run", str(scene)] if command == "run" else
            ["render", str(scene), "--method", "triple", "--env", str(bad),
             "--out", str(tmp_path / "out.exr")])
    result = subprocess.run([sys.executable, "-m", "pipeline", *args, "--workdir",
                             str(tmp_path / "w"), "-q"], cwd=tmp_path, capture_output=True,
                            text=True, timeout=300)
    assert result.returncode == 2, result.stderr
    line = result.stderr.strip()
    assert "\n" not in line and line.startswith(f"error: {bad}: environment map")
    assert ("twice as wide" if problem == "shape" else "(x 5, y 3)") in line
    assert not (tmp_path / "w").exists() and not (tmp_path / "out.exr").exists()

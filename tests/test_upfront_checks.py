"""A scene a method cannot render is refused before anything is baked, with one line
naming the light and the methods that do render it (never a black frame and exit 0)."""

from __future__ import annotations

import subprocess
import sys

import pytest
from helpers import constant_environment, small_scene_dict, write_scene


@pytest.mark.parametrize("method", ["direct", "d2i"])
@pytest.mark.parametrize("lights", ["environment", "none"])
def test_unsupported_lights_are_refused_before_baking(tmp_path, method, lights):
    """An environment-lit scene (or one with no light) and `prt render --method M`:
    exit 2, one `error:` line naming the problem, and no work directory written."""
    doc = small_scene_dict(size=8)
    doc["lights"] = [] if lights == "none" else [
        {"type": "environment", "file": constant_environment(tmp_path / "env.exr",
                                                             [1, 1, 1]).name}]
    scene = write_scene(tmp_path, doc)
    result = subprocess.run([sys.executable, "-m", "pipeline", "render", str(scene),
                             "--method", method, "--out", str(tmp_path / "f.exr"),
                             "--workdir", str(tmp_path / "w"), "-q"],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 2, result.stderr
    line = result.stderr.strip()
    assert line.startswith("error: ") and "\n" not in line, line
    expected = ("lights[0]: method " + method + " does not render environment lights"
                if lights == "environment" else "lights: the scene has no light")
    assert expected in line, line
    assert not (tmp_path / "w").exists() and not (tmp_path / "f.exr").exists()

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


@pytest.mark.filterwarnings("ignore:overflow encountered in cast:RuntimeWarning")
def test_a_stage_writing_inf_is_an_error_and_stores_nothing(tmp_path):
    """A stage chunk whose output overflows to Inf (toy per_object at scale 1e39 in
    float32) is refused: PrtError naming the stage and chunk; nothing of it is stored."""
    from helpers import TESTS

    from pipeline.engine.runner import run
    from pipeline.engine.stagefile import load_stagefile
    from pipeline.engine.store import Workdir
    from pipeline.errors import PrtError
    from pipeline.scene.file import load_scene

    doc = small_scene_dict()
    doc["settings"] = {"toy.scale": 1e39}
    workdir = Workdir(tmp_path / "w")
    with pytest.raises(PrtError, match=r"stage per_object, chunk \w+: array value has 3 NaN"):
        run(load_scene(write_scene(tmp_path, doc)), load_stagefile(TESTS / "toy" /
                                                                   "stages.yaml"),
            workdir, progress=False)
    assert not any((workdir.markers("per_object")).glob("*.json"))


def test_a_non_finite_option_is_refused(tmp_path):
    """`--option gain=nan` (the toy plug-in's float option): exit 2, one line."""
    import os

    from helpers import TESTS

    doc = small_scene_dict(size=8)
    doc["methods"] = ["toy"]
    scene = write_scene(tmp_path, doc)
    env = {**os.environ, "PRT_PLUGINS": "toy_method", "PYTHONPATH": str(TESTS)}
    result = subprocess.run([sys.executable, "-m", "pipeline", "render", str(scene), "--out",
                             str(tmp_path / "f.exr"), "--option", "gain=nan", "--workdir",
                             str(tmp_path / "w"), "-q"], capture_output=True, text=True,
                            env=env, timeout=300)
    assert result.returncode == 2, result.stderr
    assert result.stderr.strip() == "error: --option: gain='nan': expected a finite number"


def test_a_frame_with_nan_is_refused(tmp_path):
    """A frame holding a NaN pixel is an error naming the output, not an image."""
    import numpy as np

    from pipeline.errors import PrtError
    from pipeline.job import checked_frame
    from pipeline.render import Frame

    rgb = np.ones((4, 4, 3), np.float32)
    rgb[1, 2, 0] = np.nan
    out = tmp_path / "f.exr"
    with pytest.raises(PrtError, match="rendered 1 NaN or Inf values") as error:
        checked_frame(Frame("toy", rgb, {}), out)
    assert str(out) in error.value.one_line()
    assert checked_frame(Frame("toy", np.ones((4, 4, 3), np.float32), {}), out).rgb.all()

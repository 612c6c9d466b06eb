"""Methods as plug-ins and exact code versions.

A toy method that lives entirely under tests/ (tests/toy_method: stage file, stages,
schemas, kernels, renderer, descriptor) runs through every command with no core file
edited; edits of its code re-run exactly what they must: a header re-runs the stages
whose kernels include it, a comment in a stage module re-runs that stage and (its
output being byte-identical) nothing downstream, a renderer's kernel edit invalidates
the cached frame. The plug-in is copied to a temporary folder first, so that the tests
edit the copy.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import TESTS, small_scene_dict, write_scene

from pipeline import job
from pipeline.engine import codeversion
from pipeline.engine.planning import stage_code
from pipeline.images import read_exr


@pytest.fixture()
def plugin(tmp_path):
    """(prt runner, scene path, plug-in folder): the toy method copied under tmp_path,
    registered through PRT_PLUGINS for the subprocesses."""
    plugins = tmp_path / "plugins"
    shutil.copytree(TESTS / "toy_method", plugins / "toy_method")
    doc = small_scene_dict(size=16)
    doc["methods"] = ["toy"]
    scene = write_scene(tmp_path, doc)
    env = {**os.environ, "PRT_PLUGINS": "toy_method",
           "PYTHONPATH": os.pathsep.join([str(plugins), str(TESTS)])}

    def prt(*args):
        result = subprocess.run([sys.executable, "-m", "pipeline", *map(str, args)],
                                cwd=tmp_path, env=env, capture_output=True, text=True,
                                timeout=300)
        assert result.returncode == 0, result.stderr
        return result

    return prt, scene, plugins / "toy_method"


def ran_stages(report: dict) -> set[str]:
    return {s["name"] for s in report["stages"] if s["action"] == "ran"}


def test_toy_method_runs_through_every_command(plugin, tmp_path):
    """run bakes only what the toy method reads (no d2i stage) and renders its frame and
    sequence; status lists its stages; render takes its option; evaluate charts it."""
    prt, scene, _ = plugin
    report = json.loads(prt("run", scene, "--workdir", "w", "--frames", "f", "--json",
                            "-q").stdout)
    assert ran_stages(report) == {"geometry", "gbuffer", "toy.shade", "toy.level"}
    assert report["frame"].endswith("tiny_toy.exr") and len(report["sequences"]["gain"]) == 2
    assert not list((tmp_path / "w").glob("d2i.*"))
    status = json.loads(prt("status", scene, "--workdir", "w", "--json").stdout)
    assert {s["name"]: s["state"] for s in status["stages"]} == {
        "geometry": "fresh", "gbuffer": "fresh", "toy.shade": "fresh", "toy.level": "fresh"}
    prt("render", scene, "--workdir", "w", "--out", "g2.exr", "--option", "gain=2", "-q")
    one, two = read_exr(tmp_path / "f" / "tiny_toy.exr"), read_exr(tmp_path / "g2.exr")
    # every pixel is gain × shade + level: 2 × one − two is the same level everywhere
    level = 2 * one - two
    np.testing.assert_allclose(level, level.mean(), rtol=0, atol=1e-6)
    assert one.max() > level.mean() + 0.1
    prt("evaluate", scene, "--workdir", "w", "--out", "ev", "--repeats", "1", "-q")
    records = json.loads((tmp_path / "ev" / "results.json").read_text())
    assert {r["method"] for r in records} == {"toy"} and records[0]["budget"] == {"size": 8}
    assert (tmp_path / "ev" / "error_vs_frame_time.png").is_file()


def test_code_edits_rerun_exactly_what_they_touch(plugin):
    """A comment in a header re-runs the stage whose kernel includes it (toy.shade), and
    by early cut-off nothing downstream, nor the frame; a renderer kernel edit
    re-renders the frame and bakes nothing; a comment in a stage module re-runs that
    stage only (toy.shade draws random numbers: seeded without the code, it writes the
    same bytes, so toy.level stays fresh)."""
    prt, scene, folder = plugin

    def run() -> dict:
        return json.loads(prt("run", scene, "--workdir", "w", "--frames", "f", "--json",
                              "-q").stdout)

    def frame_key() -> str:
        return json.loads(Path(scene.parent / "f" / "tiny_toy.json").read_text())["key"]

    run()
    key = frame_key()
    with open(folder / "kernels" / "toy_common.h", "a") as f:
        f.write("/* an edited comment */\n")
    assert ran_stages(run()) == {"toy.shade"}
    assert frame_key() == key
    with open(folder / "kernels" / "toy_gain.cl", "a") as f:
        f.write("/* an edited comment */\n")
    report = run()
    assert ran_stages(report) == set() and report["sequences"]  # the frame was rendered
    assert frame_key() != key
    with open(folder / "level.py", "a") as f:
        f.write("# an edited comment\n")
    assert ran_stages(run()) == {"toy.level"}
    with open(folder / "shade.py", "a") as f:
        f.write("# an edited comment\n")
    assert ran_stages(run()) == {"toy.shade"}


def test_editing_a_math_module_changes_exactly_the_stages_importing_it(tmp_path,
                                                                       monkeypatch):
    """pipeline/methods/d2i/transfer.py (the d2i estimators) is imported by the gather,
    transfer, glossy transfer and bounce stages (the last two through the transfer
    stage's helpers): an edit changes their code versions and no other stage's."""
    graph = job.stages()
    before = {name: stage_code(spec) for name, spec in graph.stages.items()}
    original = codeversion.module_file("pipeline.methods.d2i.transfer")
    edited = tmp_path / "transfer.py"
    edited.write_text(original.read_text() + "\n# an edited comment\n")
    real = codeversion.module_file
    monkeypatch.setattr(codeversion, "module_file",
                        lambda m: edited if m == "pipeline.methods.d2i.transfer" else real(m))
    after = {name: stage_code(spec) for name, spec in graph.stages.items()}
    assert {n for n in before if before[n] != after[n]} == {
        "d2i.gather", "d2i.transfer", "d2i.transfer_t", "d2i.bounce"}

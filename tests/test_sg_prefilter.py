"""Method sg's prefiltered environment: the fast stack (pipeline/methods/sg/prefilter.py)
against the brute-force reference, the stage ``sg.env_prefilter`` (stored stack, rebuilt
when the map changes), and the plug-in skeleton's refusals."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from helpers import PROJECT, small_scene_dict, write_scene
from test_sg import sg_lights_map

from pipeline import job
from pipeline.engine.runner import run
from pipeline.engine.store import Workdir, open_artifact
from pipeline.errors import PrtError
from pipeline.images import read_environment, write_exr
from pipeline.math import sg
from pipeline.methods.sg import prefilter as sg_prefilter
from pipeline.methods.sg.stages.env_prefilter import read_stack
from pipeline.registry import check_method_scene, get_method
from pipeline.scene.file import load_scene

STAGEFILE = job.stages()


def spiky_map(height: int, width: int, seed: int) -> np.ndarray:
    """Noise from 0 to 1 plus one texel of 500: features sharper than any level."""
    rgb = np.random.default_rng(seed).random((height, width, 3))
    rgb[height // 3, width // 5] += 500.0
    return rgb


def write_map(path, rgb: np.ndarray):
    """``rgb`` written as a float32 EXR at ``path``; returns ``path``."""
    write_exr(path, rgb.astype(np.float32))
    return path


def worst_per_level(fast: list[np.ndarray], ref: list[np.ndarray]) -> np.ndarray:
    return np.array([np.abs(a - b).max() / np.abs(b).max() for a, b in zip(fast, ref,
                                                                            strict=True)])


@pytest.mark.parametrize("rgb", [sg_lights_map(), spiky_map(17, 40, 1), spiky_map(21, 37, 2)],
                         ids=["sg-lights-33x64", "spike-17x40", "spike-odd-21x37"])
def test_fast_stack_equals_the_brute_force_reference(rgb):
    """Every level of the Fourier-domain stack against sg.prefilter_reference, relative
    to the level's largest texel. Both compute the same sum over the map's samples
    (the fast one drops only terms below e^{-30} of a row's weight): measured ≤ 5e-14,
    float64 rounding of sums over up to 10³ texels. Tolerance 1e-12; a wrong phase,
    fold, weight or a series cut too early (the first version cut at the level's
    Nyquist frequency: 4e-6 on the spike maps) is caught."""
    levels = sg.prefilter_levels(*rgb.shape[:2])
    fast = sg_prefilter.prefilter(rgb, levels)
    assert [a.shape[:2] for a in fast] == list(levels.shapes)
    assert worst_per_level(fast, sg.prefilter_reference(rgb, levels)).max() < 1e-12


def test_a_constant_map_stays_constant():
    """Normalised prefiltering of a constant is the constant at every level."""
    rgb = np.broadcast_to(np.array([0.5, 2.0, 3.0]), (17, 34, 3))
    for level in sg_prefilter.prefilter(rgb, sg.prefilter_levels(17, 34)):
        np.testing.assert_allclose(level, np.broadcast_to([0.5, 2.0, 3.0], level.shape),
                                   rtol=1e-12)


# --- the stage and the plug-in ---------------------------------------------------------


def sg_scene(folder, map_path) -> dict:
    doc = small_scene_dict(16)
    doc["methods"] = ["sg"]
    doc["lights"] = [{"type": "environment", "file": str(map_path)}]
    return doc


def bake(folder, doc):
    scene = load_scene(write_scene(folder, doc))
    report = run(scene, STAGEFILE, Workdir(folder / "work"), until="sg.env_prefilter",
                 progress=False)
    return {r.name for r in report if r.action == "ran"}


def test_stage_stores_the_stack_and_reruns_only_when_the_map_or_its_params_change(tmp_path):
    """The stored stack is the reference's to float32 (tolerance 1e-6 of each level's
    largest texel: float32 rounding is 6e-8 of a value, and the spike map's smallest
    texels are ~1e-3 of its largest at the sharp levels); a second
    run does nothing; a new map, or another level ratio, re-runs the stage."""
    map_path = write_map(tmp_path / "env.exr", spiky_map(17, 34, 3))
    doc = sg_scene(tmp_path, map_path)
    assert bake(tmp_path, doc) == {"sg.env_prefilter"}
    artifact = open_artifact(Workdir(tmp_path / "work").artifact("sg.env_prefilter"))
    stack, levels = read_stack(artifact)
    expected_levels = sg.prefilter_levels(17, 34)
    assert levels.shapes == expected_levels.shapes
    assert levels.sigma0 == pytest.approx(expected_levels.sigma0, rel=1e-12)
    rgb = read_environment(map_path)
    assert worst_per_level(stack, sg.prefilter_reference(rgb, expected_levels)).max() < 1e-6

    assert bake(tmp_path, doc) == set()
    write_map(map_path, spiky_map(17, 34, 4))
    assert bake(tmp_path, doc) == {"sg.env_prefilter"}
    doc["settings"] = {"sg.prefilter_ratio": 2.0}
    assert bake(tmp_path, doc) == {"sg.env_prefilter"}
    stack, levels = read_stack(open_artifact(Workdir(tmp_path / "work")
                                             .artifact("sg.env_prefilter")))
    assert levels.ratio == 2.0 and len(stack) == sg.prefilter_levels(17, 34, 2.0).count


def test_scene_without_one_environment_light_is_refused_before_baking(tmp_path):
    doc = small_scene_dict(16)  # a point and a quad light
    with pytest.raises(PrtError, match="method sg does not render point lights"):
        check_method_scene(get_method("sg"), load_scene(write_scene(tmp_path, doc)))


def test_render_bakes_every_sg_stage_and_writes_a_frame(tmp_path):
    """``prt render --method sg`` (a subprocess: the CLI's bake) bakes sg.env_prefilter,
    sg.diffuse and sg.visibility — not sg.fit, which the default does not read (decision
    0046) — and writes a finite, non-negative frame whose surfaces are lit; with
    ``--option normal=vertex`` it bakes sg.fit and renders the lobes (the method's
    accuracy against the reference: tests/test_sg_accuracy.py)."""
    from pipeline.images import read_exr

    map_path = write_map(tmp_path / "env.exr", spiky_map(9, 18, 5))
    doc = sg_scene(tmp_path, map_path)
    doc["objects"]["ball"]["primitive"]["subdivisions"] = 0  # sg.fit: 12 glossy vertices
    doc["settings"] = {"sg.fit_grid": [9, 16], "sg.indirect_samples": 4,
                       "sg.diffuse_samples": 64}
    scene = write_scene(tmp_path, doc)
    out = tmp_path / "frame.exr"
    work = Workdir(tmp_path / "work")
    for option in ([], ["--option", "normal=vertex"]):
        done = subprocess.run([sys.executable, "-m", "pipeline", "render", str(scene),
                               "--method", "sg", "--out", str(out), "--workdir",
                               str(tmp_path / "work"), "--quiet", *option],
                              capture_output=True, text=True, cwd=PROJECT, timeout=600)
        assert done.returncode == 0, done.stderr
        frame = read_exr(out)
        assert np.isfinite(frame).all() and frame.min() >= 0.0 and frame.max() > 0.0
        if not option:
            assert open_artifact(work.artifact("sg.visibility")).attrs["resolution"] == 32
            assert not work.artifact("sg.fit").exists()
    assert open_artifact(work.artifact("sg.env_prefilter")).attrs["levels"] == \
        sg.prefilter_levels(9, 18).count
    assert open_artifact(work.artifact("sg.fit")).attrs["max_lobes"] == 3
    assert open_artifact(work.artifact("sg.diffuse")).attrs["order"] == \
        STAGEFILE.params["sg.diffuse_order"]


def test_evaluate_measures_the_glossy_and_diffuse_parts_apart(tmp_path):
    """``prt evaluate --method sg`` records, beside the whole frame's error against the
    first-glossy reference, the error of its glossy lobes and of its SH diffuse term,
    each against that transport with one lobe of the BRDF at the first surface
    (pipeline/methods/sg/__init__.py components), for a sweep of the lobe count."""
    import json

    map_path = write_map(tmp_path / "env.exr", spiky_map(9, 18, 5))
    doc = sg_scene(tmp_path, map_path)
    doc["objects"]["ball"]["primitive"]["subdivisions"] = 0
    doc["settings"] = {"sg.fit_grid": [9, 16], "sg.indirect_samples": 4,
                       "sg.diffuse_samples": 64}
    scene = write_scene(tmp_path, doc)
    out = tmp_path / "eval"
    done = subprocess.run([sys.executable, "-m", "pipeline", "evaluate", str(scene),
                           "--method", "sg", "--sweep", "sg.fit_max_lobes=1", "--out",
                           str(out), "--repeats", "1", "--reference-max-spp", "64",
                           "--workdir", str(tmp_path / "work"), "-q"],
                          capture_output=True, text=True, cwd=PROJECT, timeout=900)
    assert done.returncode == 0, done.stderr
    records = json.loads((out / "results.json").read_text())
    assert [r["budget"] for r in records] == [{"sg.fit_max_lobes": 1},
                                              {"sg.fit_max_lobes": 3}]
    for r in records:
        for part in ("glossy", "diffuse"):
            assert 0 < r[f"rel_rmse_{part}"] < np.inf and r[f"{part}_mean_ratio"] > 0
            assert r[f"reference_spp_{part}"] >= 16
        assert 0 < r["rel_rmse_surfaces"] < 1
    references = {p.name.rsplit("-", 1)[0] for p in (tmp_path / "work" / "reference").iterdir()}
    assert {"first-glossy", "first-glossy-glossy", "first-glossy-diffuse"} <= references

"""Re-bake after the common scene edits, at chunk granularity, forecast before running
(pipeline/engine/planning.py; ``prt status``, ``prt run --dry-run``): for each edit the
forecast names exactly the chunks the run then re-runs, and the result is bit-identical
to a bake of the edited scene from scratch. Per method: a material's parameters (the
γ range of one of two glossy materials for d2i: tests/test_incremental.py), a light or
the environment map, a moved object, the camera."""

from __future__ import annotations

import copy
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers import (
    TESTS,
    TOY_STAGEFILE,
    TOY_STAGES,
    artifact_bytes,
    small_scene_dict,
    write_scene,
)

from pipeline import job
from pipeline.engine.runner import run
from pipeline.engine.stagefile import load_stagefile
from pipeline.engine.store import Workdir
from pipeline.images import write_exr
from pipeline.scene.file import load_scene


def ran(report) -> dict[str, set[str]]:
    """stage -> the chunks that ran, for the stages that ran."""
    return {r.name: set(r.ran_chunks) for r in report if r.action == "ran"}


def forecast(scene, workdir, stagefile=None) -> dict[str, set[str]]:
    """stage -> the chunks the forecast says re-run, for the stages it says are not fresh
    (every stage planned: a stage waiting for an unbuilt input would read None)."""
    plan = job.rebake_forecast(scene, workdir, stagefile)
    assert all(f.chunks is not None for f in plan), [f.name for f in plan if f.chunks is None]
    return {f.name: set(f.chunks) for f in plan if f.state != "fresh"}


def edit_and_check(folder: Path, edited: dict, base: Path, stages: tuple[str, ...],
                   bake, stagefile=None) -> tuple[dict, dict]:
    """Copy the work directory ``base`` (baked before the edit), forecast the edit
    ``edited`` there, re-bake it, bake ``edited`` from scratch: (forecast, ran), after
    asserting the artifacts of ``stages`` bit-identical."""
    shutil.copytree(base, folder / "edited_work")
    scene = load_scene(write_scene(folder, edited, "edited.yaml"))
    workdir = job.workdir_for(scene, folder / "edited_work", stagefile)
    predicted = forecast(scene, workdir, stagefile)
    report = bake(scene, workdir)
    fresh = job.workdir_for(scene, folder / "fresh_work", stagefile)
    bake(scene, fresh)
    assert artifact_bytes(workdir, stages) == artifact_bytes(fresh, stages)
    return predicted, ran(report)


# ------------------------------------------------------------------- the engine (toy graph)


@pytest.fixture()
def toy(tmp_path):
    doc = small_scene_dict()
    workdir = Workdir(tmp_path / "work")
    run(load_scene(write_scene(tmp_path, doc)), load_stagefile(TOY_STAGEFILE), workdir,
        progress=False)
    return doc, workdir, tmp_path


def toy_bake(scene, workdir):
    return run(scene, load_stagefile(TOY_STAGEFILE), workdir, progress=False)


@pytest.mark.parametrize("edit, expected", [
    # a material's parameter: its objects' chunk, then the stages reading it whole
    (lambda d: d["materials"]["shiny"].update(albedo=[0.5, 0.1, 0.1]),
     {"per_object": {"ball"}, "total": {"all"}, "tiles": "every"}),
    # a moved object: its geometry chunk, the G-buffer (reads all of the geometry)
    (lambda d: d["objects"]["ball"]["transform"].update(translate=[0.7, 0.35, 0.2]),
     {"geometry": {"ball"}, "gbuffer": "every"}),
    # the camera: the camera-dependent stages only
    (lambda d: d["camera"].update(position=[0.2, 1.5, 4.0]),
     {"gbuffer": "every", "tiles": "every"}),
    # a light: no toy stage declares the lights
    (lambda d: d["lights"][0].update(position=[0.0, 2.0, 1.0]), {}),
])
def test_forecast_names_exactly_the_chunks_that_run(toy, edit, expected):
    doc, base, folder = toy
    edited = copy.deepcopy(doc)
    edit(edited)
    predicted, actual = edit_and_check(folder, edited, base.root, TOY_STAGES, toy_bake,
                                       TOY_STAGEFILE)
    tiles = {f"y{y:05d}_x{x:05d}" for y in (0, 8, 16) for x in (0, 8, 16)}
    assert predicted == actual == {k: tiles if v == "every" else v
                                   for k, v in expected.items()}


def test_forecast_is_an_upper_bound_where_a_rerun_writes_the_same_bytes(tmp_path):
    """A parameter change that leaves a stage's output as it was (the toy atlas's
    texels per vertex 0.5 → 0.499: every texture keeps its ⌈√(n × t)⌉ side): the atlas
    re-runs and writes what it wrote, so the texel tiles after it stay fresh (early
    cut-off); the forecast counted every tile, as it cannot know the bytes before."""
    stagefile = TESTS / "toy" / "chunked_stages.yaml"
    doc = small_scene_dict()
    workdir = Workdir(tmp_path / "w")
    run(load_scene(write_scene(tmp_path, doc)), load_stagefile(stagefile), workdir,
        progress=False)
    doc["settings"] = {"toy.texels_per_vertex": 0.499}
    scene = load_scene(write_scene(tmp_path, doc))
    predicted = forecast(scene, workdir, stagefile)
    actual = ran(run(scene, load_stagefile(stagefile), workdir, progress=False))
    assert actual == {"atlas": {"all"}}
    assert predicted["atlas"] == {"all"} and set(predicted) == {"atlas", "texels"}
    assert len(predicted["texels"]) > 1


def test_status_and_dry_run_explain_the_plan_and_write_nothing(toy):
    """``prt status`` says per stage how many chunks re-run and which declared part of
    their keys changed; ``prt run --dry-run`` prints the same plan and writes nothing."""
    doc, base, folder = toy
    edited = copy.deepcopy(doc)
    edited["materials"]["shiny"]["albedo"] = [0.5, 0.1, 0.1]
    scene_file = write_scene(folder, edited, "edited.yaml")
    before = sorted((p, p.stat().st_mtime_ns) for p in base.root.rglob("*"))

    def prt(*args):
        result = subprocess.run([sys.executable, "-m", "pipeline", *args, str(scene_file),
                                 "--stages", str(TOY_STAGEFILE), "--workdir", str(base.root)],
                                capture_output=True, text=True)
        assert result.returncode == 0, result.stderr
        return result.stdout

    status = prt("status")
    assert "1/3 chunks re-run: scene materials.shiny changed (1)" in status, status
    assert "9/9 chunks re-run: input total changed (9)" in status, status
    assert "each reads all of total" in status
    dry = prt("run", "--dry-run")
    assert "per_object   stale: 1/3 chunks re-run: scene materials.shiny changed (1)" in dry
    assert "Dry run: 3 of 5 stages would run; nothing was written." in dry
    plan = json.loads(prt("run", "--dry-run", "--json"))["dry_run"]
    assert {p["name"]: p["chunks"] for p in plan if p["state"] != "fresh"} == {
        "per_object": ["ball"], "total": ["all"],
        "tiles": [f"y{y:05d}_x{x:05d}" for y in (0, 8, 16) for x in (0, 8, 16)]}
    rows = json.loads(prt("status", "--json"))["stages"]
    assert {r["name"]: r["plan"]["rerun"] for r in rows} == {
        "geometry": 0, "gbuffer": 0, "per_object": 1, "total": 1, "tiles": 9}
    assert sorted((p, p.stat().st_mtime_ns) for p in base.root.rglob("*")) == before


@pytest.mark.parametrize("what", ["material", "object", "camera"])
def test_status_dry_run_and_run_name_the_same_chunks(toy, what):
    """From the command line, on three edits: the chunks ``prt status --json`` says
    re-run, those ``prt run --dry-run --json`` says it would run and those ``prt run
    --json`` then ran are the same, stage by stage (one rule decides them all:
    pipeline/engine/planning.py ``chunks_to_run``)."""
    doc, base, folder = toy
    edited = copy.deepcopy(doc)
    if what == "material":
        edited["materials"]["shiny"]["albedo"] = [0.5, 0.1, 0.1]
    elif what == "object":
        edited["objects"]["ball"]["transform"]["translate"] = [0.7, 0.35, 0.2]
    else:
        edited["camera"]["position"] = [0.2, 1.5, 4.0]
    scene_file = write_scene(folder, edited, "edited.yaml")

    def prt(*args):
        result = subprocess.run([sys.executable, "-m", "pipeline", *args, str(scene_file),
                                 "--stages", str(TOY_STAGEFILE), "--workdir", str(base.root),
                                 "--json"], capture_output=True, text=True)
        assert result.returncode == 0, result.stderr
        return json.loads(result.stdout)

    status = {r["name"]: set(r["plan"]["chunks"]) for r in prt("status")["stages"]
              if r["plan"]["rerun"]}
    dry = {p["name"]: set(p["chunks"]) for p in prt("run", "--dry-run")["dry_run"]
           if p["state"] != "fresh"}
    done = {r["name"]: set(r["ran_chunks"]) for r in prt("run")["stages"]
            if r["action"] == "ran"}
    assert status == dry == done
    assert done  # each edit re-runs something


def test_an_unbuilt_input_makes_its_dependents_wait(tmp_path):
    """Before the first bake nothing can be planned past the first stages: the forecast
    says every chunk, waiting for the inputs."""
    scene = load_scene(write_scene(tmp_path, small_scene_dict()))
    plan = {f.name: f for f in job.rebake_forecast(scene, Workdir(tmp_path / "w"),
                                                   TOY_STAGEFILE)}
    assert plan["geometry"].rerun == plan["geometry"].total == 3
    assert plan["total"].chunks is None and "waits for per_object" in plan["total"].reasons


# -------------------------------------------------------------------------------- methods


def sky(path: Path, warm: float = 6.0) -> Path:
    """A 32 × 64 lat-long map: blue sky, dim ground, a bright blob of ``warm``."""
    rows = (np.arange(32) + 0.5) / 32
    rgb = np.zeros((32, 64, 3), np.float32)
    rgb[:] = np.where(rows[:, None, None] < 0.5, [0.3, 0.4, 0.6], [0.05, 0.04, 0.03])
    rgb[8:12, 20:26] = [warm, 4.0, 2.0]
    write_exr(path, rgb)
    return path


TRIPLE = {"triple.leaf_level": 3, "triple.frame_grid": [16, 9, 16],
          "triple.view_grid": [16, 8], "triple.texels_per_pixel": 2.0,
          "triple.light_block": 576, "triple.store_budget": 320,
          "triple.light_budget": 320}
SG = {"sg.fit_grid": [9, 16], "sg.fit_batch": 64, "sg.indirect_samples": 0,
      "sg.diffuse_samples": 64}
D2I = {"gather.count": 256, "transfer.tile": 8, "gbuffer.tile": 8}
METHOD_SETTINGS = {"d2i": D2I, "triple": TRIPLE, "sg": SG}
EVERY = "every"  # every chunk of the stage


def method_doc(method: str, folder: Path) -> dict:
    """The tiny scene (16², its ball subdivided once) for ``method``: under an
    environment map for triple and sg, its point and quad lights for d2i."""
    doc = small_scene_dict(16)
    doc["objects"]["ball"]["primitive"]["subdivisions"] = 1
    doc["methods"] = [method]
    if method != "d2i":
        doc["lights"] = [{"type": "environment", "file": str(sky(folder / "env.exr"))}]
    doc["settings"] = METHOD_SETTINGS[method]
    return doc


@pytest.fixture(scope="module")
def method_bakes(tmp_path_factory):
    """method -> (scene dict, baked work directory), each baked once, when first asked."""
    cache: dict[str, tuple[dict, Path]] = {}

    def get(method: str) -> tuple[dict, Path]:
        if method not in cache:
            folder = tmp_path_factory.mktemp(method)
            doc = method_doc(method, folder)
            scene = load_scene(write_scene(folder, doc))
            job.bake(scene, job.workdir_for(scene, folder / "base"), quiet=True)
            cache[method] = doc, folder / "base"
        return cache[method]
    return get


def edit(doc: dict, what: str, folder: Path) -> None:
    """Apply one of the common edits to a scene dictionary."""
    if what == "gamma":
        doc["materials"]["shiny"]["gamma"] = 35
    elif what == "map":
        doc["lights"][0]["file"] = str(sky(folder / "env2.exr", warm=9.0))
    elif what == "light":
        doc["lights"][0]["position"] = [0.0, 2.0, 1.0]
    elif what == "camera":
        doc["camera"]["position"] = [0.2, 1.5, 4.0]


EXPECTED = {
    # a material's parameters: that material's table, or the fits of its object only
    ("triple", "gamma"): {"triple.brdf_tables": {"shiny"}},
    # (sg's default reads γ at render time; its lobes, normal=vertex, would re-fit the
    # ball's batches)
    ("sg", "gamma"): {},
    # a light or the map: nothing where the method takes it at run time; else only
    # what the method resamples it into
    ("d2i", "light"): {},
    ("triple", "map"): {"triple.light_rotations": EVERY},
    # (sg: the map's prefiltered stack, and what the vertices see of its bright sources)
    ("sg", "map"): {"sg.env_prefilter": {"all"}, "sg.source_visibility": {"all"}},
    # the camera: the view-dependent stages only
    ("d2i", "camera"): {s: EVERY for s in ("gbuffer", "d2i.gather", "d2i.transfer",
                                           "d2i.transfer_t", "d2i.bounce", "d2i.truncate",
                                           "d2i.truncate_t", "d2i.truncate_ms")},
    ("sg", "camera"): {},
}


@pytest.mark.parametrize("method, what", list(EXPECTED))
def test_method_edits_rebake_exactly_the_forecast(method_bakes, tmp_path, method, what):
    from pipeline.engine.graph import with_upstream

    doc, base = method_bakes(method)
    edited = copy.deepcopy(doc)
    edit(edited, what, tmp_path)
    scene = load_scene(write_scene(tmp_path, edited))
    stages = tuple(with_upstream(job.stages(None), sorted(job.baked_stages(scene))))
    predicted, actual = edit_and_check(
        tmp_path, edited, base, stages,
        lambda sc, workdir: job.bake(sc, workdir, quiet=True))
    assert predicted == actual
    expected = EXPECTED[method, what]
    assert set(actual) == set(expected)
    workdir = job.workdir_for(scene, tmp_path / "edited_work")
    for stage, chunks in expected.items():
        if chunks == EVERY:
            record = json.loads((workdir.artifact(stage) / "zarr.json").read_text())
            assert actual[stage] == set(record["attributes"]["prt"]["chunks"]), stage
        elif chunks == "ball":  # the vertex batches of the ball
            assert actual[stage] and all(c.startswith("ball/") for c in actual[stage])
        else:
            assert actual[stage] == chunks, stage


def test_chunk_inputs_must_be_scoped_by_object_material_twin_or_parent(tmp_path):
    """A stage may read only some chunks of an input chunked by object or material, its
    twin chunk of an input chunked exactly as it is, or (chunked by tile_material) its
    parent tile of an input chunked by those tiles; any other ``chunk_inputs`` is
    refused in one line naming the stage file."""
    from pipeline.errors import PrtError

    doc = yaml.safe_load(TOY_STAGEFILE.read_text())
    doc["stages"]["tiles"]["chunk_inputs"] = ["total"]  # total is one chunk, tiles by tile
    path = tmp_path / "stages.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    with pytest.raises(PrtError, match="stages.tiles.chunk_inputs: 'total' is not chunked "
                                       "by object or material, nor as this stage is, nor "
                                       "by the tiles it splits"):
        load_stagefile(path)
    split = TESTS / "toy" / "material_tiles_stages.yaml"
    assert load_stagefile(split).stages["material_values"].chunk_inputs == ("tiles",)
    doc = yaml.safe_load(split.read_text())
    doc["stages"]["tiles"]["chunks"] = {"by": "tile", "size": "toy.tile"}  # other tiles
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    with pytest.raises(PrtError, match="stages.material_values.chunk_inputs: 'tiles' is not "
                                       "chunked"):
        load_stagefile(path)


def test_a_missing_piece_is_one_error_line(toy):
    """Artifact.read_piece of a chunk the artifact has no piece for names the array."""
    from pipeline.engine.store import open_artifact
    from pipeline.errors import PrtError

    _, workdir, _ = toy
    artifact = open_artifact(workdir.artifact("per_object"))
    assert artifact.read_piece("noise", "ball").shape == (1,)
    with pytest.raises(PrtError, match="no piece for chunk 'nope'"):
        artifact.read_piece("noise", "nope")

"""The prt command line: summaries, JSON outputs, inspect, help text."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from helpers import small_scene_dict, write_scene

from pipeline import job
from pipeline.engine.graph import topological_order, with_upstream
from pipeline.evaluation import reference_cache
from pipeline.scene.file import load_scene


def needed_stages(scene) -> set[str]:
    """The stages the scene file's methods bake (their reads and everything upstream)."""
    return with_upstream(job.stages(), sorted(job.baked_stages(load_scene(scene))))


def prt(*args, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pipeline", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    """A tiny scene run once through `prt run`: (scene, workdir, frames, first result)."""
    tmp = tmp_path_factory.mktemp("cli")
    doc = small_scene_dict(size=16)
    doc["settings"] = {"gather.count": 512}  # a small d2i bake
    doc["methods"] = ["d2i"]
    scene = write_scene(tmp, doc)
    first = prt("run", scene, "--workdir", tmp / "w", "--frames", tmp / "f", "-q", cwd=tmp)
    assert first.returncode == 0, first.stderr
    return scene, tmp / "w", tmp / "f", first


def test_run_summary_then_noop(baked):
    """The first run lists the stages it ran and the frame; the second runs nothing."""
    scene, workdir, frames, first = baked
    assert "geometry" in first.stdout and "ran" in first.stdout
    assert f"{frames / 'tiny_d2i.exr'}" in first.stdout
    for kind in ("light", "gamma"):  # the main job also writes both edit sequences
        assert f"Sequence {kind}: 8 frames tiny_d2i_{kind}_0000.exr .. " in first.stdout
        assert (frames / f"tiny_d2i_{kind}_0007.png").is_file()
    again = prt("run", scene, "--workdir", workdir, "--frames", frames, "-q")
    assert again.returncode == 0
    stages = len(needed_stages(scene))
    assert f"All {stages} stages fresh: nothing to bake." in again.stdout
    assert "Frame up to date" in again.stdout
    report = json.loads(prt("run", scene, "--workdir", workdir, "--frames", frames, "--json",
                            "-q").stdout)
    assert [s["action"] for s in report["stages"]] == ["skipped"] * stages


def test_status_json(baked):
    """`prt status --json` lists every stage with state, reason and re-bake plan (nothing
    to re-run), and the frame and sequences `prt run` wrote."""
    scene, workdir, frames, _ = baked
    out = json.loads(prt("status", scene, "--workdir", workdir, "--frames", frames,
                         "--json").stdout)
    needed = needed_stages(scene)
    plans = [row.pop("plan") for row in out["stages"]]
    assert out["stages"] == [{"name": n, "state": "fresh", "reason": "", "partial": None}
                             for n in topological_order(job.stages()) if n in needed]
    assert all(p["rerun"] == 0 and p["chunks"] == [] and p["total"] >= 1 for p in plans)
    assert [(f["name"], f["state"]) for f in out["frames"]] == [
        ("frame", "present"), ("sequence light:8", "present"), ("sequence gamma:8", "present")]


def test_inspect_reports_schema_and_arrays(baked):
    """`prt inspect --json` gives kind, version, dims, chunks, bytes and statistics."""
    _, workdir, _, _ = baked
    info = json.loads(prt("inspect", workdir / "gbuffer.zarr", "--json").stdout)
    assert (info["kind"], info["schema_version"]) == ("gbuffer", 1)
    normal = info["arrays"]["normal"]
    assert normal["shape"] == [16, 16, 3] and normal["dims"] == ["y", "x", "xyz"]
    assert normal["dtype"] == "float32" and normal["stored_bytes"] > 0
    assert -1.0 <= normal["min"] <= normal["max"] <= 1.0 and normal["nan_count"] == 0
    text = prt("inspect", workdir / "geometry.zarr")
    assert text.returncode == 0 and "object_ranges" in text.stdout


def test_render_json_and_size(baked, tmp_path):
    """`prt render --json` prints one JSON line with timings and the requested size."""
    scene, workdir, _, _ = baked
    out = tmp_path / "frame.exr"
    result = prt("render", scene, "--method", "direct", "--workdir", tmp_path / "w2", "--out",
                 out, "--size", "20x12", "--json", "-q")
    assert result.returncode == 0, result.stderr
    line = json.loads(result.stdout)
    assert (line["width"], line["height"], line["method"]) == (20, 12, "direct")
    assert line["setup_ms"] > 0 and line["kernel_ms"] > 0
    assert out.is_file() and out.with_suffix(".png").is_file()


@pytest.mark.parametrize("command", ["", "run", "status", "inspect", "render", "reference",
                                     "evaluate", "clean", "methods", "verify"])
def test_help_everywhere(command):
    """Every command has help text."""
    result = prt(*([command] if command else []), "--help")
    assert result.returncode == 0 and "Usage:" in result.stdout and len(result.stdout) > 200


def test_clean_removes_workdir(tmp_path):
    """`prt clean` deletes the scene's artifacts."""
    scene = write_scene(tmp_path, small_scene_dict(size=8))
    assert prt("run", scene, "--workdir", tmp_path / "w", "--until", "geometry", "-q"
               ).returncode == 0
    assert (tmp_path / "w" / "geometry.zarr").is_dir()
    result = prt("clean", scene, "--workdir", tmp_path / "w")
    assert result.returncode == 0 and not (tmp_path / "w" / "geometry.zarr").exists()


def test_render_material_edits(baked, tmp_path):
    """`prt render --set`: an in-range γ edit renders a different frame with no re-bake;
    γ outside the baked gamma_range, an unknown name and a Lambertian γ are one-line
    errors naming the scene file, with exit status 2."""
    scene, workdir, frames, _ = baked
    out = prt("render", scene, "--workdir", workdir, "--out", tmp_path / "a.exr", "--set",
              "ball.gamma=250", "--json", "-q")
    assert out.returncode == 0, out.stderr
    for edit, problem in [("ball.gamma=301", "outside the baked PCA range [3, 300]"),
                          ("shiny.gamma=1", "outside the baked PCA range [3, 300]"),
                          ("nothing.gamma=5", "no material or object named 'nothing'"),
                          ("floor.gamma=5", "is Lambertian"),
                          ("ball.roughness=5", "cannot edit 'roughness'")]:
        bad = prt("render", scene, "--workdir", workdir, "--out", tmp_path / "b.exr",
                  "--set", edit, "-q")
        assert bad.returncode == 2
        assert f"{scene}: --set {edit}: " in bad.stderr and problem in bad.stderr
        assert "Traceback" not in bad.stderr


def test_reference_writes_image_and_reuses_its_cache(baked, tmp_path):
    scene, workdir, _, _ = baked
    out = tmp_path / "ref.exr"
    args = ("reference", scene, "--transport", "direct", "--out", out, "--max-spp", "4",
            "--tolerance", "0", "--workdir", workdir, "--json", "-q")
    first = prt(*args)
    assert first.returncode == 0, first.stderr
    stats = json.loads(first.stdout)
    assert (stats["spp"], stats["cached"]) == (4, False)
    assert out.is_file() and out.with_suffix(".png").is_file()
    again = json.loads(prt(*args).stdout)
    assert again["cached"] and again["artifact"] == stats["artifact"]
    other = json.loads(prt(*args[:-2], "--seed", "3", "--json", "-q").stdout)
    assert not other["cached"] and other["artifact"] != stats["artifact"]


def test_reference_cache_outlives_a_geometry_rebake_with_the_same_bytes(tmp_path):
    """A reference is keyed on the geometry's bytes, not on the geometry stage's key: a
    setting that re-runs that stage without changing what it writes (the zarr chunk
    length of its arrays) leaves the reference cached; geometry that changes (a moved
    object) renders a new one."""
    from pipeline.engine.store import read_record
    from pipeline.evaluation.reference import ReferenceSettings

    doc = small_scene_dict(8)
    scene = load_scene(write_scene(tmp_path, doc))
    workdir = job.workdir_for(scene, tmp_path / "w")
    settings = ReferenceSettings("direct", tolerance=0.0, min_spp=1, max_spp=1)
    first = reference_cache.reference(scene, workdir, settings, quiet=True)
    key = read_record(workdir.artifact("geometry"))["key"]
    rechunked = scene.with_settings({"geometry.vertex_chunk": 1024})
    again = reference_cache.reference(rechunked, workdir, settings, quiet=True)
    assert read_record(workdir.artifact("geometry"))["key"] != key  # the stage re-ran
    assert again.cached and again.artifact == first.artifact
    doc["objects"]["ball"]["transform"]["translate"] = [0.5, 0.35, 0.2]
    moved = load_scene(write_scene(tmp_path, doc, "moved.yaml"))
    assert not reference_cache.reference(moved, workdir, settings, quiet=True).cached


def test_evaluate_writes_records_and_charts(baked, tmp_path):
    scene, workdir, _, _ = baked
    out = tmp_path / "eval"
    result = prt("evaluate", scene, "--method", "direct", "--sweep", "size=8,12", "--out",
                 out, "--repeats", "1", "--reference-max-spp", "64", "--workdir", workdir,
                 "-q")
    assert result.returncode == 0, result.stderr
    records = json.loads((out / "results.json").read_text())
    assert [r["budget"] for r in records] == [{"size": 8}, {"size": 12}, {"size": 16}]
    assert [r["default"] for r in records] == [False, False, True]
    for r in records:
        assert r["method"] == "direct" and r["frame_ms"] >= r["kernel_ms"] > 0
        assert r["storage_bytes"] > 0 and r["bake_s"] > 0 and 0 < r["rel_rmse"] < 1
        # the path tracer (seed 1) renders until its estimated error reaches the frame's
        # (direct: rel_rmse over the whole image, a few % here): it gets there before its
        # cap of 4096 paths per pixel (measured: after its first pass, 512-2048 spp)
        assert 1 <= r["pathtrace_spp"] < 4096
        assert 0 < r["pathtrace_estimate"] <= r["rel_rmse"]
        assert r["pathtrace_ms_equal_error"] > 0 and r["pathtrace_rel_rmse"] > 0
        assert (out / "frames" / f"size-{r['budget']['size']}_error.png").is_file()
        # the model error: against full path tracing, which the direct transport
        # leaves the box's interreflections out of; the transport's own gap is most of
        # it (its references' noise on top), at most all of it plus the method error
        assert r["model_transport"] == "full" and r["model_reference_spp"] >= 64
        assert r["model_rel_rmse"] > r["rel_rmse"] and r["transport_rel_rmse"] > 0
        assert r["model_rel_rmse"] <= r["transport_rel_rmse"] + r["rel_rmse"] \
            + r["reference_model_rel_rmse"] + r["reference_rel_rmse"]
        assert (out / "frames" / f"size-{r['budget']['size']}_model_error.png").is_file()
    # which stages each budget ran: geometry once (the sweep's own work directory),
    # the gbuffer at every size; the summary table is printed also with -q
    assert [r["bake_stages"]["geometry"]["ran"] for r in records] == [True, False, False]
    assert all(r["bake_stages"]["gbuffer"]["ran"] for r in records)
    assert len({r["bake_stages"]["geometry"]["key"] for r in records}) == 1
    rows = [line.split()[0] for line in result.stdout.splitlines()[1:4]]
    assert rows == ["size-8", "size-12", "size-16"] and "size-16 *" in result.stdout
    probe = json.loads((out / "probe.json").read_text())["bandwidth_probe"]
    assert probe["opencl_copy_gbs"] > 0
    for chart in ("error_vs_frame_time", "error_vs_storage", "error_vs_bake_time"):
        assert (out / f"{chart}.png").is_file()
    bad = prt("evaluate", scene, "--sweep", "nonsense.key=1", "--out", out, "--workdir",
              workdir, "-q")
    assert bad.returncode == 2 and "has no budget 'nonsense.key' (its budgets: size" in bad.stderr


def test_evaluate_d2i_records_its_indirect_error(baked, tmp_path):
    """A d2i sweep over bounces records the indirect image's error against the
    reference's d2i-indirect transport, and more bounces bring more indirect light; the
    indirect charts are written."""
    scene, workdir, _, _ = baked
    out = tmp_path / "eval"
    result = prt("evaluate", scene, "--method", "d2i", "--sweep", "render.max_bounces=0,8",
                 "--out", out, "--repeats", "1", "--reference-max-spp", "64", "--workdir",
                 workdir, "-q")
    assert result.returncode == 0, result.stderr
    records = {r["budget"]["render.max_bounces"]: r
               for r in json.loads((out / "results.json").read_text())}
    assert set(records) == {0, 8, 32}
    for r in records.values():
        assert 0 < r["rel_rmse_indirect"] < 1 and r["reference_spp_indirect"] >= 16
        assert 0 < r["rel_rmse_surfaces"] < 1
    # no bounce: only the gather samples' direct light reflected once
    assert records[0]["indirect_mean_ratio"] < records[8]["indirect_mean_ratio"]
    for chart in ("indirect_error_vs_frame_time", "indirect_error_vs_storage"):
        assert (out / f"{chart}.png").is_file()


def test_render_d2i_sequences(baked, tmp_path):
    """`prt render --method d2i --frames light:3` writes the frame and three light-edit
    frames that differ from each other; a gamma sweep on a scene's glossy material
    writes its frames; --frames with a method without sequences is an error."""
    scene, workdir, _, _ = baked
    out = tmp_path / "d2i.exr"
    result = prt("render", scene, "--method", "d2i", "--out", out, "--workdir", workdir,
                 "--frames", "light:3", "-q")
    assert result.returncode == 0, result.stderr
    from pipeline.images import read_exr

    frames = [read_exr(tmp_path / f"d2i_light_{i:04d}.exr") for i in range(3)]
    assert out.is_file() and all((tmp_path / f"d2i_light_{i:04d}.png").is_file()
                                 for i in range(3))
    assert not np.allclose(frames[0], frames[1])
    result = prt("render", scene, "--method", "d2i", "--out", out, "--workdir", workdir,
                 "--frames", "gamma:shiny:2", "-q")
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "d2i_gamma_0001.exr").is_file()
    bad = prt("render", scene, "--method", "direct", "--out", out, "--workdir", workdir,
              "--frames", "light:2")
    assert bad.returncode == 2 and "method direct has no edit sequences" in bad.stderr
    bad = prt("render", scene, "--method", "d2i", "--out", out, "--workdir", workdir,
              "--frames", "spin:2")
    assert bad.returncode == 2 and "expected light[:LIGHT]:N" in bad.stderr

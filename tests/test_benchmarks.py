"""Every benchmark runs end to end at its tiny size (``python -m benchmarks run NAME
--tiny``), so that a renamed artifact or option does not leave one broken until someone
needs its numbers (it happened once: a benchmark read a renamed artifact). Timings are
not checked — only that every part ran and what must hold whatever the machine."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from helpers import PROJECT

from benchmarks.__main__ import benchmarks

CHECKED_APART = ("d2i.frames", "engine.rebake")  # smoke-tested below, with their facts


def run_tiny(name: str, folder) -> dict:
    """``name`` run at its tiny size into ``folder`` (its bakes there too, not in the
    project's .prt/benchmarks); its result."""
    env = {**os.environ, "PRT_BENCH_CACHE": str(folder / "cache")}
    done = subprocess.run([sys.executable, "-m", "benchmarks", "run", name, "--tiny",
                           "--out", str(folder)], cwd=PROJECT, capture_output=True,
                          text=True, env=env)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads((folder / f"{name}.json").read_text())


def test_the_runner_lists_every_suite_and_refuses_an_unknown_name():
    names = benchmarks()
    assert {n.partition(".")[0] for n in names} == {"engine", "d2i", "triple", "sg"}
    assert all(doc for doc in names.values()), "every benchmark says what it measures"
    done = subprocess.run([sys.executable, "-m", "benchmarks", "run", "no.such"],
                          cwd=PROJECT, capture_output=True, text=True)
    assert done.returncode != 0 and "no benchmark 'no.such'" in done.stderr


@pytest.mark.parametrize("name", [n for n in benchmarks() if n not in CHECKED_APART])
def test_every_benchmark_runs_at_its_tiny_size(name, tmp_path):
    result = run_tiny(name, tmp_path)
    assert result["benchmark"] == name and result["machine"]["cores"] >= 1


def test_d2i_frames_run_and_their_shadow_rays_agree(tmp_path):
    """d2i.frames at its tiny size: frame timings for every mode, storage of T, D and
    Ms, the bandwidth probe, and the shadow-ray comparison — the device's BVH and
    Embree give the same answer for every ray of the scene's lights."""
    result = run_tiny("d2i.frames", tmp_path)
    assert set(result["frames"]) == {"light_edit_point", "light_edit_area16", "brdf_edit"}
    assert all(f["total_ms"] > 0 for f in result["frames"].values())
    assert set(result["storage"]) == {"T", "D", "Ms"}
    assert result["shadow_rays"]["rays"] > 0 and result["shadow_rays"]["differ"] == 0
    assert result["bandwidth_probe"]["opencl_copy_gbs"] > 0


def test_engine_rebake_reruns_only_the_edited_materials_chunks(tmp_path):
    """engine.rebake at its tiny size: the γ-range edit re-runs the box's basis and only
    some chunks of d2i.transfer_t and d2i.truncate_t (its own), nothing else; the
    narrower range needs no larger basis than the full bake's, and the range toggled
    back needs the full bake's; the moved box re-runs its own geometry chunk of several."""
    result = run_tiny("engine.rebake", tmp_path)
    edit = result["gamma_range_edit"]
    assert set(edit["ran"]) == {"brdf_basis", "d2i.transfer_t", "d2i.truncate_t"}
    assert edit["ran"]["brdf_basis"]["chunks"] == 1
    for stage in ("d2i.transfer_t", "d2i.truncate_t"):
        assert 0 < edit["ran"][stage]["chunks"] < edit["ran"][stage]["of"]
    narrower, back = edit["repeats"]
    assert narrower["gamma_range"] == [0.15, 0.5] and back["gamma_range"] == [0.1, 0.5]
    assert narrower["k"] <= edit["full_bake_k"] == back["k"]
    moved = result["moved_small_box"]["ran"]["geometry"]
    assert moved["chunks"] == 1 < moved["of"]


def test_the_table_generator_fills_a_method_page(tmp_path, monkeypatch):
    """``python -m benchmarks table`` writes docs/results.md, replaces a method page's
    generated section with the method's accuracy table and the README's with a row per
    method (here from a hand-made result, into stand-ins for the pages)."""
    from benchmarks import table

    docs = tmp_path / "docs"
    (docs / "methods").mkdir(parents=True)
    page = docs / "methods" / "d2i.md"
    page.write_text("# d2i\n\n## Current figures\n\n" + table.MARKER.format(m="d2i")
                    + "\n\nold figures\n\n## After\n\nkept\n")
    results = tmp_path / "results" / "d2i"
    results.mkdir(parents=True)
    readme = tmp_path / "README.md"
    readme.write_text("## Which method\n\n" + table.README_MARKER + "\n\nold\n\n"
                      "Which to use: d2i.\n")
    record = {"budget": {"gather.count": 4096}, "default": True, "headline": "rel_rmse",
              "width": 96, "height": 96,
              "frame_ms": 12.5, "rel_rmse": 0.021, "reference_rel_rmse": 0.004,
              "model_rel_rmse": 0.063, "reference_model_rel_rmse": 0.005,
              "storage_bytes": 3e6, "bake_s": 40.0, "pathtrace_ms_equal_error": 900.0}
    (results / "accuracy.json").write_text(json.dumps({
        "method": "d2i", "scene": "scenes/cornell_box.yaml", "size": [96, 96],
        "machine": {"cpu": "a CPU", "cores": 2, "opencl_device": "a device"},
        "finished": "2026-11-29T00:00:00", "load": [[1.0, 1, 1], [2.0, 2, 2]],
        "budgets": [record]}))
    monkeypatch.setattr(table, "DOCS", docs)
    written = table.write_tables(tmp_path / "results")
    text = page.read_text()
    assert "old figures" not in text and "## After\n\nkept" in text
    assert "| gather.count=4096 (default) | 12.5 | 2.1 % | 0.4 % | 6.3 % | 0.5 % | 3.0 | " \
        "40 | 900 |" in text
    assert docs / "results.md" in written and readme in written
    assert "| `d2i` | `cornell_box.yaml` | 96×96 | 6.3 % | 2.1 % | 0.4 % | 12.5 | 40 | " \
        "a CPU, 2026-11-29 |" in readme.read_text()
    assert "old" not in readme.read_text() and "Which to use: d2i." in readme.read_text()
    assert "Not measured: run `python -m benchmarks run triple.accuracy`" in \
        (docs / "results.md").read_text()


def test_the_table_generator_tabulates_a_scene_suite(tmp_path, monkeypatch):
    """A ``<method>.suite`` result becomes one row per scene and budget, with both
    errors and a frame time per size, on the method page and in docs/results.md."""
    from benchmarks import table

    docs = tmp_path / "docs"
    (docs / "methods").mkdir(parents=True)
    page = docs / "methods" / "sg.md"
    page.write_text("# sg\n\n## Scene suite\n\n" + table.SUITE_MARKER.format(m="sg")
                    + "\n\nNot measured yet.\n")
    results = tmp_path / "results" / "sg"
    results.mkdir(parents=True)
    record = {"budget": {"sg.diffuse_order": 8}, "default": True,
              "headline": "rel_rmse_surfaces", "rel_rmse_surfaces": 0.075,
              "reference_rel_rmse_surfaces": 0.032, "model_rel_rmse_surfaces": 0.171,
              "reference_model_rel_rmse_surfaces": 0.04, "storage_bytes": 6.7e7,
              "bake_s": 704.0, "frame_ms_at": {"256x256": {"frame_ms": 4.2},
                                               "1024x768": {"frame_ms": 31.0}}}
    (results / "suite.json").write_text(json.dumps({
        "method": "sg", "size": [64, 64], "frame_sizes": ["256x256", "1024x768"],
        "machine": {"cpu": "a CPU", "cores": 2, "opencl_device": "a device"},
        "finished": "2026-11-29T00:00:00", "load": [[1.0, 1, 1], [2.0, 2, 2]],
        "chart": "x/error_vs_frame_time.png",
        "scenes": [{"scene": "bunny_sg", "why": "shipped", "budgets": [record]}]}))
    monkeypatch.setattr(table, "DOCS", docs)
    written = table.write_tables(tmp_path / "results")
    assert page in written
    row = "| bunny_sg | sg.diffuse_order=8 (default) | 7.5 % | 3.2 % | 17.1 % | 4.0 % | " \
        "4.2 | 31.0 | 67.0 | 704 |"
    assert row in page.read_text() and "Not measured yet" not in page.read_text()
    assert row in (docs / "results.md").read_text()

"""Reporting: budgets that miss their tolerance warn in `prt run` and show in
`prt inspect`; `prt inspect WORKDIR` summarises every artifact; `prt status` shows the
chunk progress of an interrupted stage."""

from __future__ import annotations

import json

import pytest
from helpers import small_scene_dict, write_scene
from test_cli import prt

from pipeline.engine import chunkwrite
from pipeline.engine.store import Workdir, read_record
from pipeline.engine.tolerance import ToleranceResult, unmet, warning


@pytest.fixture(scope="module")
def wide_ward(tmp_path_factory):
    """A scene whose Ward material spans γ over six decades (issue 15, item 4): its PCA
    fit stops at max_k with a worst relative RMS near 0.9 against a tolerance of 0.01.
    Only brdf_basis is baked (three materials: three chunks)."""
    tmp = tmp_path_factory.mktemp("ward")
    doc = small_scene_dict(size=8)
    doc["materials"]["shiny"] = {"model": "ward", "albedo": [0.2, 0.4, 0.6],
                                 "specular": 0.3, "gamma": 0.05,
                                 "gamma_range": [0.001, 1000]}
    doc["materials"]["grey"] = {"model": "blinn_phong", "albedo": [0.2, 0.2, 0.2],
                                "specular": 0.15, "gamma": 20, "gamma_range": [3, 300]}
    scene = write_scene(tmp, doc)
    first = prt("run", scene, "--workdir", tmp / "w", "--until", "brdf_basis", "--json", "-q")
    assert first.returncode == 0, first.stderr
    return scene, tmp / "w", json.loads(first.stdout)


def test_run_warns_when_a_tolerance_is_not_reached(wide_ward):
    """The JSON report carries the stage's tolerance results and a warning naming the
    material; a second run (the stage fresh) warns again, in text."""
    scene, workdir, report = wide_ward
    (stage,) = report["stages"]
    by_subject = {t["subject"]: t for t in stage["tolerances"]}
    ward, phong = by_subject["material shiny"], by_subject["material grey"]
    assert (ward["reached"], ward["budget"], ward["tolerance"]) == (False, {"k": 24}, 0.01)
    assert ward["achieved"] > 0.5  # measured 0.90: the fit cannot follow six decades of γ
    assert phong["reached"] and phong["achieved"] <= 0.01 and phong["budget"]["k"] < 24
    assert "material red" not in by_subject  # Lambertian: nothing budgeted
    (line,) = report["warnings"]
    assert line.startswith("brdf_basis: material shiny: tolerance not reached")
    again = prt("run", scene, "--workdir", workdir, "--until", "brdf_basis", "-q")
    assert again.returncode == 0 and "fresh, skipped" in again.stdout
    assert f"warning: {line}" in again.stdout


def test_inspect_shows_tolerances(wide_ward):
    """`prt inspect ARTIFACT` and `prt inspect WORKDIR` list k, tolerance, worst error
    and whether it was reached per material; the work directory's summary warns."""
    _, workdir, report = wide_ward
    one = prt("inspect", workdir / "brdf_basis.zarr")
    assert one.returncode == 0, one.stderr
    assert "material shiny: k 24; worst relative RMS of the PCA fit 0.9" in one.stdout
    assert "tolerance 0.01: NOT reached (capped at max_k 24)" in one.stdout
    info = json.loads(prt("inspect", workdir / "brdf_basis.zarr", "--json").stdout)
    assert info["tolerances"] == report["stages"][0]["tolerances"]
    whole = prt("inspect", workdir)
    assert whole.returncode == 0, whole.stderr
    assert "brdf_basis.zarr" in whole.stdout and "complete 3 chunks" in whole.stdout
    assert "tolerance 0.01: reached" in whole.stdout  # the Blinn-Phong material
    assert f"warning: {report['warnings'][0]}" in whole.stdout
    summary = json.loads(prt("inspect", workdir, "--json").stdout)
    (row,) = [r for r in summary["artifacts"] if r["stage"] == "brdf_basis"]
    assert (row["kind"], row["state"], row["chunks"], row["chunks_done"]) == \
        ("brdf_basis", "complete", 3, 3)
    assert row["stored_bytes"] > 0 and row["warnings"] == report["warnings"]


def test_status_and_inspect_show_partial_progress(tmp_path):
    """The state a kill -9 half-way through a stage leaves (record incomplete, some
    chunk markers written) reads `partial: 2/3 chunks` in `prt status`, and as partial
    in `prt inspect WORKDIR`."""
    doc = small_scene_dict(size=8)
    doc["methods"] = ["d2i"]  # whose frames read brdf_basis
    scene = write_scene(tmp_path, doc)
    assert prt("run", scene, "--workdir", tmp_path / "w", "--until", "brdf_basis", "-q"
               ).returncode == 0
    wd = Workdir(tmp_path / "w")
    record = read_record(wd.artifact("brdf_basis"))
    chunkwrite.restore_record(wd.artifact("brdf_basis"), {**record, "complete": False})
    wd.marker("brdf_basis", record["chunks"][1]).unlink()
    text = prt("status", scene, "--workdir", wd.root)
    assert "brdf_basis   partial: 2/3 chunks  (incomplete" in text.stdout, text.stdout
    rows = json.loads(prt("status", scene, "--workdir", wd.root, "--json").stdout)["stages"]
    partial = {r["name"]: r["partial"] for r in rows}
    assert partial["brdf_basis"] == {"done": 2, "total": 3} and partial["geometry"] is None
    summary = json.loads(prt("inspect", wd.root, "--json").stdout)
    (row,) = summary["artifacts"]
    assert (row["state"], row["chunks_done"], row["chunks"]) == ("partial", 2, 3)
    assert "partial  2/3 chunks" in prt("inspect", wd.root).stdout
    # issue 40 item 6: while another run holds the work directory, the partial stage
    # is being written, not "interrupted"
    reason = {r["name"]: r["reason"] for r in rows}["brdf_basis"]
    assert "stopped before finishing it (interrupted or failed)" in reason
    with wd.lock():  # as a run writing it now holds it (prt status: another process)
        rows = json.loads(prt("status", scene, "--workdir", wd.root, "--json").stdout)
    reason = {r["name"]: r["reason"] for r in rows["stages"]}["brdf_basis"]
    assert reason == "incomplete: another prt run is writing it now", reason


def test_inspect_refuses_a_folder_without_artifacts(tmp_path):
    result = prt("inspect", tmp_path)
    assert result.returncode == 2 and "holds no prt artifacts" in result.stderr


def test_tolerance_result_warning():
    """A result is reached when the worst error is within the tolerance (equal counts);
    the warning names stage, subject, both numbers, the budget and the cap."""
    met = ToleranceResult("material a", "worst relative RMS", 0.01, 0.01, {"k": 5})
    short = ToleranceResult("material b", "worst relative RMS", 0.01, 0.2, {"k": 24},
                            "max_k 24", "raise max_k")
    assert met.reached and not short.reached
    records = {"tolerances": [met.as_record(), short.as_record()]}
    assert unmet(records) == [short.as_record()]
    assert warning("s", short.as_record()) == (
        "s: material b: tolerance not reached: worst relative RMS 0.2 > 0.01 at k = 24, "
        "capped at max_k 24 (raise max_k)")

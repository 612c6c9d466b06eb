"""Benchmark scripts run end to end on tiny inputs, so that a renamed artifact or option
does not leave them broken until someone needs their numbers (it happened once:
benchmarks/d2i_breakdown.py read a renamed artifact). Timings are not checked — only
that every part ran and what must hold whatever the machine."""

from __future__ import annotations

import json
import subprocess
import sys

from helpers import PROJECT


def test_bench_d2i_runs_and_its_shadow_rays_agree(tmp_path):
    """bench_d2i at 24², 256 gathers: frame timings for every mode, storage of T, D and
    Ms, the bandwidth probe, and the shadow-ray comparison — the device's BVH and
    Embree give the same answer for every ray of the scene's lights (the Cornell box:
    axis-aligned quads, nothing grazes an edge)."""
    out = tmp_path / "bench.json"
    subprocess.run([sys.executable, "benchmarks/bench_d2i.py", "--size", "24", "--gathers",
                    "256", "--workdir", str(tmp_path / "w"), "--skip-breakdown",
                    "--out", str(out)], cwd=PROJECT, check=True, capture_output=True)
    result = json.loads(out.read_text())
    assert set(result["frames"]) == {"light_edit_point", "light_edit_area16", "brdf_edit"}
    assert all(f["total_ms"] > 0 for f in result["frames"].values())
    assert set(result["storage"]) == {"T", "D", "Ms"}
    assert result["shadow_rays"]["rays"] > 0 and result["shadow_rays"]["differ"] == 0
    assert result["bandwidth_probe"]["opencl_copy_gbs"] > 0


def test_bench_rebake_reruns_only_the_edited_materials_chunks(tmp_path):
    """bench_rebake at 24², 256 gathers, two γ-range re-bakes without waiting for quiet:
    the edit re-runs the box's basis and only some chunks of d2i.transfer_t and
    d2i.truncate_t (its own), nothing else; the narrower range needs no larger basis
    than the full bake's, and the range toggled back needs the full bake's; the moved
    box re-runs its own geometry chunk of several."""
    out = tmp_path / "rebake.json"
    subprocess.run([sys.executable, "benchmarks/bench_rebake.py", "--size", "24", "--tile",
                    "8", "--gathers", "256", "--repeats", "2", "--no-quiet", "--workdir",
                    str(tmp_path / "w"), "--out", str(out)], cwd=PROJECT, check=True,
                   capture_output=True)
    result = json.loads(out.read_text())
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

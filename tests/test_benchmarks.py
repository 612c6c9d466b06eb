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

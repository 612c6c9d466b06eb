"""Every kernel of the project launched on tiny inputs, recorded for Oclgrind:
``python scenarios.py FOLDER`` (run on the ordinary device, in one process: PRT_JOBS=1).

Tiny scenes of tests/helpers.py: each method's bake and frame (direct; d2i in both
product layouts, its shadows traced by the device's BVH kernel, a light edit, a BRDF
edit and bounces until the tail is extrapolated; triple's sparse and dense paths; sg),
the BVH's occlusion rays and the bandwidth probe; then the kernel-vs-NumPy tests of the
kernels only tests launch (:data:`TESTS_OF_TEST_KERNELS`). Sizes are cut so that
Oclgrind, which interprets every work-item, gets through a launch in seconds.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

TESTS = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(TESTS), str(TESTS.parent)]  # helpers; tests.helpers
os.environ.setdefault("PRT_JOBS", "1")

from capture import capturing  # noqa: E402
from helpers import small_scene_dict, write_scene  # noqa: E402

SIZE = 8
# the tests that launch the kernels no product path does (NumPy twins of shared headers)
TESTS_OF_TEST_KERNELS = (
    "test_brdf.py::test_opencl_matches_numpy",
    "test_triple_tables.py::test_envmap_kernel_matches_environment_map",
    "test_sg.py::test_formula_kernel_matches_numpy",
    "test_sg.py::test_env_kernel_matches_numpy",
    "test_sphwavelet.py::test_triple_product_kernel_matches_numpy",
    "test_d2i.py::test_bounce_tail_extrapolation_matches_iterating_to_convergence",
)
D2I = {"gather.count": 64, "bounce.block": 32, "transfer.tile": 8}
TRIPLE = {"triple.leaf_level": 2, "triple.visibility_refine": 1, "triple.frame_grid": [8, 5, 8],
          "triple.view_grid": [8, 4], "triple.texture_max": 16, "triple.texel_tile": 16,
          "triple.light_block": 64, "triple.store_budget": 64}
SG = {"sg.fit_grid": [9, 18], "sg.indirect_samples": 4, "sg.diffuse_samples": 16,
      "sg.diffuse_order": 3, "sg.fit_batch": 32}


def sky_map(path: Path) -> Path:
    """A 16 × 32 latitude-longitude map: sky, ground and a bright warm blob."""
    from pipeline.images import write_exr

    rows = (np.arange(16) + 0.5) / 16
    rgb = np.where(rows[:, None, None] < 0.5, [0.3, 0.4, 0.6], [0.05, 0.04, 0.03])
    rgb = np.broadcast_to(rgb, (16, 32, 3)).astype(np.float32).copy()
    rgb[4:6, 10:13] = [6.0, 4.0, 2.0]
    write_exr(path, rgb)
    return path


def run_all(folder: Path, work: Path) -> None:
    import pytest

    from pipeline import bandwidth, bvh, job
    from pipeline.scene import load_scene
    from pipeline.scene_edits import with_light_offset, with_material_edits

    def scene(name: str, methods: list[str], settings: dict, env: Path | None = None):
        doc = small_scene_dict(SIZE)
        doc["name"], doc["methods"], doc["settings"] = name, methods, settings
        if env is not None:
            doc["lights"] = [{"type": "environment", "file": str(env)}]
        (work / name).mkdir(parents=True, exist_ok=True)
        return load_scene(write_scene(work / name, doc))

    with capturing(folder):
        bandwidth.probe(megabytes=1, repeats=1)
        sc = scene("d2i", ["d2i"], D2I)
        wd = job.workdir_for(sc, work / "d2i" / "w")
        job.bake(sc, wd, quiet=True)
        job.render_frame(sc, wd, "direct")
        for layout in ("cpu", "gpu"):
            render = job.frame_renderer(sc, wd, "d2i", {"layout": layout, "shadows": "device"})
            render(sc)
            render(with_light_offset(sc, 0, (0.1, 0.0, 0.0)))
            render(with_material_edits(sc, ["shiny.gamma=50"]))
        geometry, _ = job.load_geometry(sc, wd)
        rays = np.random.default_rng(0).normal(size=(64, 3))
        bvh.occluded(bvh.Bvh.build(geometry["vertices"], geometry["faces"]),
                     np.tile([0.0, 1.0, 0.0], (64, 1)), rays, np.ones(64))
        env = sky_map(work / "sky.exr")
        for name, settings in (("sg", SG), ("triple", TRIPLE)):
            sc = scene(name, [name], settings, env)
            wd = job.workdir_for(sc, work / name / "w")
            job.bake(sc, wd, quiet=True)
            job.render_frame(sc, wd, name)
        job.render_frame(sc, wd, "triple", {"budget": 16})
        code = pytest.main(["-q", "-p", "no:cacheprovider", "-p", "no:randomly",
                            *(str(TESTS / t) for t in TESTS_OF_TEST_KERNELS)])
        if code != 0:
            raise SystemExit(f"the kernel tests failed while recorded (exit {code})")


if __name__ == "__main__":
    out = Path(sys.argv[1])
    run_all(out, out.parent / "work")

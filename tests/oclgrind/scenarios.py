"""Every kernel of the project launched on tiny inputs, recorded for Oclgrind:
``python scenarios.py FOLDER`` (run on the ordinary device, in one process: PRT_JOBS=1).

Each method's tiny scene (tests/tiny_scenes.py) baked and rendered: direct; d2i in both
product layouts with its shadows traced by the device's BVH kernel, a light edit and a
BRDF edit; sg (its visibility maps, its lobes as fitted, turned to the pixel's normal and
as a ratio); triple's sparse
and dense paths; the BVH's occlusion and closest-hit rays and the bandwidth probe; then the
kernel-vs-NumPy tests of the kernels only tests launch (:data:`TESTS_OF_TEST_KERNELS`).
Sizes are cut so that Oclgrind, which interprets every work-item, gets through a launch
in seconds.
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
from tiny_scenes import tiny_scene  # noqa: E402

# the tests that launch the kernels no product path does (NumPy twins of shared headers),
# and sg's source terms, which the tiny scene's sky has no source for
TESTS_OF_TEST_KERNELS = (
    "test_brdf.py::test_opencl_matches_numpy",
    "test_triple_tables.py::test_envmap_kernel_matches_environment_map",
    "test_sg.py::test_formula_kernel_matches_numpy",
    "test_sg.py::test_env_kernel_matches_numpy",
    "test_sphwavelet.py::test_triple_product_kernel_matches_numpy",
    "test_d2i.py::test_bounce_tail_extrapolation_matches_iterating_to_convergence",
    "test_sg_render.py::test_visibility_kernel_reads_the_sources_table_when_the_map_turns_about_y",
)


def run_all(folder: Path, work: Path) -> None:
    import pytest

    from pipeline import job
    from pipeline.device import bandwidth, bvh
    from pipeline.scene.edits import with_light_offset, with_material_edits

    with capturing(folder):
        bandwidth.probe(megabytes=1, repeats=1)
        sc = tiny_scene(work, "d2i")
        wd = job.workdir_for(sc, work / "d2i" / "w")
        job.bake(sc, wd, quiet=True)
        job.render_frame(sc, wd, "direct")
        for layout in ("cpu", "gpu"):
            render = job.frame_renderer(sc, wd, "d2i", {"layout": layout, "shadows": "device"})
            render.frame(sc)
            render.frame(with_light_offset(sc, 0, (0.1, 0.0, 0.0)))
            render.frame(with_material_edits(sc, ["shiny.gamma=50"]))
            # the BRDF-edit mode re-shades the edited material's pixels alone
            render.edit_mode("gamma", sc)(with_material_edits(sc, ["shiny.gamma=50"]))
        geometry, _ = job.load_geometry(sc, wd)
        rays = np.random.default_rng(0).normal(size=(64, 3))
        bvh.occluded(bvh.Bvh.build(geometry["vertices"], geometry["faces"]),
                     np.tile([0.0, 1.0, 0.0], (64, 1)), rays, np.ones(64))
        bvh.closest(bvh.Bvh.build(geometry["vertices"], geometry["faces"]),
                    np.tile([0.0, 1.0, 0.0], (64, 1)), rays)
        for name in ("sg", "triple"):
            sc = tiny_scene(work, name)
            wd = job.workdir_for(sc, work / name / "w")
            job.bake(sc, wd, quiet=True)
            job.render_frame(sc, wd, name)  # sg: sg_shade_visibility (the default)
        sg_scene = tiny_scene(work, "sg")
        sg_work = job.workdir_for(sg_scene, work / "sg" / "w")
        job.bake(sg_scene, sg_work, quiet=True, options={"normal": "vertex"})  # the lobes
        for normal in ("vertex", "pixel", "ratio"):  # sg_shade: plain, PIXEL_NORMAL = 1,
            job.render_frame(sg_scene, sg_work, "sg", {"normal": normal})  # BRDF_RATIO = 1
        job.render_frame(sc, wd, "triple", {"budget": 16})
        job.render_frame(sc, wd, "triple", {"budget": 0})  # the stored rows: sparse path
        code = pytest.main(["-q", "-p", "no:cacheprovider",
                            *(str(TESTS / t) for t in TESTS_OF_TEST_KERNELS)])
        if code != 0:
            raise SystemExit(f"the kernel tests failed while recorded (exit {code})")


if __name__ == "__main__":
    out = Path(sys.argv[1])
    run_all(out, out.parent / "work")

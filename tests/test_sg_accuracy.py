"""Method sg end to end against the reference path tracer (decisions 0039, 0042, 0046): a
coarse glossy ball baked and rendered, its glossy light compared with ``prt reference --transport
first-glossy --lobe glossy`` on the same scene.

The scene: an icosphere of 42 vertices (1 subdivision: neighbouring vertex normals 32°
apart), Blinn–Phong γ 120 (the lobe σ ≈ 7.4° about the half vector, ≈ 15° about the
mirror direction), under a dim sky with two small bright sources (normalised SGs of
σ 4°), seen at 32² so that a face spans several pixels: the highlight's place inside a
face is what the pixel's normal decides. The fit grid is the default 55 × 110 (the
lobe needs it); no indirect light (nothing to occlude)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import write_scene

from pipeline import job
from pipeline.evaluation import metrics, reference_cache
from pipeline.evaluation.reference import ReferenceSettings
from pipeline.images import write_exr
from pipeline.math import sg
from pipeline.scene.file import load_scene

SIZE, SPP = 32, 1024


def ball_scene(folder):
    d, _ = sg.latlong_directions(64, 128)
    rgb = np.full((64, 128, 3), 0.1) + 0.1 * (d[..., 1:2] > 0)
    for centre, power in (([0.5, 0.6, 0.6], [30, 25, 20]), ([-0.7, 0.3, 0.4], [10, 14, 20])):
        centre = np.asarray(centre) / np.linalg.norm(centre)
        rgb += np.asarray(power) * sg.evaluate(d, centre, 1 / np.radians(4.0) ** 2)[..., None]
    write_exr(folder / "env.exr", rgb.astype(np.float32))
    doc = {"format": "prt-scene/1", "name": "ball", "methods": ["sg"],
           "camera": {"position": [0, 0, 2.2], "look_at": [0, 0, 0], "up": [0, 1, 0],
                      "fov": 40, "width": SIZE, "height": SIZE},
           "materials": {"shiny": {"model": "blinn_phong", "albedo": [0.2, 0.3, 0.4],
                                   "specular": 0.15, "gamma": 120}},
           "objects": {"ball": {"primitive": {"type": "sphere", "radius": 0.6,
                                              "subdivisions": 1}, "material": "shiny"}},
           "lights": [{"type": "environment", "file": str(folder / "env.exr")}],
           "settings": {"sg.indirect_samples": 0, "sg.diffuse_samples": 64,
                        "sg.diffuse_order": 3}}
    return load_scene(write_scene(folder, doc))


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sg_ball")
    scene = ball_scene(folder)
    workdir = job.workdir_for(scene, folder / "w")
    for normal in ("vertex", "visibility"):  # the fitted lobes, and the default's maps
        job.bake(scene, workdir, quiet=True, options={"normal": normal})
    reference = reference_cache.reference(scene, workdir, ReferenceSettings(
        "first-glossy", tolerance=0.0, min_spp=SPP, max_spp=SPP, lobe="glossy"),
        quiet=True).image
    return scene, workdir, reference


def test_glossy_light_is_within_its_measured_error_of_the_path_tracer(ball):
    """sg's glossy image against the first-glossy glossy reference at 1024 paths per
    pixel, over the ball's pixels. Measured (Intel and PoCL alike): 23.5 % relative
    RMSE with the lobes as fitted at the vertices (the default, ``normal=vertex``),
    17.2 % with each vertex's lobes turned towards the pixel's normal
    (``normal=pixel``, decision 0039: on this coarse, unoccluded ball the highlight's
    place inside a face is most of the error); the reference's own estimated noise is
    4.0 % (it adds in quadrature: 23.2 % and 16.7 % are sg's), the glossy mean ratio
    0.82 / 0.86 (the one-lobe fit's bias, decision 0037). Bounded at 26 % and 20 %:
    the measured errors plus room for the reference's seed-fixed noise and float32
    differences between devices (1e-4 of a pixel), and the turn must keep at least
    3 points of its 6.3-point gain: reverting it (pixel = vertex) fails. With the BRDF at
    the pixel's normal and the vertices' lobes as a visibility ratio (``normal=ratio``,
    decision 0042) 8.0 % (mean ratio 0.96; sg's own part ≈ 6.9 % beside the 4.0 %
    noise): bounded at 11 % (the same room, 3 points), and it must beat the turn by 5 of
    its 9.2 points: ``ratio`` rendering as ``vertex`` or ``pixel`` fails. With no lobes,
    the BRDF at the pixel's normal against the vertices' visibility maps
    (``normal=visibility``, the default since decision 0046) 4.4 % (mean ratio 0.98: at
    the reference's own noise): bounded at 7.5 % (the same room) and it must beat the
    ratio by 2 of its 3.6 points."""
    scene, workdir, reference = ball
    surface = reference.mean.sum(axis=-1) > 0
    assert surface.sum() > 300 and reference.estimate < 0.05
    error = {}
    for normal in ("vertex", "pixel", "ratio", "visibility"):
        frame = job.render_frame(scene, workdir, "sg",
                                 {"component": "glossy", "normal": normal}).rgb
        error[normal] = metrics.relative_rmse(frame, reference.mean, surface)
    assert error["vertex"] < 0.26, error
    assert error["pixel"] < 0.20, error
    assert error["vertex"] > error["pixel"] + 0.03, error
    assert error["ratio"] < 0.11, error
    assert error["pixel"] > error["ratio"] + 0.05, error
    assert error["visibility"] < 0.075, error
    assert error["ratio"] > error["visibility"] + 0.02, error
    default = job.render_frame(scene, workdir, "sg", {"component": "glossy"}).rgb
    assert metrics.relative_rmse(default, reference.mean, surface) == \
        pytest.approx(error["visibility"], abs=1e-9)

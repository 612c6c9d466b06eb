"""Method sg's bright sources seen as the map turns (decision 0049;
pipeline/methods/sg/source_rings.py and stage sg.source_visibility): the circular
correlation, the quadrature against Monte Carlo over the source's Gaussian, the table's
reading between turns, and the stage on a scene with a cast shadow. The kernel reading
the table against its twin: tests/test_sg_render.py."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import write_scene

from pipeline import job
from pipeline.engine.store import open_artifact
from pipeline.images import write_exr
from pipeline.math import sg
from pipeline.methods.sg import source_rings
from pipeline.methods.sg.vertex_scene import VertexScene
from pipeline.scene.file import load_scene


def gaussian_samples(mu: np.ndarray, sharpness: float, n: int, seed: int) -> np.ndarray:
    """n directions (n, 3) drawn from the normalised spherical Gaussian about unit ``mu``
    (von Mises–Fisher: cos θ by inversion)."""
    rng = np.random.default_rng(seed)
    u, v = rng.random(n), rng.random(n)
    c = 1.0 + np.log(u + (1.0 - u) * np.exp(-2.0 * sharpness)) / sharpness
    s = np.sqrt(np.maximum(0.0, 1.0 - c * c))
    t = np.cross(mu, [0.0, 1.0, 0.0] if abs(mu[1]) < 0.9 else [1.0, 0.0, 0.0])
    t /= np.linalg.norm(t)
    b = np.cross(mu, t)
    phi = 2.0 * np.pi * v
    return c[:, None] * mu + s[:, None] * (np.cos(phi)[:, None] * t
                                           + np.sin(phi)[:, None] * b)


def test_correlate_is_the_circular_sum():
    """The FFT correlation equals Σ_i Σ_k w[i, k] V[p, i, (t + k) mod N] summed directly
    (1e-12: float64 FFT rounding on values ≤ 1)."""
    rng = np.random.default_rng(1)
    visible = rng.random((3, 4, 11)) < 0.5
    weights = rng.random((4, 11))
    weights /= weights.sum()
    want = np.array([[sum(weights[i, k] * visible[p, i, (t + k) % 11]
                          for i in range(4) for k in range(11)) for t in range(11)]
                     for p in range(3)])
    np.testing.assert_allclose(source_rings.correlate(visible, weights), want, atol=1e-12)


@pytest.mark.parametrize("sigma, elevation", [(0.03, 0.4), (0.08, 0.4), (0.1, 1.45),
                                              (0.2, -0.3)])
def test_ring_quadrature_matches_the_sources_gaussian(sigma, elevation):
    """What a half-space (ω·a > 0.05, its edge crossing the source's circle) lets through
    of a source, tabulated over a turn at the default step (σ/2), against 200k directions
    drawn from the source's Gaussian at each of 40 turns. The table's rays are a midpoint
    rule on a grid σ/2 apart: where the edge cuts the Gaussian a row's share is off by up
    to its cell's half, ≈ 1 % of the whole (measured 1.0–1.5 %); Monte Carlo adds ≤ 0.3 %
    (4 standard errors at 200k). Bound 2.5 %. Includes a source 5° from the pole (its
    rows cross it) and one below the horizon."""
    d = np.array([np.cos(elevation), np.sin(elevation), 0.0])
    sharpness = 1.0 / sigma ** 2
    rows, weights, count = source_rings.ring_rows(d, sharpness, 0.5)
    assert weights.sum() == pytest.approx(1.0)
    a = np.array([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0])
    visible = source_rings.ring_directions(rows, count) @ a > 0.05
    table = source_rings.correlate(visible[None], weights)[0]
    errors = []
    for t in range(0, count, max(1, count // 40)):
        mu = source_rings.turn(np.array(360.0 * t / count)) @ d
        drawn = gaussian_samples(mu, sharpness, 200_000, seed=t)
        errors.append(table[t] - np.mean(drawn @ a > 0.05))
    assert np.ptp(table) > 0.3  # the edge crosses the source as the map turns
    assert np.max(np.abs(errors)) < 0.025, np.max(np.abs(errors))


def test_at_turn_reads_columns_and_between_them():
    """Source 0 has 4 columns, source 1 has 3. At 90° source 0 reads its column 1; source 1
    sits 3/4 of the way from its column 0 to 1. At 315° (and 2 turns later) source 0 is
    halfway from its last column back to its first, source 1 5/8 of the way from its
    last to its first."""
    table = np.array([[0, 255, 51, 102, 10, 20, 30]], np.uint8)
    offsets = np.array([0, 4, 7])
    np.testing.assert_allclose(source_rings.at_turn(table, offsets, slice(None), 90.0),
                               [[1.0, (0.25 * 10 + 0.75 * 20) / 255]])
    for degrees in (315.0, 315.0 + 720.0):
        np.testing.assert_allclose(
            source_rings.at_turn(table, offsets, slice(None), degrees),
            [[(102 + 0) / 2 / 255, (0.375 * 30 + 0.625 * 10) / 255]])


def shadow_scene(folder):
    """A ball above a ground, under a dim sky and one bright spot 50° up (σ 4°)."""
    d, _ = sg.latlong_directions(128, 256)
    rgb = np.full((128, 256, 3), 0.05)
    spot = np.array([0.6, np.sin(np.radians(50.0)), 0.2])
    spot /= np.linalg.norm(spot)
    rgb += 400.0 * sg.evaluate(d, spot, 1.0 / np.radians(4.0) ** 2)[..., None]
    write_exr(folder / "env.exr", rgb.astype(np.float32))
    doc = {"format": "prt-scene/1", "name": "shadow", "methods": ["sg"],
           "camera": {"position": [0, 2.5, 3.0], "look_at": [0, 0, 0], "up": [0, 1, 0],
                      "fov": 40, "width": 32, "height": 32},
           "materials": {"grey": {"model": "lambert", "albedo": [0.5, 0.5, 0.5]}},
           "objects": {"ball": {"primitive": {"type": "sphere", "radius": 0.35,
                                              "subdivisions": 2},
                                "transform": {"translate": [0, 0.6, 0]}, "material": "grey"},
                       "ground": {"primitive": {"type": "plane", "size": [3, 3],
                                                "segments": 12}, "material": "grey"}},
           "lights": [{"type": "environment", "file": str(folder / "env.exr")}],
           "settings": {"sg.diffuse_samples": 64, "sg.diffuse_order": 3,
                        "sg.visibility_resolution": 8}}
    return load_scene(write_scene(folder, doc))


def test_the_stage_tabulates_the_shadow_the_source_casts(tmp_path):
    """sg.source_visibility on a ball above a ground: the map has one source; at 8 turns
    each vertex's value is what 4096 rays drawn from the source's Gaussian (turned) see
    past the scene from the same origin (VertexScene's rays). Tolerance: the quadrature's
    2.5 % (test above) + 4 standard errors of 4096 draws (≤ 3.1 %) + the table's rounding
    to /255 and linear reading between turns ≤ 0.5 %: 6 %. Some ground vertices are in
    the ball's shadow at some turns and not at others (the table sees the shadow move)."""
    scene = shadow_scene(tmp_path)
    workdir = job.workdir_for(scene, tmp_path / "w")
    job.bake(scene, workdir, until=("sg.source_visibility",), quiet=True)
    stages = job.stages().stages
    art = open_artifact(workdir.artifact("sg.source_visibility"),
                        stages["sg.source_visibility"].output)
    table, offsets = np.asarray(art.read("table")), np.asarray(art.read("offsets"))
    prefiltered = open_artifact(workdir.artifact("sg.env_prefilter"),
                                stages["sg.env_prefilter"].output)
    sources = np.asarray(prefiltered.read("sources"), np.float64)
    assert len(sources) == 1 and offsets.tolist() == [0, table.shape[1]]
    geometry = open_artifact(workdir.artifact("geometry"), stages["geometry"].output)
    vertex_scene = VertexScene.from_arrays(
        {name: geometry.read(name) for name in ("vertices", "normals", "faces",
                                                 "object_ranges", "object_material")}, [])
    origins = vertex_scene.positions + vertex_scene.offset * vertex_scene.normals
    turns = np.arange(8) * 45.0 + 10.0
    got = np.stack([source_rings.at_turn(table, offsets, slice(None), t)[:, 0]
                    for t in turns])
    want = np.empty_like(got)
    for i, t in enumerate(turns):
        drawn = gaussian_samples(source_rings.turn(np.array(t)) @ sources[0, :3],
                                 float(sources[0, 6]), 4096, seed=i)
        hits = vertex_scene.intersect(np.repeat(origins, len(drawn), axis=0),
                                      np.tile(drawn, (len(origins), 1)))
        want[i] = (hits.prim < 0).reshape(len(origins), len(drawn)).mean(axis=1)
    assert np.abs(got - want).max() < 0.06, np.abs(got - want).max()
    moving = (want.max(axis=0) > 0.9) & (want.min(axis=0) < 0.1)
    assert moving.sum() >= 5, moving.sum()

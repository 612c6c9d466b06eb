"""Method sg's fit stage (pipeline/methods/sg/stages/fit.py) and its parts: the support-cap fast
path (pipeline/methods/sg/support.py), lobe correspondence, flips and relaxation
(pipeline/methods/sg/coherence.py), N from the tolerance, the stage on a tiny scene."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import small_scene_dict, write_scene
from test_sg import sg_lights_map
from test_sg_fit import DIRECTIONS, SOLID_ANGLES, random_lobes, tabulate

from pipeline import job
from pipeline.engine.runner import run
from pipeline.engine.store import Workdir, open_artifact
from pipeline.images import write_exr
from pipeline.math import sg
from pipeline.methods.sg import coherence as sg_coherence
from pipeline.methods.sg import fit as sg_fit
from pipeline.methods.sg import support as sg_support
from pipeline.methods.sg.stages import fit as stage
from pipeline.methods.sg.transport import view_directions
from pipeline.scene.file import load_scene


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=-1), -1, 1)))


@pytest.mark.parametrize("n", [1, 2, 3])
def test_support_path_recovers_known_gaussians(n):
    """Planted lobes (σ 8–20°, ≥ 50° apart, 1 % multiplicative noise) on the 33 × 64
    grid: the fit on each function's cap finds the means within 1° and σ within 5 %
    (the issue's bar; measured ≤ 0.3° and 1.2 %), and its whole-grid error is the
    whole-grid fit's within 1 % (what the cap leaves out adds ≤ √1e-4 = 1 % relative;
    measured ratio ≤ 1.0001)."""
    mean, sigma, weight = random_lobes(12, n, seed=10 + n)
    values = tabulate(mean, sigma, weight)
    values *= 1 + 0.01 * np.random.default_rng(n).normal(size=values.shape)
    options = sg_fit.FitOptions(lobes=n)
    fast, size = sg_support.fit(DIRECTIONS, SOLID_ANGLES, values, options)
    if n == 1:  # one lobe: the cap is a small part of the sphere (lobes ≥ 50° apart
        assert np.median(size) < len(DIRECTIONS) / 4  # share a cap around the highest)
    for f in range(len(values)):
        # match lobes by mean (the fit's slot order is its own)
        cost = sg_coherence.match_cost(mean[f], fast.mean[f])
        perm = sg_coherence.permutations(n)[np.argmin(cost)]
        assert angle_deg(mean[f], fast.mean[f, perm]).max() < 1.0
        np.testing.assert_allclose(fast.sigma[f, perm], sigma[f], rtol=0.05)
    whole = sg_fit.fit(DIRECTIONS, SOLID_ANGLES, values, options)
    ratio = (sg_support.relative_error(DIRECTIONS, SOLID_ANGLES, values, fast)
             / sg_support.relative_error(DIRECTIONS, SOLID_ANGLES, values, whole))
    assert ratio.max() < 1.01


def test_relative_errors_match_the_model_image():
    """sg_support.relative_errors (expanded form, float32 grid sums, errors < 0.05
    re-measured directly) against ‖T̃ − T‖ / ‖T‖ formed in float64 on the grid, for two
    sets of weights on the same lobes: data off the model by 0–60 % (errors up to
    ~0.6), an exact copy of the model (error 0: the direct branch), a zero function
    (NaN). Tolerance 1e-4 absolute: float32 sums carry ~1e-6 of ‖T‖², i.e. ≤ 1e-5 of
    error above 0.05."""
    from pipeline.methods.sg.fit import SGFit

    mean, sigma, weight = random_lobes(12, 2, seed=7)
    rng = np.random.default_rng(8)
    model = tabulate(mean, sigma, weight)
    values = model * (1 + rng.uniform(0, 0.6, (12, 1, 1)) * rng.normal(size=model.shape))
    values[4] = model[4]
    values[5] = 0.0
    fit = SGFit(mean, sg.sharpness(sigma), weight, np.zeros(12), np.zeros(12, np.int64),
                np.ones(12, bool))
    scaled = weight * rng.uniform(0.5, 2.0, (12, 1, 3))
    got = sg_support.relative_errors(DIRECTIONS, SOLID_ANGLES, values.astype(np.float32),
                                     fit, [weight, scaled])
    norm = np.sqrt(np.einsum("fsc,fsc,s->f", values, values, SOLID_ANGLES))
    for w, errors in zip((weight, scaled), got, strict=True):
        image = tabulate(mean, sigma, w)
        with np.errstate(invalid="ignore", divide="ignore"):
            want = np.sqrt(np.einsum("fsc,fsc,s->f", image - values, image - values,
                                     SOLID_ANGLES)) / norm
        want[5] = np.nan  # T ≡ 0: no relative error
        np.testing.assert_allclose(errors, want, atol=1e-4)
    assert got[0][4] < 1e-5 and np.isnan(got[0][5]) and np.nanmax(got[0]) > 0.3


def test_cap_holds_all_but_the_allowed_energy():
    """Each cap leaves out at most ``outside_energy`` of ∫‖T‖² (here 1e-4), holds the
    peak, and a zero function's cap is one sample."""
    mean, sigma, weight = random_lobes(10, 2, seed=4)
    values = tabulate(mean, sigma, weight)
    values[3] = 0.0
    inside, top = sg_support.caps(DIRECTIONS, SOLID_ANGLES, values)
    energy = np.sum(values ** 2, axis=2) * SOLID_ANGLES
    outside = np.sum(energy * ~inside, axis=1)
    assert np.all(outside <= 1e-4 * energy.sum(axis=1) + 1e-300)
    assert inside[np.arange(10), top].all() and inside[3].sum() == 1


def test_flips_are_counted_and_relaxation_removes_them():
    """Three vertices in a chain, two lobes 90° apart at every view; the middle vertex
    holds them in swapped slots at every view: both edges flip at every view (2 × 92),
    the views within a vertex do not. The relaxation relabels the middle vertex's slots
    and no flip is left."""
    views = view_directions()
    nbs = sg_coherence.view_neighbours(views)
    assert {len(n) for n in nbs} == {5, 6}
    lobes = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]])
    mean = np.broadcast_to(lobes, (3, 92, 3, 3)).copy()
    mean[1, :, :2] = mean[1, :, 1::-1]
    active = np.ones((3, 92), bool)
    count = np.array([2, 2, 2])
    edges = np.array([[0, 1], [1, 2]])
    before = sg_coherence.count_flips(mean, active, count, edges, nbs)
    assert before["vertex_flips"] == before["vertex_flips_5deg"] == 2 * 92
    assert before["view_flips"] == 0
    perm, sweeps = sg_coherence.relax(mean, active, count, [np.array([1]), np.array([0, 2]),
                                                            np.array([1])], nbs,
                                      np.array([0, 1, 2]), sweeps=4)
    relaxed = np.take_along_axis(mean, perm[..., None], axis=2)
    after = sg_coherence.count_flips(relaxed, active, count, edges, nbs)
    assert after["vertex_flips"] == 0 and after["view_flips"] == 0 and sweeps >= 1


class FakeArtifact:
    """An opened artifact as a stage reads it: ``read`` and ``attrs``."""

    def __init__(self, arrays: dict, attrs: dict | None = None) -> None:
        self.arrays, self.attrs = arrays, attrs or {}

    def read(self, name: str, region: tuple[slice, ...] | None = None) -> np.ndarray:
        return self.arrays[name] if region is None else self.arrays[name][region]


def test_relax_stage_removes_flips_across_batches():
    """sg.relax on a strip of 4 vertices (faces 012, 123) fitted as two batches {0, 1},
    {2, 3} that each hold two lobes 90° apart consistently, but in swapped slots from
    one batch to the other: every edge across the batches (0-2, 1-2, 1-3) flips at
    every view, none inside. After the stage none is left, and each (vertex, view)
    keeps the same lobes (only their slots change), counts and errors untouched."""
    from pipeline.engine.chunk import make_chunk
    from pipeline.engine.stage import ChunkContext
    from pipeline.methods.sg.stages import relax as sg_relax

    views = view_directions()
    lobes = np.zeros((4, 92, 3, 7), np.float32)
    lobes[..., 0:3] = [[0.5], [0.2], [0.0]]                 # weights per slot
    lobes[..., 3:6] = [[1.0, 0, 0], [0, 1.0, 0], [1.0, 0, 0]]
    lobes[..., 6] = [50.0, 20.0, 50.0]
    lobes[2:, :, :2] = lobes[2:, :, 1::-1]                 # the second batch swapped
    count = np.full(4, 2, np.uint8)
    error = np.full((4, 92), 0.1, np.float32)
    geometry = FakeArtifact({"object_ranges": np.array([[0, 4, 0, 2]]),
                             "faces": np.array([[0, 1, 2], [1, 2, 3]])},
                            {"object_names": ["strip"]})
    rows, first = stage.pack_slots(lobes, count.astype(np.int64))
    fit = FakeArtifact({"lobes": rows, "first": first, "count": count, "error": error,
                        "views": views},
                       {"flips_before_relaxation": {}, "flips_after_relaxation": {}})
    ctx = ChunkContext(params={"sg.fit_relaxation_sweeps": 4}, scene={},
                       inputs={"geometry": geometry, "sg.fit": fit},
                       chunk=make_chunk("strip", "object", object="strip", index=0))
    out = sg_relax.run_chunk(ctx)
    assert ctx.meta["flips_before"]["vertex_flips"] == 3 * 92
    assert ctx.meta["flips_after"]["vertex_flips"] == 0
    assert ctx.meta["flips_after"]["view_flips"] == 0
    relaxed = stage.unpack_slots(out["lobes"], out["first"], count.astype(np.int64))
    np.testing.assert_array_equal(out["first"], first)
    np.testing.assert_array_equal(np.sort(relaxed[:, :, :2], axis=2),
                                  np.sort(lobes[:, :, :2], axis=2))
    np.testing.assert_array_equal(out["count"], count)
    np.testing.assert_array_equal(out["error"], error)


def synthetic_transport(second_lobe: bool) -> np.ndarray:
    """T (1, 92, S, 3) of a vertex with normal +y on the 33 × 64 grid: per view above
    the horizon, a lobe of σ 10° at the mirror direction (and, if ``second_lobe``, one
    of σ 12° and half the weight at a fixed direction 70° from +y); zero below the
    horizon."""
    views = view_directions()
    mirror = stage.mirror(views, np.array([[0.0, 1.0, 0.0]]))[0]
    t = sg.evaluate(DIRECTIONS[None], mirror[:, None], sg.sharpness(np.radians(10.0)))
    if second_lobe:
        fixed = np.array([np.sin(np.radians(70)), np.cos(np.radians(70)), 0.0])
        t = t + 0.5 * sg.evaluate(DIRECTIONS, fixed, sg.sharpness(np.radians(12.0)))[None]
    t = t * (views[:, 1] > 0)[:, None]
    return (t[..., None] * [1.0, 0.8, 0.6])[None].astype(np.float32)


def test_n_is_chosen_from_the_tolerance_and_views_below_the_horizon_are_filled():
    """One lobe per view → N = 1 with the mirror directions within 1°; a second, fixed
    lobe → N = 2 (one lobe leaves ≥ 30 % error, above the tolerance 5 %). Views below
    the horizon: w = 0, μ unit, λ > 0, error −1; slots ≥ N: w = 0."""
    views = view_directions()
    view_nbs = sg_coherence.view_neighbours(views)
    cfg = stage.settings({"sg.fit_tolerance": 0.05, "sg.fit_max_lobes": 3,
                          "sg.fit_mean_weight": 0.01, "sg.fit_sigma_weight": 0.01,
                          "sg.fit_spatial_weight": 0.1, "sg.fit_relaxation_sweeps": 2,
                          "sg.fit_match_integral": True})
    normal = np.array([[0.0, 1.0, 0.0]])
    above = views[:, 1] > 0
    for second, expected in ((False, 1), (True, 2)):
        t = synthetic_transport(second)
        lobes = stage.Lobes(1, 92, stage.mirror(views, normal))
        stage.fit_group(lobes, np.array([0]), t, views, view_nbs, [np.array([], np.int64)],
                        np.zeros(1, bool), DIRECTIONS, SOLID_ANGLES, cfg)
        assert lobes.count[0] == expected
        assert np.all(lobes.error[0, above] <= 0.05) and np.all(lobes.error[0, ~above] == -1)
        assert np.all(lobes.weight[0, ~above] == 0) and np.all(lobes.weight[0, :, expected:] == 0)
        np.testing.assert_allclose(np.linalg.norm(lobes.mean[0], axis=-1), 1.0, atol=1e-9)
        assert np.all(lobes.sharpness[0] > 0) and np.isfinite(lobes.sharpness).all()
        if not second:
            mirror = stage.mirror(views, normal)[0]
            assert angle_deg(lobes.mean[0, above, 0], mirror[above]).max() < 1.0


def test_stage_writes_valid_lobes_on_a_tiny_scene(tmp_path):
    """A glossy icosphere (12 vertices) in the open, a second one shut inside a closed
    box, a Lambert floor; grid 9 × 16. The artifact follows the contract: shapes, the 92
    views, unit means, λ > 0, w ≥ 0 and finite everywhere; Lambert vertices and the
    shut-in sphere's (all views occluded) have N = 0, w = 0, error −1; open glossy
    vertices have 1 ≤ N ≤ 3 and errors in [0, 4] (median < 0.5); views below a vertex's horizon have
    w = 0; the flip counts are in the attributes."""
    write_exr(tmp_path / "env.exr", sg_lights_map().astype(np.float32))
    doc = small_scene_dict(8)
    doc["objects"]["ball"]["primitive"]["subdivisions"] = 0
    doc["objects"]["shut"] = {"primitive": {"type": "sphere", "radius": 0.1,
                                            "subdivisions": 0},
                              "transform": {"translate": [-0.6, 0.3, 0.0]},
                              "material": "shiny"}
    doc["lights"] = [{"type": "environment", "file": str(tmp_path / "env.exr")}]
    # no indirect paths: "shut" sits inside the box, whose per-vertex diffuse transfer
    # (its corner vertices see the sky) would leak light into it — the per-vertex
    # limit of paper 003's diffuse light, not what this test is about (an all-occluded
    # vertex gets a defined, empty result)
    doc["settings"] = {"sg.fit_grid": [9, 16], "sg.fit_batch": 64, "sg.indirect_samples": 0}
    scene = load_scene(write_scene(tmp_path, doc))
    run(scene, job.stages(), Workdir(tmp_path / "work"),
        until="sg.fit", progress=False)
    artifact = open_artifact(Workdir(tmp_path / "work").artifact("sg.fit"))
    geometry = open_artifact(Workdir(tmp_path / "work").artifact("geometry"))
    rows, first = artifact.read("lobes"), artifact.read("first")
    count, error = artifact.read("count"), artifact.read("error")
    stored = stage.slot_counts(first, len(rows))
    lobes = stage.unpack_slots(rows, first, stored)
    vertices = len(geometry.read("vertices"))
    assert rows.shape == (stored.sum(), 92, 7) and count.shape == (vertices,)
    np.testing.assert_array_equal(artifact.read("views"), view_directions())
    assert np.isfinite(lobes).all() and np.all(lobes[..., :3] >= 0)
    np.testing.assert_allclose(np.linalg.norm(lobes[..., 3:6], axis=-1), 1.0, atol=1e-5)
    assert np.all(lobes[..., 6] > 0)
    ranges = dict(zip(geometry.attrs["object_names"], geometry.read("object_ranges"),
                      strict=True))
    for name in ("floor", "box", "shut"):
        a, b = ranges[name][:2]
        assert np.all(count[a:b] == 0) and np.all(lobes[a:b, ..., :3] == 0)
        assert np.all(error[a:b] == -1)
        # only the slots a vertex needs: none on Lambert, one w = 0 slot on the glossy,
        # all-occluded "shut"
        assert np.all(stored[a:b] == (1 if name == "shut" else 0))
    a, b = ranges["ball"][:2]
    assert np.all((count[a:b] >= 1) & (count[a:b] <= 3))
    assert np.all(stored[a:b] == count[a:b])
    seen = error[a:b][error[a:b] >= 0]
    # a least-squares fit m of T has ‖m‖ ≤ ‖T‖ and error e ≤ 1; scaled by s ≤ 4 to T's
    # integral (sg.fit_match_integral), ‖sm − T‖ ≤ |s − 1| ‖m‖ + e ‖T‖ ≤ 4 ‖T‖
    assert len(seen) and seen.max() <= 4.0 and np.median(seen) < 0.5
    normals = geometry.read("normals")[a:b]
    below = normals @ view_directions().T <= 0
    assert np.all(lobes[a:b][below][..., :3] == 0)
    for key in ("flips_before_relaxation", "flips_after_relaxation"):
        assert set(artifact.attrs[key]) == {"vertex_flips", "vertex_flips_5deg",
                                            "vertex_pairs", "view_flips", "view_flips_5deg",
                                            "view_pairs"}
    assert artifact.attrs["grid"]["directions"] == 144


def test_vertex_permutation_undoes_a_three_cycle():
    """Three lobes held in cyclically shifted slots (a permutation that is not its own
    inverse) at every view: the permutation found maps them back onto the neighbour's
    slots exactly; a vertex sharing no view gets None."""
    lobes = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]])
    neighbour = np.broadcast_to(lobes, (92, 3, 3))
    own = neighbour[:, [1, 2, 0]]
    shared = np.ones(92, bool)
    best = sg_coherence.vertex_permutation(own, [(neighbour, shared)])
    np.testing.assert_array_equal(own[:, best], neighbour)
    assert sg_coherence.vertex_permutation(own, [(neighbour, ~shared)]) is None

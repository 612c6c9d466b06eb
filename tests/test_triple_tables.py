"""Method triple's lighting and BRDF tables: the OpenCL kernels against their NumPy
twins, the rotation property of the frame grid, stored rows against what they store,
bad environment maps, brute-force quadrature, and which edits re-bake what. Small
settings throughout (leaf level 2, small grids and maps)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline import job
from pipeline.engine.runner import run
from pipeline.engine.store import Workdir, open_artifact
from pipeline.errors import PrtError
from pipeline.images import write_exr
from pipeline.math.brdf import BrdfParams, glossy
from pipeline.math.envmap import LUMINANCE, EnvironmentMap
from pipeline.math.geodesic import geodesic_levels
from pipeline.math.sphwavelet import depth_first_keys, leaf_means, wavelet_basis
from pipeline.methods.triple.brdf_tables import diffuse_leaf_means, glossy_leaf_means
from pipeline.methods.triple.frame_grids import FrameGrid, ViewGrid
from pipeline.methods.triple.light_grid import frame_leaf_means, prefilter
from pipeline.methods.triple.wavelet_rows import from_half, rows_to_dense, select_rows
from pipeline.scene.file import load_scene
from tests.helpers import small_scene_dict, write_scene

LEVEL = 2  # 320 leaves


def _random_map(height: int, width: int, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    rgb = rng.random((height, width, 3)).astype(np.float32)
    rgb[height // 3, width // 5] = [40.0, 30.0, 20.0]  # a small bright source
    return rgb


# ------------------------------------------------------------------------------ kernels


def test_envmap_kernel_matches_environment_map():
    """kernels/envmap.h looks up what EnvironmentMap.radiance does, rotation included.
    Tolerance 1e-4 of the map's largest texel: float32 atan2/acos move a lookup by
    ~1e-6 rad (3e-4 rad at the poles, where acos loses digits), a small fraction of a
    texel here, and the bilinear sums round at ~1e-7."""
    import pyopencl as cl_

    from pipeline.device import cl

    rgb = _random_map(16, 32)
    rng = np.random.default_rng(2)
    d = rng.normal(size=(4000, 3))
    d[:4] = [[0, 1, 0], [0, -1, 0], [0, 0, -1], [1e-7, 0.3, -1]]  # poles, seam
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    rotation = 37.0
    expected = EnvironmentMap(rgb, rotation=rotation).radiance(d)
    out = np.empty((len(d), 3), np.float32)
    a = np.radians(rotation)
    kernel = cl.kernel("envmap_eval.cl", "envmap_eval")
    cl.run(kernel, len(d), cl.read_only_buffer(d.astype(np.float32)), cl.read_only_buffer(rgb),
           np.int32(32), np.int32(16), np.float32(np.cos(a)), np.float32(np.sin(a)),
           np.int32(len(d)), out=out)
    assert cl_ is not None
    np.testing.assert_allclose(out, expected, atol=1e-4 * rgb.max())


@pytest.mark.parametrize("n_psi", [4, 3])
def test_light_kernel_matches_numpy_twin(n_psi):
    """kernels/triple/light_rotations.cl (φ steps as column shifts; for an even n_ψ, ψ + π as
    a leaf permutation) against the twin's leaf means in the grid's own frames (full
    rotations), for grid entries of φ indices 2..4 from the third of φ = 2 to the
    second-last of φ = 4 (a span cut inside its planes, as a chunk's: the kernel
    computes only the entries inside it). Tolerance 1e-5 of the largest texel: float32
    lookups (see above) and a 4-sample weighted sum."""
    from pipeline.methods.triple.stages.light_rotations import kernel_leaf_means

    rgb = _random_map(32, 64)
    grid = FrameGrid(8, 5, n_psi)
    start, end = 2 * 5 * n_psi + 2, 5 * 5 * n_psi - 1
    got = kernel_leaf_means(rgb, grid, start, end, LEVEL, 1)
    frames = grid.frames()[start:end]
    expected = frame_leaf_means(rgb, frames, LEVEL, 1).reshape(got.shape)
    np.testing.assert_allclose(got, expected, atol=1e-5 * rgb.max())


def test_forward_kernel_matches_numpy():
    """kernels/wavelet_forward.cl against WaveletBasis.forward; float32 sums of four
    terms per level: 1e-6 of the largest coefficient."""
    from pipeline.device.sphwavelet_cl import forward

    values = np.random.default_rng(3).random((5, 3, 320))
    expected = wavelet_basis(LEVEL).forward(values)
    np.testing.assert_allclose(forward(values, LEVEL), expected, atol=1e-6 * abs(expected).max())


BRDFS = [BrdfParams("blinn_phong", (0, 0, 0), (1, 1, 1), gamma=40.0),
         BrdfParams("ward", (0, 0, 0), (1, 1, 1), gamma=0.2),
         BrdfParams("ward_duer", (0, 0, 0), (1, 1, 1), gamma=0.25),
         BrdfParams("ward_anisotropic", (0, 0, 0), (1, 1, 1), gamma=0.15, alpha_ratio=3.0),
         BrdfParams("lafortune", (0, 0, 0), (1, 1, 1), gamma=30.0, cxy=-1.0, cz=0.9),
         BrdfParams("cook_torrance", (0, 0, 0), (1, 1, 1), gamma=0.3, f0=0.3),
         BrdfParams("ashikhmin_shirley", (0, 0, 0), (1, 1, 1), gamma=50.0, f0=0.05)]


@pytest.mark.parametrize("params", BRDFS, ids=[p.model for p in BRDFS])
def test_brdf_kernel_matches_numpy_twin(params):
    """kernels/triple/brdf_tables.cl (brdf_glossy of kernels/brdf.h × cos θi) against the
    twin, views from normal to grazing. Tolerance 2e-4 of each view's largest leaf mean:
    brdf.h keeps float32 lobes to a few ulps before the power γ (its docstring); the
    rest is a 4-sample weighted sum."""
    from pipeline.methods.triple.stages.brdf_tables import kernel_leaf_means

    views = ViewGrid(4, 6).directions()
    got = kernel_leaf_means(params, views, LEVEL, 1)
    expected = glossy_leaf_means(params, views, LEVEL, 1)
    scale = np.abs(expected).max(axis=1, keepdims=True)
    assert np.all(np.abs(got - expected) <= 2e-4 * scale + 1e-30)


@pytest.mark.parametrize("params", BRDFS[2:5], ids=[p.model for p in BRDFS[2:5]])
def test_brdf_views_mirrored_from_a_quarter_match_direct_evaluation(params):
    """view_leaf_means (a quarter of the φ_o evaluated, the rest mirrored by leaf
    permutations) equals the kernel run on every view: the same float32 sums on
    permuted samples, so to 1e-6 of each view's largest leaf mean."""
    from pipeline.methods.triple.stages.brdf_tables import (
        kernel_leaf_means,
        sampled_views,
        view_leaf_means,
    )

    grid = ViewGrid(8, 3)
    got = view_leaf_means(params, grid, LEVEL, 1)
    expected = kernel_leaf_means(params, sampled_views(grid), LEVEL, 1)
    scale = np.abs(expected).max(axis=1, keepdims=True)
    assert np.all(np.abs(got - expected) <= 1e-6 * scale + 1e-30)


# ------------------------------------------------------------------- rotation property


def test_one_phi_step_is_the_map_turned_about_the_pole():
    """The leaf means in frame (φ + 2π/n_φ, θ, ψ) equal those in frame (φ, θ, ψ) of the
    map turned by 2π/n_φ about +y: its columns shifted by W/n_φ, and EnvironmentMap's
    own rotation by −2π/n_φ (the renderer's convention: a map rotated by ρ lights frame
    φ as the unrotated map lights φ − ρ). Float64 rounding only."""
    rgb = _random_map(16, 32).astype(np.float64)
    grid = FrameGrid(8, 5, 4)
    frames = grid.frames().reshape(8, 20, 3, 3)
    turned = frame_leaf_means(rgb, frames[3], LEVEL, 1)
    shifted = frame_leaf_means(np.roll(rgb, 32 // 8, axis=1), frames[2], LEVEL, 1)
    np.testing.assert_allclose(turned, shifted, atol=1e-9 * rgb.max())
    env = EnvironmentMap(rgb, rotation=-360.0 / 8)
    rotated = np.stack([leaf_means(lambda d, r=r: env.radiance(d @ r.T).T, LEVEL, 1)
                        for r in frames[2]])
    np.testing.assert_allclose(turned, rotated, atol=1e-9 * rgb.max())


def test_prefilter_keeps_the_mean_and_spreads_a_point_source():
    """The prefiltered map keeps the map's mean radiance over the sphere (a box filter,
    and here a resampling from width 100 to 104, a multiple of n_φ: within 1 %) and
    spreads a one-texel source over the spacing: ≥ 3 × 3 texels."""
    rgb = np.full((50, 100, 3), 0.5, np.float32)
    rgb[20, 40] = 1000.0
    out = prefilter(rgb, spacing=0.2, n_phi=8)
    assert out.shape == (52, 104, 3)  # 100 columns resampled to a multiple of n_φ

    def sphere_mean(m: np.ndarray) -> float:
        theta = np.pi * np.arange(m.shape[0]) / (m.shape[0] - 1)
        w = np.sin(theta)[:, None]
        return float((m[..., 0] * w).sum() / (w.sum() * m.shape[1]))

    assert sphere_mean(out) == pytest.approx(sphere_mean(rgb), rel=0.01)
    assert (out[..., 0] > 0.5 + 0.1 * (out[..., 0].max() - 0.5)).sum() >= 9
    assert prefilter(rgb[:, :96], spacing=0.2, n_phi=8).shape == (50, 96, 3)


# --------------------------------------------------------------------------- selection


def test_select_rows_keeps_the_top_meets_the_tolerance_and_sorts_depth_first():
    rng = np.random.default_rng(4)
    c = rng.normal(size=(6, 3, 320)) * np.exp(-np.arange(320) / 40.0)
    c[0, :, 5] = 0.0  # a zero in the top part is not stored
    rows = select_rows(c, LEVEL, budget=200, tolerance=0.05, keep_first=80,
                       channel_weights=LUMINANCE)
    count, index = rows["count"], rows["index"].astype(np.int64)
    starts = np.concatenate([[0], np.cumsum(count)])
    energy = np.einsum("c,rcn->rn", LUMINANCE, c * c)
    keys = depth_first_keys(LEVEL)
    for r in range(6):
        own = index[starts[r]:starts[r + 1]]
        assert np.all(np.diff(keys[own]) > 0)  # depth-first order, no repeats
        top = set(own[own < 80].tolist())
        assert top == {i for i in range(80) if energy[r, i] > 0}
        dropped = np.setdiff1d(np.arange(320), own)
        assert np.sqrt(energy[r, dropped].sum() / energy[r].sum()) <= 0.05 + 1e-7
        tail = own[own >= 80]  # minimal: without its smallest kept tail entry, too much lost
        smallest = tail[np.argmin(energy[r, tail])]
        lost = energy[r, dropped].sum() + energy[r, smallest]
        assert np.sqrt(lost / energy[r].sum()) > 0.05
    dense = rows_to_dense(count, rows["index"], rows["value"], 320)
    error = np.einsum("c,rcn->r", LUMINANCE, (dense - c) ** 2)
    np.testing.assert_allclose(np.sqrt(error / energy.sum(axis=1)), rows["residual"],
                               rtol=1e-4)
    assert not np.any(index[starts[0]:starts[1]] == 5)

    capped = select_rows(c, LEVEL, budget=90, tolerance=0.0, keep_first=80)
    assert np.all(capped["count"] == 90)


# ------------------------------------------------------------------------------ stages


SETTINGS = {"triple.leaf_level": LEVEL, "triple.frame_grid": [8, 5, 4],
            "triple.light_refine": 1, "triple.light_block": 30, "triple.view_grid": [8, 4],
            "triple.brdf_refine": 2, "triple.store_tolerance": 0.02, "triple.store_budget": 200,
            "triple.light_tolerance": 0.02, "triple.light_budget": 200, "triple.store_top": 80}


def _scene(tmp_path, env: np.ndarray | None = None, name: str = "scene.yaml",
           materials: dict | None = None, env_name: str = "env.exr", **light):
    doc = small_scene_dict(8)
    if env is not None:
        write_exr(tmp_path / env_name, env)
    doc["lights"] = [{"type": "environment", "file": str(tmp_path / env_name), **light}]
    doc["settings"] = dict(SETTINGS)
    doc["materials"]["satin"] = {"model": "ward", "albedo": [0.3, 0.3, 0.3],
                                 "specular": 0.2, "gamma": 0.3}
    doc["objects"]["box"]["material"] = "satin"
    for material, values in (materials or {}).items():
        doc["materials"][material].update(values)
    return load_scene(write_scene(tmp_path, doc, name))


def _runs(scene, workdir, stage):
    return {r.name: r for r in run(scene, job.stages(), workdir, until=stage,
                                   progress=False)}


def test_stored_lighting_rows_reconstruct_leaf_means_within_their_residual(tmp_path):
    """Every stored row, expanded, is the twin's leaf means of the prefiltered map in
    that grid frame to within its stored residual (luminance-weighted relative L2;
    + 1e-5 for the float32 kernel); blocks of 30 rows cut φ slices of 20 rows."""
    from pipeline.methods.triple.stages.light_rotations import prefiltered_map

    rgb = _random_map(32, 64)
    scene = _scene(tmp_path, rgb)
    workdir = Workdir(tmp_path / "w")
    _runs(scene, workdir, "triple.light_rotations")
    art = open_artifact(workdir.artifact("triple.light_rotations"))
    count, residual = art.read("count"), art.read("residual")
    assert len(count) == 160 and art.attrs["frame_grid"] == [8, 5, 4]
    value = from_half(count, art.read("value"), art.read("scale"))
    dense = rows_to_dense(count, art.read("index"), value, 320)
    got = wavelet_basis(LEVEL).inverse(dense)
    params = {**SETTINGS}
    expected = frame_leaf_means(prefiltered_map(rgb, params), FrameGrid(8, 5, 4).frames(),
                                LEVEL, 1)
    areas = geodesic_levels(LEVEL)[LEVEL].areas
    error = np.einsum("c,rcn,n->r", LUMINANCE, (got - expected) ** 2, areas)
    norm = np.einsum("c,rcn,n->r", LUMINANCE, expected ** 2, areas)
    # float16 values: each within 2^-11 of itself, so a row within 2^-11 more (to_half)
    assert np.all(np.sqrt(error / norm) <= residual + 2.0 ** -11 + 1e-5)
    assert residual.max() <= 0.02 + 1e-6 or count.max() == 200


@pytest.mark.parametrize("problem", ["nan", "inf", "negative", "shape"])
def test_bad_environment_map_is_a_one_line_error_naming_the_file(tmp_path, problem):
    rgb = np.ones((8, 16, 3), np.float32)
    if problem == "shape":
        rgb = np.ones((8, 8, 3), np.float32)
    else:
        rgb[3, 5, 1] = {"nan": np.nan, "inf": np.inf, "negative": -1.0}[problem]
    scene = _scene(tmp_path, rgb)
    with pytest.raises(PrtError) as info:
        _runs(scene, Workdir(tmp_path / "w"), "triple.light_rotations")
    message = str(info.value)
    assert str(tmp_path / "env.exr") in message and "\n" not in message
    assert ("twice as wide" if problem == "shape" else "(x 5, y 3)") in message


def _brute_force_leaf_means(f, leaves: np.ndarray, level: int, refine: int) -> np.ndarray:
    """Means of f over the given leaves by the solid-angle-weighted centroid rule on
    their 4^refine sub-triangles (exact solid angles)."""
    fine = geodesic_levels(level + refine)[-1]
    per = 4 ** refine
    picks = (leaves[:, None] * per + np.arange(per)).reshape(-1)
    values = f(fine.centroids[picks]).reshape(*f(fine.centroids[:1]).shape[:-1], -1, per)
    w = fine.areas[picks].reshape(-1, per)
    return np.einsum("...nk,nk->...n", values, w) / w.sum(axis=1)


def test_brdf_table_against_brute_force_quadrature(tmp_path):
    """The stored table of a Blinn-Phong material (γ 20), expanded, against brute-force
    quadrature of f_g cos θi (4^6 = 4096 points per leaf) on the leaves where it is
    largest and on grazing ones. The stage samples 4^2 points per leaf: the error is
    the rule's (≤ 3 % of the view's largest leaf mean at this γ and leaf size) plus
    the stored truncation (tolerance 0.02, relative L2)."""
    scene = _scene(tmp_path, np.ones((8, 16, 3), np.float32),
                   materials={"shiny": {"gamma": 20}})
    workdir = Workdir(tmp_path / "w")
    _runs(scene, workdir, "triple.brdf_tables")
    art = open_artifact(workdir.artifact("triple.brdf_tables"))
    names, start = art.attrs["material_names"], art.attrs["row_start"]
    m = names.index("shiny")
    count = art.read("count")
    value = from_half(count, art.read("value"), art.read("scale"))
    dense = rows_to_dense(count, art.read("index"), value, 320)[:, 0]
    table = wavelet_basis(LEVEL).inverse(dense[start[m]:start[m + 1]])
    from pipeline.methods.triple.stages.brdf_tables import sampled_views

    views = sampled_views(ViewGrid(8, 4))  # the grazing row half a θ step inside
    assert table.shape == (1 + len(views), 320)
    params = BrdfParams("blinn_phong", (0, 0, 0), (1, 1, 1), gamma=20.0)
    centroids = geodesic_levels(LEVEL)[LEVEL].centroids
    for v in (0, 2, len(views) - 1):  # normal, oblique and grazing views
        row = table[1 + v]
        leaves = np.concatenate([np.argsort(-row)[:4], np.argsort(np.abs(centroids[:, 2]))[:2]])

        def f(wi, wo=views[v]):
            return glossy(wi, wo[None], params) * np.maximum(wi[:, 2], 0.0)

        exact = _brute_force_leaf_means(f, leaves, LEVEL, 6)
        assert np.all(np.abs(row[leaves] - exact) <= 0.03 * row.max())
    areas = geodesic_levels(LEVEL)[LEVEL].areas
    expected = diffuse_leaf_means(LEVEL, 2)  # the diffuse row: within its stored residual
    error = np.sqrt(np.sum(areas * (table[0] - expected) ** 2) / np.sum(areas * expected ** 2))
    assert error <= art.read("residual")[start[m]] + 2.0 ** -11 + 1e-6  # + float16
    lambert = names.index("grey")
    assert start[lambert + 1] - start[lambert] == 1  # a Lambertian material: diffuse only


def test_material_edits_rebake_only_the_table_they_shape(tmp_path):
    """Albedo and ρs edits re-bake no table; a γ edit re-bakes that material's only;
    the map's rotation and scale re-bake no lighting, its bytes do."""
    rgb = _random_map(8, 16)
    workdir = Workdir(tmp_path / "w")
    first = _runs(_scene(tmp_path, rgb), workdir, "triple.brdf_tables")
    assert sorted(first["triple.brdf_tables"].ran_chunks) == ["grey", "red", "satin", "shiny"]
    _runs(_scene(tmp_path, rgb), workdir, "triple.light_rotations")

    edited = _scene(tmp_path, None, "a.yaml", materials={
        "shiny": {"albedo": [0.1, 0.1, 0.1], "specular": 0.2},
        "satin": {"albedo": [0.5, 0.2, 0.2]}}, rotation=45.0, scale=2.0)
    assert _runs(edited, workdir, "triple.brdf_tables")["triple.brdf_tables"].action == "skipped"
    assert _runs(edited, workdir,
                 "triple.light_rotations")["triple.light_rotations"].action == "skipped"

    gamma = _scene(tmp_path, None, "g.yaml", materials={"shiny": {"gamma": 80}})
    assert _runs(gamma, workdir, "triple.brdf_tables")["triple.brdf_tables"].ran_chunks \
        == ["shiny"]

    rgb[2, 3] += 1.0  # the map's bytes change
    changed = _scene(tmp_path, rgb, "m.yaml")
    report = _runs(changed, workdir, "triple.light_rotations")["triple.light_rotations"]
    assert report.action == "ran" and len(report.ran_chunks) == 6  # 160 rows in blocks of 30


def test_select_rows_with_every_index_forced_keeps_every_non_zero():
    """keep_first = N (a leaf level whose 20·4^L coefficients all lie below store_top):
    nothing is left to choose, every non-zero coefficient is stored whatever the
    budget, and the residual is 0."""
    size = 20 * 4 ** 2
    c = np.random.default_rng(3).normal(size=(4, 1, size))
    c[:, :, ::7] = 0.0
    rows = select_rows(c, 2, budget=10, tolerance=0.5, keep_first=size)
    assert np.array_equal(rows["count"], np.count_nonzero(c[:, 0], axis=1))
    assert np.all(rows["residual"] == 0.0)

"""Method triple's device lookups from a G-buffer and the dense top-only path
(kernels/triple/triple_lookup.h, kernels/triple/triple.cl; pipeline/methods/triple/gbuffer.py,
triple_dense.py), against their NumPy twins, with synthetic inputs: random shading
frames (as a bump map gives them, independent of any geometry), two-material blends,
texels left empty."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_triple_render import LEVEL, random_rows, synthetic_tables

from pipeline.device import cl
from pipeline.math.envmap import EnvironmentMap
from pipeline.math.geodesic import geodesic_levels
from pipeline.methods.triple.dense import (
    DenseTables,
    dense_level,
    kept_triangles,
    shade_dense_numpy,
)
from pipeline.methods.triple.gbuffer import (
    GBuffer,
    LookupTables,
    device_lookups,
    lookups_numpy,
    read_lookups,
)
from pipeline.methods.triple.render import shade_gbuffer, shade_numpy
from pipeline.methods.triple.tables import Atlas

TURN = 0.7  # radians: an environment rotation that is not a multiple of the grid step


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def synthetic_gbuffer(rng, n: int) -> tuple[GBuffer, Atlas]:
    """``n`` pixels over two objects (textures 5×6 and 4×4, 46 texels, every third
    empty, the rest mapped to the synthetic tables' 30 visibility rows); the first four
    normals exactly at the poles (the floor's case); blends 0, 1 and in between."""
    normal = unit(rng.normal(size=(n, 3)))
    normal[:4] = [[0, 1, 0], [0, -1, 0], [0, 1, 0], [0, -1, 0]]
    tangent = unit(np.cross(normal, rng.normal(size=(n, 3))))
    view = unit(rng.normal(size=(n, 3)))  # about half below the shading horizon
    obj = rng.integers(0, 2, size=n)
    size = np.array([[5, 6], [4, 4]])
    texel_xy = rng.uniform(0.0, 1.0, size=(n, 2)) * size[obj][:, ::-1]
    filled = np.arange(46) % 3 != 2
    row = np.where(filled, rng.integers(0, 30, size=46), -1)
    blend = rng.uniform(size=n)
    blend[::5], blend[1::5] = 0.0, 1.0
    gbuffer = GBuffer(8, (n + 7) // 8, np.arange(n), normal, tangent, view, texel_xy, obj,
                      rng.integers(0, 2, size=n), rng.integers(0, 2, size=n), blend,
                      np.zeros(0, np.int64), np.zeros((0, 3)))
    atlas = Atlas(np.zeros((0, 3, 2)), size, np.array([0, 30]), filled, row)
    return gbuffer, atlas


def lookup_tables(tables, atlas) -> LookupTables:
    kd = np.array([[0.3, 0.2, 0.1], [0.5, 0.5, 0.5]])
    rho_s = np.array([[0.1, 0.2, 0.3], [0.7, 0.1, 0.4]])  # b's ρs must not leak in
    return LookupTables.of(tables, atlas, kd, rho_s)


def scattered(rows: np.ndarray, weight: np.ndarray, count: int) -> np.ndarray:
    """Weights summed per (pixel, row): (P, count, ...) — the function a pixel reads,
    whatever order or placeholder rows its zero weights have."""
    out = np.zeros((len(rows), count, *weight.shape[2:]))
    for r in range(rows.shape[1]):
        np.add.at(out, (np.arange(len(rows)), rows[:, r]), weight[:, r])
    return out


def test_device_lookups_match_numpy_twin():
    """Frame, texel and BRDF rows and weights from the G-buffer. Tolerance 1e-4 on the
    weights: the kernel's float32 acos/atan2 move a grid coordinate by ~1e-6 × the grid
    size (≤ 32), so a weight by ~3e-5."""
    rng = np.random.default_rng(5)
    tables = synthetic_tables(rng)
    gbuffer, atlas = synthetic_gbuffer(rng, 200)
    lookup = lookup_tables(tables, atlas)
    expected = lookups_numpy(gbuffer, tables, lookup, TURN)
    buffers, _ = device_lookups(gbuffer, tables, lookup, TURN)
    got = read_lookups(buffers, gbuffer.count)
    for name, count in (("light", tables.light.rows), ("vis", tables.visibility.rows),
                        ("brdf", tables.brdf.rows)):
        a = scattered(getattr(got, f"{name}_rows"), getattr(got, f"{name}_weight"), count)
        b = scattered(getattr(expected, f"{name}_rows"), getattr(expected, f"{name}_weight"),
                      count)
        assert np.abs(a - b).max() < 1e-4, name
    # the twin itself: weights sum to 1 (light, filled texels), empty texels unread,
    # the blend splits ρs between a and b
    assert np.allclose(expected.light_weight.sum(1), 1.0)
    total = expected.vis_weight.sum(1)  # 0 only where all four texels are empty
    assert np.all(np.isclose(total, 1.0) | (total == 0)) and np.mean(total == 1.0) > 0.9
    assert not np.any(expected.vis_weight[lookup.texel_row[0] < 0])
    above = np.sum(gbuffer.view * gbuffer.normal, 1) > 0
    glossy_b = (gbuffer.material_b == 0) & (gbuffer.blend > 0) & above
    assert np.allclose(expected.brdf_weight[glossy_b, 5:].sum(1),
                       gbuffer.blend[glossy_b, None] * lookup.rho_s[0], atol=1e-6)
    assert not np.any(expected.brdf_weight[gbuffer.blend == 0, 5:])
    # a view below the shading horizon reflects nothing (every BRDF is 0 there), as the
    # reference renders it; 80 of the 200 pixels or so
    assert 40 < np.sum(~above) < 160
    assert not np.any(expected.brdf_weight[~above]) and np.all(
        expected.brdf_weight[above, 0] > 0)


def below_horizon_free_brdf(rng, tables):
    """``tables`` with BRDF rows that are zero on every leaf whose centroid lies below
    the local horizon, as real ρ̃ = BRDF × cos θ_i rows are (random above it)."""
    above = geodesic_levels(LEVEL)[LEVEL].centroids[:, 2] > 0
    rows = random_rows(rng, tables.brdf.rows, 1, 10_000, mask=above)
    return dataclasses.replace(tables, brdf=rows)


@pytest.mark.parametrize("horizon", [False, True])
@pytest.mark.parametrize("budget", [20, 50, 80, 320])
def test_dense_top_only_equals_sparse_triple_products(budget, horizon):
    """The dense path (triangle values of the rows cut top-only, lookups on the device)
    against the float64 sparse triple products of the same cut rows. The tables are
    float16 over a scale per row: each factor off by ≤ 2⁻¹² of its row's largest value
    (half an ulp in [½, 1)), so a product by ≤ 3·2⁻¹² of the product of the rows'
    largest values, which on these smooth rows stay within 3× of the values summed:
    the float64 twin of the dense sum within 1e-3 of the largest pixel of the sparse
    sums (measured 1e-4); the kernel against its twin within the lookups' weights
    (above, ≤ 1e-4) and float32 sums over ≤ 320 triangles: 2e-4 of it. With
    random BRDF rows every triangle is kept; with rows zero below the horizon
    (``horizon``) only the triangles above it are (12 / 44 / 168 of 20 / 80 / 320),
    except at budget 50: a cut inside level 1 leaves the rows non-zero below the
    horizon, which the check finds (every triangle kept)."""
    rng = np.random.default_rng(7)
    tables = synthetic_tables(rng)
    if horizon:
        tables = below_horizon_free_brdf(rng, tables)
    tables = tables.truncated("top-only", budget)
    gbuffer, atlas = synthetic_gbuffer(rng, 64)
    lookup = lookup_tables(tables, atlas)
    level = dense_level("top-only", budget)
    assert 20 * 4 ** level >= budget > 20 * 4 ** level // 4
    dense = DenseTables.from_tables(tables, level)
    all_triangles = 20 * 4 ** level
    only_above = horizon and budget == all_triangles
    kept = kept_triangles(LEVEL, level) if only_above else np.arange(all_triangles)
    np.testing.assert_array_equal(dense.kept, kept)
    assert len(kept) == ({0: 12, 1: 44, 2: 168}[level] if only_above else all_triangles)
    rgb, times, moved = shade_gbuffer(tables, dense, gbuffer, lookup, TURN, {})
    host = lookups_numpy(gbuffer, tables, lookup, TURN)
    pixels = np.arange(0, 64, 3)
    expected = shade_numpy(tables, host, pixels)
    scale = np.abs(expected).max()
    assert scale > 1.0 and moved > 0 and times["kernel_ms"] >= 0.0
    twin = shade_dense_numpy(dense, host)[pixels]
    assert np.allclose(twin, expected, rtol=0, atol=1e-3 * scale)
    assert np.allclose(rgb[pixels], twin, rtol=0, atol=2e-4 * scale)


def test_sparse_path_from_the_gbuffer_matches_numpy():
    """The general path (adaptive rows, lookups through memory) against the twin;
    tolerance as the dense test's."""
    rng = np.random.default_rng(9)
    tables = synthetic_tables(rng).truncated("adaptive", 60)
    gbuffer, atlas = synthetic_gbuffer(rng, 48)
    lookup = lookup_tables(tables, atlas)
    rgb, times, _ = shade_gbuffer(tables, None, gbuffer, lookup, TURN, {})
    pixels = np.arange(0, 48, 3)
    expected = shade_numpy(tables, lookups_numpy(gbuffer, tables, lookup, TURN), pixels)
    assert np.abs(expected).max() > 1.0 and times["lookup_ms"] >= 0.0
    assert np.allclose(rgb[pixels], expected, rtol=0, atol=2e-4 * np.abs(expected).max())


def test_dense_level_and_sparse_fallbacks():
    assert [dense_level("top-only", b) for b in (1, 20, 21, 80, 81, 320)] == [0, 0, 1, 1, 2, 2]
    assert dense_level("top-only", 321) is None and dense_level("top-only", 0) is None
    assert dense_level("adaptive", 80) is None


def test_background_kernel_matches_environment_map():
    """triple_background: the map rotated by the turn and scaled, as EnvironmentMap,
    from the G-buffer's per-camera (u, v) of the unrotated map, for turns of either
    sign and past a full turn; float32 bilinear lookups: 1e-4 relative."""
    rng = np.random.default_rng(3)
    rgb = rng.uniform(0.0, 4.0, size=(16, 32, 3)).astype(np.float32)
    d = unit(rng.normal(size=(100, 3))).astype(np.float32)
    gbuffer, _ = synthetic_gbuffer(rng, 4)
    gbuffer = dataclasses.replace(gbuffer, miss=d)
    kernel = cl.kernel("triple.cl", "triple_background", {"SW_LEVELS": 2})
    for degrees in (40.0, -75.0, 400.0):
        out = np.empty((100, 3), np.float32)
        cl.run(kernel, 100, cl.read_only_buffer(rgb), np.int32(32), np.int32(16),
               gbuffer.miss_uv_device, np.float32(np.radians(degrees)), np.float32(1.5),
               np.int32(100), out=out)
        expected = EnvironmentMap(rgb, degrees, 1.5).radiance(d.astype(np.float64))
        assert np.allclose(out, expected, rtol=1e-4, atol=1e-4)


def test_renderer_caches_the_camera_and_follows_gamma_edits(tmp_path):
    """Through the renderer at top-only 80 (the dense path): an environment rotation
    re-traces nothing, a camera move does; a γ edit re-converts the BRDF table, and a
    frame after edits γ 60 → 100 → back equals a fresh renderer's frame of the same scene
    (bit for bit: the same tables and kernels)."""
    from test_triple_method import sky, triple_scene

    from pipeline import job
    from pipeline.registry import get_method
    from pipeline.scene.edits import (
        with_camera_position,
        with_environment_rotation,
        with_material_edits,
    )

    scene = triple_scene(tmp_path, sky(tmp_path / "sky.exr"))
    workdir = job.workdir_for(scene, tmp_path / "w")
    job.bake(scene, workdir, quiet=True, methods=[get_method("triple")])

    def renderer():
        return job.frame_renderer(scene, workdir, "triple", {"budget": 80})

    render = renderer().frame
    first = render(scene)
    turned = render(with_environment_rotation(scene, 45.0))
    assert first.timings["gbuffer_cached"] == 0 and turned.timings["gbuffer_cached"] == 1
    assert turned.timings["angles_ms"] == 0 and first.timings["angles_ms"] > 0
    g60, g100 = (with_material_edits(scene, [f"shiny.gamma={g}"]) for g in (60, 100))
    frames = {name: render(s).rgb for name, s in (("g60", g60), ("g100", g100),
                                                  ("back", scene))}
    assert np.array_equal(frames["back"], first.rgb)
    for name, edited in (("g60", g60), ("g100", g100)):
        fresh = renderer().frame(edited).rgb
        assert np.array_equal(frames[name], fresh), name
        assert np.abs(fresh - first.rgb).max() > 1e-3 * np.abs(first.rgb).max()
    moved = render(with_camera_position(scene, tuple(np.add(scene.camera.position,
                                                            [0.3, 0.0, 0.0]))))
    assert moved.timings["gbuffer_cached"] == 0


def test_surface_kernel_matches_the_numpy_gbuffer(tmp_path):
    """camera_gbuffer (kernel triple_surface, SceneDetail on the floor's pixels) against
    its twin camera_gbuffer_numpy on the tiny scene at 40×32: a floor with a uv bump and
    a blend, the box's flat faces, the ball without uv (the tangent's fallback). The same
    pixels, objects, materials, blends and views exactly; normals and tangents within
    1e-6 (both float32: blends and normalisations differ by a few ulp of 1 where the
    kernel fuses multiply-adds); texel coordinates within 1e-6 × the texture's 64 texels
    (float32 interpolation against float64 rounded to float32)."""
    from test_surface_detail import detail_scene, png

    from pipeline import job
    from pipeline.device.raytrace import Mesh, RayTracer
    from pipeline.engine.store import open_artifact
    from pipeline.methods.triple.render import camera_gbuffer, camera_gbuffer_numpy
    from pipeline.render.surface_detail import SceneDetail
    from pipeline.scene.edits import with_camera_position

    png(tmp_path / "ramp.png", np.tile(np.arange(16) / 15, (4, 1)))
    scene = detail_scene(tmp_path, bump={"texture": "ramp.png", "height": 0.3,
                                         "projection": "uv", "scale": 3.0},
                         blend={"material": "shiny", "texture": "ramp.png",
                                "projection": "xz", "scale": 0.7})
    scene = scene.with_image_size(40, 32)
    workdir = job.workdir_for(scene, tmp_path / "w")
    job.bake(scene, workdir, quiet=True, until="geometry", jobs=1)
    geo = open_artifact(workdir.artifact("geometry"))
    arrays = {n: geo.read(n) for n in
              ("vertices", "normals", "uv", "faces", "face_object", "object_material")}
    mesh = Mesh.from_arrays(arrays)
    rng = np.random.default_rng(3)
    atlas = Atlas(rng.uniform(0.0, 64.0, size=(len(mesh.faces), 3, 2)), np.array([[64, 64]]),
                  np.array([0]), np.ones(4096, bool), np.arange(4096))
    tracer = RayTracer(arrays["vertices"], arrays["faces"])
    detail = SceneDetail(scene, geo.attrs["material_names"])
    for position in (scene.camera.position, (0.5, 1.0, -4.0)):  # behind: normals' z < 0
        cam = with_camera_position(scene, position).camera
        got = camera_gbuffer(tracer, mesh, atlas, detail, cam)
        expected = camera_gbuffer_numpy(tracer, mesh, atlas, detail, cam)
        assert len(set(expected.object.tolist())) == 3 and len(expected.miss_pixel)
        assert expected.blend.max() > 0.0 and (expected.normal[:, 2] < -0.5).any() == \
            (position[2] < 0)
        for name in ("pixel", "object", "material_a", "material_b", "blend", "view",
                     "miss_pixel", "miss"):
            assert np.array_equal(getattr(got, name), getattr(expected, name)), name
        for name, tolerance in (("normal", 1e-6), ("tangent", 1e-6), ("texel_xy", 64e-6)):
            error = np.abs(getattr(got, name) - getattr(expected, name)).max()
            assert error <= tolerance, (name, error)
        bumped = np.abs(expected.normal - [0.0, 1.0, 0.0]).max(axis=1) > 1e-3
        assert (bumped & (expected.object == 0)).any()  # the bump turned floor normals


def test_camera_rays_traced_on_the_device_give_embrees_frame(tmp_path):
    """``--option trace=device`` (the BVH kernel) against ``trace=embree``: the same
    faces at every pixel but rays through an edge between two faces (a tie either may
    take: ≤ 1 % of the pixels, a neighbouring face's attributes there), so the frames
    agree elsewhere to float32 rounding of the two intersection formulas (barycentrics
    within 1e-3: 1e-3 of the largest value)."""
    from test_triple_method import sky, triple_scene

    from pipeline import job
    from pipeline.device.bvh import DeviceRayTracer
    from pipeline.registry import get_method

    scene = triple_scene(tmp_path, sky(tmp_path / "sky.exr"), size=32)
    workdir = job.workdir_for(scene, tmp_path / "w")
    job.bake(scene, workdir, quiet=True, methods=[get_method("triple")])
    frames = {}
    for trace in ("device", "embree"):
        renderer = job.frame_renderer(scene, workdir, "triple", {"trace": trace})
        assert isinstance(renderer.tracer, DeviceRayTracer) == (trace == "device")
        frames[trace] = renderer.frame(scene).rgb
    largest = np.abs(frames["embree"]).max()
    off = np.abs(frames["device"] - frames["embree"]).max(axis=2) > 1e-3 * largest
    assert largest > 0 and off.mean() <= 0.01, off.mean()

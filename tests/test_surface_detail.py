"""Surface detail (pipeline/math/textures.py, pipeline/render/surface_detail.py): textures,
blends of two materials, bump maps; their scene syntax, refusals, method triple's BRDF
lookups and the reference's blended BRDF."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import small_scene_dict, write_scene
from PIL import Image

from pipeline import job
from pipeline.device.raytrace import Hits, Mesh, surface_at
from pipeline.errors import PrtError
from pipeline.evaluation.reference import PathTracer, _brdf, _brdf_pdf, _Vertex
from pipeline.images import read_texture, write_exr
from pipeline.math.brdf import BrdfParams
from pipeline.math.textures import sample
from pipeline.methods.triple.render import shade, shade_numpy
from pipeline.methods.triple.tables import PixelLookups, brdf_lookups
from pipeline.registry import check_method_scene, get_method
from pipeline.render.surface_detail import SceneDetail
from pipeline.scene.file import load_scene

# --------------------------------------------------------------------------- textures


def test_bilinear_sampling_hits_texel_centres_and_interpolates_between():
    """Texel (i, j) is centred at u = (j + ½)/W, v = 1 − (i + ½)/H; halfway between
    two centres the value is their mean; derivatives are the patch's (per unit u, v)."""
    texture = np.arange(12.0).reshape(3, 4)
    centres = np.array([[(j + 0.5) / 4, 1 - (i + 0.5) / 3] for i in range(3) for j in range(4)])
    value, _ = sample(texture, centres, "clamp")
    assert np.allclose(value, texture.reshape(-1))
    value, d = sample(texture, np.array([[2 / 4, 1 - 1.5 / 3]]), "clamp")  # between (1,1),(1,2)
    assert np.isclose(value[0], 5.5)
    assert np.allclose(d[0], [1.0 * 4, -4.0 * 3])  # +1 per column, +4 per row (rows go down)


def test_repeat_wraps_and_clamp_holds_the_edges():
    texture = np.array([[0.0, 1.0, 2.0, 3.0]])
    uv = np.array([[0.3, 0.5], [1.3, 0.5], [-0.7, 0.5]])
    value, _ = sample(texture, uv, "repeat")
    assert np.allclose(value, value[0])
    edge = np.array([[0.0, 0.5], [1.0, 0.5]])  # outside the outermost centres
    value, d = sample(texture, edge, "repeat")
    assert np.allclose(value, [1.5, 1.5])  # halfway between the last and the first texel
    value, d = sample(texture, edge, "clamp")
    assert np.allclose(value, [0.0, 3.0]) and np.allclose(d[:, 0], 0.0)


# ---------------------------------------------------------------------- scene syntax


def png(path, values: np.ndarray):
    """An 8-bit grey PNG of ``values`` in [0, 1]."""
    Image.fromarray(np.round(np.asarray(values) * 255).astype(np.uint8), "L").save(path)
    return path


def detail_scene(tmp_path, blend=None, bump=None, name="scene.yaml"):
    doc = small_scene_dict(16)
    if blend is not None:
        doc["materials"]["grey"]["blend"] = blend
    if bump is not None:
        doc["materials"]["grey"]["bump"] = bump
    return load_scene(write_scene(tmp_path, doc, name))


def test_textures_are_read_as_linear_values_and_keyed_by_their_bytes(tmp_path):
    png(tmp_path / "t.png", np.array([[0.0, 1.0], [0.2, 0.6]]))
    scene = detail_scene(tmp_path, blend={"material": "shiny", "texture": "t.png"})
    blend = scene.materials["grey"].blend
    assert blend.material == "shiny" and blend.texture.projection == "uv"
    before = scene.section("materials")
    png(tmp_path / "t.png", np.array([[0.0, 1.0], [0.2, 0.8]]))
    assert detail_scene(tmp_path, blend={"material": "shiny", "texture": "t.png"}
                        ).section("materials") != before
    assert np.allclose(read_texture(tmp_path / "t.png"), [[0, 1], [51 / 255, 204 / 255]])
    Image.fromarray(np.array([[0, 65535, 13107]], np.uint16)).save(tmp_path / "w.png")
    assert np.allclose(read_texture(tmp_path / "w.png"), [[0.0, 1.0, 0.2]])  # 16-bit
    Image.fromarray(np.array([[[255, 0, 0], [30, 60, 90]]], np.uint8), "RGB").save(
        tmp_path / "c.png")
    assert np.allclose(read_texture(tmp_path / "c.png"), [[1 / 3, 60 / 255]])  # RGB mean


@pytest.mark.parametrize("case", ["garbage", "jpeg", "blend_above_one", "nan_exr"])
def test_a_bad_texture_is_a_one_line_error_naming_the_texture(tmp_path, case):
    if case == "garbage":
        path = tmp_path / "t.png"
        path.write_bytes(b"not a png")
    elif case == "jpeg":
        path = tmp_path / "t.jpg"
        Image.new("L", (4, 4)).save(path, "JPEG")
    else:
        path = tmp_path / "t.exr"
        rgb = np.full((4, 4, 3), 0.5, np.float32)
        rgb[1, 2] = 2.0 if case == "blend_above_one" else np.nan
        write_exr(path, rgb)
    with pytest.raises(PrtError) as error:
        detail_scene(tmp_path, blend={"material": "shiny", "texture": path.name})
    assert error.value.path == str(path) and "\n" not in str(error.value)


@pytest.mark.parametrize("key,value,message", [
    ("blend", {"material": "nope", "texture": "t.png"}, "unknown material 'nope'"),
    ("blend", {"material": "grey", "texture": "t.png"}, "cannot blend with itself"),
    ("blend", {"material": "shiny", "texture": "t.png", "projection": "zw"},
     "blend.projection: expected one of uv, xy, xz, yz"),
    ("blend", {"material": "shiny", "texture": "missing.png"}, "file not found"),
    ("bump", {"texture": "t.png"}, "bump: missing required key 'height'"),
    ("bump", {"texture": "t.png", "height": 0.1, "wrap": "mirror"}, "expected one of repeat"),
])
def test_bad_detail_keys_are_errors_naming_the_scene_and_key(tmp_path, key, value, message):
    png(tmp_path / "t.png", np.zeros((2, 2)))
    with pytest.raises(PrtError) as error:
        detail_scene(tmp_path, **{key: value})
    assert error.value.path.endswith("scene.yaml") and message in error.value.problem
    assert "materials.grey" in error.value.problem


def test_methods_without_surface_detail_refuse_it_up_front(tmp_path):
    """direct and d2i would silently shade the plain material: they refuse; triple
    declares both features."""
    png(tmp_path / "t.png", np.zeros((2, 2)))
    for kind, value in (("blend", {"material": "shiny", "texture": "t.png"}),
                        ("bump", {"texture": "t.png", "height": 0.1})):
        scene = detail_scene(tmp_path, **{kind: value})
        for method in ("direct", "d2i"):
            with pytest.raises(PrtError, match=f"materials.grey.{kind}: method {method} "
                                               "does not render.*methods that do: triple"):
                check_method_scene(get_method(method), scene)
        assert kind + "s" in get_method("triple").features


# ------------------------------------------------------------------------ bump frame

PLANE = 4.0  # the floor plane's side: the primitive's uv runs 0..1 over it along x and z


def plane_mesh() -> Mesh:
    """The plane primitive (normal +y, uv u along +x, v along +z) at y = 0."""
    h = PLANE / 2
    vertices = np.array([[-h, 0, -h], [h, 0, -h], [h, 0, h], [-h, 0, h]])
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    return Mesh(vertices, np.tile([0.0, 1.0, 0.0], (4, 1)), uv, np.array([[0, 2, 1], [0, 3, 2]]),
                np.zeros(2, np.int64), np.zeros(1, np.int64))


def plane_hits(mesh: Mesh, points: np.ndarray):
    """Surface attributes at ``points`` (x ≥ z: face 0) seen from straight above."""
    p0, p1, p2 = (mesh.vertices[mesh.faces[0, k]] for k in range(3))
    m = np.stack([p1 - p0, p2 - p0], 1)[[0, 2]]  # x and z rows
    bary = np.linalg.solve(m, (points - p0)[:, [0, 2]].T).T
    hits = Hits(np.ones(len(points)), np.zeros(len(points), np.int32), bary[:, 0], bary[:, 1])
    origins = points + [0.0, 1.0, 0.0]
    return surface_at(mesh, hits, origins, np.tile([0.0, -1.0, 0.0], (len(points), 1)))


POINTS = np.array([[0.5, 0.0, -0.3], [1.0, 0.0, 0.2], [1.5, 0.0, -1.5]])  # 0 < u < 1


@pytest.mark.parametrize("projection,scale,per_unit", [("xz", 0.2, 0.2), ("uv", 1.0, 1 / PLANE)])
def test_a_ramp_tilts_the_normal_by_its_slope_and_a_flat_map_tilts_nothing(tmp_path, projection,
                                                                            scale, per_unit):
    """Heights rising linearly along u: 16 texels 0, 1/15, ..., 1 (clamped), so
    ∂h/∂u = 16/15 and the displaced surface has slope s = height · 16/15 · (u per scene
    unit): the normal turns by arctan(s) towards −x (away from the rise), the tangent
    stays ⊥ to it. A constant map leaves the frame as it was."""
    png(tmp_path / "ramp.png", np.tile(np.arange(16) / 15, (4, 1)))
    png(tmp_path / "flat.png", np.full((4, 4), 0.5))
    height = 0.3
    mesh = plane_mesh()
    surface = plane_hits(mesh, POINTS)
    for texture, slope in (("ramp.png", height * 16 / 15 * per_unit), ("flat.png", 0.0)):
        scene = detail_scene(tmp_path, bump={"texture": texture, "height": height,
                                             "projection": projection, "scale": scale,
                                             "wrap": "clamp"}, name=f"{texture}.yaml")
        detail = SceneDetail(scene, ["grey"]).at(surface)
        expected = np.array([-slope, 1.0, 0.0]) / np.hypot(slope, 1.0)
        assert np.allclose(detail.normal, expected, atol=1e-6), (texture, detail.normal)
        assert np.allclose(np.sum(detail.tangent * detail.normal, 1), 0.0, atol=1e-9)
        assert np.allclose(np.linalg.norm(detail.tangent, axis=1), 1.0)
        if slope == 0.0:
            assert np.allclose(detail.tangent, surface.tangent)
    assert np.degrees(np.arctan(height * 16 / 15 * per_unit)) > 1.0  # a visible tilt


def test_blend_weights_follow_the_texture(tmp_path):
    """Two texels 0 | 1 centred at u = ¼, ¾ (clamped beyond), u = ½ x."""
    png(tmp_path / "t.png", np.array([[0.0, 1.0]]))
    scene = detail_scene(tmp_path, blend={"material": "shiny", "texture": "t.png",
                                          "projection": "xz", "scale": 0.5, "wrap": "clamp"})
    names = list(scene.materials)
    surface = plane_hits(plane_mesh(), np.array([[0.5, 0, -1.0], [1.5, 0, 0.0],
                                                 [1.0, 0, -0.5]]))
    detail = SceneDetail(scene, names).at(surface)
    assert np.allclose(detail.blend, [0.0, 1.0, 0.5], atol=1e-6)
    assert (detail.material_a == names.index("grey")).all()
    assert (detail.material_b == names.index("shiny")).all()


# ------------------------------------------------------------- blends in the methods


def blended_lookups(rng, tables, n):
    """Lookups of ``n`` pixels on material 0 blended with material 1 by ``blend``."""
    from test_triple_render import random_lookups

    plain = random_lookups(rng, tables, n)
    wo = rng.normal(size=(n, 3))
    wo[:, 2] = np.abs(wo[:, 2])
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    kd = np.array([[0.3, 0.2, 0.1], [0.5, 0.5, 0.5], [0.1, 0.6, 0.2]])
    rho_s = np.array([[0.1, 0.2, 0.3], [0.0, 0.0, 0.0], [0.3, 0.1, 0.05]])

    def lookups(material, material_b=None, t=None):
        rows, weight = brdf_lookups(tables, material, wo, kd, rho_s, material_b, t)
        return PixelLookups(plain.light_rows, plain.light_weight, plain.vis_rows,
                            plain.vis_weight, rows, weight)
    return lookups


def three_material_tables(rng):
    """synthetic_tables plus a third, glossy material sharing material 0's rows shifted
    by one view (its own rows in the table)."""
    from test_triple_render import synthetic_tables

    tables = synthetic_tables(rng)
    tables.glossy_base = np.array([0, -1, 1])
    tables.diffuse_row = np.append(tables.diffuse_row, tables.diffuse_row[0])
    return tables


def test_triple_blend_at_zero_and_one_equals_each_material_and_matches_numpy():
    """The kernel with 9 BRDF rows: t = 0 gives material a's frame, t = 1 material b's
    (to float32 rounding of the row order: 1e-5), and a blend in between matches the
    float64 NumPy twin (1e-4, as the plain kernel test) and lies between the two."""
    rng = np.random.default_rng(5)
    tables = three_material_tables(rng)
    n = 48
    lookups = blended_lookups(rng, tables, n)
    a, b = np.zeros(n, np.int64), np.full(n, 2, np.int64)
    alone_a, alone_b = shade(tables, lookups(a))[0], shade(tables, lookups(b))[0]
    at_zero = shade(tables, lookups(a, b, np.zeros(n)))[0]
    at_one = shade(tables, lookups(a, b, np.ones(n)))[0]
    scale = np.abs(alone_a).max()
    assert np.allclose(at_zero, alone_a, atol=1e-5 * scale)
    assert np.allclose(at_one, alone_b, atol=1e-5 * scale)
    t = rng.random(n)
    mixed = lookups(a, b, t)
    rgb = shade(tables, mixed)[0]
    pixels = np.arange(0, n, 4)
    assert np.allclose(rgb[pixels], shade_numpy(tables, mixed, pixels), rtol=1e-4,
                       atol=1e-4 * scale)
    assert np.allclose(rgb, (1 - t)[:, None] * alone_a + t[:, None] * alone_b,
                       atol=1e-4 * scale)  # linear in t
    assert not np.allclose(alone_a, alone_b, atol=1e-2 * scale)


def test_reference_blend_at_zero_and_one_equals_each_material():
    """The reference's BRDF, its density and its samples' weights for a blend of a
    Lambertian and a Blinn-Phong material at t = 0 and 1 equal each material's own."""
    rng = np.random.default_rng(3)
    n = 200
    table = [BrdfParams("lambert", (0.5, 0.4, 0.3)),
             BrdfParams("blinn_phong", (0.1, 0.1, 0.1), (0.3, 0.3, 0.3), gamma=40.0)]
    normal = np.tile([0.0, 0.0, 1.0], (n, 1))
    tangent = np.tile([1.0, 0.0, 0.0], (n, 1))
    wo = rng.normal(size=(n, 3))
    wo[:, 2] = np.abs(wo[:, 2]) + 0.1
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    wi = rng.normal(size=(n, 3))
    wi[:, 2] = np.abs(wi[:, 2])
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    x = np.zeros((n, 3))

    def vertex(material, material_b=None, t=None):
        return _Vertex(x, normal, tangent, normal, wo, np.full(n, material), None,
                       None if material_b is None else np.full(n, material_b),
                       None if t is None else np.full(n, float(t)))

    for t, alone in ((0.0, 0), (1.0, 1)):
        blended, plain = vertex(0, 1, t), vertex(alone)
        assert np.allclose(_brdf(blended, wi, table), _brdf(plain, wi, table))
        assert np.allclose(_brdf_pdf(blended, wi, table), _brdf_pdf(plain, wi, table))
        wi_s, pdf, weight = PathTracer._sample_brdf(None, blended, table,
                                                  np.random.default_rng(1))  # uses no state
        assert np.allclose(pdf, _brdf_pdf(plain, wi_s, table))
        assert np.allclose(weight, np.where(pdf[:, None] > 0, _brdf(plain, wi_s, table)
                                            * wi_s[:, 2:] / np.maximum(pdf, 1e-300)[:, None],
                                            0.0))
    half = vertex(0, 1, 0.5)
    assert np.allclose(_brdf(half, wi, table),
                       0.5 * _brdf(vertex(0), wi, table) + 0.5 * _brdf(vertex(1), wi, table))


def test_triple_renders_a_blended_floor_as_the_reference(tmp_path, record_property):
    """End to end: the small test scene's floor blended with the glossy material by a
    4 × 4 checker (the plane's uv), triple against an env-direct reference on the
    pixels that see a surface. Tolerance 4 % (found 2.1 %), as the plain scene's test
    (found 2.2 % there): the reference's noise (≈ 1.2 %), rows cut at 1 %, level-3
    leaves and the coarse frame grid; the blend is the same function in both (bilinear
    weights of one texture). Then the unblended scene in the same work directory is
    fresh: a blend re-bakes nothing."""
    from test_triple_method import error_against_reference, render, sky, triple_scene

    png(tmp_path / "checker.png", np.indices((4, 4)).sum(0) % 2)
    scene = triple_scene(tmp_path, sky(tmp_path / "sky.exr"))
    doc = __import__("yaml").safe_load(scene.path.read_text())
    doc["materials"]["grey"]["blend"] = {"material": "shiny", "texture": "checker.png"}
    scene = load_scene(write_scene(tmp_path, doc, "blended.yaml"))
    frame = render(scene, tmp_path / "w", tmp_path / "t.exr")
    error = error_against_reference(scene, job.workdir_for(scene, tmp_path / "w"), frame.rgb)
    record_property("rel_rmse", error)
    assert error < 0.04, error
    plain = load_scene(scene.path.with_name("scene.yaml"))  # the same scene, no blend
    states = {p.spec.name: p.state
              for p in job.status(plain, job.workdir_for(plain, tmp_path / "w"))}
    assert set(states.values()) == {"fresh"}, states  # the blend is baked into nothing


def test_the_grazing_view_row_of_a_ward_table_is_finite():
    """Anisotropic Ward (paper 004 Fig. 11: αx 0.1, αy 1.0) has 1/√(N·L N·V), infinite at
    the view grid's grazing row (N·V = 0): that row is sampled half a θ step inside, so
    its mean stays of the order of the row one step above (measured 1.6e5 × before; the
    bound 3 allows the growth of 1/√cos θ_o over half a step, √2 at the horizon)."""
    from pipeline.methods.triple.frame_grids import ViewGrid
    from pipeline.methods.triple.stages.brdf_tables import view_leaf_means

    grid = ViewGrid(8, 16)
    params = BrdfParams("ward_anisotropic", (0, 0, 0), (1, 1, 1), gamma=0.1, alpha_ratio=10.0)
    means = view_leaf_means(params, grid, 2, 1).reshape(grid.n_phi, grid.n_theta, -1)
    row_mean = means.mean(axis=2)
    assert np.isfinite(means).all()
    assert (row_mean[:, -1] < 3 * row_mean[:, -2]).all(), row_mean[:, -2:]


def test_run_time_material_edits_keep_the_blend_and_the_bump(tmp_path):
    """`--set` re-validates the edited material alone: its blend and bump survive."""
    from pipeline.scene.edits import with_material_edits

    png(tmp_path / "t.png", np.zeros((2, 2)))
    scene = detail_scene(tmp_path, blend={"material": "shiny", "texture": "t.png"},
                         bump={"texture": "t.png", "height": 0.1})
    edited = with_material_edits(scene, ["grey.albedo=0.3"])
    assert edited.materials["grey"].albedo == (0.3, 0.3, 0.3)
    assert edited.materials["grey"].blend == scene.materials["grey"].blend
    assert edited.materials["grey"].bump == scene.materials["grey"].bump

"""Method sg's tabulated glossy transport (pipeline/methods/sg/transport.py): the 92 view
directions, the direct transport's integral against the BRDF's directional albedo, its
visibility against an analytic occluder, and the indirect glossy estimator against
quadrature."""

from __future__ import annotations

import numpy as np
import trimesh

from pipeline.device.raytrace import RayTracer
from pipeline.math import sg, sh
from pipeline.math.brdf import BrdfParams, directional_albedo, glossy
from pipeline.math.geodesic import icosahedron
from pipeline.methods.sg.transport import (
    direct_glossy,
    glossy_transport,
    indirect_glossy_sh,
    scene_visibility,
    view_directions,
    visibility,
)
from pipeline.methods.sg.vertex_scene import VertexScene
from pipeline.scene.meshio import primitive_mesh

SHINY = BrdfParams("blinn_phong", (0.2, 0.2, 0.2), (0.3, 0.5, 0.7), gamma=20.0)


def test_92_views_cover_the_sphere_evenly():
    """10·3² + 2 = 92 distinct unit vectors holding the 12 icosahedron vertices; the
    icosahedron's 63.4° edges cut in three give neighbours 20–24° apart (measured 20.1°
    to 23.8°: the projection onto the sphere stretches face centres)."""
    v = view_directions()
    assert v.shape == (92, 3)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(v[:12], icosahedron()[0], atol=1e-12)
    cos = v @ v.T
    np.fill_diagonal(cos, -1.0)
    nearest = np.degrees(np.arccos(cos.max(axis=1)))
    assert nearest.min() > 19.5 and nearest.max() < 24.5


def test_unoccluded_transport_integrates_to_the_glossy_albedo():
    """On an open plane (V = 1 above the horizon) Σ_s T(ω_s) Ω_s over a 129 × 256
    lat-long grid is ρs × the glossy part's directional albedo, which brdf.py integrates
    in half-vector coordinates (a different quadrature), for every 4th view above 0.2
    of the horizon. γ = 20 (σ ≈ 13°, 9 grid steps): measured ≤ 1.2e-4 (2.2e-5 on a grid
    twice as fine, so it is the grid's quadrature error); tolerance 1e-3. Views below
    the horizon give 0 everywhere."""
    d, omega = sg.latlong_directions(129, 256)
    d, omega = d.reshape(-1, 3), omega.ravel()
    normal, tangent = np.array([[0.0, 1.0, 0.0]]), np.array([[1.0, 0.0, 0.0]])
    views = view_directions()
    visible = (d @ normal[0] > 0)[None]
    t = direct_glossy(normal, tangent, SHINY, views, d, visible)       # (1, 92, S, 3)
    assert t.shape == (1, 92, len(d), 3) and np.all(t >= 0)
    integral = np.einsum("ksc,s->kc", t[0], omega)
    checked = 0
    for k in np.flatnonzero(views @ normal[0] > 0.2)[::4]:  # not grazing: lobe whole
        # local frame (tangent, normal × tangent, normal) = (x, −z, y) in world terms
        lo = np.array([views[k, 0], -views[k, 2], views[k, 1]])
        albedo = directional_albedo(lambda wi, lo=lo: glossy(wi, lo, SHINY), lo, 512, 256)
        np.testing.assert_allclose(integral[k], np.asarray(SHINY.specular) * albedo,
                                   rtol=1e-3)
        checked += 1
    assert checked >= 10
    assert np.all(t[0, views @ normal[0] <= 0] == 0)


def test_visibility_matches_an_analytic_box():
    """A point on a floor under a floating axis-aligned box: directions whose ray hits
    the box shrunk by 1e-3 are occluded, those missing it grown by 1e-3 are visible
    (the margin absorbs Embree's float32 arithmetic); directions below the floor are
    not visible."""
    lo_corner, hi_corner = np.array([-0.5, 0.5, -0.3]), np.array([0.4, 0.9, 0.6])
    box = trimesh.creation.box(bounds=[lo_corner, hi_corner])
    tracer = RayTracer(box.vertices, box.faces, threads=1)
    d = sg.latlong_directions(65, 128)[0].reshape(-1, 3)
    position, normal = np.array([[0.1, 0.0, 0.05]]), np.array([[0.0, 1.0, 0.0]])
    v = visibility(tracer, position, normal, d, offset=1e-4)[0]

    def hits(margin: float) -> np.ndarray:
        """Slab test of rays from the point against the box grown by ``margin``."""
        with np.errstate(divide="ignore", invalid="ignore"):
            t0 = (lo_corner - margin - position[0]) / d
            t1 = (hi_corner + margin - position[0]) / d
        near = np.nanmax(np.minimum(t0, t1), axis=1)
        far = np.nanmin(np.maximum(t0, t1), axis=1)
        return (near <= far) & (far > 0)

    above = d[:, 1] > 0
    assert not v[~above].any()
    assert not v[above & hits(-1e-3)].any()
    assert v[above & ~hits(1e-3)].all()
    assert (above & hits(-1e-3)).sum() > 100  # the box covers a good part of the sky


def _floor_and_wall() -> VertexScene:
    """A glossy 4 × 4 floor (normal +y, 2 × 2 grid, vertex 4 at the origin) and a
    Lambertian wall z = −0.5 facing it (+z), x ∈ ±2, y ∈ [0, 3]."""
    floor = primitive_mesh({"type": "plane", "size": [4.0, 4.0], "segments": 2})
    wall = primitive_mesh({"type": "plane", "size": [4.0, 3.0]})
    turn = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # +y → +z
    wall_v = wall.vertices @ turn.T + [0.0, 1.5, -0.5]
    return VertexScene.from_arrays(
        {"vertices": np.concatenate([floor.vertices, wall_v]),
         "normals": np.concatenate([np.tile([0.0, 1.0, 0.0], (9, 1)),
                                    np.tile([0.0, 0.0, 1.0], (4, 1))]),
         "faces": np.concatenate([floor.faces, wall.faces + 9]),
         "object_ranges": np.array([[0, 9, 0, 8], [9, 13, 8, 10]]),
         "object_material": np.array([0, 1])},
        [SHINY, BrdfParams("lambert", (0.5, 0.5, 0.5))])


def test_indirect_glossy_against_quadrature():
    """The floor's centre vertex reflecting a wall whose every vertex carries the same
    diffuse transfer q (3, 25) (so t_y = q wherever a path lands): the estimator's SH
    vector must be ρs · I(ωo) · q with I(ωo) = ∫_{rays that hit the wall} f_F f_E cos dω,
    here by a 129 × 256 lat-long quadrature over the traced rays (its own error ≈ 1e-4,
    as above), for the 26 views whose I is ≥ 10 % of the largest. Noise, not bias (the
    wall's edge cuts the lobe): the worst view was 6–8 % off with 2048 paths per view
    (three seeds), 2.2 % with 4 × 16384. With 8192 (three seeds): worst view 3.9–7.5 %,
    the sum over the 26 views 0.16–0.31 %; tolerances 10 % and 1.5 %."""
    scene = _floor_and_wall()
    q = np.random.default_rng(7).normal(size=(3, 25))
    transfer = np.broadcast_to(q, (13, 3, 25)).copy()
    views = view_directions()
    a = indirect_glossy_sh(scene, np.array([4]), views, transfer, 8192,
                           np.random.default_rng(0))[0]                      # (92, 3, 25)
    d, omega = sg.latlong_directions(129, 256)
    d, omega = d.reshape(-1, 3), omega.ravel()
    origin = np.tile(scene.positions[4] + scene.offset * scene.normals[4], (len(d), 1))
    wall = (scene.intersect(origin, d).prim >= 8) & (d[:, 1] > 0)
    normal, tangent = np.array([[0.0, 1.0, 0.0]]), np.array([[1.0, 0.0, 0.0]])
    f = direct_glossy(normal, tangent, SHINY, views, d, wall[None])[0]       # (92, S, 3)
    integral = np.einsum("ksc,s->kc", f, omega)                              # ρs · I
    checked = np.flatnonzero(integral[:, 0] >= 0.1 * integral[:, 0].max())
    assert len(checked) >= 20
    expected = integral[checked][:, :, None] * q                             # (n, 3, 25)
    error = np.linalg.norm(a[checked] - expected, axis=(1, 2))
    assert np.all(error <= 0.1 * np.linalg.norm(expected, axis=(1, 2)))
    np.testing.assert_allclose(a[checked].sum(0), expected.sum(0), rtol=0.015,
                               atol=0.015 * np.abs(expected.sum(0)).max())
    assert np.all(a[views[:, 1] <= 0] == 0)


def test_glossy_transport_is_direct_plus_indirect():
    """glossy_transport without a diffuse transfer is the direct transport of the traced
    visibility; with one it adds Σ_k A_k Y_k(ω) of indirect_glossy_sh drawn from the same
    seed; Lambertian vertices get 0."""
    scene = _floor_and_wall()
    d = sg.latlong_directions(17, 32)[0].reshape(-1, 3)
    vertices = np.array([4, 0, 10])
    direct = glossy_transport(scene, vertices, d, None, 0, np.random.default_rng(1))
    assert direct.shape == (3, 92, len(d), 3) and direct.dtype == np.float32
    visible = scene_visibility(scene, vertices[:2], d)
    expected = direct_glossy(scene.normals[vertices[:2]], np.array([[1.0, 0, 0]] * 2),
                             SHINY, view_directions(), d, visible)
    np.testing.assert_allclose(direct[:2], expected, rtol=1e-6, atol=1e-7)
    assert np.all(direct[2] == 0)
    transfer = np.random.default_rng(2).normal(size=(13, 3, 25))
    both = glossy_transport(scene, vertices, d, transfer, 16, np.random.default_rng(1))
    a = indirect_glossy_sh(scene, vertices, view_directions(), transfer, 16,
                           np.random.default_rng(1))
    np.testing.assert_allclose(both - direct, np.einsum("pkcn,sn->pksc", a, sh.basis(d)),
                               rtol=1e-4, atol=1e-5)
    assert np.abs(both[0] - direct[0]).max() > 1e-3 and np.all(both[2] == 0)

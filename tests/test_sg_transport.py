"""Method sg's tabulated direct glossy transport (pipeline/math/sg_transport.py): the 92
view directions, the transport's integral against the BRDF's directional albedo, and
its visibility against an analytic occluder."""

from __future__ import annotations

import numpy as np
import trimesh

from pipeline.math import sg
from pipeline.math.brdf import BrdfParams, directional_albedo, glossy
from pipeline.math.geodesic import icosahedron
from pipeline.math.sg_transport import direct_glossy, view_directions, visibility
from pipeline.raytrace import RayTracer

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

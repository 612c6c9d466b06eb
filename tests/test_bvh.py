"""The device BVH's shadow rays (pipeline/device/bvh.py, kernels/bvh.h) against Embree's.

Both intersect float32 triangles in float32 arithmetic, by different formulas: a ray
that passes within rounding of a triangle's edge (or touches a vertex, or ends on a
surface) may be counted by one and not the other. So the test asks for identical
answers except on rays whose own answer is not stable: Embree gives the other answer
for the ray moved by a few ulps of the scene's size (EDGE_EPSILON). Such rays must be
rare (≤ 1 in 2,000 here)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import SHARED_DATA

from pipeline.device.bvh import LEAF, Bvh, morton_codes, occluded
from pipeline.device.raytrace import RayTracer
from pipeline.scene.meshio import read_mesh

EDGE_EPSILON = 1e-5  # relative to the scene's size: a few float32 ulps of a coordinate


def bunny_on_a_plane() -> tuple[np.ndarray, np.ndarray]:
    """The 6.6k-face bunny standing on a 4 × 4 quad: curved, thin and flat parts."""
    bunny = read_mesh(SHARED_DATA / "meshes" / "bunny_6.6kf.obj")
    v = bunny.vertices - bunny.vertices.mean(0)
    v /= np.abs(v).max()
    floor = np.array([[-2, v[:, 1].min(), -2], [2, v[:, 1].min(), -2],
                      [2, v[:, 1].min(), 2], [-2, v[:, 1].min(), 2]])
    vertices = np.concatenate([v, floor])
    faces = np.concatenate([bunny.faces, len(v) + np.array([[0, 1, 2], [0, 2, 3]])])
    return vertices.astype(np.float32), faces


def unstable(tracer: RayTracer, o: np.ndarray, d: np.ndarray, t: np.ndarray,
             answer: np.ndarray, scale: float) -> np.ndarray:
    """Rays for which Embree gives ``answer`` once the origin and end point are moved
    by EDGE_EPSILON · scale along one of 26 directions."""
    steps = np.array([[x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)
                      if (x, y, z) != (0, 0, 0)], np.float64)
    steps /= np.linalg.norm(steps, axis=1, keepdims=True)
    found = np.zeros(len(o), bool)
    for step in steps * EDGE_EPSILON * scale:
        for end_step in (step, -step):
            end = o + t[:, None] * d + end_step
            start = o + step
            found |= tracer.occluded(start, end - start, t) == answer
    return found


def test_morton_codes_interleave_the_axes():
    """x takes bits 3b + 2, y 3b + 1, z 3b: the corner (1, 0, 0) is 0b100100…100."""
    lo, hi = np.zeros(3), np.ones(3)
    x = morton_codes(np.array([[1.0, 0, 0]]), lo, hi)[0]
    assert x == sum(1 << (3 * b + 2) for b in range(10))
    assert morton_codes(np.array([[0.0, 0, 1.0]]), lo, hi)[0] == x >> 2


def test_every_triangle_lies_in_its_leaf_and_its_ancestors():
    vertices, faces = bunny_on_a_plane()
    bvh = Bvh.build(vertices, faces)
    v = vertices[faces[bvh.order]]
    leaf = bvh.leaves + np.arange(len(v)) // LEAF
    node = leaf.copy()
    while np.any(node >= 1):
        assert np.all(bvh.lo[node, :3] <= v.min(1)) and np.all(bvh.hi[node, :3] >= v.max(1))
        node //= 2
        if node[0] == 0:
            break
    assert sorted(bvh.order) == list(range(len(faces)))


@pytest.mark.parametrize("kind", ["segments", "towards_a_light"])
def test_device_occlusion_equals_embree_away_from_edges(kind):
    """Segments between random points of the scene's box, and shadow rays from surface
    points towards a point light (the renderer's: t_max just short of 1)."""
    vertices, faces = bunny_on_a_plane()
    rng = np.random.default_rng(11)
    tracer = RayTracer(vertices, faces)
    n = 20000
    lo, hi = vertices.min(0) - 0.2, vertices.max(0) + 0.2
    if kind == "segments":
        o = rng.uniform(lo, hi, (n, 3))
        d = rng.uniform(lo, hi, (n, 3)) - o
        t = np.ones(n)
    else:  # points on the surface, offset along their face normal, to a light
        p, normal = surface_points(vertices, faces, n, 11)
        o = p.astype(np.float64) + 2e-4 * normal
        d = np.array([0.7, 1.9, 0.5]) - o
        t = np.full(n, 1.0 - 1e-4)
    o, d = o.astype(np.float32), d.astype(np.float32)
    expected = tracer.occluded(o, d, t)
    got, _ = occluded(Bvh.build(vertices, faces), o, d, t.astype(np.float32))
    assert 0.1 < expected.mean() < 0.9  # both answers are well represented
    differ = np.flatnonzero(got != expected)
    scale = float(np.linalg.norm(hi - lo))
    assert len(differ) <= n // 2000, f"{len(differ)} of {n} rays differ"
    ok = unstable(tracer, o[differ].astype(np.float64), d[differ].astype(np.float64),
                  t[differ], got[differ], scale)
    assert np.all(ok), f"{int((~ok).sum())} rays differ away from any edge"


def test_an_empty_scene_and_rays_parallel_to_the_axes():
    """No triangles: nothing occludes. One triangle in the plane z = 0: axis-parallel
    rays (inf in 1 / d) through its inside hit, beside it miss, stopping short miss."""
    none, _ = occluded(Bvh.build(np.zeros((0, 3)), np.zeros((0, 3), np.int64)),
                       np.zeros((3, 3)), np.ones((3, 3)), np.ones(3))
    assert not none.any()
    bvh = Bvh.build(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32),
                    np.array([[0, 1, 2]]))
    o = np.array([[0.2, 0.2, 1], [0.8, 0.8, 1], [0.2, 0.2, 1]], np.float32)
    d = np.array([[0, 0, -2], [0, 0, -2], [0, 0, -2]], np.float32)
    got, _ = occluded(bvh, o, d, np.array([1, 1, 0.4], np.float32))
    assert got.tolist() == [True, False, False]


def surface_points(vertices: np.ndarray, faces: np.ndarray, n: int, seed: int
                   ) -> tuple[np.ndarray, np.ndarray]:
    """``n`` uniform points on random faces and their unit face normals, float32."""
    rng = np.random.default_rng(seed)
    tri = vertices[faces[rng.integers(0, len(faces), n)]].astype(np.float64)
    a, b = rng.random((2, n, 1))
    flip = a + b > 1
    a, b = np.where(flip, 1 - a, a), np.where(flip, 1 - b, b)
    p = tri[:, 0] + a * (tri[:, 1] - tri[:, 0]) + b * (tri[:, 2] - tri[:, 0])
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True) + 1e-30
    return p.astype(np.float32), normal.astype(np.float32)


def test_light_visibility_on_the_device_equals_embree():
    """DeviceShadows against render/shadows.py's Embree path: point, spot, directional
    and a 16-sample quad, the same samples (pixel ids), equal except on rays that are
    unstable as above (counted over all samples: ≤ 1 in 2,000)."""
    from pipeline.device import cl
    from pipeline.math.lights import pack_lights
    from pipeline.render.shadows import DeviceShadows, light_visibility

    vertices, faces = bunny_on_a_plane()
    position, normal = surface_points(vertices, faces, 6000, 3)
    pixel = np.arange(len(position), dtype=np.uint32) * 7 + 11
    packed = pack_lights([
        ("point", {"position": [0.6, 1.8, 0.4], "intensity": [1, 1, 1]}),
        ("spot", {"position": [-1.2, 1.5, 1.0], "direction": [1, -1, -0.8],
                  "intensity": [1, 1, 1], "angle": 40}),
        ("directional", {"direction": [0.3, -1, -0.2], "irradiance": [1, 1, 1]}),
        ("quad", {"corner": [-0.5, 1.6, -0.5], "edge_u": [1, 0, 0], "edge_v": [0, 0, 1],
                  "radiance": [1, 1, 1], "samples": 16})], {})
    diagonal = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    expected = light_visibility(RayTracer(vertices, faces), position, normal, pixel, packed,
                                diagonal)
    buffer, _ = DeviceShadows(vertices, faces).visibility(
        cl.read_only_buffer(position), cl.read_only_buffer(normal), cl.read_only_buffer(pixel),
        len(position), packed, diagonal)
    got = np.empty_like(expected)
    import pyopencl

    pyopencl.enqueue_copy(cl.queue(), got, buffer)
    assert 0.2 < expected.mean() < 0.8
    differ = got != expected
    assert differ.sum() <= expected.size // 2000, f"{differ.sum()} of {expected.size} differ"


def test_device_closest_hits_equal_embree_away_from_edges():
    """Rays from random points of the scene's box in random directions: the device's
    closest hit is Embree's face, at its t and barycentrics, except where a ray passes
    within rounding of an edge between two faces (both at the same t: the tie may go
    either way; ≤ 1 in 2,000 rays) or grazes past a silhouette (Embree's own answer
    flips for the ray moved by EDGE_EPSILON). t, u, v agree to float32 rounding of
    different formulas: 1e-4 of the scene's size (t) and 1e-3 (u, v)."""
    from pipeline.device.bvh import closest

    vertices, faces = bunny_on_a_plane()
    rng = np.random.default_rng(5)
    tracer = RayTracer(vertices, faces)
    n = 20000
    lo, hi = vertices.min(0) - 0.2, vertices.max(0) + 0.2
    o = rng.uniform(lo, hi, (n, 3)).astype(np.float32)
    d = rng.normal(size=(n, 3))
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    expected = tracer.intersect(o, d)
    got, ms = closest(Bvh.build(vertices, faces), o, d)
    scale = float(np.linalg.norm(hi - lo))
    hit = expected.prim >= 0
    assert 0.2 < hit.mean() < 0.95 and ms >= 0.0
    assert np.array_equal(got.prim >= 0, hit) or \
        (np.sum((got.prim >= 0) != hit) <= n // 2000)
    both = hit & (got.prim >= 0)
    np.testing.assert_allclose(got.t[both], expected.t[both], rtol=0, atol=1e-4 * scale)
    same = both & (got.prim == expected.prim)
    assert np.sum(both & ~same) <= n // 2000
    np.testing.assert_allclose(got.u[same], expected.u[same], atol=1e-3)
    np.testing.assert_allclose(got.v[same], expected.v[same], atol=1e-3)
    assert np.all(np.isinf(got.t[got.prim < 0]))
    empty, _ = closest(Bvh.build(np.zeros((0, 3)), np.zeros((0, 3), np.int64)),
                       np.zeros((2, 3), np.float32), np.ones((2, 3), np.float32))
    assert np.all(empty.prim == -1)

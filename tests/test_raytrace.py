"""pipeline/device/raytrace.py: surface attributes at hits (surface_at)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.device.raytrace import Mesh, RayTracer, surface_at


def _mesh(normal_dtype=None) -> Mesh:
    """One triangle in the plane z = 0 with tilted vertex normals, uv = (x, y)."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    normals = np.array([[0, 0, 1], [0.6, 0, 0.8], [0, 0.6, 0.8]], np.float32)
    return Mesh.from_arrays({"vertices": vertices, "normals": normals, "uv": vertices[:, :2],
                             "faces": np.array([[0, 1, 2]], np.int32),
                             "face_object": np.array([1], np.int32),
                             "object_material": np.array([4, 7], np.int32)}, normal_dtype)


def test_surface_at_blends_normals_and_faces_the_ray():
    """From above and from below: the position on the plane, the barycentric blend of
    the vertex normals (unit, turned towards the ray's origin), the face normal turned
    likewise, a unit tangent along +u orthogonal to the normal, uv, object and material."""
    mesh = _mesh(np.float64)
    tracer = RayTracer(mesh.vertices, mesh.faces)
    origins = np.array([[0.2, 0.3, 1.0], [0.2, 0.3, -1.0]])
    directions = np.array([[0, 0, -1.0], [0, 0, 1.0]])
    hits = tracer.intersect(origins, directions)
    assert np.all(hits.prim == 0)
    s = surface_at(mesh, hits, origins, directions)
    np.testing.assert_allclose(s.position, [[0.2, 0.3, 0], [0.2, 0.3, 0]], atol=1e-6)
    blend = 0.5 * mesh.normals[0] + 0.2 * mesh.normals[1] + 0.3 * mesh.normals[2]
    blend /= np.linalg.norm(blend)
    np.testing.assert_allclose(s.normal, [blend, -blend], atol=1e-6)
    np.testing.assert_allclose(s.geometric_normal, [[0, 0, 1], [0, 0, -1]])
    np.testing.assert_allclose(np.linalg.norm(s.tangent, axis=1), 1.0)
    np.testing.assert_allclose(np.sum(s.tangent * s.normal, axis=1), 0.0, atol=1e-12)
    assert np.all(s.tangent[:, 0] > 0.7)  # along +u = +x, tilted off the plane by n
    np.testing.assert_allclose(s.uv, [[0.2, 0.3], [0.2, 0.3]], atol=1e-6)
    assert s.face.tolist() == [0, 0] and s.object_id.tolist() == [1, 1]
    assert s.material_id.tolist() == [7, 7]


def test_surface_at_normal_precision():
    """float32 vertex normals are blended in float32 and normalised in ``normal_dtype``;
    float64 normals blend in float64 (the reference path tracer)."""
    origins, directions = np.array([[0.2, 0.3, 1.0]]), np.array([[0, 0, -1.0]])
    for normal_dtype, mesh_dtype, expected in ((np.float32, None, np.float32),
                                               (np.float64, None, np.float64),
                                               (np.float64, np.float64, np.float64)):
        mesh = _mesh(mesh_dtype)
        hits = RayTracer(mesh.vertices, mesh.faces).intersect(origins, directions)
        s = surface_at(mesh, hits, origins, directions, normal_dtype)
        assert s.normal.dtype == expected
        np.testing.assert_allclose(np.linalg.norm(s.normal, axis=1), 1.0, rtol=1e-6)


@pytest.mark.parametrize("size", [(7, 5), (64, 48)])
def test_image_rays_equal_camera_rays(size):
    """image_rays (the camera's own directions cached per size, turned by one 3×3
    product) gives camera_rays' rays, flat: the same float64 sums in another order, so
    equal after the cast to float32 to within one float32 rounding (measured: equal)."""
    from pipeline.math.camera import camera_rays, image_rays

    camera = ([0.3, 0.55, 3.4], [0.0, -0.05, 0.0], [0, 1, 0], 32.0, *size)
    origins, directions = camera_rays(*camera)
    o, d = image_rays(*camera)
    assert o.shape == d.shape == (size[0] * size[1], 3)
    np.testing.assert_array_equal(o, origins.reshape(-1, 3))
    np.testing.assert_allclose(d, directions.reshape(-1, 3), rtol=0, atol=2 ** -23)

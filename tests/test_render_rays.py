"""pipeline/render/rays.py: the camera rays of the renderers that trace every camera
move (triple, sg) against math.camera.image_rays."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from pipeline.device import cl
from pipeline.math.camera import image_rays
from pipeline.render.rays import aligned_image_rays


@pytest.mark.parametrize("size", [(7, 5), (64, 48)])
def test_aligned_image_rays_are_the_cameras_image_rays(size):
    """aligned_image_rays turns the camera-frame directions in float32 where image_rays
    turns them in float64 and rounds once: each component is a 3-term float32 dot
    product of operands already rounded to float32 (the local direction and the frame,
    |·| ≤ 1), so it differs by at most ≈ 3 roundings of the products, 2 of the sums and 1
    of the result: 6 · 2⁻²⁴ ≤ 2⁻²¹. The origins are the camera's position in every row;
    the directions lie in page-aligned memory."""
    cam = SimpleNamespace(position=(0.3, 0.55, 3.4), look_at=(0.0, -0.05, 0.0), up=(0, 1, 0),
                          fov=32.0, width=size[0], height=size[1])
    o, d = aligned_image_rays(cam)
    origins, directions = image_rays(cam.position, cam.look_at, cam.up, cam.fov, *size)
    np.testing.assert_array_equal(o, origins)
    np.testing.assert_allclose(d, directions, rtol=0, atol=2.0 ** -21)
    assert d.ctypes.data % cl.PAGE == 0 and o.flags.c_contiguous

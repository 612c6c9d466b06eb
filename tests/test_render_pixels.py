"""pipeline.render.scatter_pixels: whole pixel rows written as records."""

from __future__ import annotations

import numpy as np

from pipeline.render import scatter_pixels


def test_scatter_pixels_equals_fancy_indexing():
    """Rows land where NumPy's fancy index puts them, bit for bit; others untouched."""
    rng = np.random.default_rng(3)
    image = rng.random((50, 3), dtype=np.float32)
    expected = image.copy()
    pixel = rng.choice(50, size=20, replace=False)
    values = rng.random((20, 3)).astype(np.float32)
    expected[pixel] = values
    scatter_pixels(image, pixel, values)
    np.testing.assert_array_equal(image, expected)
    scatter_pixels(image, pixel[:0], values[:0])  # no pixels: nothing changes
    np.testing.assert_array_equal(image, expected)


def test_device_image_scatter_equals_numpy_twin():
    """DeviceImage (kernel scatter_rgb) against scatter_pixels: the same rows, scaled —
    bit for bit with scale 1 (a copy), to one float32 rounding with another scale."""
    from pipeline.device import cl
    from pipeline.render import DeviceImage

    rng = np.random.default_rng(5)
    pixel = rng.permutation(60).astype(np.int32)
    values = rng.random((60, 3)).astype(np.float32)
    image = DeviceImage(60)
    image.scatter(cl.read_only_buffer(values[:40]), cl.read_only_buffer(pixel[:40]), 40)
    image.scatter(cl.read_only_buffer(values[40:]), cl.read_only_buffer(pixel[40:]), 20, 2.5)
    expected = np.zeros((60, 3), np.float32)
    scatter_pixels(expected, pixel[:40], values[:40])
    scatter_pixels(expected, pixel[40:], values[40:] * np.float32(2.5))
    got = image.read()
    np.testing.assert_array_equal(got[pixel[:40]], expected[pixel[:40]])
    np.testing.assert_allclose(got[pixel[40:]], expected[pixel[40:]], rtol=1.2e-7)
    image.clear()  # a frame that leaves pixels unwritten starts from black
    assert not image.read().any()

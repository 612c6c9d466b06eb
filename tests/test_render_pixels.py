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

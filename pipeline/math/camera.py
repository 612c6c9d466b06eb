"""Pinhole camera rays.

The camera frame is right-handed: ``forward`` points from the eye to ``look_at``,
``right = forward × up`` (normalised), ``true_up = right × forward``. Pixel (row i,
column j) looks through its centre; row 0 is the top of the image. ``fov`` is the
vertical field of view in degrees.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np


def camera_frame(position, look_at, up) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit (right, true_up, forward) vectors, float64."""
    forward = np.asarray(look_at, float) - np.asarray(position, float)
    forward = forward / np.abs(forward).max()  # exact scaling first, as for up below
    forward /= np.linalg.norm(forward)
    up = np.asarray(up, float)
    up = up / np.abs(up).max()  # exact scaling first: an up of 1e-300 keeps its digits
    right = np.cross(forward, up / np.linalg.norm(up))
    norm = np.linalg.norm(right)
    if norm < 1e-12:
        raise ValueError("camera up is parallel to the view direction")
    right /= norm
    return right, np.cross(right, forward), forward


def pixel_directions(position, look_at, up, fov: float, width: int, height: int,
                     x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Unit float64 directions (..., 3) through continuous image points ``x`` (columns,
    0 at the left edge, ``width`` at the right) and ``y`` (rows, 0 at the top edge); the
    centre of pixel (row i, column j) is (x, y) = (j + ½, i + ½)."""
    right, true_up, forward = camera_frame(position, look_at, up)
    half_h = np.tan(np.radians(fov) / 2.0)
    half_w = half_h * width / height
    sx = (2.0 * np.asarray(x, float) / width - 1.0) * half_w
    sy = (1.0 - 2.0 * np.asarray(y, float) / height) * half_h
    d = forward + sx[..., None] * right + sy[..., None] * true_up
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def camera_rays(position, look_at, up, fov: float, width: int, height: int,
                region: tuple[int, int, int, int] | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Origins and unit directions, each (rows, cols, 3) float32, through the pixel
    centres of ``region`` = (y0, y1, x0, x1) (default: the whole image)."""
    y0, y1, x0, x1 = region or (0, height, 0, width)
    y, x = np.meshgrid(np.arange(y0, y1) + 0.5, np.arange(x0, x1) + 0.5, indexing="ij")
    d = pixel_directions(position, look_at, up, fov, width, height, x, y)
    origins = np.broadcast_to(np.asarray(position, float), d.shape)
    return origins.astype(np.float32), d.astype(np.float32)


@lru_cache(maxsize=4)
def _local_directions(fov: float, width: int, height: int) -> np.ndarray:
    """Unit directions (H·W, 3) float64 through the pixel centres in the camera's own
    frame (right, true_up, forward), row-major from the top row (cached per size)."""
    half_h = np.tan(np.radians(fov) / 2.0)
    half_w = half_h * width / height
    sx = (2.0 * (np.arange(width) + 0.5) / width - 1.0) * half_w
    sy = (1.0 - 2.0 * (np.arange(height) + 0.5) / height) * half_h
    d = np.empty((height, width, 3))
    d[..., 0], d[..., 1], d[..., 2] = sx[None, :], sy[:, None], 1.0
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    d.setflags(write=False)
    return d.reshape(-1, 3)


def image_rays(position, look_at, up, fov: float, width: int, height: int
               ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`camera_rays` of the whole image, flat: origins and unit directions, each
    (H·W, 3) float32, the directions turned from the camera's frame (cached per image
    size and fov) by one 3×3 product: a new camera costs one pass over the pixels
    (equal to camera_rays' to float64 rounding, then float32)."""
    right, true_up, forward = camera_frame(position, look_at, up)
    d = (_local_directions(float(fov), int(width), int(height))
         @ np.stack([right, true_up, forward])).astype(np.float32)
    return np.broadcast_to(np.asarray(position, np.float32), d.shape), d

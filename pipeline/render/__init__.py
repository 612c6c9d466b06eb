"""Renderers: each reads baked artifacts and produces a :class:`Frame`; none imports stages."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pipeline import cl


@dataclass
class Frame:
    """A rendered image: ``rgb`` (height, width, 3) float32 linear radiance, row 0 on
    top, wall-clock ``timings`` in milliseconds (``setup_ms``, ``kernel_ms`` (every
    kernel of the frame), ..., ``total_ms``) and ``kernel_bytes``, the bytes that some
    of the frame's kernels read and write, with ``timings["counted_kernel_ms"]`` the
    time of exactly those kernels: their effective bandwidth is ``kernel_bytes`` /
    ``counted_kernel_ms``. Each renderer says which kernels it counts (direct: its one
    kernel; d2i: the sparse-row products). ``read_bytes``: where a renderer cuts its
    stored data at run time (triple's ``budget``), the bytes of what this frame reads, as
    held (uncompressed); None: the frame reads its artifacts whole."""

    method: str
    rgb: np.ndarray
    timings: dict[str, float]
    notes: list[str] = field(default_factory=list)
    kernel_bytes: int = 0
    read_bytes: int | None = None

    @property
    def height(self) -> int:
        return int(self.rgb.shape[0])

    @property
    def width(self) -> int:
        return int(self.rgb.shape[1])


def camera_key(cam) -> tuple:
    """What a per-camera G-buffer depends on (position, look_at, up, fov, size): renderers
    keep their last camera's traced buffers under this key."""
    return (tuple(cam.position), tuple(cam.look_at), tuple(cam.up), cam.fov, cam.width,
            cam.height)


def scatter_pixels(image: np.ndarray, pixel: np.ndarray, values: np.ndarray) -> None:
    """``image`` (H·W, 3) float32 rows ``pixel`` (P,) set to ``values`` (P, 3) float32,
    each row moved as one 12-byte record (≈ 2.3× faster than NumPy's fancy index over
    the 2-D arrays, which copies float by float). The host twin of
    :meth:`DeviceImage.scatter`, which the renderers use (this one cost ≈ 12 ms of a
    1024×768 frame)."""
    record = np.dtype((np.void, 3 * image.itemsize))
    image.view(record).reshape(-1)[pixel] = \
        np.ascontiguousarray(values, image.dtype).view(record).reshape(-1)


class DeviceImage:
    """A frame assembled on the OpenCL device: per-pixel results, still in device
    buffers, are scattered into one (H·W, 3) float32 image buffer (kernel ``scatter_rgb``,
    kernels/image.cl; the twin of :func:`scatter_pixels`), which comes back in one copy.
    Keeps the host out of the frame's per-pixel work (a 1024×768 frame's two host
    scatters and read-backs cost more than its shading kernel on a GPU)."""

    @classmethod
    def of_size(cls, cache: dict[int, DeviceImage], pixels: int) -> DeviceImage:
        """The image of ``pixels`` kept in a renderer's ``cache``: the last size's only
        (a new size drops the previous buffers)."""
        if pixels not in cache:
            cache.clear()
            cache[pixels] = cls(pixels)
        return cache[pixels]

    def __init__(self, pixels: int) -> None:
        self.pixels = pixels
        self.buffers: dict[str, Any] = {}
        self.image = cl.scratch_buffer(self.buffers, "image", 12 * pixels)

    def scatter(self, values: Any, pixel: Any, count: int, scale: float = 1.0) -> float:
        """``image[pixel[i]] = max(scale · values[i], 0)`` (radiance is never negative;
        kernels/image.cl says where a truncated basis dips below 0) for the ``count`` (P)
        rows of device buffers ``values`` (P, 3) float32 and ``pixel`` (P,) int32; kernel
        ms."""
        if count == 0:
            return 0.0
        return cl.run(cl.kernel("image.cl", "scatter_rgb"), count, values, pixel,
                      np.float32(scale), np.int32(count), out=None, out_buffer=self.image)

    def clear(self) -> None:
        """Every pixel black (for frames that do not write every pixel)."""
        import pyopencl as pcl

        pcl.enqueue_fill_buffer(cl.queue(), self.image, np.float32(0), 0, 12 * self.pixels)

    def read(self) -> np.ndarray:
        """The image (H·W, 3) float32, copied from the device."""
        import pyopencl as pcl

        out = np.empty((self.pixels, 3), np.float32)
        pcl.enqueue_copy(cl.queue(), out, self.image)
        return out

"""What every method's renderer is (:class:`Renderer`) and shares: the :class:`Frame` it
produces, device images, back-face notes; the shared direct-light renderer (``direct``),
shadows, emitters, surface detail and edit sequences live beside this module."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from pipeline.device import cl

if TYPE_CHECKING:
    from pipeline.scene.model import Scene

WORK_GROUP = 64  # work-items per group of the per-pixel kernels (pipeline.device.cl.run's local)


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


@runtime_checkable
class Renderer(Protocol):
    """A method's renderer: built once (``Method.renderer`` names its factory, called as
    ``factory(scene, artifacts, **options)`` with the opened artifacts of the method's
    ``reads``), it keeps what it loaded and every cache it fills as named attributes,
    and renders edited copies of the scene it was built for (run-time edits:
    pipeline/scene/edits.py; what is edited at run time is read from each scene).

    ``frame(scene)``: the frame of ``scene``, its timings leaving out the loading;
    ``edit_mode(kind, scene)``: the frame function for a sequence of ``kind`` edits that
    starts at ``scene`` (a faster path where the method has one, else ``frame``)."""

    def frame(self, scene: Scene) -> Frame: ...

    def edit_mode(self, kind: str, scene: Scene) -> Callable[[Scene], Frame]: ...


def camera_key(cam) -> tuple:
    """What a per-camera G-buffer depends on (position, look_at, up, fov, size): renderers
    keep their last camera's traced buffers under this key."""
    return (tuple(cam.position), tuple(cam.look_at), tuple(cam.up), cam.fov, cam.width,
            cam.height)


BACK_FACE_SHARE = 0.01  # the share of an object's shaded pixels that makes a note


def sees_back(directions: np.ndarray, face_normal: np.ndarray) -> np.ndarray:
    """Whether each camera ray of ``directions`` (P, 3) meets the back of its hit face,
    of normal ``face_normal`` (P, 3) as wound (outward for a closed mesh wound
    counter-clockwise seen from outside): (P,) bool."""
    return np.einsum("ij,ij->i", np.asarray(directions, np.float64),
                     np.asarray(face_normal, np.float64)) > 0.0


def back_face_notes(method: str, back: np.ndarray, objects: np.ndarray,
                    names: list[str]) -> list[str]:
    """A note naming the objects of which more than :data:`BACK_FACE_SHARE` of the
    shaded pixels see the back of their face (``back`` (P,) bool, ``objects`` (P,) the
    pixels' object indices into ``names``). For a method that bakes light on the side a
    face's normal points to (triple's visibility, sg's transport), such pixels — a mesh
    wound inward, or the camera inside a closed object — are lit as if seen from the
    front, where the reference (two-sided for the camera) sees the shadowed or dark
    side."""
    seen = np.bincount(objects, minlength=len(names))
    backs = np.bincount(objects[back], minlength=len(names))
    objects = [f"{names[i]} {backs[i] / seen[i]:.0%}" for i in np.flatnonzero(seen)
               if backs[i] > BACK_FACE_SHARE * seen[i]]
    if not objects:
        return []
    return [f"{', '.join(objects)} of the pixels see the back of a face (a mesh wound "
            f"inward, or the camera inside a closed object): method {method} bakes light "
            "on the side each face's normal points to, so those pixels are not what the "
            "reference shows; wind the mesh outward (counter-clockwise seen from "
            "outside) or move the camera"]

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
        if count > self.pixels or values.size < 12 * count:
            raise RuntimeError(f"scatter_rgb: {count} values into an image of {self.pixels} "
                               f"pixels from a buffer of {values.size} bytes")
        return cl.run(cl.kernel("image.cl", "scatter_rgb"), count, values, pixel,
                      np.float32(scale), np.int32(count), out=None,
                      writes=12 * self.pixels, out_buffer=self.image)

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

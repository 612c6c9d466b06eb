"""Camera rays for the renderers that trace their camera every move (methods triple and
sg): math.camera.image_rays' rays, made where the frame's kernels read them.

image_rays turns the camera-frame pixel directions (cached per image size) in float64
and casts to float32, and gives broadcast origins, which the tracer copies into a
contiguous array: at 1024×768 about 7 + 7 ms on the 2-core build machine. Here the
directions are turned in float32 straight into page-aligned memory (a CPU device's
kernels read such memory in place: pipeline/device/cl.py ``aligned_empty``) and the
origins are tiled once: 1.3 + 1.8 ms. The directions differ from image_rays' by a few
float32 roundings (tests/test_render_rays.py).

(math/camera.py itself is in the path tracer's code closure, so changing it would
re-key every cached reference image.)
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np

from pipeline.device import cl
from pipeline.math.camera import _local_directions, camera_frame


@lru_cache(maxsize=4)
def _local_directions32(fov: float, width: int, height: int) -> np.ndarray:
    """math.camera's camera-frame pixel directions (H·W, 3), float32."""
    return np.ascontiguousarray(_local_directions(fov, width, height), np.float32)


def aligned_image_rays(cam: Any) -> tuple[np.ndarray, np.ndarray]:
    """The rays of camera ``cam``'s pixels (``position``, ``look_at``, ``up``, ``fov``,
    ``width``, ``height``), row-major from the top row: origins (H·W, 3) float32,
    contiguous, and unit directions (H·W, 3) float32 in page-aligned memory."""
    local = _local_directions32(float(cam.fov), int(cam.width), int(cam.height))
    frame = np.stack(camera_frame(cam.position, cam.look_at, cam.up)).astype(np.float32)
    directions = cl.aligned_empty(local.shape, np.float32)
    np.matmul(local, frame, out=directions)
    return np.tile(np.asarray(cam.position, np.float32), (len(local), 1)), directions

"""Method direct's renderer: the shared direct-light shader (pipeline/render/direct.py
``DirectShader``) over the baked G-buffer, one frame per call."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping

import numpy as np

from pipeline.engine.store import Artifact
from pipeline.math.brdf import pack_materials, scene_brdfs
from pipeline.render import Frame
from pipeline.render.direct import DirectShader
from pipeline.scene.model import Scene


class DirectRenderer:
    """Method direct's renderer (pipeline/render/__init__.py ``Renderer``): frames of
    direct lighting from ``gbuffer`` and ``geometry`` (and their Embree scene), loaded
    once in the :class:`DirectShader`; each frame traces the scene's lights and shades
    its camera view; its timings leave out the loading. No cache between frames."""

    def __init__(self, scene: Scene, artifacts: Mapping[str, Artifact]) -> None:
        self.shader = DirectShader(artifacts, scene.camera)

    def edit_mode(self, kind: str, scene: Scene) -> Callable[[Scene], Frame]:
        return self.frame

    def frame(self, scene: Scene) -> Frame:
        shader = self.shader
        t0 = time.perf_counter()
        packed, notes = shader.packed_lights(scene)
        materials = pack_materials(scene_brdfs(scene, shader.material_names))
        t1 = time.perf_counter()
        shader.trace(packed)
        t2 = time.perf_counter()
        rgb, kernel_ms, moved = shader.shade(materials, np.asarray(scene.camera.position))
        rgb = shader.emitters.draw(rgb, scene)
        t3 = time.perf_counter()
        # one kernel: kernel_bytes are its bytes, counted_kernel_ms its time
        timings = {"setup_ms": (t1 - t0) * 1e3, "shadow_ms": (t2 - t1) * 1e3,
                   "kernel_ms": kernel_ms, "counted_kernel_ms": kernel_ms,
                   "total_ms": (t3 - t0) * 1e3}
        return Frame("direct", rgb.reshape(shader.height, shader.width, 3), timings, notes,
                     moved)

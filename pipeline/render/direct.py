"""Direct lighting of the baked G-buffer (kernels/direct.cl): method direct's frames
(pipeline/methods/direct/render.py) and method d2i's direct term.

Per frame: load the G-buffer and geometry artifacts, build the Embree scene, trace shadow
rays to every light sample (point, spot, directional; quad lights with stratified
samples), then shade every pixel on the OpenCL device with its material's analytic BRDF
(pipeline/math/brdf.py, kernels/brdf.h) at the material's γ. Emitting quads show their
radiance, where they are (render/emitters.py). Environment lights are not part of this method.

:class:`DirectShader` keeps the traced shadows and the uploaded G-buffer, so that a BRDF
edit re-shades without tracing again (method d2i uses it for its direct term).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from pipeline.device import cl
from pipeline.device.raytrace import RayTracer
from pipeline.engine.store import Artifact
from pipeline.math.lights import LIGHT_FLOATS, light_defines, pack_lights, total_samples
from pipeline.render.emitters import EmitterOverlay, object_bounds, unbound_lights
from pipeline.render.shadows import DeviceShadows, light_visibility
from pipeline.scene.model import Camera, Scene


def packed_scene_lights(scene: Scene, object_names: list[str], moved: Sequence[int] = ()
                        ) -> tuple[np.ndarray, list[str]]:
    """The scene's point, spot, directional and quad lights packed for kernels/lights.h,
    the ``moved`` ones (indices, see render/emitters.py) without their emitter object,
    and notes on what was left out (environment lights)."""
    lights = [(kind, params) for kind, params in unbound_lights(scene, list(moved))
              if kind != "environment"]
    notes = ["environment lights are ignored by this method"] \
        if len(lights) < len(scene.lights) else []
    return pack_lights(lights, {n: i for i, n in enumerate(object_names)}), notes


class DirectShader:
    """Direct light at every G-buffer pixel from the scene's lights, with shadows.

    ``trace(packed_lights)`` casts the shadow rays (setup of a light edit);
    ``shade(materials)`` runs the kernel with packed material rows (a BRDF edit);
    ``emitters`` draws quad lights moved off their baked emitter geometry
    (render/emitters.py) for ``camera``, the camera the G-buffer was baked for."""

    def __init__(self, artifacts: Mapping[str, Artifact], camera: Camera,
                 tracer: RayTracer | None = None, shadows: DeviceShadows | None = None
                 ) -> None:
        gbuf, geo = artifacts["gbuffer"], artifacts["geometry"]
        self.height, self.width = gbuf.attrs["height"], gbuf.attrs["width"]
        self.object_names = geo.attrs["object_names"]
        self.material_names = geo.attrs["material_names"]
        self.position = gbuf.read("position").reshape(-1, 3)
        self.normal = gbuf.read("normal").reshape(-1, 3)
        self.tangent = gbuf.read("tangent").reshape(-1, 3)
        self.object_id = gbuf.read("object_id").reshape(-1)
        self.material_id = gbuf.read("material_id").reshape(-1)
        vertices = geo.read("vertices")
        self.tracer = tracer or RayTracer(vertices, geo.read("faces"))
        self.diagonal = float(np.linalg.norm(np.subtract(geo.attrs["bbox_max"],
                                                         geo.attrs["bbox_min"])))
        self.gbuffer = [cl.read_only_buffer(a) for a in (self.position, self.normal, self.tangent,
                                                  self.object_id, self.material_id)]
        self.lights = np.zeros((0, LIGHT_FLOATS), np.float32)
        # the shadow rays' answers, (pixels, max(samples, 1)) uint8, on the device: traced
        # there (``shadows``: a GPU's frame) or by Embree and uploaded once per trace
        self.shadows = shadows
        self.visibility_buffer = cl.read_only_buffer(np.zeros((len(self.position), 1), np.uint8))
        self.visibility_stride = 1
        self.pixel_ids = cl.read_only_buffer(np.arange(len(self.position), dtype=np.uint32)) \
            if shadows is not None else None
        self.buffers: dict[str, Any] = {}  # per-frame device intermediates (cl.scratch_buffer)
        # the pixels that see a surface, and their points: the shadow rays' origins
        self.hit = np.flatnonzero(self.material_id >= 0)
        self.hit_position, self.hit_normal = self.position[self.hit], self.normal[self.hit]
        bounds = object_bounds(self.object_names, vertices, geo.read("object_ranges"))
        self.emitters = EmitterOverlay(camera, self.position, self.material_id, bounds)

    def packed_lights(self, scene: Scene) -> tuple[np.ndarray, list[str]]:
        """``scene``'s lights packed (see :func:`packed_scene_lights`), a light moved off
        its baked emitter geometry unbound from it."""
        return packed_scene_lights(scene, self.object_names, self.emitters.moved(scene))

    def trace(self, packed_lights: np.ndarray) -> float:
        """Shadow rays from every pixel to every light sample; the device kernel's
        milliseconds (0 for Embree's)."""
        self.lights = packed_lights
        n = len(self.position)
        self.visibility_stride = max(total_samples(packed_lights), 1)
        if self.shadows is not None:
            out = cl.scratch_buffer(self.buffers, "visibility", n * self.visibility_stride)
            self.visibility_buffer, ms = self.shadows.visibility(
                self.gbuffer[0], self.gbuffer[1], self.pixel_ids, n, packed_lights,
                self.diagonal, out)
            return ms
        visibility = np.zeros((n, self.visibility_stride), np.uint8)
        if len(packed_lights):
            visibility[self.hit, :total_samples(packed_lights)] = light_visibility(
                self.tracer, self.hit_position, self.hit_normal, self.hit, packed_lights,
                self.diagonal)
        self.visibility_buffer = cl.read_only_buffer(visibility)
        return 0.0

    def pixel_rows(self, pixels: np.ndarray) -> dict[str, Any]:
        """The G-buffer rows and traced visibility rows of ``pixels`` (ids into the
        image) on the device, with the lights they were traced for: what
        :meth:`shade_pixels` reads (kept by the caller while the lights stay; a new
        :meth:`trace` needs new rows)."""
        import pyopencl as pcl

        n = len(self.position)
        visibility = np.empty((n, self.visibility_stride), np.uint8)
        pcl.enqueue_copy(cl.queue(), visibility, self.visibility_buffer)
        pixels = np.asarray(pixels, np.int64)
        return {"count": len(pixels), "lights": self.lights,
                "stride": self.visibility_stride,
                "pixel": cl.read_only_buffer(pixels.astype(np.uint32)),
                "gbuffer": [cl.read_only_buffer(a[pixels]) for a in (
                    self.position, self.normal, self.tangent, self.object_id,
                    self.material_id)],
                "visibility": cl.read_only_buffer(visibility[pixels])}

    def shade_pixels(self, materials: np.ndarray, camera: np.ndarray,
                     rows: dict[str, Any]) -> tuple[np.ndarray, float]:
        """Radiance (pixels, 3) float32 of the pixels of ``rows`` (:meth:`pixel_rows`)
        only, each the value :meth:`shade` gives it, bit for bit (kernels/direct.cl: the
        same function per pixel), and the kernel milliseconds."""
        n = rows["count"]
        out = np.empty((n, 3), np.float32)
        if n == 0:
            return out, 0.0
        lights = rows["lights"] if len(rows["lights"]) else np.zeros((1, LIGHT_FLOATS),
                                                                     np.float32)
        kernel = cl.kernel("direct.cl", "direct_lighting_pixels", light_defines())
        ms = cl.run(kernel, n, *rows["gbuffer"], cl.read_only_buffer(materials),
                    cl.read_only_buffer(lights), np.int32(len(rows["lights"])),
                    rows["visibility"], np.int32(rows["stride"]),
                    np.array([*camera, 0.0], np.float32), rows["pixel"], np.int32(n),
                    out=out, writes=12 * n)
        return out, ms

    def shade(self, materials: np.ndarray, camera: np.ndarray, out_buffer: Any = None
              ) -> tuple[np.ndarray | None, float, int]:
        """Radiance (P, 3) float32 (left in device buffer ``out_buffer`` when given, and
        None returned), kernel milliseconds and the bytes it moved."""
        n = len(self.position)
        out = None if out_buffer is not None else np.empty((n, 3), np.float32)
        rows = self.lights if len(self.lights) else np.zeros((1, LIGHT_FLOATS), np.float32)
        kernel = cl.kernel("direct.cl", "direct_lighting", light_defines())
        ms = cl.run(kernel, n, *self.gbuffer, cl.read_only_buffer(materials),
                    cl.read_only_buffer(rows), np.int32(len(self.lights)),
                    self.visibility_buffer, np.int32(self.visibility_stride),
                    np.array([*camera, 0.0], np.float32), np.int32(n), out=out,
                    writes=12 * n, out_buffer=out_buffer)
        moved = sum(a.nbytes for a in (self.position, self.normal, self.tangent,
                                       self.object_id, self.material_id, materials, rows)) \
            + n * self.visibility_stride + 12 * n
        return out, ms, moved

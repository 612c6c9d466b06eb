"""Method ``direct``: direct lighting of the baked G-buffer (kernels/direct.cl).

Per frame: load the G-buffer and geometry artifacts, build the Embree scene, trace shadow
rays to every light sample (point, spot, directional; quad lights with stratified
samples), then shade every pixel on the OpenCL device with its material's analytic BRDF
(pipeline/math/brdf.py, kernels/brdf.h) at the material's γ. Emitting quads show their
radiance. Environment lights are not part of this method.
"""

from __future__ import annotations

import time

import numpy as np

from pipeline import cl
from pipeline.math.brdf import pack_materials, scene_brdfs
from pipeline.math.lights import pack_lights, total_samples
from pipeline.raytrace import RayTracer
from pipeline.render import Frame
from pipeline.render.shadows import light_visibility
from pipeline.scene import Scene
from pipeline.store import Workdir, open_artifact


def render_direct(scene: Scene, workdir: Workdir) -> Frame:
    """Render the scene's camera view with direct lighting from its lights."""
    import pyopencl as pcl

    t0 = time.perf_counter()
    gbuf = open_artifact(workdir.artifact("gbuffer"), "gbuffer")
    geo = open_artifact(workdir.artifact("geometry"), "geometry")
    h, w = gbuf.attrs["height"], gbuf.attrs["width"]
    position = gbuf.read("position").reshape(-1, 3)
    normal = gbuf.read("normal").reshape(-1, 3)
    object_id = gbuf.read("object_id").reshape(-1)
    material_id = gbuf.read("material_id").reshape(-1)
    object_names = geo.attrs["object_names"]
    tangent = gbuf.read("tangent").reshape(-1, 3)
    materials = pack_materials(scene_brdfs(scene, geo.attrs["material_names"]))
    lights = [(light.type, light.params) for light in scene.lights if light.type != "environment"]
    notes = ["environment lights are ignored by method direct"] \
        if len(lights) < len(scene.lights) else []
    packed = pack_lights(lights, {n: i for i, n in enumerate(object_names)})
    tracer = RayTracer(geo.read("vertices"), geo.read("faces"))
    diagonal = float(np.linalg.norm(np.subtract(geo.attrs["bbox_max"], geo.attrs["bbox_min"])))
    t1 = time.perf_counter()

    hit = np.flatnonzero(material_id >= 0)
    visibility = np.zeros((h * w, max(total_samples(packed), 1)), np.uint8)
    if len(packed):
        visibility[hit, :total_samples(packed)] = light_visibility(
            tracer, position[hit], normal[hit], hit, packed, diagonal)
    t2 = time.perf_counter()

    queue, ctx = cl.queue(), cl.context()
    kernel = cl.kernel("direct.cl", "direct_lighting")
    mf = pcl.mem_flags

    def buf(a: np.ndarray):
        return pcl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(a))

    out = np.empty((h * w, 3), np.float32)
    out_buf = pcl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes)
    light_rows = packed if len(packed) else np.zeros((1, packed.shape[1]), np.float32)
    camera = np.array([*scene.camera.position, 0.0], np.float32)
    inputs = [position, normal, tangent, object_id, material_id, materials, light_rows]
    args = [*map(buf, inputs), np.int32(len(packed)), buf(visibility),
            np.int32(visibility.shape[1]), camera, np.int32(h * w), out_buf]
    kernel_bytes = sum(a.nbytes for a in inputs) + visibility.nbytes + out.nbytes
    t3 = time.perf_counter()
    event = kernel(queue, (h * w,), None, *args)
    pcl.enqueue_copy(queue, out, out_buf, wait_for=[event])
    t4 = time.perf_counter()
    timings = {"setup_ms": (t1 - t0 + t3 - t2) * 1e3, "shadow_ms": (t2 - t1) * 1e3,
               "kernel_ms": cl.event_ms(event), "total_ms": (t4 - t0) * 1e3}
    return Frame("direct", out.reshape(h, w, 3), timings, notes, kernel_bytes)

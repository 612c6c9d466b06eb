"""Method triple's G-buffer and the per-pixel lookups it feeds (kernels/triple/triple_lookup.h).

The G-buffer is what a camera sees, computed once per camera and reused by every frame
whose camera did not change (an environment rotation, material edits, γ sweeps). Per
shaded pixel (P of them, the pixels whose ray hits a surface, in image order):

* ``normal``, ``tangent`` (P, 3): the unit shading normal and a unit tangent ⊥ normal,
  world frame; the lighting lookup and ω_o use this shading frame (t, n × t, n). Under a
  bump map they differ from the geometric ones; the visibility stays the texel's.
* ``view`` (P, 3): unit world direction from the surface toward the camera;
* ``texel_xy`` (P, 2): continuous coordinates in the object's visibility texture (x
  right, y down, texel (i, j) centred at (j + ½, i + ½)) and ``object`` (P,);
* ``material_a``, ``material_b`` (P,) and ``blend`` (P,) ∈ [0, 1], the weight of b:
  ρ̃ = diffuse row × ((1 − t)·kd_a + t·kd_b) + a's glossy rows × (1 − t)·ρs_a + b's ×
  t·ρs_b. Without a blend texture b = a and t = 0.

Plus ``pixel`` (P,), each shaded pixel's flat index in the image, and ``miss`` (M, 3),
the world directions of the pixels that see the environment (``miss_pixel`` (M,)).
Floats are float32 (what the device reads; the NumPy twins read the same values).
:meth:`GBuffer.angles` turns the shading frames and views into grid coordinates once per
camera (the lookups' trigonometry); every frame's lookups start from them.

:func:`lookups_numpy` is the host twin of the kernels' lookups
(pipeline.methods.triple.frame_grids, pipeline.methods.triple.tables.texel_lookups / brdf_lookups);
:func:`device_lookups` runs ``triple_lookups`` and reads its rows back (tests, and the
sparse path keeps them on the device).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

import numpy as np

from pipeline.device import cl
from pipeline.device.raytrace import Hits, Mesh
from pipeline.math.brdf import to_local
from pipeline.methods.triple.frame_grids import FrameGrid, ViewGrid
from pipeline.methods.triple.tables import (
    BRDF_ROWS,
    LIGHT_ROWS,
    VIS_ROWS,
    Atlas,
    PixelLookups,
    TripleTables,
    brdf_lookups,
    texel_lookups,
)
from pipeline.render import WORK_GROUP


def aligned(array: np.ndarray, dtype: Any) -> np.ndarray:
    """``array`` as a C-contiguous array of ``dtype`` starting on a page (cl.PAGE): itself
    when it is one, else a cl.aligned_empty copy. A CPU device reads such memory in place
    through cl.shared_read_only_buffer, where Intel's runtime copies anything else at
    every buffer it makes (a camera's G-buffer: ≈ 10 ms at 1024×768)."""
    a = np.asarray(array)
    if a.dtype == np.dtype(dtype) and a.flags.c_contiguous and a.ctypes.data % cl.PAGE == 0:
        return a
    out = cl.aligned_empty(a.shape, dtype)
    out[...] = a
    return out


@dataclass
class GBuffer:
    """One camera's G-buffer (module docstring); ``width``, ``height`` of the image."""

    width: int
    height: int
    pixel: np.ndarray
    normal: np.ndarray
    tangent: np.ndarray
    view: np.ndarray
    texel_xy: np.ndarray
    object: np.ndarray
    material_a: np.ndarray
    material_b: np.ndarray
    blend: np.ndarray
    miss_pixel: np.ndarray
    miss: np.ndarray
    back: np.ndarray | None = None  # (P,) bool: the pixel sees the back of its face
    _angles: dict[tuple[FrameGrid, ViewGrid], list[Any]] = field(
        init=False, default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name in ("normal", "tangent", "view", "texel_xy", "blend", "miss"):
            setattr(self, name, np.ascontiguousarray(getattr(self, name), np.float32))
        for name in ("object", "material_a", "material_b"):
            setattr(self, name, np.ascontiguousarray(getattr(self, name), np.int32))

    @property
    def count(self) -> int:
        """P, the shaded pixels."""
        return len(self.pixel)

    @cached_property
    def device(self) -> list[Any]:
        """The per-frame arrays as device buffers in the kernels' order (texel_xy, object,
        material_a, material_b, blend), uploaded once per camera."""
        return [cl.shared_read_only_buffer(a) for a in (
            self.texel_xy, self.object, self.material_a, self.material_b, self.blend)]

    def angles(self, frames: FrameGrid, views: ViewGrid) -> tuple[list[Any], float]:
        """Device buffers of every pixel's frame-grid (P, 3) and view-grid (P, 2)
        coordinates (kernel ``triple_angles``: the lookups' trigonometry, run once per
        camera and grids) and the milliseconds that took (0 once cached)."""
        import pyopencl as pcl

        if (frames, views) in self._angles:
            return self._angles[frames, views], 0.0
        n = max(self.count, 1)
        out = [pcl.Buffer(cl.context(), pcl.mem_flags.READ_WRITE, n * k * 4) for k in (3, 2)]
        inputs = [cl.shared_read_only_buffer(a) for a in (self.normal, self.tangent, self.view)]
        kernel = cl.kernel("triple.cl", "triple_angles", {"SW_LEVELS": 1})
        event = kernel(cl.queue(), (-(-n // WORK_GROUP) * WORK_GROUP,), (WORK_GROUP,),
                       *inputs, *(np.int32(x) for x in (frames.n_phi, frames.n_theta,
                                                         frames.n_psi, views.n_phi,
                                                         views.n_theta)),
                       np.int32(self.count), *out)
        self._angles[frames, views] = out
        return out, cl.event_ms(event)

    @cached_property
    def pixel_device(self) -> tuple[Any, Any]:
        """The shaded and the missing pixels' ids (P,), (M,) int32 on the device, for the
        frame's scatter into a DeviceImage (pipeline/render/__init__.py)."""
        return (cl.shared_read_only_buffer(aligned(self.pixel, np.int32)),
                cl.shared_read_only_buffer(aligned(self.miss_pixel, np.int32)))

    def turned(self, to_world: np.ndarray) -> GBuffer:
        """This G-buffer as the map's own frame sees it, for a map turned by the
        map-to-world rotation R (``to_world``, 3×3) about any axis: shading frames, views
        and the missing rays' directions taken into the map by Rᵀ. Lighting the unturned
        map from frame RᵀF is lighting the turned map from F, and the local view
        (RᵀF)ᵀ(Rᵀω_o) = Fᵀω_o is unchanged; texels, materials and pixels are the same
        (their device buffers shared). A turn about +y needs none of this: it shifts the
        lookup's φ (``turn``)."""
        r = np.asarray(to_world, np.float64)

        def into_map(rows: np.ndarray) -> np.ndarray:  # Rᵀv for each row v: vᵀR
            return rows.astype(np.float64) @ r

        turned = replace(self, normal=into_map(self.normal), tangent=into_map(self.tangent),
                         view=into_map(self.view), miss=into_map(self.miss))
        for shared in ("device", "pixel_device"):
            if shared in self.__dict__:
                turned.__dict__[shared] = self.__dict__[shared]
        return turned

    @cached_property
    def miss_uv_device(self) -> Any:
        """The missing rays' map coordinates (M, 2) float32 (u, v) in an unrotated map, on
        the device (kernel ``triple_miss_uv``; twin envmap.direction_to_uv): a turn of
        the map about +y only adds turn/2π to u (kernel ``triple_background``), so the
        trigonometry runs once per camera."""
        import pyopencl as pcl

        m = len(self.miss)
        uv = pcl.Buffer(cl.context(), pcl.mem_flags.READ_WRITE, max(m, 1) * 8)
        if m:
            kernel = cl.kernel("triple.cl", "triple_miss_uv", {"SW_LEVELS": 1})
            kernel(cl.queue(), (-(-m // WORK_GROUP) * WORK_GROUP,), (WORK_GROUP,),
                   cl.shared_read_only_buffer(self.miss), np.int32(m), uv)
        return uv


def surface_attributes(mesh: Mesh, face_uv: np.ndarray, hits: Hits, directions: np.ndarray,
                       pixel: np.ndarray, static: dict[str, Any] | None = None
                       ) -> dict[str, np.ndarray]:
    """Kernel ``triple_surface`` (kernels/triple/triple_surface.cl): the G-buffer's ``normal``,
    ``tangent``, ``view`` (P, 3), ``texel_xy`` (P, 2) float32, ``object`` (P,) int32 and
    ``back`` (P,) uint8 (1: the ray meets the back of its face) at the camera rays
    ``pixel`` (P,) of ``hits`` and unit ``directions`` (N, 3) (all of them hits), from
    the mesh's vertex normals (blended in float32), unit face normals and unit uv
    tangents and the atlas's corners ``face_uv`` (F, 3, 2) in texels (uploaded once where
    ``static``, a renderer's cache of device buffers, is given). Its NumPy twin is
    pipeline.device.raytrace.Surface with Atlas.texel_xy and render.sees_back."""

    n = len(pixel)
    static = {} if static is None else static
    if "surface_mesh" not in static:
        tangent = mesh.face_tangent
        tangent = tangent / np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-300)
        static["surface_mesh"] = [cl.read_only_buffer(np.asarray(a, dtype)) for a, dtype in (
            (mesh.faces, np.int32), (mesh.normals, np.float32),
            (mesh.face_normal, np.float32), (tangent, np.float32), (face_uv, np.float32),
            (mesh.face_object, np.int32))]
    inputs = [cl.shared_read_only_buffer(np.asarray(a, dtype)) for a, dtype in (
        (pixel, np.int32), (hits.prim, np.int32), (hits.u, np.float32), (hits.v, np.float32),
        (directions, np.float32))] + static["surface_mesh"]
    # aligned: on a CPU device the kernel writes them in place, and the G-buffer's
    # device buffers (GBuffer.device, .angles) are these arrays again, not copies
    out = {name: cl.aligned_empty((n, k) if k > 1 else (n,), dtype) for name, k, dtype in (
        ("normal", 3, np.float32), ("tangent", 3, np.float32), ("view", 3, np.float32),
        ("texel_xy", 2, np.float32), ("object", 1, np.int32), ("back", 1, np.uint8))}
    if not n:
        return out
    buffers = [cl.shared_output_buffer(a) for a in out.values()]
    kernel = cl.kernel("triple_surface.cl", "triple_surface")
    kernel(cl.queue(), (-(-n // WORK_GROUP) * WORK_GROUP,), (WORK_GROUP,), *inputs,
           np.int32(n), *buffers)
    for a, buffer in zip(out.values(), buffers, strict=True):
        cl.read_output_buffer(a, buffer)
    return out


@dataclass
class LookupTables:
    """What the lookups read besides the G-buffer: per object its texture
    ``object_texture`` (objects, 3) int32 = (height, width, flat offset), per flat
    texel its visibility row ``texel_row`` (−1: empty), per material ``glossy_base`` and
    ``diffuse_row`` (int32) and this frame's ``kd``, ``rho_s`` (materials, 3)."""

    object_texture: np.ndarray
    texel_row: np.ndarray
    glossy_base: np.ndarray
    diffuse_row: np.ndarray
    kd: np.ndarray
    rho_s: np.ndarray

    @classmethod
    def of(cls, tables: TripleTables, atlas: Atlas, kd: np.ndarray, rho_s: np.ndarray
           ) -> LookupTables:
        texture = np.column_stack([atlas.size, atlas.offset]).astype(np.int32)
        row = np.where(atlas.filled, atlas.row, -1).astype(np.int32)
        return cls(texture, row, tables.glossy_base.astype(np.int32),
                   tables.diffuse_row.astype(np.int32), np.asarray(kd, np.float32),
                   np.asarray(rho_s, np.float32))


def kernel_arguments(gbuffer: GBuffer, tables: TripleTables, lookup: LookupTables,
                     turn: float, static: dict[str, Any]) -> list[Any]:
    """The kernels' TRIPLE_GBUFFER_ARGS (kernels/triple/triple.cl): the camera's grid
    coordinates (:meth:`GBuffer.angles`), the G-buffer's per-frame buffers, the lookup
    tables (``static`` caches the atlas's buffers across frames) and the grids."""
    if "texture" not in static:
        static["texture"] = cl.read_only_buffer(lookup.object_texture)
        static["texel_row"] = cl.read_only_buffer(lookup.texel_row)
        static["glossy_base"] = cl.read_only_buffer(lookup.glossy_base)
        static["diffuse_row"] = cl.read_only_buffer(lookup.diffuse_row)
    f, v = tables.frames, tables.views
    return [*gbuffer.angles(f, v)[0], *gbuffer.device, static["texture"],
            static["texel_row"], static["glossy_base"], static["diffuse_row"],
            cl.read_only_buffer(lookup.kd), cl.read_only_buffer(lookup.rho_s),
            *(np.int32(x) for x in (f.n_phi, f.n_theta, f.n_psi, v.n_phi, v.n_theta)),
            np.float32(turn)]


def lookups_numpy(gbuffer: GBuffer, tables: TripleTables, lookup: LookupTables,
                  turn: float) -> PixelLookups:
    """The kernels' lookups on the host, in float64 from the G-buffer's float32 values:
    FrameGrid.weights, texel_lookups (renormalised over filled texels), brdf_lookups
    with the blend."""

    normal, tangent = gbuffer.normal.astype(np.float64), gbuffer.tangent.astype(np.float64)
    light_rows, light_weight = tables.frames.weights(normal, tangent, turn)
    texture = lookup.object_texture[gbuffer.object].astype(np.int64)
    filled = lookup.texel_row >= 0
    texels, vis_weight = texel_lookups(gbuffer.texel_xy.astype(np.float64), texture[:, :2],
                                       texture[:, 2], filled)
    vis_rows = np.where(vis_weight > 0, lookup.texel_row[texels], 0)
    wo = to_local(gbuffer.view.astype(np.float64), normal, tangent)
    brdf_rows, brdf_weight = brdf_lookups(tables, gbuffer.material_a, wo,
                                          lookup.kd.astype(np.float64),
                                          lookup.rho_s.astype(np.float64),
                                          gbuffer.material_b, gbuffer.blend.astype(np.float64))
    return PixelLookups(light_rows, light_weight, vis_rows, vis_weight, brdf_rows,
                        brdf_weight)


def device_lookups(gbuffer: GBuffer, tables: TripleTables, lookup: LookupTables,
                   turn: float, static: dict[str, Any] | None = None
                   ) -> tuple[list[Any], float]:
    """Runs ``triple_lookups``: the device buffers of the rows and weights (as
    :class:`~pipeline.methods.triple.tables.PixelLookups`' arrays, kept on the device) and the
    kernel's milliseconds."""
    import pyopencl as pcl


    n = max(gbuffer.count, 1)
    sizes = [(LIGHT_ROWS, 4), (LIGHT_ROWS, 4), (VIS_ROWS, 4), (VIS_ROWS, 4),
             (BRDF_ROWS, 4), (3 * BRDF_ROWS, 4)]
    out = [pcl.Buffer(cl.context(), pcl.mem_flags.READ_WRITE, n * k * b) for k, b in sizes]
    kernel = cl.kernel("triple.cl", "triple_lookups",
                       {"SW_LEVELS": tables.basis.leaf_level})
    args = kernel_arguments(gbuffer, tables, lookup, turn, {} if static is None else static)
    event = kernel(cl.queue(), (-(-n // WORK_GROUP) * WORK_GROUP,), (WORK_GROUP,), *args,
                   np.int32(gbuffer.count), *out)
    return out, cl.event_ms(event)


def read_lookups(buffers: list[Any], count: int) -> PixelLookups:
    """Host copies of :func:`device_lookups`' buffers."""
    import pyopencl as pcl


    shapes = [((count, LIGHT_ROWS), np.uint32), ((count, LIGHT_ROWS), np.float32),
              ((count, VIS_ROWS), np.uint32), ((count, VIS_ROWS), np.float32),
              ((count, BRDF_ROWS), np.uint32), ((count, BRDF_ROWS, 3), np.float32)]
    arrays = []
    for buffer, (shape, dtype) in zip(buffers, shapes, strict=True):
        a = np.empty(shape, dtype)
        if count:
            pcl.enqueue_copy(cl.queue(), a, buffer)
        arrays.append(a)
    return PixelLookups(*arrays)

"""Method ``d2i``: direct-to-indirect transfer with PCA-linearized BRDF editing (paper 000).

A frame, from the truncate stages' artifacts (D, T and Ms as Haar rows), the gather
samples and the G-buffer:

1. shadow rays to every light sample from the pixels and the gather samples — Embree on
   the host, or (``shadows``: ``device``, the default on a GPU) the BVH kernel of
   render/shadows.py on the device —, direct light at the pixels with the exact BRDF
   (render/direct.py);
2. L_d = kd_g/π ⊙ E_g, the gather samples' directly lit radiance (Lambertian; kernel
   ``gather_direct`` of kernels/direct.cl, twin pipeline/math/lights.py shade_direct);
3. bounces in the Haar domain (paper eq. 17): L_{n+1} = kd_g ⊙ (Ms^w · W (|A| ⊙ L_n)),
   the rows stored per unit source area (pipeline/methods/d2i/stages/transfer.py), summed
   until a bounce adds at most ``bounce_tolerance`` of the total (relative L2) or
   ``max_bounces`` bounces. Once the power ratio of consecutive bounces has settled
   (two ratios within ``RATIO_SETTLED``), the bounces are a power iteration that has
   found its dominant eigenvector, and the rest of the series is summed in closed form,
   L_n ρ/(1 − ρ): a few products instead of the ≈ 10 that the tolerance takes. The
   loop runs on the device (kernels/d2i/d2i.cl: the Haar transform level by level, the
   product, the bounce step); the host reads back only the stopping rule's sums;
4. per pixel: D L and T_j L as sparse products (kernels/d2i/sparse_rows.cl; on a GPU with
   values float16 over a per-row scale, as stored) with W (|A| ⊙ L) (and, for a row's
   near entries, with |A| ⊙ L itself) — D's rows (and in step 3 Ms's) are stored across
   blocks of neighbours (pipeline/methods/d2i/blocks.py), so their products are unblocked per
   item (kernel ``unblock``) —, then (kernels/d2i/d2i.cl) I = direct + kd ⊙ D L + ρs ⊙ max(0,
   Σ_j c_j(γ) T_j L), with c_0 = 1 (the mean b0); every term stays in device buffers
   and the frame is read back once.

Edits reuse what did not change (paper §6.2, "freezing", done as caching):

* BRDF edit (γ, ρs of a glossy material): the products T_j L and D L stay; the frame is
  the direct kernel (shadows kept) and the per-pixel combination: Σ_j c_j(γ) (T_j L)
  costs k + 1 multiply-adds per pixel, less than the paper's frozen rows.
* Light edit: c(γ) is fixed, so each glossy pixel's rows are merged once into one row
  Σ_j c_j T_j^w (the paper's freezing); a frame traces the shadows, lights the gather
  samples, bounces, and takes one sparse product per pixel for D and one for T.
* Albedo edit: changes L (every bounce) and the direct term; shadows are kept.

A frame's ``kernel_bytes`` are the bytes its sparse-row products (bounces, D L, T L) move
at least — each launch's rows (offsets, indices, values), the float4 radiance vector once
and the float4 outputs — and ``timings["counted_kernel_ms"]`` their kernel time (a
BRDF-edit frame that reuses its products counts none); ``kernel_ms`` also holds the
direct and combination kernels.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from pipeline.device import cl
from pipeline.engine.rows import Rows, place_in_runs, quantise_values, sort_rows
from pipeline.engine.store import Artifact
from pipeline.errors import PrtError
from pipeline.math import haar
from pipeline.math.brdf import BrdfParams, pack_materials, scene_brdfs
from pipeline.math.lights import LIGHT_FLOATS, light_defines, total_samples
from pipeline.methods.d2i.blocks import block_transform, pixel_blocks
from pipeline.methods.d2i.brdf_pca import read_basis
from pipeline.render import Frame
from pipeline.render.direct import DirectShader
from pipeline.render.shadows import DeviceShadows, light_visibility
from pipeline.scene.model import Scene

GATHER_ID_OFFSET = 1 << 26  # light-sample hash ids of gather samples, apart from pixels
RATIO_SETTLED = 0.02  # bounce power ratios this close on two bounces: extrapolate the rest
BOUNCE_GROUP = 64  # kernels/d2i/d2i.cl bounce_step's work-group (D2I_GROUP)
HAAR_BLOCK = 256  # Haar levels per launch: log2 of this (work-groups of this size)
SPARSE_GROUP = 32  # work-items per row of sparse_rows_grouped (a GPU's products)
SHADOW_TRACERS = ("auto", "device", "embree")  # auto: the device's BVH on a GPU, else Embree
LAYOUTS = ("auto", "gpu", "cpu")  # the products' value type and work shape (D2iRenderer)


def _ordered_rows(artifact: Artifact, prefix: str, key: str, size: int, expand: bool
                  ) -> tuple[Rows, np.ndarray]:
    """The ``prefix`` (d, t or ms) rows of a truncate stage's artifact, stored chunk by
    chunk, ordered by ``key`` (T: their pixel, a pixel's rows keeping their order; D: the
    block row), and the keys in that order. Values as stored, float16 over a per-row
    scale, or with ``expand`` float32; the stored arrays are let go as soon as they are
    reordered (the 400² Tableau's T: 105 M entries)."""
    stored = artifact.read_all()
    keys = stored.pop(key)
    rows = sort_rows(keys, {name: stored.pop(f"{prefix}_{name}")
                            for name in ("count", "index", "value", "scale")})
    del stored
    ordered = Rows.from_counts(rows.pop("count"), rows.pop("index"), rows.pop("value"), size,
                               rows.pop("scale"))
    return (ordered.expanded() if expand else ordered), np.sort(keys, kind="stable")


class D2iRenderer:
    """The d2i frame of one baked scene; keeps device buffers and cached products.

    ``shadows``: ``device`` (the BVH kernel), ``embree`` or ``auto`` (the device's on a
    GPU); ``layout``: ``gpu`` (float16 product values, a work-group per row), ``cpu``
    (float32 values, a work-item per row) or ``auto`` (by the OpenCL device's type).
    Every combination renders the same frame (to float16 rounding of the frozen rows);
    the choices are for speed, and let the GPU's kernels be tested on PoCL."""

    def __init__(self, scene: Scene, artifacts: Mapping[str, Artifact], max_bounces: int = 32,
                 bounce_tolerance: float = 1e-3, shadows: str = "auto",
                 layout: str = "auto") -> None:
        import pyopencl as pcl

        self.pcl, self.ctx, self.queue = pcl, cl.context(), cl.queue()
        for name, value, allowed in (("shadows", shadows, SHADOW_TRACERS),
                                     ("layout", layout, LAYOUTS)):
            if value not in allowed:
                raise PrtError("--option", f"{name}={value!r}: expected one of "
                               f"{', '.join(allowed)}")
        on_gpu = bool(cl.device().type & pcl.device_type.GPU)
        gpu_layout = layout == "gpu" or (layout == "auto" and on_gpu)
        geo = artifacts["geometry"]
        self.device_shadows = DeviceShadows(geo.read("vertices"), geo.read("faces")) \
            if shadows == "device" or (shadows == "auto" and on_gpu) else None
        # the sparse-row products since the frame began: their kernel time and the bytes
        # they moved at least (Frame.kernel_bytes and timings["counted_kernel_ms"])
        self.counted_ms, self.counted_bytes = 0.0, 0
        self.scene = scene
        self.max_bounces, self.bounce_tolerance = max_bounces, bounce_tolerance
        transport, gather = artifacts["d2i.truncate"], artifacts["d2i.gather"]
        self.basis = artifacts["brdf_basis"]
        self.bases: dict[str, Any] = {}  # material -> BrdfBasis (None: Lambertian)
        self.direct = DirectShader(artifacts, scene.camera, shadows=self.device_shadows)
        self.material_names = self.direct.material_names
        self.haar_length = int(transport.attrs["haar_length"])
        self.gather_position = gather.read("position").astype(np.float64)
        self.gather_normal = gather.read("normal").astype(np.float64)
        self.gather_material = gather.read("material_id")
        self.gather_area = gather.read("area").astype(np.float64)
        # the radiance vector the rows index: Haar coefficients, then gather values
        self.size = self.haar_length + len(self.gather_area)
        # float16 values halve the products' value bytes; a GPU converts them for free,
        # PoCL's CPU device element by element (the 400² light edit took 2.1× longer)
        self.half_values = gpu_layout
        # a work-group per row (coalesced reads) on a GPU; one work-item per row, which
        # streams its row through the cache, on a CPU
        self.grouped_products = gpu_layout
        self.sparse_group = SPARSE_GROUP  # work-items per row when grouped
        expand = not self.half_values
        # Ms and D are stored as rows across blocks of gather samples and of pixels
        # (pipeline/methods/d2i/blocks.py): their products are unblocked per item (kernel unblock)
        bounce = artifacts["d2i.truncate_ms"]
        self.ms, _ = _ordered_rows(bounce, "ms", "ms_row", self.size, expand)
        ms_block = int(bounce.attrs["block"])
        gathers = np.arange(len(self.gather_area))
        self.blocks = {"ms": (gathers // ms_block, gathers % ms_block, haar.matrix(ms_block))}
        # D rows are stored tile by tile, T rows by tile and material: D in block-row
        # order, T in raster order of their pixels (a pixel's T rows b0..bk stay in order)
        self.d, _ = _ordered_rows(transport, "d", "d_row", self.size, expand)
        self.t, self.t_pixel = _ordered_rows(artifacts["d2i.truncate_t"], "t", "t_pixel",
                                             self.size, expand)
        d_block = int(transport.attrs["d_block"])
        pixel_block, pixel_slot = pixel_blocks(np.arange(self.direct.width
                                                              * self.direct.height),
                                                    self.direct.width, d_block)
        self.blocks["d"] = (pixel_block, pixel_slot, block_transform(d_block))
        for name, rows, source in (("ms", self.ms, bounce), ("d", self.d, transport)):
            block_of, _, transform = self.blocks[name]
            expected = (int(block_of.max(initial=-1)) + 1) * len(transform)
            if rows.count != expected:
                raise PrtError(source.path, f"holds {rows.count} {name} rows, expected "
                               f"{expected} (blocks of {len(transform)}): re-bake it")
        npix = len(self.direct.material_id)
        self.glossy_first = np.full(npix, -1, np.int32)
        self.glossy_rows = np.zeros(npix, np.int32)
        if len(self.t_pixel):
            pixels, first, rows = np.unique(self.t_pixel, return_index=True, return_counts=True)
            self.glossy_first[pixels], self.glossy_rows[pixels] = first, rows
        self.rmax = int(max(self.glossy_rows.max(initial=0), 1))
        self.buffers: dict[str, dict[str, Any]] = {}
        # the radiance vector of every product, rewritten before each (float4 per entry)
        self.radiance_buffer = self.pcl.Buffer(self.ctx, self.pcl.mem_flags.READ_WRITE,
                                               16 * self.size)
        for name, rows in (("ms", self.ms), ("d", self.d), ("t", self.t)):
            self.upload(name, rows)
        self.notes: list[str] = []
        self.packed_lights = np.zeros((0, LIGHT_FLOATS), np.float32)
        self.gather_visibility: Any = None  # (G, samples) uint8 on the device, once traced
        # the gathers on the device: the bounce loop's inputs and the shadow rays' origins
        self.gather_buffers = {
            "area": cl.read_only_buffer(self.gather_area.astype(np.float32)),
            "material": cl.read_only_buffer(self.gather_material.astype(np.int32)),
            "position": cl.read_only_buffer(self.gather_position.astype(np.float32)),
            "normal": cl.read_only_buffer(self.gather_normal.astype(np.float32)),
            "id": cl.read_only_buffer(np.arange(len(self.gather_area), dtype=np.uint32)
                                      + np.uint32(GATHER_ID_OFFSET))}
        self.work: dict[str, Any] = {}  # per-frame device intermediates (cl.scratch_buffer)
        self.static: dict[str, Any] = {}  # per-pixel device inputs of the combination

    # ------------------------------------------------------------------------ device

    def upload(self, name: str, rows: Rows) -> None:
        """Device buffers of ``rows`` (on a CPU device their own memory) and a buffer
        for their products, for ``_sparse(name, rows, ...)``."""
        self.buffers[name] = {k: cl.shared_read_only_buffer(getattr(rows, k))
                              for k in ("offsets", "index", "value")}
        self.buffers[name]["scale"] = cl.read_only_buffer(
            np.ones(1, np.float32) if rows.scale is None else rows.scale)
        self.buffers[name]["out"] = self.pcl.Buffer(self.ctx, self.pcl.mem_flags.WRITE_ONLY,
                                                    16 * max(rows.count, 1))

    def _sparse(self, name: str, rows: Rows, radiance_w: np.ndarray | None = None,
                read: bool = True) -> tuple[np.ndarray | None, float]:
        """Each row's product with the radiance vector (N, 4) — ``radiance_w`` uploaded
        first when given, else the one the bounce loop left on the device —, written to
        the device buffer ``buffers[name]["out"]`` and, with ``read``, returned (rows, 4);
        and kernel ms. Adds the launch to the counted kernels: its time, and the bytes it
        moves at least (the rows' offsets, indices and values, the radiance vector once,
        the output)."""
        out = np.zeros((rows.count, 4), np.float32) if read else None
        if rows.count == 0:
            return out, 0.0
        buf = self.buffers[name]
        if radiance_w is not None:
            self.pcl.enqueue_copy(self.queue, self.radiance_buffer,
                                  np.ascontiguousarray(radiance_w, np.float32))
        defines = {"INDEX_T": "ushort" if rows.index.dtype == np.uint16 else "int",
                   "VALUE_HALF": int(rows.scale is not None),
                   "SPARSE_GROUP": self.sparse_group}
        args = (buf["offsets"], buf["index"], buf["value"], buf["scale"],
                self.radiance_buffer, np.int32(rows.count))
        if self.grouped_products:
            ms = cl.run(cl.kernel("sparse_rows.cl", "sparse_rows_grouped", defines),
                        rows.count * self.sparse_group, *args, out=out,
                        writes=16 * rows.count, out_buffer=buf["out"],
                        local=self.sparse_group)  # a float4 per row
        else:
            ms = cl.run(cl.kernel("sparse_rows.cl", "sparse_rows", defines), rows.count,
                        *args, out=out, writes=16 * rows.count, out_buffer=buf["out"])
        self.counted_ms += ms
        self.counted_bytes += rows.nbytes + 16 * self.size + 16 * rows.count
        return out, ms

    # ------------------------------------------------------------------------ stages

    def trace_lights(self, scene: Scene) -> dict[str, float]:
        """Shadow rays of the pixels and the gather samples; the gathers' visibility is
        left on the device (``gather_visibility``) for :meth:`gather_radiance`."""
        t0 = time.perf_counter()
        packed, self.notes = self.direct.packed_lights(scene)
        _check_lights(packed)
        kernel_ms = self.direct.trace(packed)
        self.packed_lights = packed
        g, stride = len(self.gather_position), max(total_samples(packed), 1)
        out = cl.scratch_buffer(self.work, "gather_visibility", g * stride)
        if not len(packed) or g == 0:  # nothing to trace: gather_radiance starts from 0
            self.gather_visibility = out
        elif self.device_shadows is not None:
            b = self.gather_buffers
            self.gather_visibility, ms = self.device_shadows.visibility(
                b["position"], b["normal"], b["id"], g, packed, self.direct.diagonal, out)
            kernel_ms += ms
        else:
            vis = light_visibility(self.direct.tracer, self.gather_position,
                                   self.gather_normal,
                                   np.arange(g) + GATHER_ID_OFFSET, packed, self.direct.diagonal)
            self.pcl.enqueue_copy(self.queue, out, np.ascontiguousarray(vis))
            self.gather_visibility = out
        return {"shadow_ms": (time.perf_counter() - t0) * 1e3, "shadow_kernel_ms": kernel_ms}

    def direct_gather_radiance(self, albedo: np.ndarray, out: Any) -> float:
        """L_d = kd/π ⊙ E_g, the gathers' directly lit radiance (G, float4), into device
        buffer ``out`` from the traced visibility (kernel ``gather_direct``); kernel ms."""
        g, packed = len(self.gather_material), self.packed_lights
        if not len(packed) or g == 0:
            self.pcl.enqueue_fill_buffer(self.queue, out, np.float32(0), 0, 16 * max(g, 1))
            return 0.0
        lambert = pack_materials([BrdfParams("lambert", tuple(a)) for a in albedo])
        b = self.gather_buffers
        return cl.run(cl.kernel("direct.cl", "gather_direct", light_defines()), g,
                      b["position"], b["normal"], b["id"], b["material"],
                      cl.read_only_buffer(lambert), cl.read_only_buffer(packed),
                      np.int32(len(packed)), self.gather_visibility,
                      np.int32(max(total_samples(packed), 1)), np.int32(g), out=None,
                      writes=16 * g, out_buffer=out)  # a float4 per gather

    def gather_radiance(self, albedo: np.ndarray) -> dict[str, float]:
        """L = Σ_n L_n from the irradiance and per-material albedos ``albedo``
        (materials, 3), on the device: its radiance vector W L is left in
        ``radiance_buffer`` for the products; timings with the bounce count. Each bounce
        reads back 8 floats per 64 gathers (the stopping rule's sums), nothing else."""
        t0 = time.perf_counter()
        g = len(self.gather_material)
        bounce = cl.scratch_buffer(self.work, "bounce", 16 * max(g, 1))
        total = cl.scratch_buffer(self.work, "total", 16 * max(g, 1))
        kernel_ms = self.direct_gather_radiance(albedo, bounce)
        self.pcl.enqueue_copy(self.queue, total, bounce, byte_count=16 * max(g, 1))
        albedo4 = np.zeros((max(len(albedo), 1), 4), np.float32)
        albedo4[:len(albedo), :3] = albedo
        albedo_buffer = cl.read_only_buffer(albedo4)
        groups = -(-max(g, 1) // BOUNCE_GROUP)
        partial = np.empty((groups, 2, 4), np.float32)
        partial_buffer = cl.scratch_buffer(self.work, "partial", partial.nbytes)
        step = cl.kernel("d2i.cl", "bounce_step")
        product_ms, bounces, ratio = 0.0, 0, None
        alive = bool(len(self.packed_lights)) and g > 0
        for _ in range(self.max_bounces if g else 0):
            if not alive:
                break
            kernel_ms += self.radiance_vector(bounce)
            _, ms = self._sparse("ms", self.ms, read=False)
            kernel_ms, product_ms = kernel_ms + ms, product_ms + ms
            per_gather, ms = self.unblock("ms", self.buffers["ms"]["out"])
            kernel_ms += ms
            kernel_ms += cl.run(step, g, per_gather, self.gather_buffers["material"],
                                albedo_buffer, self.gather_buffers["area"], np.int32(g), bounce,
                                total, out=partial, writes=partial.nbytes,
                                out_buffer=partial_buffer, local=BOUNCE_GROUP)
            sums = partial.astype(np.float64).sum(axis=0)
            power_now, norm_now = sums[0, :3], np.sqrt(sums[0, 3])
            power_before, norm_total = sums[1, :3], np.sqrt(sums[1, 3])
            bounces += 1
            alive = norm_now > 0
            if norm_now <= self.bounce_tolerance * norm_total:
                break
            ratio, settled = _settled_ratio(power_now, power_before, ratio)
            if settled and bounces < self.max_bounces:
                # the rest is geometric: Σ_{m>n} L_m = L_n ρ/(1 − ρ) per channel
                factor = np.zeros(4, np.float32)
                factor[:3] = ratio / (1.0 - ratio)
                kernel_ms += cl.run(cl.kernel("d2i.cl", "add_scaled"), g, bounce, factor,
                                    np.int32(g), out=None, writes=16 * g, out_buffer=total)
                break
        kernel_ms += self.radiance_vector(total)
        return {"bounce_ms": (time.perf_counter() - t0) * 1e3,
                "bounce_kernel_ms": kernel_ms, "bounce_product_ms": product_ms,
                "bounces": float(bounces)}

    def radiance_vector(self, radiance: Any) -> float:
        """[W (|A| ⊙ L); |A| ⊙ L] of the gathers' radiance in device buffer ``radiance``
        (G, float4) into ``radiance_buffer`` (kernels haar_input, haar_blocks; the twin
        of :meth:`to_haar`); kernel ms."""
        n, g = self.haar_length, len(self.gather_area)
        if g == 0:
            return 0.0
        a = cl.scratch_buffer(self.work, "haar_a", 16 * n)
        b = cl.scratch_buffer(self.work, "haar_b", 16 * n)
        # [W ...; |A| ⊙ L]: a float4 per Haar coefficient and per gather, and the blocks
        cl.check_writes("haar_input", self.radiance_buffer, 16 * (n + g))
        cl.check_writes("haar_input", a, 16 * n)
        events = [cl.enqueue(cl.kernel("d2i.cl", "haar_input"), n, radiance,
                             self.gather_buffers["area"], np.int32(g), np.int32(n),
                             self.radiance_buffer, a)]
        blocks = cl.kernel("d2i.cl", "haar_blocks", {"HAAR_BLOCK": HAAR_BLOCK})
        length = n
        while length > 1:  # log2(HAAR_BLOCK) levels per launch, queued back to back
            size = min(HAAR_BLOCK, length)
            events.append(cl.enqueue(blocks, length, a, np.int32(length), b,
                                     self.radiance_buffer, local=size))
            a, b = b, a
            length //= size
        return sum(cl.event_ms(e) for e in events)

    def to_haar(self, radiance: np.ndarray) -> np.ndarray:
        """[W (|A| ⊙ L); |A| ⊙ L] as (N + G, 4) float32 (RGB, 0), N = haar_length, in
        NumPy (the twin of :meth:`radiance_vector`): the rows of T, D and Ms are stored
        per unit source area, their far parts as Haar coefficients (indices < N), their
        near entries in the gather domain (N + g) (pipeline/methods/d2i/stages/transfer.py)."""
        out = np.zeros((self.size, 4), np.float32)
        if len(radiance):
            weighted = (radiance * self.gather_area[:, None]).astype(np.float32)
            out[:self.haar_length, :3] = haar.forward(weighted.T).T[:self.haar_length]
            out[self.haar_length:, :3] = weighted
        return out

    def products(self, frozen: Rows | None = None) -> tuple[Any, Any, float, float]:
        """D L (pixels, float4) and T L (T rows, or the frozen rows, float4) of the
        radiance vector on the device, as device buffers; the sparse products' kernel ms
        and the unblocking's."""
        _, ms_d = self._sparse("d", self.d, read=False)
        name, rows = ("t", self.t) if frozen is None else ("frozen", frozen)
        _, ms_t = self._sparse(name, rows, read=False)
        dl, ms_unblock = self.unblock("d", self.buffers["d"]["out"])
        return dl, self.buffers[name]["out"], ms_d + ms_t, ms_unblock

    def unblock(self, name: str, block_products: Any) -> tuple[Any, float]:
        """Per item (pixel for ``d``, gather sample for ``ms``) its own row's product
        (device buffer, items × float4) from the products of the block rows (kernel
        ``unblock``, twin pipeline.methods.d2i.blocks.unblock); kernel ms. Blocks of one item are
        the items' own rows: returned as they are."""
        block_of, slot, transform = self.blocks[name]
        if len(transform) == 1:
            return block_products, 0.0
        key = f"unblock_{name}"
        if key not in self.static:
            self.static[key] = tuple(cl.read_only_buffer(a) for a in (
                transform.astype(np.float32), block_of.astype(np.int32),
                slot.astype(np.int32)))
        transform_buffer, block_buffer, slot_buffer = self.static[key]
        out = cl.scratch_buffer(self.work, key, 16 * max(len(block_of), 1))
        ms = cl.run(cl.kernel("d2i.cl", "unblock"), len(block_of), block_products,
                    transform_buffer, np.int32(len(transform)), block_buffer, slot_buffer,
                    np.int32(len(block_of)), out=None, writes=16 * len(block_of),
                    out_buffer=out)
        return out, ms

    def coefficients(self, scene: Scene) -> np.ndarray:
        """c(γ) per material (materials, rmax): [1, c_1(γ), ..., c_k(γ)], 0 for Lambert."""
        out = np.zeros((len(self.material_names), self.rmax), np.float32)
        for i, params in enumerate(scene_brdfs(scene, self.material_names)):
            name = self.material_names[i]
            if name not in self.bases:  # the basis depends on what the bake keyed on only
                self.bases[name] = read_basis(self.basis, name, params)
            basis = self.bases[name]
            if basis is None:
                continue
            c = np.r_[1.0, basis.coefficients(params.gamma)]
            out[i, :len(c)] = c[:self.rmax]
        return out

    def freeze(self, coefficients: np.ndarray) -> Rows:
        """Each glossy pixel's T rows merged into one row Σ_j c_j T_j^w (light edits):
        the sparse product C T of the pixels' coefficient rows C (pixels × T rows, c_j
        of its material at its row j) with T, summed in float32 (≤ k + 1 terms per
        entry), entries that cancel exactly dropped, indices ascending per row. SciPy's
        product runs in one pass over T with a dense accumulator per pixel: linear in
        T's entries and in memory (a sort of all entries' keys took 28 s and 9 GB on the
        400² Tableau)."""
        import scipy.sparse as sp

        first = np.r_[True, self.t_pixel[1:] != self.t_pixel[:-1]] if len(self.t_pixel) \
            else np.zeros(0, bool)
        pixel_of_row = np.cumsum(first) - 1
        material = self.direct.material_id[self.t_pixel]
        weight = coefficients[material, place_in_runs(self.t_pixel)].astype(np.float32)
        combine = sp.csr_matrix((weight, (pixel_of_row, np.arange(self.t.count))),
                                shape=(int(first.sum()), self.t.count))
        t = sp.csr_matrix((self.t.values(), self.t.index.astype(np.int32, copy=False),
                           self.t.offsets), shape=(self.t.count, self.size))
        frozen = combine @ t
        frozen.sort_indices()
        per_pixel = np.diff(frozen.indptr)
        if self.half_values:  # quantised as the truncate stage stores rows
            row_scale, half = quantise_values(per_pixel, frozen.data)
            rows = Rows.from_counts(per_pixel, frozen.indices, half, self.size, row_scale)
        else:
            rows = Rows.from_counts(per_pixel, frozen.indices, frozen.data, self.size)
        self.upload("frozen", rows)
        return rows

    def combine(self, direct: Any, dl: Any, tl: Any, materials: np.ndarray,
                coefficients: np.ndarray, frozen: bool) -> tuple[np.ndarray, float]:
        """The frame (pixels, 3) float32 from device buffers ``direct`` (pixels, 3),
        ``dl`` (pixels, float4) and ``tl`` (T or frozen rows, float4); kernel ms."""
        npix = len(self.direct.material_id)
        key = "frozen" if frozen else "rows"
        if key not in self.static:
            first, rows = self.glossy_first, self.glossy_rows
            if frozen:
                glossy = first >= 0
                first = np.where(glossy, np.cumsum(glossy) - 1, -1).astype(np.int32)
                rows = glossy.astype(np.int32)
            self.static[key] = (cl.read_only_buffer(first), cl.read_only_buffer(rows))
            self.static.setdefault("material_id", cl.read_only_buffer(self.direct.material_id))
        if frozen:
            coefficients = np.ones((len(materials), 1), np.float32)
        out = np.empty((npix, 3), np.float32)
        ms = cl.run(cl.kernel("d2i.cl", "combine"), npix, direct, dl,
                    self.static["material_id"], cl.read_only_buffer(materials),
                    *self.static[key], tl,
                    cl.read_only_buffer(np.ascontiguousarray(coefficients, np.float32)),
                    np.int32(coefficients.shape[1]), np.int32(npix), out=out,
                    writes=12 * npix)
        return out, ms

    # ------------------------------------------------------------------------ frames

    def edit_mode(self, kind: str, scene: Scene) -> Callable[[Scene], Frame]:
        """Frames of a sequence of ``kind`` edits of ``scene``: ``light`` (light-edit
        mode) or ``gamma`` (BRDF-edit mode)."""
        return {"light": self.light_edits, "gamma": self.brdf_edits}[kind](scene)

    def frame(self, scene: Scene) -> Frame:
        """A full frame for ``scene``'s lights and materials (nothing cached)."""
        t0 = time.perf_counter()
        self._count_from_here()
        timings = self.trace_lights(scene)
        timings.update(self.gather_radiance(_albedo(scene_brdfs(scene, self.material_names))))
        t1 = time.perf_counter()
        dl, tl, product_ms, unblock_ms = self.products()
        frame = self._finish(scene, dl, tl, frozen=False, t0=t0, t1=t1, timings=timings)
        frame.timings["kernel_ms"] += product_ms + unblock_ms
        frame.timings.update(product_kernel_ms=product_ms, unblock_kernel_ms=unblock_ms)
        return frame

    def brdf_edits(self, scene: Scene) -> Callable[[Scene], Frame]:
        """BRDF-edit mode: lights fixed, so L, D L and every T_j L are computed once; each
        frame re-shades the direct term (shadows kept) of the pixels whose material
        changed (a pixel's direct light reads its own material's row only: the others
        keep their values, the same bytes as a full re-shade) and recombines with c(γ).
        Albedo edits change L: such a frame bounces again (still without tracing)."""
        self.trace_lights(scene)
        albedo = _albedo(scene_brdfs(scene, self.material_names))
        self.gather_radiance(albedo)
        dl, tl, _, _ = self.products()
        cache = {"albedo": albedo, "dl": dl, "tl": tl}
        shaded = _ShadedDirect(self, scene)

        def frame(edited: Scene) -> Frame:
            t0 = time.perf_counter()
            self._count_from_here()
            timings: dict[str, float] = {"shadow_ms": 0.0}
            new_albedo = _albedo(scene_brdfs(edited, self.material_names))
            if not np.array_equal(new_albedo, cache["albedo"]):
                timings.update(self.gather_radiance(new_albedo))
                cache["dl"], cache["tl"], _, _ = self.products()
                cache["albedo"] = new_albedo
            return self._finish(edited, cache["dl"], cache["tl"], frozen=False, t0=t0,
                                t1=time.perf_counter(), timings=timings,
                                direct=shaded.update(edited))

        return frame

    def light_edits(self, scene: Scene) -> Callable[[Scene], Frame]:
        """Light-edit mode: materials fixed, so each glossy pixel's T rows are frozen into
        one row Σ_j c_j(γ) T_j^w; each frame traces shadows, lights the gather samples,
        bounces, and takes one D and one frozen-T product per pixel."""
        frozen = self.freeze(self.coefficients(scene))
        materials = scene.section("materials")

        def frame(edited: Scene) -> Frame:
            if edited.section("materials") != materials:
                raise PrtError(edited.path, "light-edit mode keeps the materials as frozen; "
                               "render a BRDF-edit sequence to change them")
            t0 = time.perf_counter()
            self._count_from_here()
            timings = self.trace_lights(edited)
            timings.update(self.gather_radiance(_albedo(scene_brdfs(edited,
                                                                   self.material_names))))
            t1 = time.perf_counter()
            dl, tl, product_ms, unblock_ms = self.products(frozen)
            out = self._finish(edited, dl, tl, frozen=True, t0=t0, t1=t1, timings=timings)
            out.timings["kernel_ms"] += product_ms + unblock_ms
            out.timings.update(product_kernel_ms=product_ms, unblock_kernel_ms=unblock_ms)
            return out

        return frame

    def _finish(self, scene: Scene, dl: Any, tl: Any, frozen: bool, t0: float,
                t1: float, timings: dict[str, float],
                direct: tuple[Any, float] | None = None) -> Frame:
        """Direct term (or ``direct``: a device buffer of it already shaded, and its
        kernel ms) and combination: the frame, with ``timings`` completed."""
        materials = pack_materials(scene_brdfs(scene, self.material_names))
        coefficients = self.coefficients(scene)
        if direct is None:
            direct = cl.scratch_buffer(self.work, "direct", 12 * len(self.direct.material_id))
            _, direct_ms, _ = self.direct.shade(materials, np.asarray(scene.camera.position),
                                                out_buffer=direct)
        else:
            direct, direct_ms = direct
        rgb, combine_ms = self.combine(direct, dl, tl, materials, coefficients, frozen)
        rgb = self.direct.emitters.draw(rgb, scene)
        t2 = time.perf_counter()
        timings = {**timings, "direct_kernel_ms": direct_ms, "combine_kernel_ms": combine_ms,
                   "pixel_ms": (t2 - t1) * 1e3, "total_ms": (t2 - t0) * 1e3,
                   "setup_ms": (t1 - t0) * 1e3,
                   "kernel_ms": direct_ms + combine_ms + timings.get("bounce_kernel_ms", 0.0)
                   + timings.get("shadow_kernel_ms", 0.0),
                   "counted_kernel_ms": self.counted_ms}
        h, w = self.direct.height, self.direct.width
        return Frame("d2i", rgb.reshape(h, w, 3), timings, list(self.notes),
                     self.counted_bytes)

    def _count_from_here(self) -> None:
        """Start a frame's count of sparse-row products (kernel time and bytes)."""
        self.counted_ms, self.counted_bytes = 0.0, 0


class _ShadedDirect:
    """The direct term of a BRDF-edit mode's frames (lights and shadows fixed) on the
    host and in a device buffer of its own, with the material rows and camera it was
    shaded for; :meth:`update` re-shades only the pixels of the materials whose row
    changed (kernels/direct.cl ``direct_lighting_pixels``: each pixel's value is the full
    shade's, bit for bit), a new camera all of them. A γ drag on a material covering 9 %
    of the Cornell box's pixels re-shades 9 % of them."""

    def __init__(self, renderer: D2iRenderer, scene: Scene) -> None:
        self.direct, self.names = renderer.direct, renderer.material_names
        self.materials = pack_materials(scene_brdfs(scene, self.names))
        self.camera = np.asarray(scene.camera.position, np.float64)
        self.rgb, _, _ = self.direct.shade(self.materials, self.camera)
        self.buffer = cl.read_only_buffer(self.rgb)
        self.rows: dict[int, tuple[np.ndarray, dict[str, Any]]] = {}  # material -> pixels

    def update(self, scene: Scene) -> tuple[Any, float]:
        """The device buffer of ``scene``'s direct term and the kernel ms it took now."""
        import pyopencl as pcl

        materials = pack_materials(scene_brdfs(scene, self.names))
        camera = np.asarray(scene.camera.position, np.float64)
        ms = 0.0
        if not np.array_equal(camera, self.camera) or materials.shape != self.materials.shape:
            self.rgb, ms, _ = self.direct.shade(materials, camera)
            changed = True
        else:
            which = [m for m in range(len(materials))
                     if not np.array_equal(materials[m], self.materials[m])]
            for m in which:
                if m not in self.rows:
                    pixels = np.flatnonzero(self.direct.material_id == m)
                    self.rows[m] = (pixels, self.direct.pixel_rows(pixels))
                pixels, rows = self.rows[m]
                shaded, kernel_ms = self.direct.shade_pixels(materials, camera, rows)
                self.rgb[pixels] = shaded
                ms += kernel_ms
            changed = bool(which)
        if changed:
            pcl.enqueue_copy(cl.queue(), self.buffer, self.rgb)
        self.materials, self.camera = materials, camera
        return self.buffer, ms


def _settled_ratio(power: np.ndarray, previous: np.ndarray, last: np.ndarray | None
                   ) -> tuple[np.ndarray, bool]:
    """ρ (3,): each channel's power (Σ_g |A_g| L_g) of a bounce, ``power``, over the
    ``previous`` bounce's, and whether it is settled — within ``RATIO_SETTLED`` of
    ``last`` bounce's ratio, below 1 — so that later bounces shrink by the same factor
    (the power iteration has found the dominant eigenvector of kd ⊙ Ms)."""
    ratio = np.divide(power, previous, out=np.zeros(3), where=previous > 0)
    settled = last is not None and bool(np.all(ratio < 1) and np.all(
        np.abs(ratio - last) <= RATIO_SETTLED * ratio))
    return ratio, settled


def _albedo(params: list[BrdfParams]) -> np.ndarray:
    return np.array([p.albedo for p in params], np.float64).reshape(-1, 3)


def _check_lights(packed: np.ndarray) -> None:
    if not np.all(np.isfinite(packed)):
        raise PrtError(None, "a light has a non-finite parameter (position, direction, "
                       "intensity or radiance): cannot light the scene")

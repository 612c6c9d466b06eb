"""Stage ``transfer_glossy`` (``d2i.transfer_t``): the glossy transfer basis matrix T of
method d2i (paper 000 §3, §5.2) for one material's pixels of one pixel tile. Schema
``glossy_transfer``.

Per pixel x of the material and gather disk g, rows b0 and b1..bk (the k PCA bases of
the material's edited BRDF term, stage ``brdf_basis``) of the sub-area estimator of
pipeline/methods/d2i/transfer.py on the OpenCL device (kernels/d2i/transfer.cl), with the
visibility V_g(x) the ``transfer`` stage stored for the pixel (its tile's ``v_bits``):
no ray is traced here. Rows are per unit source area, in the Haar domain and cut
near-losslessly as D's (pipeline/methods/d2i/stages/transfer.py ``compress_rows``).

The chunks split the transfer stage's tiles by material (chunking ``tile_material``):
a chunk reads its own material's basis and its parent tile's visibility, so an edit of
one material's γ range (a new basis) re-runs only that material's chunks.
"""

from __future__ import annotations

import numpy as np

from pipeline.engine.stage import AssembleContext, Chunk, ChunkContext, Layout, Output
from pipeline.errors import PrtError
from pipeline.math.brdf import BrdfParams
from pipeline.methods.d2i.brdf_pca import read_basis
from pipeline.methods.d2i.stages.transfer import (
    PIXEL_BATCH,
    compress_rows,
    gather_tools,
    row_attrs,
    rows_by_pixel,
    tile_pixels,
)
from pipeline.methods.d2i.stages.transfer import layout as transfer_layout
from pipeline.methods.d2i.transfer import GlossyTable, Receivers


def glossy_table(ctx: AssembleContext, name: str) -> GlossyTable:
    """Material ``name``'s basis tabulated for the kernel, with its fixed parameters
    (albedo 0, ρs 1; γ is the basis's variable, not read)."""
    shape = {key: ctx.scene.get(f"materials.{name}.{key}")
             for key in ("alpha_ratio", "cxy", "cz", "f0", "ior")}
    params = BrdfParams.from_material(
        ctx.scene[f"materials.{name}.model"], (0.0, 0.0, 0.0),
        {**{k: v for k, v in shape.items() if v is not None}, "specular": (1.0, 1.0, 1.0),
         "gamma": 1.0})
    return GlossyTable.from_basis(read_basis(ctx.inputs["brdf_basis"], name, params))


def parent_visibility(ctx: ChunkContext, pixel: np.ndarray) -> np.ndarray:
    """V (P, G) uint8 of the global pixels ``pixel`` from the parent tile's stored
    bits; PrtError naming the transfer artifact if one of them has none."""
    transfer = ctx.inputs["d2i.transfer"]
    tile = ctx.chunk.get("tile")
    stored = transfer.read_piece("v_pixel", tile)
    row = np.searchsorted(stored, pixel)
    if len(pixel) and (row.max() >= len(stored) or np.any(stored[row] != pixel)):
        raise PrtError(transfer.path, f"tile {tile} holds no visibility for some pixels of "
                       f"material {ctx.chunk.materials[0]}: re-bake it")
    bits = transfer.read_piece("v_bits", tile)[row]
    count = int(transfer.attrs["gather_count"])
    return np.unpackbits(bits, axis=1, count=count)


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    tile, pixel = tile_pixels(ctx)
    name = ctx.chunk.materials[0]
    index = list(ctx.inputs["geometry"].attrs["material_names"]).index(name)
    own = np.flatnonzero(tile["material"] == index)
    vis = parent_visibility(ctx, pixel[own])
    disks, kernel = gather_tools(ctx)
    table = glossy_table(ctx, name)
    keep = float(ctx.params["transfer.keep_tolerance"])
    cap = int(ctx.params["transfer.max_coefficients"])
    parts: list[tuple[np.ndarray, dict, int]] = []
    for start in range(0, len(own), PIXEL_BATCH):
        batch = own[start:start + PIXEL_BATCH]
        receivers = Receivers(tile["position"][batch], tile["normal"][batch],
                              tile["tangent"][batch], tile["wo"][batch])
        _, t = kernel(receivers, vis[start:start + PIXEL_BATCH], table)
        rows = t.shape[1]
        t = t.reshape(t.shape[0] * rows, t.shape[-1])  # -1 cannot stand for 0 gathers
        t *= disks.inverse_area  # in place: the kernel's fresh array
        parts.append((batch, compress_rows(t, disks.area, keep, cap), rows))
    return {f"t_{k}": v for k, v in rows_by_pixel(pixel, parts).items()}


def layout(ctx: AssembleContext) -> Layout:
    return transfer_layout(ctx)


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    return Output(row_attrs(ctx, "transfer.max_coefficients"))

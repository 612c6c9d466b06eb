"""Stage ``triple.brdf_tables``: each material's BRDF table over local views, as stored
wavelet rows (method triple, paper 004 §3.2 and §5). Schema ``triple_brdf``; one chunk
per material.

A material's rows, in order: row 0 the diffuse row ρ̃_d(ω_i) = max(cos θ_i, 0)/π (kept
to ``triple.store_tolerance`` whatever ``triple.store_budget``: one row), then
(glossy models only) one row per view of the view grid (``triple.view_grid``, row
1 + ViewGrid entry index) holding ρ̃_g(ω_i; ω_o) = f_g(ω_i, ω_o) max(cos θ_i, 0) without
ρs (pipeline/methods/triple/brdf_tables.py). Each is a function of ω_i in the local frame, as leaf
means of level ``triple.leaf_level`` from 4^r samples per leaf (``triple.brdf_refine``),
f_g evaluated in OpenCL (kernels/triple/brdf_tables.cl through kernels/brdf.h) for a quarter
of the views and mirrored to the others (:func:`view_leaf_means`), transformed
(kernels/wavelet_forward.cl) and truncated (pipeline/methods/triple/wavelet_rows.py; on the
device, kernels/triple/wavelet_select.cl); values stored as float16 with a float32 scale per
row (wavelet_rows.to_half). A chunk's
key holds only what shapes f_g (model, γ, alpha_ratio, cxy, cz, f0 or ior): editing the
albedo or ρs re-bakes nothing, editing γ re-bakes that material's table only.
"""

from __future__ import annotations

from functools import cache
from typing import Any

import numpy as np

from pipeline.device import cl
from pipeline.device.sphwavelet_cl import forward_device
from pipeline.engine.rows import ROW_CHUNKS
from pipeline.engine.stage import (
    AssembleContext,
    Chunk,
    ChunkContext,
    Layout,
    Output,
    ToleranceResult,
)
from pipeline.math.brdf import MODEL_CODES, BrdfParams, pack_materials
from pipeline.math.sphwavelet import wavelet_basis
from pipeline.methods.triple.brdf_tables import diffuse_leaf_means
from pipeline.methods.triple.frame_grids import ViewGrid
from pipeline.methods.triple.wavelet_rows import (
    from_half,
    leaf_permutation,
    leaf_samples,
    select_rows,
    to_half,
)
from pipeline.methods.triple.wavelet_select_cl import select_rows_buffer

SHAPE_KEYS = ("gamma", "alpha_ratio", "cxy", "cz", "f0", "ior")  # what shapes f_g


def view_grid(params: dict[str, Any]) -> ViewGrid:
    """The grid of ``triple.view_grid`` ([n_phi, n_theta])."""
    return ViewGrid(*(int(n) for n in params["triple.view_grid"]))


def glossy_params(model: str, shape: dict[str, Any]) -> BrdfParams:
    """The material's glossy term as BrdfParams (albedo 0, ρs 1), from its model and the
    scene values of :data:`SHAPE_KEYS` (absent ones None)."""
    given = {k: v for k, v in shape.items() if v is not None}
    return BrdfParams.from_material(model, (0.0, 0.0, 0.0), {**given, "specular": (1, 1, 1)})


LOCAL = 64  # work-group size of brdf_leaf_means (its sample arrays padded to a multiple)


@cache
def _upper_samples(leaf_level: int, refine: int) -> tuple[Any, Any, Any, int, int]:
    """Device buffers of the samples of the K leaves with a sample above the horizon
    (the others' means are 0), padded to P = K rounded up to :data:`LOCAL` with zero
    directions and weights: coordinates (3, 4^r, P) and weights (4^r, P) sample-major,
    leaf indices (P,); and K, P."""
    fine, weights = leaf_samples(leaf_level, refine)
    samples = 4 ** refine
    upper = np.flatnonzero((fine[:, 2].reshape(-1, samples) > 0).any(axis=1))
    padded = -(-len(upper) // LOCAL) * LOCAL
    coords = np.zeros((3, samples, padded), np.float32)
    coords[..., :len(upper)] = fine.reshape(-1, samples, 3)[upper].transpose(2, 1, 0)
    weight = np.zeros((samples, padded), np.float32)
    weight[:, :len(upper)] = weights.reshape(-1, samples)[upper].T
    leaf = np.zeros(padded, np.int32)
    leaf[:len(upper)] = upper
    return (cl.read_only_buffer(coords), cl.read_only_buffer(weight),
            cl.read_only_buffer(leaf), len(upper), padded)


def _defines(params: BrdfParams, refine: int) -> dict[str, int]:
    """Build constants of kernels/triple/brdf_tables.cl (one program per model and r)."""
    return {"SAMPLES": 4 ** refine, "BRDF_MODEL": MODEL_CODES[params.model]}


def leaf_means_buffer(params: BrdfParams, views: np.ndarray, leaf_level: int,
                      refine: int) -> Any:
    """A device buffer of the leaf means (V, N) float32 of ρ̃_g for local views (V, 3)
    (kernels/triple/brdf_tables.cl, built for the material's model)."""
    import pyopencl as cl_

    leaves = 20 * 4 ** leaf_level
    coords, weights, upper, n_upper, padded = _upper_samples(leaf_level, refine)
    kernel = cl.kernel("brdf_tables.cl", "brdf_leaf_means", _defines(params, refine))
    material = cl.read_only_buffer(pack_materials([params])[0])
    result = cl_.Buffer(cl.context(), cl_.mem_flags.READ_WRITE, len(views) * leaves * 4)
    cl_.enqueue_fill_buffer(cl.queue(), result, np.float32(0), 0, len(views) * leaves * 4)
    cl.check_writes("brdf_leaf_means", result, len(views) * leaves * 4)  # (V, N) float
    kernel(cl.queue(), (padded, len(views)), (LOCAL, 1), material,
           cl.read_only_buffer(np.asarray(views, np.float32)), coords, weights, upper,
           np.int32(n_upper), np.int32(padded), np.int32(leaves), result)
    return result


def kernel_leaf_means(params: BrdfParams, views: np.ndarray, leaf_level: int,
                      refine: int) -> np.ndarray:
    """The leaf means of :func:`leaf_means_buffer` on the host."""
    import pyopencl as cl_

    out = np.empty((len(views), 20 * 4 ** leaf_level), np.float32)
    cl_.enqueue_copy(cl.queue(), out, leaf_means_buffer(params, views, leaf_level, refine))
    return out


GRAZING_INSET = 0.5  # θ steps inside the horizon at which the grazing row is sampled


def sampled_views(grid: ViewGrid) -> np.ndarray:
    """The local views (grid.size, 3) at which the rows are sampled: the grid's
    directions, except that the grazing row (θ_o = π/2, N·V = 0) is sampled
    ``GRAZING_INSET`` θ steps inside the horizon. At N·V = 0 the Ward models'
    1/√(N·L N·V) is infinite (measured: the row's mean 1.6e5 against 0.0098 one step
    above, Ward αx 0.1, αy 1; Blinn-Phong 0.0076 against 0.0090), and the views the
    renderer interpolates towards that row lie between the last two rows."""
    views = grid.directions().reshape(grid.n_phi, grid.n_theta, 3)
    theta = 0.5 * np.pi * (1.0 - GRAZING_INSET / (grid.n_theta - 1))
    phi = 2 * np.pi * np.arange(grid.n_phi) / grid.n_phi
    views[:, -1] = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                             np.full_like(phi, np.cos(theta))], -1)
    return views.reshape(-1, 3)


def mirror_sources(grid: ViewGrid, leaf_level: int) -> tuple[np.ndarray, np.ndarray]:
    """For n_φ a multiple of 4, per φ index j of ``grid``: the φ index (≤ n_φ/4) whose
    leaf means view j's are, permuted, and the permutation (n_φ, N) (see
    :func:`view_leaf_means`)."""
    quarter = grid.n_phi // 4
    identity = np.arange(20 * 4 ** leaf_level)
    mirror_x = leaf_permutation(leaf_level, (-1, 1, 1))
    mirror_y = leaf_permutation(leaf_level, (1, -1, 1))
    half_turn = leaf_permutation(leaf_level, (-1, -1, 1))
    pairs = [(j, identity) if j <= quarter else
             (2 * quarter - j, mirror_x) if j <= 2 * quarter else
             (j - 2 * quarter, half_turn) if j <= 3 * quarter else
             (4 * quarter - j, mirror_y) for j in range(grid.n_phi)]
    return (np.asarray([j for j, _ in pairs], np.int32),
            np.stack([perm for _, perm in pairs]).astype(np.int32))


def view_leaf_means_buffer(params: BrdfParams, grid: ViewGrid, leaf_level: int,
                           refine: int) -> Any:
    """A device buffer of the leaf means (grid.size, N) float32 of ρ̃_g for every view of
    ``grid`` (at :func:`sampled_views`), evaluating only the views with φ_o ∈ [0, π/2]
    when n_φ is a multiple of 4 and mirroring them on the device
    (kernels/triple/brdf_tables.cl brdf_mirror_views).

    Every model here is unchanged when ω_i and ω_o are reflected together in the
    planes x = 0 or y = 0 (it reads them through n·ω, ω_i·ω_o and s_x², s_y² of
    s = ω_i + ω_o). So with g_φ(ω_i) = ρ̃_g(ω_i; ω_o(θ_o, φ)): g_{π−φ}(ω) = g_φ(M_x ω),
    g_{−φ}(ω) = g_φ(M_y ω) and g_{φ+π}(ω) = g_φ(M_x M_y ω), and their leaf means are
    g_φ's permuted (:func:`pipeline.methods.triple.wavelet_rows.leaf_permutation`)."""
    import pyopencl as cl_

    if grid.n_phi % 4:
        return leaf_means_buffer(params, sampled_views(grid), leaf_level, refine)
    quarter = grid.n_phi // 4
    views = sampled_views(grid).reshape(grid.n_phi, grid.n_theta, 3)
    base = leaf_means_buffer(params, views[:quarter + 1].reshape(-1, 3), leaf_level, refine)
    leaves = 20 * 4 ** leaf_level
    source, perm = mirror_sources(grid, leaf_level)
    out = cl_.Buffer(cl.context(), cl_.mem_flags.READ_WRITE, grid.size * leaves * 4)
    cl.check_writes("brdf_mirror_views", out, grid.n_theta * grid.n_phi * leaves * 4)
    cl.kernel("brdf_tables.cl", "brdf_mirror_views", _defines(params, refine))(
        cl.queue(), (grid.n_theta, grid.n_phi), None, base,
        cl.read_only_buffer(source), cl.read_only_buffer(perm), np.int32(grid.n_theta),
        np.int32(leaves), out)
    return out


def view_leaf_means(params: BrdfParams, grid: ViewGrid, leaf_level: int,
                    refine: int) -> np.ndarray:
    """The leaf means of :func:`view_leaf_means_buffer` on the host, (grid.size, N)."""
    import pyopencl as cl_

    out = np.empty((grid.size, 20 * 4 ** leaf_level), np.float32)
    cl_.enqueue_copy(cl.queue(), out, view_leaf_means_buffer(params, grid, leaf_level, refine))
    return out


def glossy_rows(model: str, shape: dict[str, Any], grid: ViewGrid, level: int, refine: int,
                budget: int, tolerance: float, top: int) -> dict[str, np.ndarray]:
    """The stored glossy rows of a material (one per view of ``grid``; CSR as
    :func:`~pipeline.methods.triple.wavelet_rows.select_rows`, values (nnz, 1) float32 rounded as
    stored: float16 over the row's scale): what a chunk stores, and what the renderer
    re-samples for a γ edit at run time (so that it equals a fresh bake)."""
    rows = stored_glossy_rows(model, shape, grid, level, refine, budget, tolerance, top)
    scale = rows.pop("scale")
    return {**rows, "value": from_half(rows["count"], rows["value"], scale)}


def stored_glossy_rows(model: str, shape: dict[str, Any], grid: ViewGrid, level: int,
                       refine: int, budget: int, tolerance: float, top: int
                       ) -> dict[str, np.ndarray]:
    """:func:`glossy_rows` as stored: ``value`` (nnz, 1) float16 over ``scale`` (R,)
    float32, as the device wrote them (wavelet_rows.to_half's rule)."""
    means = view_leaf_means_buffer(glossy_params(model, shape), grid, level, refine)
    glossy = forward_device(means, grid.size, level)
    return select_rows_buffer(glossy, 0, grid.size, 1, level, budget, tolerance, top,
                              half=True)


def _section(ctx: AssembleContext, name: str, key: str) -> Any:
    return ctx.scene.get(f"materials.{name}.{key}")


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    """The material's rows: the diffuse row, then one per view for a glossy model."""
    name = ctx.chunk.material
    model = _section(ctx, name, "model")
    level, refine = int(ctx.params["triple.leaf_level"]), int(ctx.params["triple.brdf_refine"])
    tolerance = float(ctx.params["triple.store_tolerance"])
    top = int(ctx.params["triple.store_top"])
    diffuse = wavelet_basis(level).forward(diffuse_leaf_means(level, refine))
    # the clamped cosine's kink at the horizon needs ~1.5k coefficients for 1 %: one row
    # per material, so it is kept to the tolerance whatever the budget
    row = select_rows(diffuse[None, None], level, diffuse.size, tolerance, top)
    value, scale = to_half(row["count"], row["value"][:, 0])
    parts = [{**row, "value": value, "scale": scale}]
    if model != "lambert":  # stored as the device wrote them (no float32 round trip)
        glossy = stored_glossy_rows(model, {k: _section(ctx, name, k) for k in SHAPE_KEYS},
                                    view_grid(ctx.params), level, refine,
                                    int(ctx.params["triple.store_budget"]), tolerance, top)
        parts.append({**glossy, "value": glossy["value"][:, 0]})
    rows = {k: np.concatenate([part[k] for part in parts]) for k in parts[0]}
    ctx.meta.update(rows=len(rows["count"]), worst_residual=float(rows["residual"].max()),
                    most_coefficients=int(rows["count"].max()), entries=len(rows["index"]))
    return rows


def layout(ctx: AssembleContext) -> Layout:
    return Layout(sizes=ROW_CHUNKS)


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    """Attributes (where each material's rows start), and per glossy material whether
    its rows met ``triple.store_tolerance``."""
    tolerance = float(ctx.params["triple.store_tolerance"])
    budget = int(ctx.params["triple.store_budget"])
    names = [chunk.material for chunk, _ in metas]
    starts = np.concatenate([[0], np.cumsum([m["rows"] for _, m in metas])]).tolist()
    results = []
    for chunk, meta in metas:
        short = meta["worst_residual"] > tolerance
        results.append(ToleranceResult(
            f"material {chunk.material}", "worst relative L2 error of a stored BRDF row",
            tolerance, meta["worst_residual"], {"coefficients": meta["most_coefficients"]},
            f"triple.store_budget {budget}" if short else "",
            "raise triple.store_budget" if short else ""))
    grid = view_grid(ctx.params)
    return Output({
        "material_names": names,
        "models": [_section(ctx, n, "model") for n in names],
        "row_start": [int(s) for s in starts],
        "view_grid": [grid.n_phi, grid.n_theta],
        "leaf_level": int(ctx.params["triple.leaf_level"]),
        "refine": int(ctx.params["triple.brdf_refine"]),
        "store_tolerance": tolerance,
        "store_budget": budget,
        "store_top": int(ctx.params["triple.store_top"]),
    }, tolerances=results)

"""Stage ``brdf_basis``: the PCA basis of each material's edited BRDF term (one chunk per
material; paper 000 §4, pipeline/methods/d2i/brdf_pca.py). Schema ``brdf_basis``.

A chunk's key holds only what shapes the edited term family: the material's model,
gamma_range, alpha_ratio (anisotropic Ward) and pca_tolerance, and the sampling params.
Editing γ, the albedos, ρs or the Fresnel F0 re-bakes nothing here.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pipeline.engine.stage import (
    AssembleContext,
    Block,
    Chunk,
    ChunkContext,
    Layout,
    Output,
    ToleranceResult,
)
from pipeline.math.brdf import BrdfParams
from pipeline.methods.d2i.brdf_pca import BASIS_FIELDS, build_basis, gamma_test_grid

_FIELDS = BASIS_FIELDS


def _material_section(ctx: AssembleContext, name: str, key: str) -> Any:
    return ctx.scene.get(f"materials.{name}.{key}")


def layout(ctx: AssembleContext) -> Layout:
    """One row per scene material in every array."""
    n = len({key.split(".")[1] for key in ctx.scene if key.startswith("materials.")})
    max_k = int(ctx.params["brdf_basis.max_k"])
    h = int(ctx.params["brdf_basis.coordinate_samples"])
    n_gamma = int(ctx.params["brdf_basis.gamma_samples"])
    n_test = len(gamma_test_grid(1.0, 2.0, n_gamma))
    return Layout({"grid": (n, h), "gamma_samples": (n, n_gamma), "mean": (n, h),
                   "basis": (n, max_k, h), "projection": (n, max_k, h),
                   "singular_values": (n, n_gamma), "gamma_test": (n, n_test),
                   "rms": (n, max_k + 1, n_test), "rel_rms": (n, max_k + 1, n_test),
                   "k": (n,)})


def run_chunk(ctx: ChunkContext) -> dict[str, Block]:
    """The material's row of every array; k and the worst relative RMS at that k go to
    ``finalize`` through ``ctx.meta`` (worst None for a Lambertian material)."""
    arrays, worst = _basis_arrays(ctx)
    ctx.meta.update(k=int(arrays["k"]), worst_rel_rms=worst)
    return {name: Block((ctx.chunk.index,), a[None]) for name, a in arrays.items()}


def _basis_arrays(ctx: ChunkContext) -> tuple[dict[str, np.ndarray], float | None]:
    name = ctx.chunk.material
    model = _material_section(ctx, name, "model")
    max_k = int(ctx.params["brdf_basis.max_k"])
    h = int(ctx.params["brdf_basis.coordinate_samples"])
    n_gamma = int(ctx.params["brdf_basis.gamma_samples"])
    if model == "lambert":
        n_test = len(gamma_test_grid(1.0, 2.0, n_gamma))
        return {"grid": np.zeros(h), "gamma_samples": np.zeros(n_gamma), "mean": np.zeros(h),
                "basis": np.zeros((max_k, h)), "projection": np.zeros((max_k, h)),
                "singular_values": np.zeros(n_gamma), "gamma_test": np.zeros(n_test),
                "rms": np.zeros((max_k + 1, n_test)), "rel_rms": np.zeros((max_k + 1, n_test)),
                "k": np.zeros((), np.int32)}, None
    lo, hi = _material_section(ctx, name, "gamma_range")
    tolerance = _tolerance(ctx, name)
    params = BrdfParams(model, (0.0, 0.0, 0.0), gamma=lo,
                        alpha_ratio=_material_section(ctx, name, "alpha_ratio") or 1.0)
    basis = build_basis(params, (lo, hi), tolerance, max_k, n_gamma, h)
    arrays = {f: getattr(basis, f) for f in _FIELDS}
    worst = float(basis.rel_rms[basis.k].max())
    return {**arrays, "k": np.array(basis.k, np.int32)}, worst


def _tolerance(ctx: AssembleContext, name: str) -> float:
    own = _material_section(ctx, name, "pca_tolerance")
    return float(own if own is not None else ctx.params["brdf_basis.tolerance"])


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    """Attributes per material, and per glossy material whether its k met the
    tolerance (pipeline/engine/tolerance.py)."""
    names = [chunk.material for chunk, _ in metas]
    models = [_material_section(ctx, n, "model") for n in names]
    max_k = int(ctx.params["brdf_basis.max_k"])
    results = []
    for chunk, meta in metas:
        worst = meta["worst_rel_rms"]
        if worst is None:
            continue
        tolerance = _tolerance(ctx, chunk.material)
        short = worst > tolerance
        results.append(ToleranceResult(
            f"material {chunk.material}", "worst relative RMS of the PCA fit", tolerance,
            worst, {"k": meta["k"]}, f"max_k {max_k}" if short else "",
            "narrow its gamma_range, or raise brdf_basis.max_k" if short else ""))
    return Output({
        "material_names": names,
        "models": models,
        "gamma_ranges": [_material_section(ctx, n, "gamma_range") for n in names],
        "tolerances": [None if m == "lambert" else _tolerance(ctx, n)
                       for n, m in zip(names, models, strict=True)],
        "reached": [m["worst_rel_rms"] is None
                    or m["worst_rel_rms"] <= _tolerance(ctx, c.material) for c, m in metas],
        "max_k": max_k,
    }, tolerances=results)

"""BRDF tables of method triple (paper 004 §3.2, §5): per local view ω_o, the function
of ω_i that the triple product integrates against lighting and visibility,

    ρ̃_g(ω_i; ω_o) = f_g(ω_i, ω_o) · max(cos θ_i, 0),   f_g = f_F · f_E without ρs
    ρ̃_d(ω_i)      = max(cos θ_i, 0) / π                (the diffuse row, without kd)

(:func:`pipeline.math.brdf.glossy`), local frame (z the normal), 1/sr. The full
reflected radiance is kd·∫L V ρ̃_d + ρs·∫L V ρ̃_g(·; ω_o): kd and ρs are applied at
render time, so editing them re-bakes nothing. The NumPy side of
kernels/triple/brdf_tables.cl: leaf means over ω_i (:mod:`pipeline.methods.triple.wavelet_rows`).
"""

from __future__ import annotations

import numpy as np

from pipeline.math.brdf import BrdfParams, glossy
from pipeline.math.sphwavelet import leaf_means


def glossy_leaf_means(params: BrdfParams, views: np.ndarray, leaf_level: int,
                      refine: int) -> np.ndarray:
    """Leaf means (V, N) over ω_i of ρ̃_g(ω_i; ω_o) for local unit views (V, 3)."""
    views = np.asarray(views, np.float64)

    def table(wi: np.ndarray) -> np.ndarray:
        cos = np.maximum(wi[:, 2], 0.0)
        return glossy(wi[None, :, :], views[:, None, :], params) * cos[None, :]

    return leaf_means(table, leaf_level, refine)


def diffuse_leaf_means(leaf_level: int, refine: int) -> np.ndarray:
    """Leaf means (N,) of ρ̃_d(ω_i) = max(cos θ_i, 0)/π."""
    return leaf_means(lambda wi: np.maximum(wi[:, 2], 0.0) / np.pi, leaf_level, refine)

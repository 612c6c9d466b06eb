"""PCA linearization of a BRDF's edited term (paper 000 §4).

Sampling. γ takes ``gamma_samples`` evenly spaced values over [γmin, γmax]; the PCA
coordinate x (pipeline/math/brdf.py: δ = ∠(N, H) for most models, the effective δ_e for
the anisotropic Ward, Lafortune's normalised lobe base) takes ``coordinate_samples``
values over its domain: δ evenly spaced on [0, π/2] (the paper's choice; it weights the
lobe's peak more than solid angle would); Lafortune's x on the paper's [ε, 1 − ε],
ε = 1e-3, evenly spaced in the angle arccos x rather than in x, so that its lobe x^γ is
sampled like Blinn-Phong's cos^γδ (evenly in x, the γ = 300 lobe's half width spans 2.4
samples of 1024 and linear interpolation alone errs by 7.6e-3;
decision 0018).

Basis. P (k' × h) stacks p_i = f_E(γ_i, x_1..h); b0 is the mean row; the SVD
P − b0 = U S Vᵀ gives the orthonormal basis rows b_1..b_k = the first k rows of Vᵀ;
H = (B'ᵀB')⁻¹B'ᵀ (= B'ᵀ's pseudo-inverse, B' = [b_1 … b_k]); c(γ) = H (p(γ) − b0).

Error. RMS(γ, k) = ‖b0 + B'c(γ) − p(γ)‖₂ / √h, the root-mean-square over the x grid
(absolute, in 1/sr), and the relative RMS = RMS / (‖p(γ)‖₂ / √h). Both are tabulated for
k = 0..max_k on a test grid of γ values: 4 (k' − 1) + 1 evenly spaced ones (the samples and
three between each pair) and k' geometrically spaced ones (the error oscillates fastest
near γmin). k is the smallest count whose worst relative RMS over the test grid
is at most the tolerance, capped at max_k.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from pipeline.errors import PrtError
from pipeline.math.brdf import BrdfParams, edited_term

LAFORTUNE_EPSILON = 1e-3
# Paper 000 Table 5's editing ranges per model (the anisotropic Ward, from paper 004,
# takes Ward's); tests and studies use them.
PAPER_GAMMA_RANGES = {
    "blinn_phong": (3.0, 300.0), "lafortune": (3.0, 300.0), "ashikhmin_shirley": (3.0, 300.0),
    "ward": (0.05, 2.0), "ward_duer": (0.05, 2.0), "ward_anisotropic": (0.05, 2.0),
    "cook_torrance": (0.1, 2.0),
}
TEST_OVERSAMPLING = 4
# The tabulated fields of a BrdfBasis, as the brdf_basis artifact stores them.
BASIS_FIELDS = ("grid", "gamma_samples", "mean", "basis", "projection", "singular_values",
                "gamma_test", "rms", "rel_rms")


def coordinate_grid(model: str, samples: int) -> np.ndarray:
    """The model's PCA coordinate samples, ascending, shape (samples,)."""
    if model == "lafortune":
        angles = np.linspace(np.arccos(1.0 - LAFORTUNE_EPSILON), np.arccos(LAFORTUNE_EPSILON),
                             samples)
        return np.cos(angles)[::-1].copy()
    return np.linspace(0.0, 0.5 * np.pi, samples)


def gamma_test_grid(lo: float, hi: float, gamma_samples: int) -> np.ndarray:
    """γ values of the error table, ascending: 4 (k' − 1) + 1 evenly spaced ones (the
    samples and three between each pair) and k' geometrically spaced ones, since the error
    oscillates fastest in γ near γmin. Its length depends on k' only."""
    return np.sort(np.concatenate([
        np.linspace(lo, hi, TEST_OVERSAMPLING * (gamma_samples - 1) + 1),
        np.geomspace(lo, hi, gamma_samples)]))


@dataclass(frozen=True)
class BrdfBasis:
    """A linearized edited term. Shapes: ``grid`` (h,), ``gamma_samples`` (k',),
    ``mean`` b0 (h,), ``basis`` (max_k, h) orthonormal rows b_1.., ``projection`` H
    (max_k, h), ``singular_values`` (k',), ``gamma_test`` (t,), ``rms`` and
    ``rel_rms`` (max_k + 1, t) for k = 0..max_k; ``k`` the chosen count."""

    params: BrdfParams
    gamma_range: tuple[float, float]
    grid: np.ndarray
    gamma_samples: np.ndarray
    mean: np.ndarray
    basis: np.ndarray
    projection: np.ndarray
    singular_values: np.ndarray
    gamma_test: np.ndarray
    rms: np.ndarray
    rel_rms: np.ndarray
    k: int
    tolerance: float

    def check_gamma(self, gamma: float, what: str = "gamma") -> None:
        """A clear error when γ lies outside the baked range (no extrapolation)."""
        lo, hi = self.gamma_range
        if not lo <= gamma <= hi:
            raise PrtError(None, f"{what} = {gamma:g} is outside the baked PCA range "
                           f"[{lo:g}, {hi:g}] of this {self.params.model} material; widen "
                           "its gamma_range and re-bake")

    def coefficients(self, gamma: float, k: int | None = None) -> np.ndarray:
        """c(γ) = H (p(γ) − b0), shape (k,) (default: the chosen k)."""
        self.check_gamma(gamma)
        k = self.k if k is None else k
        p = edited_term(gamma, self.grid, self.params)
        return self.projection[:k] @ (p - self.mean)

    def reconstruct(self, gamma: float, x: np.ndarray, k: int | None = None,
                    clamp: bool = True) -> np.ndarray:
        """f_E(γ, x) ≈ b0(x) + Σ c_j(γ) b_j(x) at coordinates ``x`` (linear interpolation
        of the tabulated basis; outside the grid, the end value). Negative values (ringing
        of the truncated basis in the lobe's tail) are clamped to 0 unless ``clamp`` is
        false."""
        k = self.k if k is None else k
        c = self.coefficients(gamma, k)
        table = self.mean + c @ self.basis[:k]
        values = np.interp(x, self.grid, table)
        return np.maximum(values, 0.0) if clamp else values


def build_basis(params: BrdfParams, gamma_range: tuple[float, float], tolerance: float,
                max_k: int, gamma_samples: int = 256, coordinate_samples: int = 1024,
                term: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
                ) -> BrdfBasis:
    """Sample, decompose and tabulate the error of ``params.model``'s edited term (or of
    ``term(γ, x)``, for studies of other normalisations)."""
    lo, hi = gamma_range
    grid = coordinate_grid(params.model, coordinate_samples)
    gammas = np.linspace(lo, hi, gamma_samples)
    term = term or (lambda g, x: edited_term(g, x, params))
    samples = term(gammas[:, None], grid[None, :])
    mean = samples.mean(axis=0)
    _, sv, vt = np.linalg.svd(samples - mean, full_matrices=False)
    kmax = min(max_k, len(sv))
    basis = np.zeros((max_k, coordinate_samples))
    basis[:kmax] = vt[:kmax]
    projection = np.zeros_like(basis)
    projection[:kmax] = np.linalg.pinv(vt[:kmax].T)

    gamma_test = gamma_test_grid(lo, hi, gamma_samples)
    test = term(gamma_test[:, None], grid[None, :]) - mean
    coeff = test @ basis.T
    rms = np.empty((max_k + 1, len(gamma_test)))
    residual = test.copy()
    for k in range(max_k + 1):
        if k:
            residual -= np.outer(coeff[:, k - 1], basis[k - 1])
        rms[k] = np.sqrt(np.mean(residual * residual, axis=1))
    norm = np.sqrt(np.mean((test + mean) ** 2, axis=1))
    rel_rms = rms / norm[None, :]
    worst = rel_rms.max(axis=1)
    under = np.flatnonzero(worst <= tolerance)
    k = int(under[0]) if len(under) else max_k
    return BrdfBasis(params, (float(lo), float(hi)), grid, gammas, mean, basis, projection,
                     sv, gamma_test, rms, rel_rms, k, tolerance)


def read_basis(artifact: Any, material: str, params: BrdfParams) -> BrdfBasis | None:
    """The basis of ``material`` from a brdf_basis artifact (any object with the
    ``attrs`` and ``read(name, region)`` of pipeline.engine.store.Artifact; ``None`` for
    Lambertian materials); ``params`` are the material's current BRDF parameters."""
    names = artifact.attrs["material_names"]
    if material not in names:
        raise KeyError(material)
    i = names.index(material)
    k = int(artifact.read("k")[i])
    if artifact.attrs["models"][i] == "lambert":
        return None
    fields = {f: artifact.read(f, (i,)) for f in BASIS_FIELDS}
    lo, hi = artifact.attrs["gamma_ranges"][i]
    return BrdfBasis(params=params, gamma_range=(lo, hi), k=k,
                     tolerance=artifact.attrs["tolerances"][i], **fields)

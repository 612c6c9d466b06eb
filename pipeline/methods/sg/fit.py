"""Fitting sums of spherical Gaussians to tabulated functions on the sphere (paper 003
§4.2): a batched Levenberg–Marquardt over many functions at once, and a reference path
through ``scipy.optimize.least_squares(method="trf")`` (the trust-region-reflective
family of Coleman & Li 1996, behind the paper's fmincon).

**Model.** Each function T (one vertex and view; C channels, RGB) is approximated by N
lobes (pipeline/math/sg.py) sharing mean and sharpness across channels:

    T̃(ω) = Σ_k w_k G(ω; μ_k, λ_k),   w_k ∈ R^C, λ_k = 1/σ_k².

**Energy** (paper eq. 6, per function; the paper sums it over the 92 views of a vertex):

    E = α D + β M + γ V + δ S,

- D = ∫_S ‖T̃(ω) − T(ω)‖² dω, by the grid's quadrature Σ_s Ω_s ‖T̃(ω_s) − T(ω_s)‖²
  (units T² sr; the paper sums unweighted cubemap texels; a solid-angle weight makes it
  the sphere's L² norm on any grid). α = 1: the other weights are relative to it.
- M = Σ_k ‖μ_k − μ̄_k‖² (eq. 8), μ̄_k a target mean: the average of the neighbouring
  views' means. V = Σ_k (σ_k − σ̄_k)² (eq. 9), σ̄_k likewise. Coupled across views,
  these make one vertex's 92 fits one problem; in this batched solver the targets are
  given (a caller alternates: average the neighbours' current parameters, refit — a
  block-Jacobi sweep). With w = 0 (an occluded view) they alone place μ and σ.
- S = Σ_{k1<k2} Σ_n max(−⟨μ_k1 − μ_k2, d_n,k1k2⟩, 0)² (eq. 10), d_n,k1k2 = μ_n,k1 −
  μ_n,k2 the difference of the means of an already fitted neighbour n (vertex flood
  fill): positive when the lobes' arrangement agrees, penalised when it is flipped.

β, γ, δ default to 0. The tests check all four terms' Jacobians and that β and γ place
an occluded view's lobes; fits of real data so far use D alone.

**Parameters and bounds** (bounded parameters keep batched fits stable and
lobes from swapping). Lobe k moves in a chart around its initial mean m_k:
μ_k = (m_k + a_k t_k + b_k b̂_k)/‖·‖ with (t_k, b̂_k) a tangent basis of m_k and
|a_k|, |b_k| ≤ tan(max_shift); ρ_k = log λ_k between log(1/σ_max²) and
log(1/σ_floor²) (σ_floor: ``_sigma_floor``, half a grid step by default); w_k ≥ 0. The
vector of a function is x = (a_1, b_1, ρ_1, …, a_N, b_N, ρ_N, w_1, …, w_N), P = N(3 + C).

**Jacobian.** With E_k(s) = √Ω_s G_k(ω_s) and the data residuals
r_sc = Σ_k w_kc E_k(s) − √Ω_s T_c(ω_s):

    ∂r_sc/∂w_kc = E_k(s),
    ∂r_sc/∂a_k = w_kc E_k(s) λ_k ω_s·∂μ_k/∂a_k,   ∂μ/∂a = (t − μ(μ·t))/‖m + a t + b b̂‖,
    ∂r_sc/∂ρ_k = w_kc E_k(s) λ_k (μ_k·ω_s − 1) = −w_kc E_k(s) λ_k ‖ω_s − μ_k‖²/2.

Writing the 4N fields Φ = (E_k, D_ka, D_kb, D_kρ) (the derivatives of E_k), JᵀJ and
Jᵀr follow from the Gram matrix Q = ΦΦᵀ (4N × 4N per function) and Φ r, so a step costs
O(S (4N)²) per function instead of O(S C P²) for the dense Jacobian:

    (JᵀJ)[θ_kj, θ_k'j'] = (Σ_c w_kc w_k'c) Q[D_kj, D_k'j'],
    (JᵀJ)[θ_kj, w_k'c]  = w_kc Q[D_kj, E_k'],   (JᵀJ)[w_kc, w_k'c'] = δ_cc' Q[E_k, E_k'],
    (Jᵀr)[θ_kj] = Σ_c w_kc (Φ r)[D_kj, c],       (Jᵀr)[w_kc] = (Φ r)[E_k, c].

**Levenberg–Marquardt.** Per function: solve (JᵀJ + ν (diag JᵀJ + ε)) δx = −Jᵀr,
project x + δx onto the bounds, accept if the energy drops (ν /= 3) else ν *= 2 and
retry; stop when an accepted step lowers E by less than ``tolerance`` · E, or E is 0,
or ν exceeds 1e12 (no descent left: a stationary point of the projected problem).
A fit stopped by ``max_iterations`` instead is reported as not converged; it happens
on flat valleys, e.g. a spare lobe (N larger than the data needs) fitting noise.
Functions converge independently; each iteration works on the ones still active.

**Initialisation (moments).** Greedily for k = 1..N, on the channel mean t(ω) of T
less the lobes placed so far (clipped at 0): p = the direction of its maximum, θ½ the
angle from p to the nearest sample below half the maximum, and a window, the cap of
half-angle ψ = 2.5 θ½ (clamped to [2 grid steps, 90°]) around p, which holds this lobe
and little of the others. The window's first moment m = Σ Ω t ω / Σ Ω t gives
μ_k = m/‖m‖, and λ_k solves A(λ, ψ) = ‖m‖, the mean resultant length of a lobe
truncated to the cap (``_cap_resultant``; a von Mises–Fisher moment estimate with the
truncation accounted for). The lobe's amplitude (least squares over the window) is
subtracted before the next. The weights are then the least-squares ones for all N
lobes (clipped at 0). A function with ∫T² dω ≤
``zero_energy`` (all views occluded) gets zero weights, mean ``default_mean`` and σ
``default_sigma``: a defined, finite result, which the alignment terms move if active.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from pipeline.math import sg

_EPS = 1e-12  # added to the damped diagonal: a lobe with w = 0 has no data Jacobian


@dataclass(frozen=True)
class FitOptions:
    """Settings of a fit; the energy weights are relative to the data term's α = 1."""

    lobes: int = 1                 # N Gaussians per function (1–3)
    mean_weight: float = 0.0       # β, mean alignment to ``FitTargets.mean``
    sigma_weight: float = 0.0      # γ, σ alignment to ``FitTargets.sigma`` (σ in radians)
    spatial_weight: float = 0.0    # δ, arrangement against ``FitTargets.neighbour_means``
    max_shift_deg: float = 45.0    # each mean stays within a box of tan(this) around m_k
    sigma_min: float = 0.005       # radians (λ ≤ 4·10⁴), raised to grid_sigma · step
    grid_sigma: float = 0.5        # σ ≥ this × the grid's step √(4π/S): see _sigma_floor
    sigma_max: float = 4.0         # radians (λ ≥ 1/16)
    max_iterations: int = 200
    # relative energy decrease that ends a fit (both paths); 1e-8 doubles the time of
    # N = 3 fits of occluded data (two lobes creeping along one feature) for 0.03 %
    tolerance: float = 1e-6
    zero_energy: float = 0.0       # ∫T² dω at or below which a function counts as zero
    default_sigma: float = 0.5     # σ of the lobes of a zero function (radians)
    batch: int = 256               # functions per batched step (memory: batch · 4N · S)
    # dtype of the fields Φ and their Gram matrix ("float32": exp and products in single
    # precision, energies and steps in float64; studies/sg_fit_coarse.py --float32)
    fields: str = "float64"


@dataclass(frozen=True)
class FitTargets:
    """Targets of the coupling terms for F functions (None where the term is off)."""

    mean: np.ndarray | None = None             # (F, N, 3) unit, μ̄_k
    sigma: np.ndarray | None = None            # (F, N) radians, σ̄_k
    neighbour_means: np.ndarray | None = None  # (F, R, N, 3) means of fitted neighbours


@dataclass(frozen=True)
class SGFit:
    """Fitted lobes of F functions."""

    mean: np.ndarray        # (F, N, 3) unit
    sharpness: np.ndarray   # (F, N) λ
    weight: np.ndarray      # (F, N, C), ≥ 0
    energy: np.ndarray      # (F,) E at the result
    iterations: np.ndarray  # (F,) accepted + rejected LM steps
    converged: np.ndarray   # (F,) bool: stopped by the tolerance (not by max_iterations)

    @property
    def sigma(self) -> np.ndarray:
        return sg.sigma_of(self.sharpness)

    def subset(self, index: np.ndarray) -> SGFit:
        """The fits of the functions ``index`` (a mask or indices over F)."""
        return SGFit(self.mean[index], self.sharpness[index], self.weight[index],
                     self.energy[index], self.iterations[index], self.converged[index])


@dataclass
class _Problem:
    """One batch: data, charts, bounds and targets (arrays over the batch's functions)."""

    # the grid's directions transposed, (3, S) or per function (F, 3, S) (support fits),
    # and √Ω (S,) or (F, S), both in the fields' dtype
    directions_t: np.ndarray
    sqrt_omega: np.ndarray
    y: np.ndarray           # (F, S, C) √Ω T
    chart: np.ndarray       # (F, N, 3, 3) rows m_k, t_k, b̂_k
    lower: np.ndarray       # (P,)
    upper: np.ndarray       # (P,)
    options: FitOptions
    targets: FitTargets
    samples: int            # size of the sphere grid the directions come from (its step)

    @property
    def lobes(self) -> int:
        return self.chart.shape[1]

    @property
    def channels(self) -> int:
        return self.y.shape[2]

    def subset(self, index: np.ndarray) -> _Problem:
        t = self.targets
        per_function = self.directions_t.ndim == 3
        return _Problem(self.directions_t[index] if per_function else self.directions_t,
                        self.sqrt_omega[index] if per_function else self.sqrt_omega,
                        self.y[index], self.chart[index], self.lower, self.upper, self.options,
                        FitTargets(*(None if a is None else a[index]
                                     for a in (t.mean, t.sigma, t.neighbour_means))),
                        self.samples)


def _tangent_basis(m: np.ndarray) -> np.ndarray:
    """Rows (m, t, b̂) (..., 3, 3): an orthonormal frame around unit m."""
    helper = np.where(np.abs(m[..., 1:2]) < 0.9, [0.0, 1.0, 0.0], [1.0, 0.0, 0.0])
    t = np.cross(m, helper)
    t /= np.linalg.norm(t, axis=-1, keepdims=True)
    return np.stack([m, t, np.cross(m, t)], axis=-2)


def _means(problem: _Problem, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Means μ (F, N, 3) of the chart coordinates θ (F, N, 3) and ∂μ/∂(a, b)
    (F, N, 2, 3)."""
    m, t, b = (problem.chart[..., i, :] for i in range(3))
    v = m + theta[..., 0:1] * t + theta[..., 1:2] * b
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    mu = v / norm
    tangents = np.stack([t, b], axis=-2)
    dmu = (tangents - mu[..., None, :] * np.sum(mu[..., None, :] * tangents, axis=-1,
                                                   keepdims=True)) / norm[..., None]
    return mu, dmu


def _fields(problem: _Problem, theta: np.ndarray, derivatives: bool
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Φ (F, N, 4, S) (E_k and, if ``derivatives``, D_ka, D_kb, D_kρ; else (F, N, 1, S)),
    the means and their chart derivatives."""
    mu, dmu = _means(problem, theta)
    dtype = np.dtype(problem.options.fields)
    lam = np.exp(theta[..., 2])[..., None].astype(dtype)          # (F, N, 1)
    omega_t = problem.directions_t                                # (3, S) or (F, 3, S)
    # 1 − μ·ω by a product (BLAS), not sg.evaluate's ‖ω − μ‖²/2: in float64 its
    # rounding, λ · 1e-16 ≤ 4e-12 in the exponent at the σ floor, does not matter here
    # (in float32, λ · 6e-8: 2e-3 at the floor of a 6k grid, a 0.2 % field error)
    half_sq = 1.0 - mu.astype(dtype) @ omega_t                    # (F, N, S)
    e = np.exp(-lam * half_sq) * problem.sqrt_omega[..., None, :]  # (F, N, S)
    if not derivatives:
        return e[..., None, :], mu, dmu
    dot = dmu.astype(dtype) @ omega_t[..., None, :, :]            # ω·∂μ/∂(a, b)
    d_ab = (e * lam)[..., None, :] * dot
    d_rho = -(e * lam * half_sq)[..., None, :]
    return np.concatenate([e[..., None, :], d_ab, d_rho], axis=-2), mu, dmu


def _prior_rows(problem: _Problem, theta: np.ndarray, mu: np.ndarray, dmu: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """Residuals (F, M) and Jacobian rows (F, M, 3N) of the β, γ, δ terms (the θ part;
    they do not depend on w). M = 0 when all three are off."""
    o, t = problem.options, problem.targets
    f, n = theta.shape[:2]
    res, rows = [], []
    if o.mean_weight > 0 and t.mean is not None:
        s = math.sqrt(o.mean_weight)
        jac = np.zeros((f, n, 3, n, 3))
        for k in range(n):
            jac[:, k, :, k, 0:2] = s * np.swapaxes(dmu[:, k], -1, -2)
        res.append((s * (mu - t.mean)).reshape(f, -1))
        rows.append(jac.reshape(f, 3 * n, 3 * n))
    if o.sigma_weight > 0 and t.sigma is not None:
        s = math.sqrt(o.sigma_weight)
        sigma = np.exp(-0.5 * theta[..., 2])
        jac = np.zeros((f, n, n, 3))
        for k in range(n):
            jac[:, k, k, 2] = -0.5 * s * sigma[:, k]
        res.append(s * (sigma - t.sigma))
        rows.append(jac.reshape(f, n, 3 * n))
    if o.spatial_weight > 0 and t.neighbour_means is not None and n > 1:
        s = math.sqrt(o.spatial_weight)
        for k1 in range(n - 1):
            for k2 in range(k1 + 1, n):
                d = t.neighbour_means[:, :, k1] - t.neighbour_means[:, :, k2]   # (F, R, 3)
                q = np.einsum("fc,frc->fr", mu[:, k1] - mu[:, k2], d)
                active = (q < 0).astype(float)
                jac = np.zeros((f, d.shape[1], n, 3))
                jac[:, :, k1, 0:2] = -s * active[..., None] * np.einsum("fjc,frc->frj",
                                                                        dmu[:, k1], d)
                jac[:, :, k2, 0:2] = s * active[..., None] * np.einsum("fjc,frc->frj",
                                                                       dmu[:, k2], d)
                res.append(s * np.maximum(-q, 0.0))
                rows.append(jac.reshape(f, d.shape[1], 3 * n))
    if not res:
        return np.zeros((f, 0)), np.zeros((f, 0, 3 * n))
    return np.concatenate(res, axis=1), np.concatenate(rows, axis=1)


def _split(problem: _Problem, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n, c = problem.lobes, problem.channels
    return x[:, :3 * n].reshape(-1, n, 3), x[:, 3 * n:].reshape(-1, n, c)


def _energy(problem: _Problem, x: np.ndarray, derivatives: bool):
    """E (F,) at x (F, P) and what a step needs: Φ, the data residuals, prior rows."""
    theta, w = _split(problem, x)
    phi, mu, dmu = _fields(problem, theta, derivatives)
    r = np.swapaxes(phi[:, :, 0], 1, 2) @ w.astype(phi.dtype) - problem.y   # (F, S, C)
    prior_r, prior_j = _prior_rows(problem, theta, mu, dmu)
    energy = (np.einsum("fsc,fsc->f", r, r, dtype=np.float64)
              + np.sum(prior_r * prior_r, axis=1))
    return energy, (phi, r, prior_r, prior_j, w)


def _normal_equations(parts) -> tuple[np.ndarray, np.ndarray]:
    """JᵀJ (F, P, P) and Jᵀr (F, P) from the fields' Gram matrix (module docstring)."""
    phi, r, prior_r, prior_j, w = parts
    f, n, _, s = phi.shape
    c = w.shape[2]
    flat = phi.reshape(f, 4 * n, s)
    q = (flat @ flat.transpose(0, 2, 1)).astype(np.float64).reshape(f, n, 4, n, 4)
    pr = (flat @ r.astype(flat.dtype)).astype(np.float64).reshape(f, n, 4, c)  # Φ r
    p = n * (3 + c)
    h = np.zeros((f, p, p))
    g = np.zeros((f, p))
    ww = w @ w.transpose(0, 2, 1)                                        # (F, N, N)
    h_tt = np.einsum("fkl,fkjlm->fkjlm", ww, q[:, :, 1:, :, 1:])          # (F, N, 3, N, 3)
    h_tw = np.einsum("fkc,fkjl->fkjlc", w, q[:, :, 1:, :, 0])            # (F, N, 3, N, C)
    h_ww = np.einsum("fkl,cd->fkcld", q[:, :, 0, :, 0], np.eye(c))       # (F, N, C, N, C)
    h[:, :3 * n, :3 * n] = h_tt.reshape(f, 3 * n, 3 * n)
    h[:, :3 * n, 3 * n:] = h_tw.reshape(f, 3 * n, n * c)
    h[:, 3 * n:, :3 * n] = h[:, :3 * n, 3 * n:].transpose(0, 2, 1)
    h[:, 3 * n:, 3 * n:] = h_ww.reshape(f, n * c, n * c)
    g[:, :3 * n] = np.einsum("fnc,fnjc->fnj", w, pr[:, :, 1:]).reshape(f, 3 * n)
    g[:, 3 * n:] = pr[:, :, 0].reshape(f, n * c)
    if prior_r.shape[1]:
        h[:, :3 * n, :3 * n] += prior_j.transpose(0, 2, 1) @ prior_j
        g[:, :3 * n] += np.einsum("fmp,fm->fp", prior_j, prior_r)
    return h, g


def _dense_jacobian(problem: _Problem, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residual vector (R,) and dense Jacobian (R, P) of one function (F = 1): the data
    rows (s, c) then the prior rows. For the scipy path and the tests."""
    _, (phi, r, prior_r, prior_j, w) = _energy(problem, x, True)
    n, _, s = phi.shape[1:]
    c = w.shape[2]
    jac = np.zeros((s, c, n * (3 + c)))
    for k in range(n):
        jac[:, :, 3 * k:3 * k + 3] = np.einsum("c,js->scj", w[0, k], phi[0, k, 1:])
        for ch in range(c):
            jac[:, ch, 3 * n + k * c + ch] = phi[0, k, 0]
    full = np.concatenate([jac.reshape(s * c, -1),
                           np.pad(prior_j[0], ((0, 0), (0, n * c)))])
    return np.concatenate([r[0].ravel(), prior_r[0]]), full


def _cap_resultant(lam: np.ndarray, cos_psi: np.ndarray) -> np.ndarray:
    """Mean resultant length A(λ, ψ) of G(·; μ, λ) restricted to the cap of half-angle ψ
    around μ, c = cos ψ, E = e^{−λ(1−c)}: A = (1 − cE)/(1 − E) − 1/λ (ψ = π gives the
    von Mises–Fisher coth λ − 1/λ); increasing in λ from (1 + c)/2 to 1."""
    one_minus_e = -np.expm1(-lam * (1 - cos_psi))
    return (one_minus_e + (1 - cos_psi) * (1 - one_minus_e)) / one_minus_e - 1 / lam


def _cosines(v: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """v·ω (F, M, S) of vectors v (F, M, 3) with the grid (S, 3) or per-function grids
    (F, S, 3)."""
    return v @ np.swapaxes(directions, -1, -2)


def _initial(directions: np.ndarray, omega: np.ndarray, values: np.ndarray,
             options: FitOptions, default_mean: np.ndarray, samples: int
             ) -> tuple[np.ndarray, np.ndarray]:
    """Moment-based initial means (F, N, 3) and sharpness (F, N) (module docstring);
    ``directions`` (S, 3) or (F, S, 3), ``omega`` (S,) or (F, S), ``samples`` the size
    of the sphere grid they come from (its step sets the window's least size)."""
    lam_lo = sg.sharpness(options.sigma_max)
    lam_hi = sg.sharpness(_sigma_floor(options, samples))
    f, n = len(values), options.lobes
    spacing = math.sqrt(4 * math.pi / samples)               # the grid's typical step (rad)
    residual = np.maximum(values.mean(axis=2), 0.0)                       # (F, S)
    mean = np.empty((f, n, 3))
    lam = np.empty((f, n))
    rows = np.arange(f)
    for k in range(n):
        top = np.argmax(residual, axis=1)
        peak = directions[top] if directions.ndim == 2 else directions[rows, top]  # (F, 3)
        height = residual[rows, top]                                       # (F,)
        cos_to_peak = _cosines(peak[:, None], directions)[:, 0]            # (F, S)
        below = residual < 0.5 * height[:, None]
        cos_half = np.where(below, cos_to_peak, -1.0).max(axis=1)         # nearest below ½
        psi = np.clip(2.5 * np.arccos(np.clip(cos_half, -1, 1)), 2 * spacing, np.pi / 2)
        cos_psi = np.cos(psi)
        mass = residual * omega * (cos_to_peak >= cos_psi[:, None])
        total = mass.sum(axis=1)
        m = (mass[:, None] @ directions)[:, 0] / np.maximum(total, 1e-300)[:, None]
        rbar = np.linalg.norm(m, axis=1)
        empty = (total <= 0) | (rbar <= 0)
        mean[:, k] = np.where(empty[:, None], default_mean, m / np.maximum(rbar, 1e-300)[:, None])
        # A(λ, ψ) = R̄ by bisection on log λ within the bounds (A is increasing)
        lo, hi = np.full(f, math.log(lam_lo)), np.full(f, math.log(lam_hi))
        for _ in range(50):
            mid = 0.5 * (lo + hi)
            low = _cap_resultant(np.exp(mid), cos_psi) < rbar
            lo, hi = np.where(low, mid, lo), np.where(low, hi, mid)
        lam[:, k] = np.where(empty, sg.sharpness(options.default_sigma), np.exp(0.5 * (lo + hi)))
        g = np.exp(lam[:, k, None] * (_cosines(mean[:, k, None], directions)[:, 0] - 1))
        window = omega * (cos_to_peak >= cos_psi[:, None])
        amplitude = (np.sum(window * g * residual, axis=1)
                     / np.maximum(np.sum(window * g * g, axis=1), 1e-300))
        residual = np.maximum(residual - amplitude[:, None] * g, 0.0)
    return mean, lam


def grown_start(directions: np.ndarray, solid_angles: np.ndarray, values: np.ndarray,
                fit: SGFit, default_mean: np.ndarray) -> SGFit:
    """A start for N + 1 lobes from a fit of N: the N fitted lobes, then one lobe placed
    by the windowed moments (:func:`_initial`, module docstring) on what they leave,
    T − T̃ (channel mean, clipped at 0). ``values`` (F, S, C) on the grid ``directions``
    (S, 3), ``solid_angles`` (S,); ``default_mean`` (F, 3) for a function with nothing
    left. Weights are zero: :func:`fit` re-solves them by least squares. Cheaper than a
    fresh start: the N lobes are already at their minimum, LM moves them little."""
    cos = fit.mean @ directions.T                                          # (F, N, S)
    g = np.exp(fit.sharpness[..., None] * (cos - 1.0))
    residual = values - np.einsum("fns,fnc->fsc", g, fit.weight)
    n = fit.mean.shape[1]
    mean, lam = _initial(directions, np.asarray(solid_angles, np.float64), residual,
                         FitOptions(lobes=1), np.asarray(default_mean, np.float64),
                         len(directions))
    f, c = len(values), values.shape[2]
    return SGFit(np.concatenate([fit.mean, mean], axis=1),
                 np.concatenate([fit.sharpness, lam], axis=1), np.zeros((f, n + 1, c)),
                 np.zeros(f), np.zeros(f, np.int64), np.ones(f, bool))


def integral_matched(fit: SGFit, values: np.ndarray, solid_angles: np.ndarray,
                     largest: float = 4.0) -> SGFit:
    """``fit`` of ``values`` (F, S, C) on a sphere grid with ``solid_angles`` (S,), its
    weights scaled per function and channel so that the lobes' integral over the sphere,
    Σ_k w_kc ∫G_k dω = Σ_k w_kc 2π(1 − e^{−2λ_k})/λ_k, equals the data's,
    ∫T_c dω ≈ Σ_s Ω_s T_c(ω_s): under uniform light the lobes then reflect exactly the
    transport's radiance. The least-squares fit does not keep it: it weighs the peak,
    and broad, low tails (the indirect part, lobes spread near the horizon) hold much of
    the integral and little of ∫T². A factor outside [1/``largest``, ``largest``], or
    where either integral is ≤ 0, is left at 1. ``energy`` is the fit's (before)."""
    data = np.einsum("fsc,s->fc", np.asarray(values, np.float64), solid_angles)
    model = np.einsum("fn,fnc->fc", sg.integral(fit.sharpness), fit.weight)
    ok = (data > 0) & (model > 0)
    factor = np.where(ok, data / np.where(ok, model, 1.0), 1.0)
    factor = np.where((factor >= 1.0 / largest) & (factor <= largest), factor, 1.0)
    return replace(fit, weight=fit.weight * factor[:, None, :])


def _least_squares_weights(problem: _Problem, theta: np.ndarray) -> np.ndarray:
    """Weights (F, N, C) minimising D for fixed lobes, clipped at 0."""
    e = _fields(problem, theta, False)[0][:, :, 0]                       # (F, N, S)
    gram = e @ e.transpose(0, 2, 1) + _EPS * np.eye(problem.lobes)
    return np.maximum(np.linalg.solve(gram, e @ problem.y), 0.0)


def _sigma_floor(options: FitOptions, samples: int) -> float:
    """The smallest σ a fit may reach: ``sigma_min``, raised to ``grid_sigma`` grid steps
    √(4π/S). A lobe narrower than the grid sees one sample: with noise in the data, a
    spare lobe otherwise sharpens without end onto one noisy sample (σ → 0, w → ∞,
    the energy creeping down; measured: 200 LM steps and > 10 min of trf on such a
    function). Data sharper than the floor needs a finer grid."""
    return max(options.sigma_min, options.grid_sigma * math.sqrt(4 * math.pi / samples))


def _setup(directions: np.ndarray, solid_angles: np.ndarray, values: np.ndarray,
           options: FitOptions, targets: FitTargets | None,
           default_mean: np.ndarray | None,
           start: tuple[np.ndarray, np.ndarray] | None = None, samples: int | None = None
           ) -> tuple[_Problem, np.ndarray]:
    """The problem and the initial x (F, P): lobes from windowed moments, or ``start``
    (means (F, N, 3), sharpnesses (F, N)), with least-squares weights. ``directions``
    (S, 3) with ``solid_angles`` (S,), or per-function subsets of a sphere grid of
    ``samples`` directions: (F, S, 3) and (F, S)."""
    samples = len(directions) if samples is None else samples
    values = np.asarray(values, np.float64)
    if values.ndim == 2:
        values = values[..., None]
    f, n, c = len(values), options.lobes, values.shape[2]
    default = np.broadcast_to(np.asarray([0.0, 0.0, 1.0] if default_mean is None
                                         else default_mean, np.float64), (f, 3))
    omega = np.asarray(solid_angles, np.float64)
    energy = np.sum(omega[..., None] * values * values, axis=(1, 2))
    zero = energy <= options.zero_energy
    mean, lam = (_initial(directions, omega, values, options, default, samples) if start is None
                 else (np.array(start[0], np.float64), np.array(start[1], np.float64)))
    mean[zero] = default[zero][:, None]
    lam[zero] = sg.sharpness(options.default_sigma)
    bound = math.tan(math.radians(options.max_shift_deg))
    log_lo, log_hi = (math.log(sg.sharpness(options.sigma_max)),
                      math.log(sg.sharpness(_sigma_floor(options, samples))))
    lower = np.concatenate([np.tile([-bound, -bound, log_lo], n), np.zeros(n * c)])
    upper = np.concatenate([np.tile([bound, bound, log_hi], n), np.full(n * c, np.inf)])
    dtype = np.dtype(options.fields)
    problem = _Problem(np.ascontiguousarray(np.swapaxes(directions, -1, -2), dtype),
                       np.sqrt(omega).astype(dtype),
                       (values * np.sqrt(omega)[..., None]).astype(dtype),
                       _tangent_basis(mean), lower, upper,
                       options, targets or FitTargets(), samples)
    theta = np.zeros((f, n, 3))
    theta[..., 2] = np.log(lam)
    w = _least_squares_weights(problem, theta)
    w[zero] = 0.0
    return problem, np.concatenate([theta.reshape(f, -1), w.reshape(f, -1)], axis=1)


def _result(problem: _Problem, x: np.ndarray, energy: np.ndarray, iterations: np.ndarray,
            converged: np.ndarray) -> SGFit:
    theta, w = _split(problem, x)
    mu, _ = _means(problem, theta)
    return SGFit(mean=mu, sharpness=np.exp(theta[..., 2]), weight=w, energy=energy,
                 iterations=iterations, converged=converged)


def _lm(problem: _Problem, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                   np.ndarray]:
    """Batched projected Levenberg–Marquardt from x (F, P): x, E, iterations, converged."""
    o = problem.options
    f, p = x.shape
    energy, parts = _energy(problem, x, True)
    nu = np.full(f, 1e-3)
    iterations = np.zeros(f, np.int64)
    converged = energy <= 0
    active = np.flatnonzero(~converged)
    h, g = _normal_equations(parts)
    sub = problem
    for _ in range(o.max_iterations):
        if not len(active):
            break
        if len(active) != len(sub.y):  # the active set only shrinks
            sub = problem.subset(active)
        ha, ga = h[active], g[active]
        diag = np.einsum("fpp->fp", ha) + _EPS
        damped = ha + (nu[active, None] * diag)[:, :, None] * np.eye(p)
        step = np.linalg.solve(damped, -ga[..., None])[..., 0]
        trial = np.clip(x[active] + step, problem.lower, problem.upper)
        trial_energy, trial_parts = _energy(sub, trial, True)
        iterations[active] += 1
        better = trial_energy < energy[active]
        drop = energy[active] - trial_energy
        done_small = better & (drop <= o.tolerance * energy[active])
        done_zero = better & (trial_energy <= 0)
        stuck = ~better & (nu[active] * 2 > 1e12)
        idx = active[better]
        x[idx] = trial[better]
        energy[idx] = trial_energy[better]
        if better.any():
            hb, gb = _normal_equations(tuple(a[better] for a in trial_parts))
            h[idx], g[idx] = hb, gb
        nu[active] = np.where(better, nu[active] / 3, nu[active] * 2)
        finished = done_small | done_zero | stuck
        converged[active[finished]] = True
        active = active[~finished]
    return x, energy, iterations, converged


def fit(directions: np.ndarray, solid_angles: np.ndarray, values: np.ndarray,
        options: FitOptions = FitOptions(), targets: FitTargets | None = None,
        default_mean: np.ndarray | None = None, start: SGFit | None = None,
        samples: int | None = None) -> SGFit:
    """Fit N lobes to each of F functions tabulated at ``directions`` (S, 3) (unit, any
    sphere grid) with quadrature ``solid_angles`` (S,) (sr): ``values`` (F, S, C) or
    (F, S). Batched Levenberg–Marquardt from moment-based starts (module docstring),
    or from the means and sharpnesses of ``start`` (e.g. a fit of the same functions on
    a coarser grid; weights re-solved on this grid).
    ``default_mean`` (3,) or (F, 3): the mean given to zero functions (default +z).
    Per-function grids (pipeline/methods/sg/support.py): ``directions`` (F, S, 3) and
    ``solid_angles`` (F, S), subsets of a sphere grid of ``samples`` directions."""
    values = np.asarray(values, np.float64)
    if values.ndim == 2:
        values = values[..., None]
    pieces = []
    for offset in range(0, len(values), options.batch):
        part = slice(offset, offset + options.batch)
        t = targets or FitTargets()
        t = FitTargets(*(None if a is None else np.asarray(a)[part]
                         for a in (t.mean, t.sigma, t.neighbour_means)))
        dm = (default_mean if default_mean is None or np.ndim(default_mean) == 1
              else np.asarray(default_mean)[part])
        begin = None if start is None else (start.mean[part], start.sharpness[part])
        grid = ((directions, solid_angles) if np.ndim(directions) == 2
                else (directions[part], solid_angles[part]))
        problem, x = _setup(*grid, values[part], options, t, dm, begin, samples)
        pieces.append(_result(problem, *_lm(problem, x)))
    return SGFit(*(np.concatenate([getattr(p, name) for p in pieces])
                   for name in ("mean", "sharpness", "weight", "energy", "iterations",
                                "converged")))


def fit_trf(directions: np.ndarray, solid_angles: np.ndarray, values: np.ndarray,
            options: FitOptions = FitOptions(), targets: FitTargets | None = None,
            default_mean: np.ndarray | None = None) -> SGFit:
    """The reference path: the same energy, bounds, parameters and initial values,
    minimised per function by ``scipy.optimize.least_squares(method="trf")`` with the
    analytic Jacobian; it stops when a step lowers the energy by less than
    ``tolerance`` relative (scipy's ftol, as the batched path) or after
    ``max_iterations`` evaluations."""
    from scipy.optimize import least_squares

    values = np.asarray(values, np.float64)
    if values.ndim == 2:
        values = values[..., None]
    problem, x0 = _setup(directions, solid_angles, values, options, targets, default_mean)
    x = x0.copy()
    energy = np.zeros(len(values))
    iterations = np.zeros(len(values), np.int64)
    converged = np.zeros(len(values), bool)
    for i in range(len(values)):
        one = problem.subset(np.array([i]))

        def residuals(v, one=one):
            return _dense_jacobian(one, v[None])[0]

        def jacobian(v, one=one):
            return _dense_jacobian(one, v[None])[1]

        start = np.clip(x0[i], problem.lower, problem.upper)
        result = least_squares(residuals, start, jac=jacobian, method="trf", x_scale="jac",
                               bounds=(problem.lower, problem.upper), ftol=options.tolerance,
                               xtol=1e-12, gtol=1e-12, max_nfev=options.max_iterations)
        x[i] = result.x
        energy[i] = 2 * result.cost
        iterations[i] = result.nfev
        converged[i] = result.status > 0
    return _result(problem, x, energy, iterations, converged)

"""The fast path of the spherical Gaussian fit (pipeline/methods/sg/fit.py): each function
is fitted on its support only — the paper's suggestion (003 §7: "leveraging the
sparseness of typical view-dependent transport data").

**Support cap.** A glossy transport function T (one vertex and view, tabulated on a
sphere grid of S directions with solid angles Ω) is close to zero over most of the
sphere: a lobe of σ = 10° has G < 10⁻³ beyond 3.7σ, under 3 % of the sphere. Per
function, with t = the channel mean of T clipped at 0, p its peak direction and h = t(p):

- ψ_E is the smallest angle from p such that the directions within it hold all but
  ``outside_energy`` of ∫‖T‖² dω (from a histogram of the energy over the cosine of
  the angle to p, ``bins`` bins uniform in cos): what the cap leaves out adds at most
  √outside_energy (1 % by default) to a fit's relative L² error. A broad, faint indirect part that
  holds more than that widens the cap: it is data;
- θ½ is the angle from p to the nearest direction with t < h/2 (the half-maximum
  angle; θ½ = 1.18σ for a lobe);
- the cap around p has half-angle ψ = max(ψ_E, ``halfmax_multiple`` · θ½) +
  ``margin_steps`` grid steps √(4π/S).

The fit (data, alignment and spatial terms alike) sees only the grid directions in the
cap. The cap holds the function's energy and, by the θ½ multiple, the model lobes' own
extent (2.5θ½ = 2.9σ: G < 0.015, 2·10⁻⁴ of a lobe's energy beyond) even where T was
cut by an occluder or the horizon, so the model's mass outside the cap — which the fit
no longer sees — stays small;
the error reported (:func:`relative_error`) is measured over the whole grid anyway.

**Batching.** Functions are sorted by cap size and fitted in batches of
``SupportOptions.batch`` consecutive ones, each padded to its largest cap: padding entries
repeat the function's peak sample with Ω = 0, so they add nothing to any sum and do not
change the windowed-moment start (a repeated real value, not a fake zero).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipeline.methods.sg import fit as sg_fit
from pipeline.methods.sg.fit import FitOptions, FitTargets, SGFit


@dataclass(frozen=True)
class SupportOptions:
    """How large each function's cap is (module docstring)."""

    outside_energy: float = 1e-4   # the cap leaves out at most this fraction of ∫‖T‖²
    halfmax_multiple: float = 2.5  # the cap reaches at least this × θ½ from the peak
    margin_steps: float = 2.0      # plus this many grid steps
    batch: int = 32                # functions per batch, consecutive in cap size
    bins: int = 2048               # bins of the energy profile, uniform in cos over [−1, 1]
                                   # (the first spans 2.5° around the peak)


DEFAULT_OPTIONS = FitOptions()
_DIRECT_BELOW = 0.05  # relative_error: below this the expanded form is re-measured directly


def caps(directions: np.ndarray, solid_angles: np.ndarray, values: np.ndarray,
         options: SupportOptions = SupportOptions()) -> tuple[np.ndarray, np.ndarray]:
    """Boolean caps (F, S) of ``values`` (F, S, C) on the grid ``directions`` (S, 3)
    with ``solid_angles`` (S,), and each function's peak index (F,). A zero function's
    cap is its peak sample alone."""
    f, s = values.shape[:2]
    # in float32 (a cap needs no more; half the memory traffic of this pass over F × S)
    values = values.astype(np.float32, copy=False)
    directions = directions.astype(np.float32)
    solid_angles = solid_angles.astype(np.float32)
    # channel sums by products: numpy's reductions over a last axis of 3 are slow
    t = np.maximum(values @ np.full(values.shape[2], 1.0 / values.shape[2], np.float32), 0.0)
    top = np.argmax(t, axis=1)
    height = t[np.arange(f), top]
    cos_peak = directions[top] @ directions.T                              # (F, S)
    # energy profile over the cap area 2π(1 − cos) from the peak (uniform bins in cos:
    # no arccos over the grid); the smallest cap holding all but ε of the energy
    bin_of = np.minimum(((1.0 - cos_peak) * (options.bins / 2)).astype(np.int64),
                        options.bins - 1)
    energy = ((values * values) @ np.ones(values.shape[2], np.float32)) * solid_angles
    profile = np.bincount((bin_of + options.bins * np.arange(f)[:, None]).ravel(),
                          energy.ravel(), f * options.bins).reshape(f, options.bins)
    cumulative = np.cumsum(profile, axis=1)
    enough = cumulative >= (1 - options.outside_energy) * cumulative[:, -1:]
    cos_energy = 1.0 - (np.argmax(enough, axis=1) + 1) * (2.0 / options.bins)
    cos_half = np.where(t < 0.5 * height[:, None], cos_peak, -1.0).max(axis=1)
    step = math.sqrt(4 * math.pi / s)
    psi = (np.maximum(np.arccos(np.clip(cos_energy, -1, 1)),
                      options.halfmax_multiple * np.arccos(np.clip(cos_half, -1, 1)))
           + options.margin_steps * step)
    inside = (cos_peak >= np.cos(np.minimum(psi, math.pi))[:, None]) & (height[:, None] > 0)
    inside[np.arange(f), top] = True
    return inside, top


def relative_error(directions: np.ndarray, solid_angles: np.ndarray, values: np.ndarray,
                   result: SGFit) -> np.ndarray:
    """‖T̃ − T‖ / ‖T‖ (F,) in the grid's L² norm (Σ_s Ω_s ‖·‖²) over the whole grid;
    NaN where T ≡ 0 (:func:`relative_errors` of the fit's own weights)."""
    return relative_errors(directions, solid_angles, values, result, [result.weight])[0]


def relative_errors(directions: np.ndarray, solid_angles: np.ndarray, values: np.ndarray,
                    lobes: SGFit, weights: list[np.ndarray]) -> list[np.ndarray]:
    """:func:`relative_error` of the models Σ_n w_n G_n with the lobes (means and
    sharpnesses) of ``lobes`` and each of ``weights`` ((F, N, C) each), e.g. a fit before
    and after its weights were scaled.

    Expanded, ‖T̃ − T‖² = ‖T‖² − 2 Σ_n w_n·⟨G_n, T⟩ + Σ_nm (w_n·w_m) ⟨G_n, G_m⟩: the lobes
    G (F, N, S) are evaluated once (float32) and the grid sums are two batched matrix
    products, shared by every set of weights, without a model image (F, S, C) — 3–5×
    faster than forming T̃ − T. The expansion cancels where the error is small (float32
    sums: ≈ 10⁻⁶ of ‖T‖², so ≈ 10⁻³ in the error), so errors below ``_DIRECT_BELOW``
    are measured again directly."""
    omega = solid_angles.astype(np.float32)
    values = values.astype(np.float32, copy=False)
    g = _lobes_on_grid(directions, lobes)                                    # (F, N, S)
    weighted = g * omega
    cross = np.matmul(weighted, values).astype(np.float64)                   # (F, N, C)
    gram = np.matmul(weighted, np.swapaxes(g, 1, 2)).astype(np.float64)      # (F, N, N)
    norm = np.einsum("fsc,fsc,s->f", values, values, omega, dtype=np.float64)
    errors = []
    for weight in weights:
        w = weight.astype(np.float64)
        diff = np.maximum(norm - 2 * np.einsum("fnc,fnc->f", w, cross)
                          + np.einsum("fnc,fnm,fmc->f", w, gram, w), 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            error = np.where(norm > 0, np.sqrt(diff / norm), np.nan)
        small = np.flatnonzero(error < _DIRECT_BELOW)
        if len(small):
            model = np.einsum("fns,fnc->fsc", g[small], weight[small].astype(np.float32))
            residual = np.einsum("fsc,fsc,s->f", model - values[small],
                                 model - values[small], omega, dtype=np.float64)
            error[small] = np.sqrt(residual / norm[small])
        errors.append(error)
    return errors


def _lobes_on_grid(directions: np.ndarray, result: SGFit) -> np.ndarray:
    """The fit's unit-weight lobes exp(λ(μ·ω − 1)) (F, N, S) on ``directions`` (S, 3),
    float32."""
    cos = result.mean.astype(np.float32) @ directions.T.astype(np.float32)
    return np.exp(result.sharpness.astype(np.float32)[..., None] * (cos - 1.0))


def fit(directions: np.ndarray, solid_angles: np.ndarray, values: np.ndarray,
        options: FitOptions = DEFAULT_OPTIONS, targets: FitTargets | None = None,
        default_mean: np.ndarray | None = None, start: SGFit | None = None,
        support: SupportOptions = SupportOptions(),
        cap: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[SGFit, np.ndarray]:
    """:func:`pipeline.methods.sg.fit.fit` of F functions ``values`` (F, S, C) (float32 or
    float64) tabulated on
    the sphere grid ``directions`` (S, 3), ``solid_angles`` (S,), each on its cap only
    (module docstring). Returns the fit (in the functions' order) and the cap sizes (F,).
    ``targets``, ``default_mean`` ((3,) or (F, 3)) and ``start`` as sg_fit.fit; ``cap``:
    the functions' :func:`caps` where the caller has them (a refit of the same data)."""
    values = np.asarray(values)
    f = len(values)
    inside, top = caps(directions, solid_angles, values, support) if cap is None else cap
    size = inside.sum(axis=1)
    order = np.argsort(size, kind="stable")
    pieces = []
    one_batch = FitOptions(**{**options.__dict__, "batch": max(f, 1)})
    for offset in range(0, f, support.batch):
        part = order[offset:offset + support.batch]
        k = int(size[part].max())
        rows, cols = np.nonzero(inside[part])
        position = np.arange(len(rows)) - np.repeat(np.cumsum(size[part]) - size[part],
                                                    size[part])
        index = np.repeat(top[part][:, None], k, axis=1)
        weight = np.zeros((len(part), k))
        index[rows, position] = cols
        weight[rows, position] = solid_angles[cols]
        t = targets or FitTargets()
        sub_targets = FitTargets(*(None if a is None else np.asarray(a)[part]
                                   for a in (t.mean, t.sigma, t.neighbour_means)))
        dm = (default_mean if default_mean is None or np.ndim(default_mean) == 1
              else np.asarray(default_mean)[part])
        sub_start = None if start is None else start.subset(part)
        pieces.append(sg_fit.fit(directions[index], weight,
                                 values[part[:, None], index].astype(np.float64), one_batch,
                                 sub_targets, dm,
                                 sub_start, samples=len(directions)))
    inverse = np.empty(f, np.int64)
    inverse[order] = np.arange(f)
    merged = SGFit(*(np.concatenate([getattr(p, name) for p in pieces])[inverse]
                     for name in ("mean", "sharpness", "weight", "energy", "iterations",
                                  "converged")))
    return merged, size

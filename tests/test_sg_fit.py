"""Batched spherical Gaussian fits (pipeline/methods/sg/fit.py): the analytic Jacobian,
recovery of known lobes, zero functions, and the batched Levenberg–Marquardt against
scipy's trust-region-reflective path on the same energy."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from pipeline.math import sg
from pipeline.methods.sg import fit as sg_fit

GRID = sg.latlong_directions(33, 64)  # 2112 directions, 5.6° apart at the equator
DIRECTIONS, SOLID_ANGLES = GRID[0].reshape(-1, 3), GRID[1].ravel()


def random_lobes(f: int, n: int, seed: int, min_separation: float = 50.0):
    """Means (F, N, 3) at least ``min_separation`` degrees apart, σ 8–20° (F, N), RGB
    peak weights 0.5–2 (F, N, 3)."""
    rng = np.random.default_rng(seed)
    means = []
    while len(means) < f:
        m = rng.normal(size=(n, 3))
        m /= np.linalg.norm(m, axis=1, keepdims=True)
        if n == 1 or (m @ m.T - 2 * np.eye(n)).max() < np.cos(np.radians(min_separation)):
            means.append(m)
    return (np.array(means), np.radians(rng.uniform(8, 20, (f, n))),
            rng.uniform(0.5, 2, (f, n, 3)))


def tabulate(mean, sigma, weight) -> np.ndarray:
    """Σ_k w_k G(ω_s; μ_k, 1/σ_k²) on the grid: (F, S, 3)."""
    g = sg.evaluate(DIRECTIONS[None, None], mean[:, :, None], sg.sharpness(sigma)[..., None])
    return np.einsum("fns,fnc->fsc", g, weight)


def test_jacobian_and_normal_equations_match_finite_differences():
    """All four terms on (two lobes; a neighbour with the lobes' arrangement flipped, so
    the spatial term is active). Central differences with h = 1e-6: truncation
    h² · |r'''| and rounding 1e-16/h, both < 1e-6 of the largest entry here."""
    mean, sigma, weight = random_lobes(1, 2, seed=3)
    values = tabulate(mean, sigma, weight)
    targets = sg_fit.FitTargets(mean=mean + 0.1, sigma=sigma * 1.2,
                                neighbour_means=mean[:, None, ::-1])
    options = sg_fit.FitOptions(lobes=2, mean_weight=0.3, sigma_weight=2.0, spatial_weight=5.0)
    problem, x = sg_fit._setup(DIRECTIONS, SOLID_ANGLES, values, options, targets, None)
    x = x + np.random.default_rng(0).normal(size=x.shape) * 0.05
    r, jac = sg_fit._dense_jacobian(problem, x)
    assert len(r) == len(DIRECTIONS) * 3 + 6 + 2 + 1
    numeric = np.empty_like(jac)
    for p in range(x.shape[1]):
        e = np.zeros_like(x)
        e[0, p] = 1e-6
        numeric[:, p] = (sg_fit._dense_jacobian(problem, x + e)[0]
                         - sg_fit._dense_jacobian(problem, x - e)[0]) / 2e-6
    assert np.abs(jac - numeric).max() < 1e-6 * np.abs(jac).max()
    energy, parts = sg_fit._energy(problem, x, True)
    h, g = sg_fit._normal_equations(parts)
    assert energy[0] == pytest.approx(r @ r, rel=1e-12)
    np.testing.assert_allclose(h[0], jac.T @ jac, atol=1e-12 * np.abs(jac.T @ jac).max())
    np.testing.assert_allclose(g[0], jac.T @ r, atol=1e-12 * np.abs(jac.T @ r).max())


def matched(fit: sg_fit.SGFit, mean: np.ndarray, sigma: np.ndarray):
    """Per function: the largest angle (degrees) between true and fitted means and the
    largest relative σ error, under the lobe permutation that best matches the means."""
    angles, sigmas = [], []
    for i in range(len(mean)):
        best = max(itertools.permutations(range(mean.shape[1])),
                   key=lambda p, i=i: np.sum(fit.mean[i, list(p)] * mean[i]))
        cos = np.clip(np.sum(fit.mean[i, list(best)] * mean[i], axis=1), -1, 1)
        angles.append(np.degrees(np.arccos(cos)).max())
        sigmas.append(np.abs(fit.sigma[i, list(best)] / sigma[i] - 1).max())
    return np.array(angles), np.array(sigmas)


@pytest.mark.parametrize("lobes", [1, 2, 3])
def test_recovers_known_gaussians(lobes):
    """20 functions of N lobes (≥ 50° apart, σ 8–20°, i.e. 1.4–3.6 grid steps) with
    Gaussian noise of 1 % of the largest weight: means within 1°, σ within 5 % (the
    issue's bar; measured ≤ 0.13° and ≤ 0.7 %)."""
    mean, sigma, weight = random_lobes(20, lobes, seed=10 + lobes)
    values = tabulate(mean, sigma, weight)
    values += np.random.default_rng(lobes).normal(size=values.shape) * 0.02
    fit = sg_fit.fit(DIRECTIONS, SOLID_ANGLES, values, sg_fit.FitOptions(lobes=lobes))
    assert fit.converged.all()
    angles, sigmas = matched(fit, mean, sigma)
    assert angles.max() < 1.0 and sigmas.max() < 0.05
    assert np.all(fit.weight >= 0)
    if lobes == 1:  # one channel (F, S) fits the same way
        grey = sg_fit.fit(DIRECTIONS, SOLID_ANGLES, values[..., 1], sg_fit.FitOptions())
        assert grey.weight.shape == (20, 1, 1)
        angles, sigmas = matched(grey, mean, sigma)
        assert angles.max() < 1.0 and sigmas.max() < 0.05


@pytest.mark.parametrize("lobes", [2, 3])
def test_a_fit_grown_from_one_lobe_fewer_recovers_the_lobes(lobes):
    """The stage's N search: a fit of N − 1 lobes plus one placed on what they leave
    (sg_fit.grown_start) is a start from which N known lobes are recovered to the same
    bar as from the moments (means within 1°, σ within 5 %), in no more LM steps."""
    mean, sigma, weight = random_lobes(20, lobes, seed=30 + lobes)
    values = tabulate(mean, sigma, weight)
    values += np.random.default_rng(lobes).normal(size=values.shape) * 0.02
    fewer = sg_fit.fit(DIRECTIONS, SOLID_ANGLES, values, sg_fit.FitOptions(lobes=lobes - 1))
    start = sg_fit.grown_start(DIRECTIONS, SOLID_ANGLES, values, fewer,
                               np.tile([0.0, 0.0, 1.0], (20, 1)))
    assert start.mean.shape == (20, lobes, 3) and start.sharpness.shape == (20, lobes)
    options = sg_fit.FitOptions(lobes=lobes)
    grown = sg_fit.fit(DIRECTIONS, SOLID_ANGLES, values, options, start=start)
    fresh = sg_fit.fit(DIRECTIONS, SOLID_ANGLES, values, options)
    assert grown.converged.all()
    angles, sigmas = matched(grown, mean, sigma)
    assert angles.max() < 1.0 and sigmas.max() < 0.05
    assert grown.iterations.sum() <= fresh.iterations.sum()


def test_zero_function_gets_a_defined_result():
    """An all-occluded view: zero weights, the default mean and σ, energy 0 — finite; with
    the alignment terms on, its mean and σ go to the targets (the data cannot move them)."""
    mean, sigma, weight = random_lobes(2, 2, seed=4)
    values = tabulate(mean, sigma, weight)
    values[1] = 0.0
    options = sg_fit.FitOptions(lobes=2)
    fit = sg_fit.fit(DIRECTIONS, SOLID_ANGLES, values, options, default_mean=[0.0, 1.0, 0.0])
    assert np.all(fit.weight[1] == 0) and fit.energy[1] == 0 and fit.converged.all()
    assert np.allclose(fit.mean[1], [0, 1, 0]) and np.allclose(fit.sigma[1], 0.5)
    for a in (fit.mean, fit.sharpness, fit.weight, fit.energy):
        assert np.all(np.isfinite(a))
    target_mean = sg.rotate(np.array([[0.0, 1.0, 0.0]] * 2), np.array(
        [[1, 0, 0], [0, np.cos(0.4), -np.sin(0.4)], [0, np.sin(0.4), np.cos(0.4)]]))
    targets = sg_fit.FitTargets(mean=np.stack([mean[0], target_mean]),
                                sigma=np.array([sigma[0], [0.3, 0.2]]))
    aligned = sg_fit.fit(DIRECTIONS, SOLID_ANGLES, values,
                         sg_fit.FitOptions(lobes=2, mean_weight=1.0, sigma_weight=1.0),
                         targets, default_mean=[0.0, 1.0, 0.0])
    assert np.all(aligned.weight[1] == 0)
    np.testing.assert_allclose(aligned.mean[1], target_mean, atol=1e-5)
    np.testing.assert_allclose(aligned.sigma[1], [0.3, 0.2], atol=1e-5)


@pytest.mark.parametrize("lobes", [1, 2])
def test_a_fit_started_from_a_coarser_grid_recovers_the_lobes(lobes):
    """Coarse to fine (``start=``): the functions of test_recovers_known_gaussians fitted
    on the 17 × 32 grid of every other row and column pair (σ 8–20° is 0.7–1.8 of its
    11° steps), then on the 33 × 64 grid from those lobes: the same bar (means within
    1°, σ within 5 %), and the fine energy no higher than the direct fit's by more than
    its stopping tolerance allows (1e-6 relative per step; 1e-4 for a few steps)."""
    mean, sigma, weight = random_lobes(20, lobes, seed=10 + lobes)
    values = tabulate(mean, sigma, weight)
    values += np.random.default_rng(lobes).normal(size=values.shape) * 0.02
    grid = values.reshape(20, 33, 64, 3)[:, ::2]
    coarse_values = (0.5 * (grid[:, :, 0::2] + grid[:, :, 1::2])).reshape(20, -1, 3)
    coarse_d, coarse_w = sg.latlong_directions(17, 32)
    options = sg_fit.FitOptions(lobes=lobes)
    coarse = sg_fit.fit(coarse_d.reshape(-1, 3), coarse_w.ravel(), coarse_values, options)
    fine = sg_fit.fit(DIRECTIONS, SOLID_ANGLES, values, options, start=coarse)
    assert fine.converged.all()
    angles, sigmas = matched(fine, mean, sigma)
    assert angles.max() < 1.0 and sigmas.max() < 0.05
    direct = sg_fit.fit(DIRECTIONS, SOLID_ANGLES, values, options)
    assert np.all(fine.energy <= direct.energy * (1 + 1e-4))


@pytest.mark.parametrize("lobes", [1, 2])
def test_float32_fields_reach_the_float64_optimum(lobes):
    """FitOptions(fields="float32") on the occluded noisy set: each function that
    converges in float64 converges in float32 (one N = 2 function creeps 200 steps in
    float64; since the residual became a matrix product (third session) float32 stops
    it by the tolerance — its flat valley, not a better or worse optimum), the energy
    (computed in float64 from float32 fields) within 1e-4 of float64's and means within
    0.5°. Field rounding is ≤ λ · 6e-8 in the exponent, so well-posed optima move by
    ~1e-6 (measured 2e-7 for N = 1); N = 2 lobes sharing a feature sit in a flat
    valley where both stop at slightly different points (measured 5.4e-5 and 0.16°)."""
    values = occluded_noisy_set(7, 6, lobes)
    double = sg_fit.fit(DIRECTIONS, SOLID_ANGLES, values, sg_fit.FitOptions(lobes=lobes))
    single = sg_fit.fit(DIRECTIONS, SOLID_ANGLES, values,
                        sg_fit.FitOptions(lobes=lobes, fields="float32"))
    assert np.all(single.converged | ~double.converged)
    np.testing.assert_allclose(single.energy, double.energy, rtol=1e-4)
    cos = np.clip(np.sum(single.mean * double.mean, axis=-1), -1, 1)
    assert np.degrees(np.arccos(cos)).max() < 0.5


def occluded_noisy_set(seed: int, f: int, lobes: int) -> np.ndarray:
    """Lobes cut by a random occluding half-space (a visibility edge through the lobes)
    plus 2 % noise: the model cannot fit exactly, so the optimum is a genuine one."""
    mean, sigma, weight = random_lobes(f, lobes, seed)
    values = tabulate(mean, sigma, weight)
    rng = np.random.default_rng(seed)
    for i in range(f):
        plane = mean[i, 0] + rng.normal(size=3) * 0.8
        values[i, DIRECTIONS @ plane < 0.2 * np.linalg.norm(plane)] = 0.0
    return values + rng.normal(size=values.shape) * 0.02


@pytest.mark.parametrize(("lobes", "count", "occluded"), [(1, 6, True), (2, 3, False)])
def test_batched_lm_reaches_the_trf_optimum(lobes, count, occluded):
    """Same energy, bounds and start, both stopped at a relative energy decrease of
    1e-12: batched LM and scipy's trf agree to 1e-8 in energy, means within 1e-3°, σ
    and weights within 1e-4 relative (near an optimum parameters move ~√(energy
    change)). Well-posed sets: one occluded lobe, or two visible lobes with noise
    (an occluder that hides one of two lobes leaves a spare lobe fitting noise, a flat
    valley where both paths stop at different points; sg_fit's docstring)."""
    if occluded:
        values = occluded_noisy_set(20 + lobes, count, lobes)
    else:
        mean, sigma, weight = random_lobes(count, lobes, seed=30)
        values = tabulate(mean, sigma, weight)
        values += np.random.default_rng(31).normal(size=values.shape) * 0.02
    options = sg_fit.FitOptions(lobes=lobes, tolerance=1e-12)
    lm = sg_fit.fit(DIRECTIONS, SOLID_ANGLES, values, options)
    trf = sg_fit.fit_trf(DIRECTIONS, SOLID_ANGLES, values, options)
    assert lm.converged.all() and trf.converged.all()
    np.testing.assert_allclose(lm.energy, trf.energy, rtol=1e-8)
    cos = np.clip(np.sum(lm.mean * trf.mean, axis=-1), -1, 1)
    assert np.degrees(np.arccos(cos)).max() < 1e-3
    np.testing.assert_allclose(lm.sigma, trf.sigma, rtol=1e-4)
    np.testing.assert_allclose(lm.weight, trf.weight, atol=1e-4 * trf.weight.max())


def test_integral_matched_weights_give_the_datas_integral():
    """sg_fit.integral_matched: a lobe fitted to a Gaussian peak on a broad pedestal
    (which least squares leaves out of the lobe) is scaled so that the lobes' analytic
    integral equals the data's quadrature per channel (1e-9: both sums are exact for
    the stored numbers); a zero function and a factor beyond the bound keep their
    weights."""
    mean, sigma, weight = random_lobes(6, 1, seed=40)
    values = tabulate(mean, sigma, weight) + 0.05        # a pedestal on the whole sphere
    values[5] = 0.0
    fit = sg_fit.fit(DIRECTIONS, SOLID_ANGLES, values, sg_fit.FitOptions(lobes=1))
    matched = sg_fit.integral_matched(fit, values, SOLID_ANGLES)
    data = np.einsum("fsc,s->fc", values, SOLID_ANGLES)
    model = np.einsum("fn,fnc->fc", sg.integral(matched.sharpness), matched.weight)
    before = np.einsum("fn,fnc->fc", sg.integral(fit.sharpness), fit.weight)
    assert np.all(before[:5] < 0.95 * data[:5])          # least squares lost the pedestal
    np.testing.assert_allclose(model[:5], data[:5], rtol=1e-9)
    np.testing.assert_array_equal(matched.weight[5], fit.weight[5])
    np.testing.assert_array_equal(matched.mean, fit.mean)
    capped = sg_fit.integral_matched(fit, 10 * values, SOLID_ANGLES, largest=4.0)
    np.testing.assert_array_equal(capped.weight, fit.weight)

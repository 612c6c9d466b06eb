"""1D Haar wavelets (pipeline/math/haar.py): exact round trips, orthonormality, the
L2-optimal truncation and the sparse products the d2i renderer takes."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.math import haar


@pytest.mark.parametrize("n", [1, 2, 5, 64, 1000])
def test_round_trip_is_exact_without_truncation(n):
    rows = np.random.default_rng(n).normal(size=(3, n))
    coefficients = haar.forward(rows)
    assert coefficients.shape == (3, haar.padded_length(n))
    # float64 arithmetic: exact up to rounding of log2(N) butterfly levels
    np.testing.assert_allclose(haar.inverse(coefficients, n), rows, rtol=0, atol=1e-13)


@pytest.mark.parametrize("n", [1, 3, 16, 17, 100, 4096, 5000])
def test_blocked_forward_equals_the_level_by_level_transform(n):
    """forward runs BLOCK_LEVELS (five) levels per matrix product; the plain butterfly
    is the definition (1e-12: float64 rounding of up to 13 levels, summed differently)."""
    rows = np.random.default_rng(n).normal(size=(2, n))
    padded = np.zeros((2, haar.padded_length(n)))
    padded[:, :n] = rows
    np.testing.assert_allclose(haar.forward(rows), haar._forward_levels(padded), rtol=0,
                               atol=1e-12 * np.abs(rows).sum())
    assert haar.forward(rows[0]).shape == (haar.padded_length(n),)


def test_transform_is_orthonormal_so_dot_products_survive():
    rng = np.random.default_rng(1)
    t, light = rng.normal(size=(4, 300)), rng.normal(size=300)
    np.testing.assert_allclose(haar.forward(t) @ haar.forward(light), t @ light, rtol=1e-12)
    basis = haar.forward(np.eye(16))
    np.testing.assert_allclose(basis @ basis.T, np.eye(16), atol=1e-15)


def test_coefficient_layout_coarse_to_fine():
    # a constant row has only the scaling coefficient; a step at the middle only the
    # coarsest wavelet
    np.testing.assert_allclose(haar.forward(np.ones(8)), [np.sqrt(8), 0, 0, 0, 0, 0, 0, 0],
                               atol=1e-15)
    step = np.r_[np.ones(4), -np.ones(4)]
    np.testing.assert_allclose(haar.forward(step), [0, np.sqrt(8), 0, 0, 0, 0, 0, 0],
                               atol=1e-15)


def _dense(result, size):
    """CSR rows of haar.truncate back to dense coefficient rows."""
    out = np.zeros((len(result["count"]), size))
    start = 0
    for r, c in enumerate(result["count"]):
        out[r, result["index"][start:start + c]] = result["value"][start:start + c]
        start += c
    return out


def test_truncate_keeps_the_biggest_and_the_error_is_the_dropped_energy():
    """With a cap and no tolerance: the kept coefficients are the largest, and the
    reconstruction error (orthonormal transform) is the dropped coefficients' norm."""
    rng = np.random.default_rng(2)
    rows = np.cumsum(rng.normal(size=(5, 256)), axis=1)  # smooth-ish rows
    w = haar.forward(rows)
    result = haar.truncate(w, 0.0, 20)
    assert np.all(result["count"] == 20)
    kept = _dense(result, 256)
    smallest_kept = np.abs(result["value"].reshape(5, 20)).min(axis=1)
    assert np.all(np.abs(w - kept).max(axis=1) <= smallest_kept * (1 + 1e-6))
    error = np.linalg.norm(haar.inverse(kept, 256) - rows, axis=1)
    np.testing.assert_allclose(error, np.linalg.norm(w - kept, axis=1), rtol=1e-5)
    np.testing.assert_allclose(result["residual"], error / np.linalg.norm(rows, axis=1),
                               rtol=1e-4)


def test_truncate_meets_the_tolerance_with_the_fewest_coefficients():
    rows = np.cumsum(np.random.default_rng(3).normal(size=(6, 512)), axis=1)
    w = haar.forward(rows)
    for tolerance in (0.3, 0.05, 0.01):
        result = haar.truncate(w, tolerance, 512)
        assert np.all(result["residual"] <= tolerance * (1 + 1e-6))
        for row, count in zip(w, result["count"], strict=True):  # one fewer would not do
            fewer = np.sort(np.abs(row))[::-1][:count - 1]
            rest = np.linalg.norm(row) ** 2 - np.sum(fewer ** 2)
            assert np.sqrt(max(rest, 0)) > tolerance * np.linalg.norm(row)
    empty = haar.truncate(np.zeros((2, 8)), 0.1, 4)
    assert np.all(empty["count"] == 0) and len(empty["index"]) == 0


def test_truncate_respects_the_cap():
    rows = np.random.default_rng(5).normal(size=(3, 1024))  # white noise: incompressible
    result = haar.truncate(haar.forward(rows), 1e-3, 100)
    assert np.all(result["count"] == 100) and np.all(result["residual"] > 0.5)


def test_truncate_stage_cut_agrees_with_truncating_from_scratch():
    """The d2i.truncate stage cuts stored rows (kept near-losslessly, with their residual) to a
    tolerance; that gives the same counts as truncating the full rows to that tolerance,
    and its CSR prefix cut keeps exactly those coefficients."""
    from pipeline.engine.rows import cut_rows
    from pipeline.methods.d2i.stages.truncate import kept_counts

    rows = np.cumsum(np.random.default_rng(6).normal(size=(8, 512)), axis=1)
    w = haar.forward(rows)
    stored = haar.truncate(w, 1e-4, 512)
    for tolerance in (0.2, 0.05, 0.01):
        direct = haar.truncate(w, tolerance, 512)
        counts = kept_counts(stored["count"], stored["residual"], stored["value"], tolerance)
        np.testing.assert_array_equal(counts, direct["count"])
        cut = cut_rows(stored["count"], stored["index"], stored["value"], counts)
        np.testing.assert_array_equal(cut["index"], direct["index"])
        np.testing.assert_allclose(cut["value"], direct["value"])


def test_cut_keeps_near_entries_and_counts_them_for_no_energy():
    """Rows with leading near entries (gather-domain values, always kept): a row of near
    entries then a smooth tail keeps its near entries and the tail's own prefix; a row
    of near entries alone keeps them; an empty row keeps nothing."""
    from pipeline.methods.d2i.stages.truncate import kept_counts

    tail = np.array([8.0, 4.0, 2.0, 1.0, 0.5])  # energy 85.25
    value = np.r_[[1e3, 1e3], tail, [5.0, 5.0], tail]
    near = np.r_[[True, True], np.zeros(5, bool), [True, True], np.zeros(5, bool)]
    count = np.array([7, 2, 0, 5])
    residual = np.zeros(4)
    kept = kept_counts(count, residual, value, 0.1, near)
    # tolerance 0.1: a tail may drop 0.01 × 85.25 = 0.85; 0.5² may go, 0.5² + 1² not
    np.testing.assert_array_equal(kept, [2 + 4, 2, 0, 4])


def test_cut_keeps_the_coarsest_coefficients_so_a_spike_cannot_take_the_mean():
    """A row like a wall pixel's beside the floor (64k gathers): a narrow spike (samples
    just below the near bar) on a broad far field holding half the product. The spike's
    chain of coefficients holds almost all the energy; its coarse end, like the field's
    mean, is small in energy, so a 2 % tolerance is met without coefficients 0..15 —
    and a row without its mean (detail coefficients sum to zero) has no product with a
    uniform radiance at all (measured: 0.0). The truncate stage keeps the coefficients
    below COARSE_KEPT whatever their size: the product is kept (measured: exact)."""
    from pipeline.engine.rows import expand_values
    from pipeline.methods.d2i.stages.truncate import COARSE_KEPT, cut_to_budget, kept_counts

    length = 1 << 16
    row = 0.02 * (1.0 + 0.4 * np.sin(np.linspace(0.0, 6.0, length)))[None]  # the field
    row[0, 9000:9004] = [150.0, 600.0, 600.0, 150.0]                           # the spike
    stored = haar.truncate(haar.forward(row), 1e-4, 512)
    uniform = haar.forward(np.ones((1, length)))[0]
    exact = float(row[0].sum())
    params = {"truncate.budget": "tolerance", "truncate.tolerance": 0.02}
    cut = cut_to_budget(params, "d", {f"d_{k}": v for k, v in stored.items()}, length)
    coarse = {int(i) for i in stored["index"] if i < COARSE_KEPT}
    assert len(coarse) > 8 and coarse <= set(cut["d_index"].tolist())
    value = expand_values(cut["d_count"], cut["d_value"], cut["d_scale"])
    assert float(value @ uniform[cut["d_index"]]) == pytest.approx(exact, rel=0.01)
    alone = int(kept_counts(stored["count"], stored["residual"], stored["value"], 0.02)[0])
    product_alone = float(stored["value"][:alone] @ uniform[stored["index"][:alone]])
    assert abs(product_alone) < 0.1 * exact


def test_stored_values_round_trip_within_float16_over_the_row_rms():
    """pipeline/engine/rows.py quantise_values / expand_values: rows with near entries 10^3 ×
    their far coefficients, an all-zero row and an empty row. Each value comes back to
    2^-11 of itself or 2^-24 × its row's RMS (float16 subnormals), whichever is larger;
    nothing overflows; zero rows stay zero."""
    from pipeline.engine.rows import expand_values, quantise_values

    rng = np.random.default_rng(4)
    far = rng.normal(0.0, 1e-2, 500) * np.exp(-np.arange(500) / 100.0)  # decaying sizes
    rows = [np.r_[[982.0, 375.0, 4.3], far], np.zeros(7), np.zeros(0), rng.normal(size=50)]
    count = np.array([len(r) for r in rows])
    value = np.concatenate(rows).astype(np.float32)
    scale, stored = quantise_values(count, value)
    assert stored.dtype == np.float16 and scale.dtype == np.float32
    assert np.all(np.isfinite(stored))
    back = expand_values(count, stored, scale)
    rms = np.repeat(scale, count)
    bound = np.maximum(np.abs(value) * 2.0 ** -11, rms * 2.0 ** -24)
    assert np.all(np.abs(back - value) <= bound * (1 + 1e-6))
    np.testing.assert_array_equal(back[503:510], 0.0)  # the zero row
    assert scale[1] == 1.0 and scale[2] == 1.0


def test_place_in_runs_numbers_each_pixels_rows_from_zero():
    """A T row's basis index is its place in its pixel's run of rows: 0, 1, ... within
    each run of equal pixel ids (a repeated id after another run starts again at 0)."""
    from pipeline.engine.rows import place_in_runs

    pixel = np.array([7, 7, 7, 3, 9, 9, 7, 7])
    np.testing.assert_array_equal(place_in_runs(pixel), [0, 1, 2, 0, 0, 1, 0, 1])
    assert place_in_runs(np.zeros(0, np.int32)).shape == (0,)

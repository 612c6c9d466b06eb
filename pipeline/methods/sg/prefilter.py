"""The SG-prefiltered environment stack, fast: each level of
:func:`pipeline.math.sg.prefilter_reference` computed row pair by row pair in the Fourier
domain along φ (method sg, paper 003 §5; stage ``sg.env_prefilter``).

**What is computed.** Level ℓ (σ_ℓ, λ = 1/σ_ℓ², shape (H_ℓ, W_ℓ)) at a destination
direction d(θ_d, φ_j) is the normalised sum over the map's samples (θ_s, φ_k) with solid
angles Ω_s (sg.latlong_directions):

    P(d) = N(d)/D(d),  N(d) = Σ_s Σ_k G(ω_sk; d, λ) L_sk Ω_s,  D(d) = the same with L = 1,

exactly the reference's formula (no resampling of the map), so the two differ by rounding
(measured ≤ 1e-13 of a level's largest texel, tests/test_sg_prefilter.py).

**Why it is fast.** With c = cos, s = sin, the lobe between a destination and a source
sample depends on the two rows and on the column difference only:

    G = exp(λ(c_d c_s + s_d s_s cos Δφ − 1))
      = exp(λ(cos(θ_d − θ_s) − 1)) · g(Δφ; a),   g(Δφ; a) = exp(−a(1 − cos Δφ)),
      a = λ s_d s_s,

so for one (destination row, source row) pair the sum over k is a circular convolution
in φ. Source columns sit at φ_k = 2π(k + ½)/W; with X_m = Σ_k L_k e^{−2πimk/W} (the rows'
real FFT) and ĝ_m the Fourier series coefficients of g (g(x) = Σ_m ĝ_m e^{imx};
ĝ_m = e^{−a} I_m(a), computed as the FFT of g sampled at n points, which is exact up to
aliasing ĝ_{m ± n}),

    Σ_k g(φ − φ_k; a) L_k = Σ_m ĝ_m e^{−imπ/W} X_m e^{imφ}.

Summing over the source rows within the lobe's reach (λ(1 − cos(θ_d − θ_s)) ≤
:data:`REACH`, a weight below e^{−30}) gives the destination row's spectrum
C_m = Σ_s Ω_s e^{λ(cos(θ_d − θ_s) − 1)} ĝ_m(a_ds) e^{−imπ/W} X_m(s), and one inverse
FFT of length W_ℓ evaluates it at the level's columns
φ_j = 2π(j + ½)/W_ℓ (phase e^{imπ/W_ℓ}). D needs m = 0 only: D(d) = W Σ_s Ω_s
e^{λ(cos(θ_d − θ_s) − 1)} ĝ_0(a_ds).

Two cases of ĝ:

* W_ℓ = W (the levels at the map's own resolution): the destination columns are the
  source columns, the sum over k is a discrete circular convolution, and the length-W
  FFT of g sampled at 2πk/W is its exact (aliased) spectrum.
* W_ℓ < W: the series is kept up to the first m where ĝ_m/ĝ_0 = I_m(a)/I_0(a) falls
  below e^{−REACH} for the largest a = λ (:func:`mode_cut`; ≈ √(2 REACH λ) for sharp
  levels, 8 for the broadest, where I_m(a)/I_0(a) ≈ (a/2)^m/m!), g sampled at n ≥ twice
  that (aliases below e^{−REACH} too), and the modes beyond the level's Nyquist
  frequency folded onto its columns (mode m lands on bin m mod W_ℓ): one inverse FFT
  of length W_ℓ then evaluates the series exactly at φ_j.

Cost per level: (row pairs) × (n exp + one FFT) + (row pairs) × (W_ℓ/2) × 3 complex
multiply-adds; row pairs ≈ H_ℓ · (2√(2 REACH) σ_ℓ/Δθ) ≈ const per level once H_ℓ
follows σ_ℓ, halved by the equator's mirror symmetry (:func:`_level`). A 1024 × 512
map's 39 levels: ``studies/sg_prefilter_speed.py``.
"""

from __future__ import annotations

import numpy as np
from scipy.fft import ifft, irfft, next_fast_len, rfft
from scipy.special import ive

from pipeline.math.sg import PrefilterLevels, latlong_directions, sharpness

# Row pairs whose lobe weight exp(λ(cos Δθ − 1)) is below e^{−REACH} are skipped.
REACH = 30.0
# Row pairs per block: bounds the (pairs, n) kernel samples held at once.
PAIR_BLOCK = 2048


def prefilter(rgb: np.ndarray, levels: PrefilterLevels) -> list[np.ndarray]:
    """The prefiltered stack of lat-long map ``rgb`` (H, W, 3) radiance (W/(m² sr)) at
    ``levels`` (module docstring): n arrays (H_ℓ, W_ℓ, 3) float64, level ℓ the normalised
    SG convolution at σ_ℓ, equal to sg.prefilter_reference up to rounding."""
    height, width = rgb.shape[:2]
    theta_src = np.pi * np.arange(height) / (height - 1)
    omega_row = latlong_directions(height, 1)[1][:, 0] / width  # Ω of one texel per row
    spectrum = np.ascontiguousarray(rfft(np.asarray(rgb, np.float64), axis=1))
    spectrum *= np.exp(-1j * np.pi * np.arange(spectrum.shape[1]) / width)[None, :, None]
    return [_level(spectrum, theta_src, omega_row, width, rows, cols, sigma)
            for (rows, cols), sigma in zip(levels.shapes, levels.sigmas, strict=True)]


def _level(spectrum: np.ndarray, theta_src: np.ndarray, omega_row: np.ndarray,
           width: int, rows: int, cols: int, sigma: float) -> np.ndarray:
    """One level (rows, cols, 3): the spectra C_m of its rows (module docstring), then
    an inverse real FFT per row. Destination rows d and rows − 1 − d mirror each other
    about the equator (θ → π − θ), as do their source rows, with the same a and Δθ:
    the kernels of the upper half serve the lower half reversed."""
    lam = float(sharpness(sigma))
    theta_dst = np.pi * np.arange(rows) / (rows - 1)
    last_src = len(theta_src) - 1
    reach = np.arccos(max(-1.0, 1.0 - REACH / lam))  # |θ_d − θ_s| within reach
    step = np.pi / last_src
    first = np.clip(np.ceil((theta_dst - reach) / step - 1e-9), 0, last_src).astype(np.int64)
    last = np.clip(np.floor((theta_dst + reach) / step + 1e-9), 0, last_src).astype(np.int64)
    if cols == width:  # the map's own columns: the exact aliased spectrum, length W
        modes, n = width // 2 + 1, width
    else:  # every mode above e^{−REACH}, folded onto the level's columns below
        modes = min(max(cols // 2, mode_cut(lam)), width // 2) + 1
        n = next_fast_len(2 * (modes - 1), real=True)
    # the source rows' spectra as (modes, rows, 6) reals: per mode, rows × (Re, Im) RGB
    source = np.ascontiguousarray(spectrum[:, :modes].view(np.float64)
                                  .reshape(len(theta_src), modes, 6).transpose(1, 0, 2))
    cos_phi = np.cos(2 * np.pi * np.arange(n) / n)
    numerator = np.zeros((rows, modes, 6))
    denominator = np.zeros(rows)
    upper = (rows + 1) // 2
    block_rows = max(1, PAIR_BLOCK // int((last - first + 1).max()))
    for start in range(0, upper, block_rows):
        block = np.arange(start, min(start + block_rows, upper))
        counts = last[block] - first[block] + 1
        dst = np.repeat(block, counts)
        src = np.repeat(first[block], counts) + np.arange(counts.sum()) \
            - np.repeat(np.cumsum(counts) - counts, counts)
        a = lam * np.sin(theta_dst[dst]) * np.sin(theta_src[src])
        weight = omega_row[src] * np.exp(lam * (np.cos(theta_dst[dst] - theta_src[src]) - 1))
        # ĝ_m(a) of g(Δφ) = exp(−a(1 − cos Δφ)) from n samples, m = 0 .. modes − 1,
        # times the row pair's weight; samples below e^{−REACH} are left 0 (most of a
        # sharp level's: its lobe spans few columns away from the poles)
        exponent = a[:, None] * (cos_phi - 1.0)
        g = np.exp(exponent, out=np.zeros_like(exponent), where=exponent > -REACH)
        g_hat = rfft(g, axis=1).real[:, :modes]
        g_hat *= (weight / n)[:, None]
        offsets = np.concatenate([[0], np.cumsum(counts)])
        for i, d in enumerate(block):
            kernels = g_hat[offsets[i]:offsets[i + 1]]  # (source rows of d, modes)
            s0, s1 = first[d], last[d] + 1
            numerator[d] = _sum_rows(kernels, source[:, s0:s1])
            denominator[d] = kernels[:, 0].sum()
            mirror = rows - 1 - d
            if mirror != d:
                numerator[mirror] = _sum_rows(kernels[::-1],
                                              source[:, last_src + 1 - s1:last_src + 1 - s0])
                denominator[mirror] = denominator[d]
    spectra = numerator.view(np.complex128).reshape(rows, modes, 3)
    spectra *= np.exp(1j * np.pi * np.arange(modes) / cols)[None, :, None]  # φ_j's ½
    if cols == width:
        level = irfft(spectra * cols, n=cols, axis=1)
    else:  # Σ_{|m| < modes} C_m e^{imφ_j}: mode m lands on bin m mod W_ℓ
        m = np.arange(modes)
        folded = np.zeros((rows, cols, 3), np.complex128)
        for start in range(0, modes, cols):  # distinct bins within each run of W_ℓ
            run = slice(start, min(start + cols, modes))
            folded[:, m[run] % cols] += spectra[:, run]
            run = slice(max(start, 1), min(start + cols, modes))
            folded[:, -m[run] % cols] += np.conj(spectra[:, run])
        level = ifft(folded * cols, axis=1).real
    return level / (width * denominator)[:, None, None]


def _sum_rows(g: np.ndarray, source: np.ndarray) -> np.ndarray:
    """Σ_s g[s, m] source[m, s, k] (modes, 6): one small product per mode m."""
    return np.matmul(g.T[:, None, :], source)[:, 0]


def mode_cut(lam: float) -> int:
    """The first m with ĝ_m(λ)/ĝ_0(λ) = I_m(λ)/I_0(λ) < e^{−REACH}: no pair's ratio is
    larger (a ≤ λ, and the ratio grows with a)."""
    m = np.arange(1, 8 + int(np.ceil(np.sqrt(2 * REACH * lam))) + 64)
    small = ive(m, lam) < np.exp(-REACH) * ive(0, lam)
    return int(m[np.argmax(small)]) if small.any() else int(m[-1])

"""Method sg's bright sources seen from each vertex as the map turns about +y (decision
0049): a table per vertex and source over one turn, finer than the visibility maps.

The map's bright sources (pipeline/methods/sg/sources.py) carry most of a studio map's
light through a few hundredths of a steradian: their shadows are as sharp as the sources
are small (σ_s = 1/√λ_s: 0.03 and 0.08 rad for the studio's two lights). Read from a
vertex's 32² visibility map (6.4° texels, visibility.py) those shadows widen by a texel;
a source turns with the map, so its visibility cannot be traced once for its direction.
It can be traced for every direction it takes: turned by φ about +y the source lies at
R_y(φ) ω_s, on a circle of constant height, and what a vertex sees of it,

    S_v(φ) = ∫ Ĝ(ω; R_y(φ) ω_s, λ_s) V_v(ω) dω,

Ĝ the source's normalised spherical Gaussian and V_v the vertex's binary visibility, is
tabulated at N turns φ_t = 2π t / N (uint8, × 255) and read linearly between them.

**Quadrature.** Rays along the source's circle: D_ij = R_y(φ_j) u_i with u_i,
i = 0 … 2m, the directions at polar angle θ_i = θ_s + (i − m) h from +y at the source's
azimuth (h = ``step`` σ_s, m = ⌈``EXTENT`` / ``step``⌉: rows over ±EXTENT σ_s; those
past a pole dropped, as their circles are rows already) and φ_j = 2π j / N, N the least
count that puts the widest row's columns at most h apart. Turning the map shifts j, so
the table is a circular correlation along j,

    S_v(φ_t) = Σ_i Σ_k w_ik V_v(D_i,t+k),   w_ik ∝ Ĝ(R_y(φ_k) u_i; ω_s) sin θ_i,

the weights (the Gaussian × each ray's solid angle) normalised to sum 1; computed by FFT
along j. A source sharper than ``MIN_STEP`` / ``step`` takes rows MIN_STEP apart and at
most ``MAX_TURNS`` columns: its shadow is then as sharp as the rays' spacing.

Only rotations about ±y are tabulated (the axis every turning sequence and ``prt view``
uses); a map turned about another axis reads the sources' visibility from the maps as
before (render.source_seen).
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.math.envmap import rotation_about
from pipeline.methods.sg.vertex_scene import VertexScene

EXTENT = 3.0      # rows over ±EXTENT σ_s: the Gaussian's weight beyond is e^(−4.5) of its peak
MIN_STEP = 0.004  # rad (0.23°): the closest rows and columns
MAX_TURNS = 2048  # columns (table entries) per source at most
MIN_TURNS = 16


def turn(degrees: np.ndarray) -> np.ndarray:
    """Rotations (..., 3, 3) by ``degrees`` (...) about +y (as the environment's)."""
    return np.stack([rotation_about((0.0, 1.0, 0.0), float(d))
                     for d in np.ravel(degrees)]).reshape(*np.shape(degrees), 3, 3)


def ring_rows(direction: np.ndarray, sharpness: float, step: float
              ) -> tuple[np.ndarray, np.ndarray, int]:
    """The quadrature of one source (module docstring): rows u (R, 3) (R ≤ 2m + 1),
    weights w (R, N) summing to 1 (w[i, k] for the shift of k columns) and N, of a source at
    unit map-frame ``direction`` (3,) of sharpness λ_s (rad⁻²), rows ``step`` σ_s apart."""
    d = np.asarray(direction, np.float64)
    sigma = 1.0 / math.sqrt(sharpness)
    h = max(step * sigma, MIN_STEP)
    m = max(1, math.ceil(EXTENT * sigma / h))
    theta = math.acos(float(np.clip(d[1], -1.0, 1.0))) + (np.arange(2 * m + 1) - m) * h
    theta = theta[(theta > 0.0) & (theta < math.pi)]  # past a pole a row repeats one
    across = np.array([d[0], 0.0, d[2]])
    length = float(np.linalg.norm(across))
    across = across / length if length > 1e-12 else np.array([1.0, 0.0, 0.0])
    rows = np.cos(theta)[:, None] * np.array([0.0, 1.0, 0.0]) + np.sin(theta)[:, None] * across
    widest = float(np.max(np.sin(theta)))
    count = int(np.clip(math.ceil(2.0 * math.pi * widest / h), MIN_TURNS, MAX_TURNS))
    turned = np.einsum("kab,ib->ika", turn(np.arange(count) * 360.0 / count), rows)
    weights = np.exp(sharpness * (turned @ d - 1.0)) * np.sin(theta)[:, None]
    return rows, weights / weights.sum(), count


def ring_directions(rows: np.ndarray, count: int) -> np.ndarray:
    """World directions (R, N, 3) of the rays: R_y(2π j / N) u_i."""
    return np.einsum("jab,ib->ija", turn(np.arange(count) * 360.0 / count), rows)


def correlate(visible: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """S (P, N) in [0, 1] from the rays' visibility ``visible`` (P, R, N) and the
    weights (R, N): S[p, t] = Σ_i Σ_k w[i, k] visible[p, i, (t + k) mod N]."""
    spectrum = np.fft.rfft(np.asarray(visible, np.float64), axis=-1) \
        * np.conj(np.fft.rfft(weights, axis=-1))
    return np.clip(np.fft.irfft(spectrum.sum(axis=1), n=weights.shape[1], axis=-1), 0.0, 1.0)


def seen_by(scene: VertexScene, vertices: np.ndarray, rows: np.ndarray, weights: np.ndarray
            ) -> np.ndarray:
    """S (P, N) uint8 (× 255, rounded) of global ``vertices`` (P,) for one source's
    quadrature (:func:`ring_rows`), each ray from the vertex pushed ``scene.offset``
    along its normal (VertexScene.intersect: as the visibility maps' rays)."""
    count = weights.shape[1]
    directions = ring_directions(rows, count).reshape(-1, 3)
    origins = scene.positions[vertices] + scene.offset * scene.normals[vertices]
    hits = scene.intersect(np.repeat(origins, len(directions), axis=0),
                           np.tile(directions, (len(vertices), 1)))
    visible = (hits.prim < 0).reshape(len(vertices), len(rows), count)
    return np.rint(correlate(visible, weights) * 255.0).astype(np.uint8)


def at_turn(table: np.ndarray, offsets: np.ndarray, vertices: np.ndarray | slice,
            degrees: float) -> np.ndarray:
    """S (P, K) float64 of ``vertices`` for K sources turned ``degrees`` about +y: each
    source's columns offsets[s] … offsets[s + 1] − 1 of ``table`` (V, Σ N) uint8, read
    linearly between the two nearest turns."""
    columns, weights = [], []
    for s in range(len(offsets) - 1):
        count = int(offsets[s + 1] - offsets[s])
        x = (degrees % 360.0) / 360.0 * count
        t0 = int(math.floor(x)) % count
        f = x - math.floor(x)
        columns += [int(offsets[s]) + t0, int(offsets[s]) + (t0 + 1) % count]
        weights += [(1.0 - f) / 255.0, f / 255.0]
    pairs = np.asarray(table[vertices][:, columns], np.float64) * np.asarray(weights)
    return pairs.reshape(len(pairs), -1, 2).sum(axis=2)

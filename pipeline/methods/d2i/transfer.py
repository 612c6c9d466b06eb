"""Transfer entries of method d2i (paper 000 §3.2, §5.2) with sub-area sampling, in NumPy.

The OpenCL twin is ``kernels/d2i/transfer.cl``; tests hold the two together and check both
against brute-force integration over the disks.

Setting. A receiver x (a view sample, or a gather sample for Ms) with unit normal n_x;
a gather sample g standing for the disk K_g of area |A_g| with normal n_g. For a point q
on the disk, ω = (q − x)/|q − x| and the geometry term of the area measure is

    G(x, q) = max(0, n_x·ω) · max(0, −n_g·ω) / |q − x|².

(Paper 000 writes the estimator in solid angle with the pdf |x − g| / (|A_g| |N_g·ω|);
the change of measure dω = cosθ_q dA / r² needs the square of the distance, which the
paper's pdf drops. With q uniform on K_g the area-measure form below is exact
in expectation.)

Estimators, with q_1..q_n the first n points of g's sub-area sample set (pipeline/stages/
gather.py) and V_g(x) the visibility of g's centre from x (paper eq. 4: a region shares
its centre's visibility and radiance). A pair with one sample (a far disk, below) is a
point sample at the centre c_g:

    D_g(x)  = V_g(x) · (1/π) · min(π, |A_g| G(x, c_g))
    T_jg(x) = V_g(x) · |A_g| f_F(ω_c, ω_o) b_j(x(ω_c, ω_o)) G(x, c_g),  j = 0..k

with ω in x's local shading frame, b_0 the PCA mean and b_1..b_k the basis rows of x's
material (pipeline/methods/d2i/brdf_pca.py), evaluated by linear interpolation on the basis grid
exactly as ``BrdfBasis.reconstruct`` does. A near pair integrates the geometry exactly
over the disk's stand-in, a regular polygon of ``POLYGON_SIDES`` sides and the same area
(:func:`disk_polygons`), clipped to x's upper half-space (:func:`polygon_geometry`,
Lambert's formula), E_g(x) = ∫ G dA, and weights the BRDF by the samples:

    D_g(x)  = V_g(x) · E_g(x) / π
    T_jg(x) = V_g(x) · E_g(x) · Σ_i f_F b_j G(x, q_i) / Σ_i G(x, q_i)

(a ratio estimator: exact for a BRDF constant over the disk; where no sample sees the
clipped polygon, the BRDF towards its vertex mean). Sampling G itself fails where a disk
nearly touches its receiver — a box standing on a floor, a room's corners: the integrand
is a peak as narrow as the gap, which the points miss or hit (dark and bright specks
along every contact line; a test measures +71 % for one such pair). A receiver within
``PLANE_MARGIN`` × radius of the disk's plane sees it edge-on and gets 0. So that the
frame is

    I(x) = direct(x) + ρs(x) · max(0, c(γ)ᵀ T(x) L) + kd(x) · D(x) L,

where L (G, 3) is the outgoing radiance of the gather samples (Lambertian). Ms is D
with gather samples as receivers: L_{n+1} = kd ⊙ Ms L_n.

Near disks still stand for their samples' Voronoi cells only roughly: equal-area disks of
neighbouring samples overlap, so a receiver right beside several of them counts the
overlap twice (Ms row sums of corner samples reach ≈ 2 at 1024 gathers, where a form
factor is ≤ 1). The error falls with the gather spacing.

Number of sub-area samples. A pair gets at most n_max = min(2^⌈log2(Ω/Ω_s)⌉, M) samples
(at least 1; M, the pattern's length, a power of two), Ω = |A_g| / |g − x|² the disk's
solid-angle scale and Ω_s = ``solid_angle``. With n_max > 4 the sum runs in prefixes of
8, 16, 32, ... and stops at the first prefix whose two halves, each an estimate of its own
(every prefix of the pattern is evenly spread), agree within ``tolerance`` × the
prefix's estimate (T row 0; paper §5.1: "the summation stops when converging within a
certain threshold"), or at n_max; receivers without T rows need no samples. n_max = 1
uses the disk's centre: the point gather sample of Hašan et al. 2006, which is what
"without sub-area sampling" means (``solid_angle`` = ∞).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.math.brdf import BrdfParams, coordinate, fixed_term, to_local
from pipeline.methods.d2i.brdf_pca import BrdfBasis

FORM_FACTOR_CAP = np.pi  # the largest |A_g|·mean G a disk can give (form factor 1, × π)
FIRST_CHECK = 4          # sub-area samples before the first convergence check
POLYGON_SIDES = 16       # the regular polygon that stands for a disk in exact integrals
PLANE_MARGIN = 1e-3      # receivers closer to a disk's plane (× its radius) see it edge-on
NEAR_FRACTION = 0.01     # entries carrying this share of a row's product are kept exactly


@dataclass(frozen=True)
class Disks:
    """Gather disks: ``center``, ``normal`` (G, 3), ``area`` (G,), their sub-area
    sample points ``points`` (G, M, 3) (:func:`subarea_points`) and the vertices of the
    equal-area polygons that stand for them in exact integrals, ``polygon`` (G, S, 3)
    (:func:`disk_polygons`). Scene units, world frame. The NumPy estimators take any
    float type; the transfer stage holds the gather artifact's float32 areas, points and
    polygons, as kernels/d2i/transfer.cl reads them (with :attr:`packed`)."""

    center: np.ndarray
    normal: np.ndarray
    area: np.ndarray
    points: np.ndarray
    polygon: np.ndarray

    @property
    def packed(self) -> np.ndarray:
        """(G, 8) float32 rows for kernels/d2i/transfer.cl: centre, normal, area, 0."""
        packed = np.zeros((len(self.area), 8), np.float32)
        packed[:, 0:3], packed[:, 3:6], packed[:, 6] = self.center, self.normal, self.area
        return packed

    @property
    def inverse_area(self) -> np.ndarray:
        """1/|A_g| (G,) in the areas' type, 0 where |A_g| = 0."""
        return np.divide(1.0, self.area, out=np.zeros_like(self.area), where=self.area > 0)


@dataclass(frozen=True)
class Receivers:
    """Receiving points: ``position``, ``normal``, ``tangent`` (P, 3); ``wo`` (P, 3)
    unit directions towards the viewer (world frame)."""

    position: np.ndarray
    normal: np.ndarray
    tangent: np.ndarray
    wo: np.ndarray


@dataclass(frozen=True)
class GlossyTable:
    """What T needs of a material: its BRDF parameters, the basis grid (h,) and the
    tabulated rows (R, h) = [b0, b1, ..., bk]."""

    params: BrdfParams
    grid: np.ndarray
    rows: np.ndarray

    @classmethod
    def from_basis(cls, basis: BrdfBasis, k: int | None = None) -> GlossyTable:
        k = basis.k if k is None else k
        return cls(basis.params, basis.grid, np.vstack([basis.mean, basis.basis[:k]]))

    def evaluate(self, wi_local: np.ndarray, wo_local: np.ndarray) -> np.ndarray:
        """f_F(ωi, ωo) · b_j(x(ωi, ωo)) for every row j: (..., R)."""
        x = coordinate(wi_local, wo_local, self.params)
        fixed = fixed_term(wi_local, wo_local, self.params)
        columns = [np.interp(x, self.grid, row) for row in self.rows]
        return np.stack(columns, axis=-1) * fixed[..., None]


def sample_counts(receivers: Receivers, disks: Disks, solid_angle: float) -> np.ndarray:
    """n_max (P, G) int: sub-area samples each pair may use."""
    d2 = np.sum((disks.center[None] - receivers.position[:, None]) ** 2, axis=-1)
    omega = disks.area[None, :] / np.maximum(d2, 1e-300)
    exponent = np.ceil(np.log2(np.maximum(omega / solid_angle, 1.0)))
    return np.minimum(2 ** exponent, disks.points.shape[1]).astype(np.int64)


def _geometry(receivers: Receivers, q: np.ndarray, disk_normal: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """G(x, q) (P, G, S) and the unit directions ω (P, G, S, 3) for points q (G, S, 3)."""
    d = q[None] - receivers.position[:, None, None]
    r2 = np.maximum(np.sum(d * d, axis=-1), 1e-300)
    w = d / np.sqrt(r2)[..., None]
    cos_x = np.maximum(np.einsum("pgsc,pc->pgs", w, receivers.normal), 0.0)
    cos_q = np.maximum(-np.einsum("pgsc,gc->pgs", w, disk_normal), 0.0)
    return cos_x * cos_q / r2, w


def transfer(receivers: Receivers, disks: Disks, visibility: np.ndarray,
             table: GlossyTable | None, solid_angle: float, tolerance: float
             ) -> tuple[np.ndarray, np.ndarray | None]:
    """D (P, G) and, for a glossy ``table``, T (P, R, G) of receivers against disks;
    ``visibility`` (P, G) of the disk centres (0/1)."""
    counts = sample_counts(receivers, disks, solid_angle)
    near = counts > 1
    geometry, w = _geometry(receivers, disks.points, disks.normal)  # (P, G, M)
    centre_geometry, centre_w = _geometry(receivers, disks.center[:, None], disks.normal)
    geometry[..., :1] = np.where(near[..., None], geometry[..., :1], centre_geometry)
    w[..., :1, :] = np.where(near[..., None, None], w[..., :1, :], centre_w)
    per_sample = geometry * disks.area[None, :, None]
    exact = np.zeros(counts.shape)
    centroid = np.zeros(counts.shape + (3,))
    # a receiver in the disk's plane (to PLANE_MARGIN of its radius: rounding) sees it
    # edge-on and gets nothing
    height = np.einsum("gc,pgc->pg", disks.normal,
                       receivers.position[:, None] - disks.center[None])
    integrate = near & (height > PLANE_MARGIN * np.sqrt(disks.area / np.pi)[None])
    p_idx, g_idx = np.nonzero(integrate)
    exact[integrate], centroid[integrate] = polygon_geometry(
        receivers.position[p_idx], receivers.normal[p_idx], disks.polygon[g_idx])
    point = np.minimum(per_sample[..., 0], FORM_FACTOR_CAP)
    d = visibility * np.where(near, exact, point) / np.pi
    if table is None:
        return d, None
    wi_local = to_local(w, receivers.normal[:, None, None], receivers.tangent[:, None, None])
    wo_local = to_local(receivers.wo, receivers.normal, receivers.tangent)[:, None, None]
    glossy = table.evaluate(wi_local, np.broadcast_to(wo_local, wi_local.shape)) \
        * per_sample[..., None]  # (P, G, M, R)
    used = _converged_counts(glossy[..., 0], counts, tolerance)
    mask = np.arange(disks.points.shape[1])[None, None, :] < used[..., None]
    glossy_sum = np.sum(glossy * mask[..., None], axis=2)  # (P, G, R)
    geometry_sum = np.sum(per_sample * mask, axis=-1)
    towards = centroid - receivers.position[:, None]
    towards /= np.maximum(np.linalg.norm(towards, axis=-1, keepdims=True), 1e-300)
    at_centroid = table.evaluate(
        to_local(towards, receivers.normal[:, None], receivers.tangent[:, None]),
        np.broadcast_to(wo_local[:, :, 0], towards.shape))
    # near pairs: the exact geometry integral times the samples' G-weighted BRDF mean
    # (a ratio estimator); where no sample sees the clipped polygon, the BRDF towards
    # its centroid
    mean_brdf = np.where((geometry_sum > 0)[..., None],
                         glossy_sum / np.maximum(geometry_sum, 1e-300)[..., None],
                         at_centroid)
    t = np.where(near[..., None], exact[..., None] * mean_brdf, glossy_sum)
    return d, np.moveaxis(t * visibility[..., None], -1, 1)


def polygon_geometry(x: np.ndarray, n: np.ndarray, polygon: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """∫ G(x, q) dA over each convex polygon (K, S, 3) facing its receiver (x, n) (K, 3),
    clipped to the receiver's upper half-space: Lambert's formula ½ |Σ_e Θ_e n·γ_e| over
    the clipped polygon's edges (Θ_e the angle the edge subtends at x, γ_e the unit
    normal of the plane through x and the edge; Θ from atan2, exact for short edges);
    and the clipped polygon's vertex mean (K, 3) (x where nothing is left)."""
    k, sides = polygon.shape[:2]
    rel = polygon - x[:, None]
    h = np.einsum("ksc,kc->ks", rel, n)
    rel_next, h_next = np.roll(rel, -1, axis=1), np.roll(h, -1, axis=1)
    crossing = (h >= 0) != (h_next >= 0)
    t = np.divide(h, h - h_next, out=np.zeros_like(h), where=crossing)
    # candidates in cyclic order: vertex i (if above), then edge i's crossing (if any)
    points = np.stack([rel, rel + t[..., None] * (rel_next - rel)], axis=2)
    points = points.reshape(k, 2 * sides, 3)
    valid = np.stack([h >= 0, crossing], axis=2).reshape(k, 2 * sides)
    big = 4 * sides
    index = np.where(valid, np.arange(2 * sides), big)
    suffix = np.minimum.accumulate(index[:, ::-1], axis=1)[:, ::-1]
    after = np.concatenate([suffix[:, 1:], np.full((k, 1), big)], axis=1)
    following = np.where(after < big, after, suffix[:, :1])
    a = points
    b = np.take_along_axis(points, np.minimum(following, 2 * sides - 1)[..., None], axis=1)
    ua = a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-300)
    ub = b / np.maximum(np.linalg.norm(b, axis=-1, keepdims=True), 1e-300)
    c = np.cross(ua, ub)
    sine = np.linalg.norm(c, axis=-1)
    theta = np.arctan2(sine, np.sum(ua * ub, axis=-1))
    term = np.where(valid & (sine > 0),
                    theta * np.einsum("kec,kc->ke", c, n) / np.maximum(sine, 1e-300), 0.0)
    count = valid.sum(axis=1)
    centroid = x + np.sum(points * valid[..., None], axis=1) / np.maximum(count, 1)[:, None]
    return 0.5 * np.abs(term.sum(axis=1)), centroid


def split_near(rows: np.ndarray, area: np.ndarray, fraction: float = NEAR_FRACTION
               ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Split rows (n, G) per unit source area into a smooth far part (n, G) and near
    entries ``(row, column, value)`` (each (m,), row-major order): an entry is near where
    its share of the row's product with a uniform radiance, |t_g| |A_g| / Σ_h |t_h| |A_h|,
    is at least ``fraction``; rows = far + the near entries.

    A receiver beside a disk (a floor pixel at a box's foot, a corner) has one or two
    entries a thousand times the rest (per unit area: E_g/(π |A_g|) of a disk that fills
    a quarter of the hemisphere). In the Haar domain such a spike owns the row's L2 norm,
    and a truncation within a few % of that norm may drop the whole far field or leave a
    uniform offset across it — cheap in L2, spread over 16k entries, but multiplied by
    the scene's total power in the product (measured at 256²: rows of 15 coefficients,
    D L negative). Near entries are kept exactly (the renderer multiplies them with the
    gather-domain radiance); in the far part each run of adjacent near entries is
    replaced by the mean of the far entries on either side of it in gather order, so
    that it stays smooth. At most 1/``fraction`` entries of a row are near, so the work
    beyond the threshold test is per near entry, not per column."""
    weight = np.abs(rows)
    weight *= area[None, :]
    bar = fraction * weight.sum(axis=1)
    candidates = np.flatnonzero((weight.max(axis=1, initial=0) >= bar) & (bar > 0))
    local, column = np.divmod(np.flatnonzero(weight[candidates] >= bar[candidates, None]),
                              rows.shape[1])  # a flat search: 2-D np.nonzero is slower
    row = candidates[local]
    far = rows.copy()
    if len(row) == 0:
        return far, (row, column, rows[row, column])
    size = rows.shape[1]
    starts = np.r_[True, (np.diff(column) != 1) | (np.diff(row) != 0)]  # runs of near
    run = np.cumsum(starts) - 1
    run_row, left = row[starts], column[starts] - 1
    right = column[np.r_[starts[1:], True]] + 1
    has_left, has_right = left >= 0, right < size
    neighbours = rows[run_row, np.maximum(left, 0)] * has_left + \
        rows[run_row, np.minimum(right, size - 1)] * has_right
    fill = neighbours / np.maximum(has_left.astype(int) + has_right, 1)
    far[row, column] = fill[run]
    return far, (row, column, rows[row, column] - far[row, column])


def fill_sourceless(rows: np.ndarray, area: np.ndarray, length: int) -> np.ndarray:
    """Rows (n, G) per unit source area extended to ``length`` ≥ G columns (the Haar
    length), with every column whose source has no area — |A_g| = 0, and the padding
    g ≥ G — set by linear interpolation between the nearest columns with area on either
    side (before the first and beyond the last: the nearest one's value).

    The product with the radiance vector (|A_g| L_g, zero in those columns) never reads
    them, so any value is exact; zeros would not be harmless, though. A hole is a spike
    down of the whole row's height: truncation drops its fine coefficients and keeps its
    share of the coarse ones, so the kept row sits lower across its neighbours, where
    the radiance is not zero. On the Tableau (64k gathers, 5.4 % of them without area)
    the first bounce came out 3.6 % dark and the indirect mean −5.9 %; with the holes
    filled and the areas stratified (pipeline/methods/d2i/stages/gather.py), −1.4 % and −2.05 %
    (decision 0015)."""
    count = rows.shape[1]
    source = np.flatnonzero(area[:count] > 0)
    out = np.empty((len(rows), length), rows.dtype)
    out[:, :count] = rows
    sourced = np.zeros(length, bool)
    sourced[source] = True
    free = np.flatnonzero(~sourced)
    if len(free) == 0:
        return out
    if len(source) == 0:
        out[:, count:] = 0
        return out
    right = np.minimum(np.searchsorted(source, free), len(source) - 1)
    left = np.maximum(right - 1, 0)
    right_col, left_col = source[right], source[left]
    span = right_col - left_col
    weight = np.where(span > 0, (free - left_col) / np.maximum(span, 1), 0.0)
    weight = np.clip(weight, 0.0, 1.0)  # beyond the last source: its value
    out[:, free] = ((1.0 - weight) * rows[:, left_col] + weight * rows[:, right_col]
                    ).astype(rows.dtype)
    return out


def _converged_counts(values: np.ndarray, counts: np.ndarray, tolerance: float) -> np.ndarray:
    """Samples used per pair: the first prefix 8, 16, ... ≤ n_max whose two halves'
    means of ``values`` (P, G, M) agree within ``tolerance`` × the prefix's mean; n_max
    (a power of two) if none does, or if n_max ≤ 4."""
    used = np.where(counts <= FIRST_CHECK, counts, 0)
    running = np.cumsum(values, axis=-1)
    size = values.shape[-1]
    if size < 2 * FIRST_CHECK:
        return np.where(used == 0, counts, used)
    previous = running[..., FIRST_CHECK - 1] / FIRST_CHECK
    prefix = 2 * FIRST_CHECK
    while prefix <= size:
        mean = running[..., prefix - 1] / prefix
        second_half = 2.0 * mean - previous
        converged = np.abs(second_half - previous) <= tolerance * np.abs(mean)
        done = (used == 0) & (prefix <= counts) & (converged | (prefix == counts))
        used = np.where(done, prefix, used)
        previous = mean
        prefix *= 2
    return np.where(used == 0, counts, used)


# ------------------------------------------------------------------------ the disks


def disk_pattern(count: int) -> np.ndarray:
    """``count`` points (count, 2) in the unit disk: Halton (2, 3) points through Shirley
    and Chiu's concentric mapping; every prefix is evenly spread over the disk."""
    index = np.arange(1, count + 1)
    u = 2.0 * np.stack([_radical_inverse(index, 2), _radical_inverse(index, 3)], 1) - 1.0
    a, b = u[:, 0], u[:, 1]
    outer = np.abs(a) > np.abs(b)
    r = np.where(outer, a, b)
    safe_a = np.where(a == 0, 1.0, a)
    safe_b = np.where(b == 0, 1.0, b)
    phi = np.where(outer, (np.pi / 4) * b / safe_a, np.pi / 2 - (np.pi / 4) * a / safe_b)
    return np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1)


def _radical_inverse(index: np.ndarray, base: int) -> np.ndarray:
    out, scale = np.zeros(len(index)), 1.0 / base
    i = index.copy()
    while np.any(i > 0):
        out += (i % base) * scale
        i //= base
        scale /= base
    return out


def disk_polygons(position: np.ndarray, normal: np.ndarray, tangent: np.ndarray,
                  area: np.ndarray, sides: int = POLYGON_SIDES) -> np.ndarray:
    """Vertices (G, S, 3) of regular S-gons of the disks' areas, centred on them in their
    planes, counter-clockwise about the normal from the tangent."""
    radius = np.sqrt(2.0 * area / (sides * np.sin(2.0 * np.pi / sides)))
    phi = 2.0 * np.pi * np.arange(sides) / sides
    bitangent = np.cross(normal, tangent)
    return position[:, None, :] + radius[:, None, None] * (
        np.cos(phi)[None, :, None] * tangent[:, None, :]
        + np.sin(phi)[None, :, None] * bitangent[:, None, :])


def subarea_points(position: np.ndarray, normal: np.ndarray, tangent: np.ndarray,
                   radius: np.ndarray, rotation: np.ndarray, pattern: np.ndarray
                   ) -> np.ndarray:
    """Sub-area sample points (G, M, 3) on the disks K_g: the pattern (M, 2) turned by
    each disk's ``rotation`` and scaled by its ``radius`` in the frame (t, n × t)."""
    c, s = np.cos(rotation)[:, None], np.sin(rotation)[:, None]
    a = c * pattern[None, :, 0] - s * pattern[None, :, 1]
    b = s * pattern[None, :, 0] + c * pattern[None, :, 1]
    bitangent = np.cross(normal, tangent)
    r = radius[:, None, None]
    return position[:, None, :] + r * (a[..., None] * tangent[:, None, :]
                                       + b[..., None] * bitangent[:, None, :])

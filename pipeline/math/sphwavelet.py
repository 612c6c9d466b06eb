"""Orthonormal spherical Haar wavelets on the geodesic sphere, and their triple products
(paper 004 §3.1, corrected for unequal areas).

**The basis.** Functions are piecewise constant on the 20·4^L leaves of the geodesic
sphere of level L (:mod:`pipeline.math.geodesic`). Each root triangle R (level 0) carries
a scaling function φ_R = 1/√|R| on R; each triangle n of levels 0 .. L − 1 carries three
wavelets ψ_{n,t}, constant on each of its four children c with the values w_{n,t}(c).
With the inner product ⟨f, g⟩ = ∫ f g dω over solid angle, the basis is orthonormal
when on every triangle n, with child solid angles a_c,

    Σ_c a_c w_{n,t}(c) = 0              (a wavelet has zero mean)
    Σ_c a_c w_{n,t}(c) w_{n,s}(c) = δ_ts  (the three are orthonormal).

The paper (after Bonneau 1999) takes the sign patterns

    p_0 = (+, −, −, +),  p_1 = (+, −, +, −),  p_2 = (+, +, −, −)   over children 0..3,

which satisfy both only when the four children have equal areas. They do not (the centre
child subtends up to 1.20× a corner child), so here each triangle's wavelets are the
orthonormal set *nearest* the patterns: remove each pattern's weighted mean, then
orthonormalise symmetrically (Löwdin), W = S^{-1/2} P with S = P diag(a) Pᵀ. That is
the unique orthonormal set minimising Σ_t ‖w_t − p_t‖²_a up to scale, and for equal
areas it is the paper's basis normalised. It is exactly orthogonal for any areas.

**Layout.** A coefficient vector of level L has N = 20·4^L entries: [0, 20) the root
scaling coefficients, then the wavelets of level l (triangles of level l, refining into
level l + 1) at [20·4^l, 20·4^(l+1)), triangle-major: index 20·4^l + 3n + t. So the
first 80 coefficients are paper 004's "top-only 80" (20 scaling + 60 level-0 wavelets)
and the first 320 add level 1.

**Triple products.** For f = Σ f_i ψ_i (likewise g, h) the integral ∫ f g h dω =
Σ_ijk C_ijk f_i g_j h_k with the tripling coefficients C_ijk = ∫ ψ_i ψ_j ψ_k dω. Since
every function is constant on the leaves, C_ijk = Σ_leaf Ω_leaf ψ_i ψ_j ψ_k exactly.
Supports are nested triangles, so C_ijk ≠ 0 only when

1. all three live on the same triangle n: the root's φ³ = 1/√|R|, or three of n's
   wavelets, T_n[a, b, c] = Σ_c a_c w_a w_b w_c (not zero in general: with unequal
   areas even ψ_a²ψ_b can be non-zero, unlike the paper's case 2);
2. two are the same wavelet ψ_{n,t} and the third, ψ_U, lives on a coarser triangle
   holding n (or is n's root scaling): C = ψ_U|_n, the constant value ψ_U takes on n
   (the paper's case 3, with ψ_U|_n in place of ±4^-l);

two distinct wavelets of n with a coarser third integrate to ψ_U|_n ⟨ψ_a, ψ_b⟩ = 0, and
one wavelet with two coarser functions integrates to zero (zero mean). The sum therefore
runs over the triangles, from the root down, in time linear in the number of triangles
(Ng et al. 2004's algorithm on this hierarchy)::

    ∫ f g h = Σ_R |R| f̄_R ḡ_R h̄_R
            + Σ_n Σ_t (f_nt g_nt h̄_n + f_nt h_nt ḡ_n + g_nt h_nt f̄_n)
            + Σ_n Σ_abc T_n[a, b, c] f_na g_nb h_nc

where f̄_n is the value on n of f's reconstruction from the coefficients coarser than
n's own (f̄_R = f_R/√|R|; a child c of n has f̄_c = f̄_n + Σ_t f_nt w_nt(c)).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import numpy as np

from pipeline.math.geodesic import ROOTS, geodesic_levels

PATTERNS = np.array([[1, -1, -1, 1], [1, -1, 1, -1], [1, 1, -1, -1]], dtype=np.float64)


def coefficient_count(leaf_level: int) -> int:
    """N = 20·4^L coefficients (= leaves) of level L."""
    return ROOTS * 4 ** leaf_level


def level_start(level: int) -> int:
    """Index of the first wavelet of level ``level`` (= 20·4^level)."""
    return ROOTS * 4 ** level


def nearest_orthonormal_wavelets(child_areas: np.ndarray) -> np.ndarray:
    """Wavelet values w (T, 3, 4) on the children of T triangles with child solid
    angles ``child_areas`` (T, 4): the orthonormal zero-mean set nearest the paper's
    sign patterns (module docstring)."""
    a = np.asarray(child_areas, np.float64)
    mean = PATTERNS @ a.T / a.sum(axis=1)  # (3, T) weighted means
    p = PATTERNS[None] - mean.T[:, :, None]  # (T, 3, 4)
    gram = np.einsum("tac,tc,tbc->tab", p, a, p)
    values, vectors = np.linalg.eigh(gram)
    inverse_root = np.einsum("tak,tk,tbk->tab", vectors, values ** -0.5, vectors)
    return inverse_root @ p


@dataclass(frozen=True)
class WaveletBasis:
    """The basis of level ``leaf_level``: ``root_areas`` (20,) sr, and per wavelet
    level l the ``child_areas[l]`` (20·4^l, 4) sr and ``wavelets[l]`` (20·4^l, 3, 4)."""

    leaf_level: int
    root_areas: np.ndarray
    child_areas: tuple[np.ndarray, ...]
    wavelets: tuple[np.ndarray, ...]

    @property
    def size(self) -> int:
        """N, the number of coefficients."""
        return coefficient_count(self.leaf_level)

    def node_tensors(self, level: int) -> np.ndarray:
        """T_n[a, b, c] = Σ_c a_c w_a w_b w_c of every triangle of ``level`` (T, 3, 3, 3)."""
        w, a = self.wavelets[level], self.child_areas[level]
        return np.einsum("tac,tbc,tdc,tc->tabd", w, w, w, a)

    def forward(self, leaf_values: np.ndarray) -> np.ndarray:
        """Coefficients (..., N) of the function with the given mean value on each leaf
        (..., N): exact, since the basis spans the piecewise-constant functions."""
        s = np.asarray(leaf_values, np.float64)
        out = np.empty(s.shape, np.float64)
        for level in reversed(range(self.leaf_level)):
            children = s.reshape(*s.shape[:-1], -1, 4)
            a = self.child_areas[level]
            weighted = a[:, None, :] * self.wavelets[level]  # (n, 3, 4): one 2-operand
            detail = np.einsum("...nc,ntc->...nt", children, weighted)  # einsum, 2× faster
            out[..., level_start(level):level_start(level + 1)] = \
                detail.reshape(*s.shape[:-1], -1)
            s = np.einsum("...nc,nc->...n", children, a) / a.sum(axis=1)
        out[..., :ROOTS] = s * np.sqrt(self.root_areas)
        return out

    def inverse(self, coefficients: np.ndarray) -> np.ndarray:
        """The value on each leaf (..., N) of the function with ``coefficients`` (..., N)."""
        c = np.asarray(coefficients, np.float64)
        s = c[..., :ROOTS] / np.sqrt(self.root_areas)
        for level in range(self.leaf_level):
            detail = c[..., level_start(level):level_start(level + 1)]
            detail = detail.reshape(*c.shape[:-1], -1, 3)
            children = s[..., None] + np.einsum("...nt,ntc->...nc", detail,
                                                self.wavelets[level])
            s = children.reshape(*c.shape[:-1], -1)
        return s

    def support_areas(self) -> np.ndarray:
        """Solid angle (N,) of each basis function's support, sr: its root's for a
        scaling function, its triangle's for a wavelet. Paper 004's "area-weighted"
        coefficient of the unnormalised ψ is the orthonormal one × √(support area)."""
        return np.concatenate([self.root_areas] + [np.repeat(a.sum(axis=1), 3)
                                                   for a in self.child_areas])

    def leaf_areas(self) -> np.ndarray:
        """Solid angles (N,) of the leaves, sr."""
        return geodesic_levels(self.leaf_level)[self.leaf_level].areas

    def triple_product(self, f: np.ndarray, g: np.ndarray, h: np.ndarray) -> np.ndarray:
        """∫ f g h dω (...) from coefficients (..., N) each, by the tree sum of the module
        docstring (all coefficients; the NumPy twin of the renderer's kernel)."""
        f, g, h = (np.asarray(x, np.float64) for x in (f, g, h))
        lead = np.broadcast_shapes(f.shape[:-1], g.shape[:-1], h.shape[:-1])
        coarse = [x[..., :ROOTS] / np.sqrt(self.root_areas) for x in (f, g, h)]
        total = np.einsum("...r,...r,...r,r->...", *coarse, self.root_areas)
        for level in range(self.leaf_level):
            lo, hi = level_start(level), level_start(level + 1)
            fd, gd, hd = (x[..., lo:hi].reshape(*x.shape[:-1], -1, 3) for x in (f, g, h))
            fb, gb, hb = coarse
            total = total + np.einsum("...nt,...nt,...n->...", fd, gd, hb) \
                + np.einsum("...nt,...nt,...n->...", fd, hd, gb) \
                + np.einsum("...nt,...nt,...n->...", gd, hd, fb) \
                + np.einsum("nabc,...na,...nb,...nc->...", self.node_tensors(level),
                            fd, gd, hd)
            w = self.wavelets[level]
            coarse = [(xb[..., None] + np.einsum("...nt,ntc->...nc", xd, w))
                      .reshape(*xb.shape[:-1], -1) for xb, xd in zip(coarse, (fd, gd, hd),
                                                                      strict=True)]
        return np.broadcast_to(total, lead)


def depth_first_keys(leaf_level: int) -> np.ndarray:
    """A sort key (N,) that orders the coefficients depth first: each root's scaling
    coefficient, then its triangle's three wavelets, then the subtree of its child 0,
    child 1, ... Sorted by it, a sparse coefficient list visits every triangle after its
    ancestors and each subtree in one run (what :func:`sparse_triple_product` needs).
    Key of wavelet t of triangle n of level l: ((n << 2(L − 1 − l)) << 4 | (l + 1)) << 2
    | t + 1; of the scaling coefficient of root r: r << 2(L − 1) << 6."""
    keys = np.empty(coefficient_count(leaf_level), np.int64)
    shift = 2 * (leaf_level - 1)
    keys[:ROOTS] = np.arange(ROOTS, dtype=np.int64) << shift << 6
    for level in range(leaf_level):
        node = np.arange(ROOTS * 4 ** level, dtype=np.int64)
        base = ((node << (shift - 2 * level)) << 4 | (level + 1)) << 2
        keys[level_start(level):level_start(level + 1)] = \
            (base[:, None] | np.arange(1, 4)).reshape(-1)
    return keys


def sparse_triple_product(basis: WaveletBasis,
                          lists: tuple[tuple[np.ndarray, np.ndarray], ...]) -> float:
    """∫ f g h dω from three sparse coefficient lists (indices, values), each sorted by
    :func:`depth_first_keys`, in time linear in their total length (times the depth).

    Walks the union of the triangles the lists touch in depth-first order, keeping for
    each function the coefficients on the current path and its coarse value f̄ on every
    triangle of the path (module docstring); a triangle none of the lists touches has
    no coefficients, so its f̄ follows from its parent's. The NumPy twin of the
    per-pixel loop in kernels/triple/triple.cl (scalar Python: for tests, not for speed)."""
    depth = basis.leaf_level
    keys = depth_first_keys(depth)
    heads = [0, 0, 0]
    path = [-1] * depth  # the triangle on the current path at each level
    own = np.zeros((3, depth, 3))  # the path triangles' wavelet coefficients
    coarse = np.zeros((3, depth))  # f̄ on the path triangles
    scaling = np.zeros(3)
    total = 0.0
    while True:
        pending = [(keys[ix[i]], int(ix[i])) for (ix, _), i in zip(lists, heads, strict=True)
                   if i < len(ix)]
        if not pending:
            return total
        index = min(pending)[1]
        if index < ROOTS:  # a root's scaling coefficients: they come first in its subtree
            root = index
            for f in range(3):
                scaling[f] = 0.0
                if heads[f] < len(lists[f][0]) and lists[f][0][heads[f]] == index:
                    scaling[f] = lists[f][1][heads[f]]
                    heads[f] += 1
            path = [-1] * depth
            path[0] = root
            own[:] = 0.0
            coarse[:, 0] = scaling / np.sqrt(basis.root_areas[root])
            total += basis.root_areas[root] * np.prod(coarse[:, 0])
            continue
        level = int(np.log2(index // ROOTS)) // 2  # index in [20·4^l, 20·4^(l+1))
        first = level_start(level) + 3 * ((index - level_start(level)) // 3)
        node = (first - level_start(level)) // 3
        c = np.zeros((3, 3))
        for f in range(3):  # this triangle's coefficients are adjacent in every list
            while heads[f] < len(lists[f][0]) and first <= lists[f][0][heads[f]] < first + 3:
                c[f, lists[f][0][heads[f]] - first] = lists[f][1][heads[f]]
                heads[f] += 1
        for k in range(level + 1):  # bring the path down to this triangle
            ancestor = node >> 2 * (level - k)
            if path[k] == ancestor and k < level:
                continue
            if k == 0 and path[0] != ancestor:  # a new root without scaling coefficients
                coarse[:, 0] = 0.0
            elif k > 0:
                parent = path[k - 1]
                coarse[:, k] = coarse[:, k - 1] + own[:, k - 1] @ \
                    basis.wavelets[k - 1][parent, :, ancestor & 3]
            path[k] = ancestor
            own[:, k] = 0.0
        own[:, level] = c
        fb, gb, hb = coarse[:, level]
        total += np.sum(c[0] * c[1]) * hb + np.sum(c[0] * c[2]) * gb + np.sum(c[1] * c[2]) * fb
        total += np.einsum("abc,a,b,c->", basis.node_tensors(level)[node], *c)


def kernel_tables(basis: WaveletBasis) -> dict[str, np.ndarray]:
    """The basis as kernels/sphwavelet.h reads it (float32): ``root_area`` (20,),
    ``wavelet`` (triangles of levels 0 .. L − 1, 12) and ``tensor`` (same, 27)."""
    levels = range(basis.leaf_level)
    return {"root_area": basis.root_areas.astype(np.float32),
            "wavelet": np.concatenate([basis.wavelets[lv].reshape(-1, 12) for lv in levels]
                                      ).astype(np.float32),
            "tensor": np.concatenate([basis.node_tensors(lv).reshape(-1, 27) for lv in levels]
                                     ).astype(np.float32)}


@cache
def wavelet_basis(leaf_level: int) -> WaveletBasis:
    """The orthonormal basis of level ``leaf_level`` (cached; treat as read-only)."""
    levels = geodesic_levels(leaf_level)
    child_areas = tuple(levels[level + 1].areas.reshape(-1, 4) for level in range(leaf_level))
    return WaveletBasis(leaf_level, levels[0].areas, child_areas,
                        tuple(nearest_orthonormal_wavelets(a) for a in child_areas))


@cache
def equal_area_basis(leaf_level: int) -> WaveletBasis:
    """Paper 004's basis for comparison: the sign patterns (normalised) with every root
    taken as 4π/20 and every child as a quarter of its parent. Its triple product is the
    paper's tripling theorem; on the real leaves it is the equal-weight sum
    Σ_leaf (4π/N) f g h instead of Σ_leaf Ω_leaf f g h."""
    child_areas = tuple(np.full((ROOTS * 4 ** level, 4), 4 * np.pi / ROOTS / 4 ** (level + 1))
                        for level in range(leaf_level))
    return WaveletBasis(leaf_level, np.full(ROOTS, 4 * np.pi / ROOTS), child_areas,
                        tuple(nearest_orthonormal_wavelets(a) for a in child_areas))


def leaf_means(function: Callable[[np.ndarray], np.ndarray], leaf_level: int,
               refine: int = 2) -> np.ndarray:
    """Mean of ``function`` over each leaf of level ``leaf_level`` (..., N): the
    solid-angle-weighted mean of its values at the centroids of the 4^refine leaves of
    level ``leaf_level + refine`` inside each. ``function`` maps unit directions (M, 3)
    to values (..., M)."""
    fine = geodesic_levels(leaf_level + refine)[-1]
    values = np.asarray(function(fine.centroids), np.float64)
    weights = fine.areas.reshape(-1, 4 ** refine)
    grouped = values.reshape(*values.shape[:-1], -1, 4 ** refine)
    return np.einsum("...nk,nk->...n", grouped, weights) / weights.sum(axis=1)


def basis_functions(basis: WaveletBasis, indices: np.ndarray) -> np.ndarray:
    """Leaf values (len(indices), N) of the basis functions ``indices``: the inverse
    transform of unit vectors."""
    unit = np.zeros((len(indices), basis.size))
    unit[np.arange(len(indices)), indices] = 1.0
    return basis.inverse(unit)


def tripling_coefficients(basis: WaveletBasis) -> tuple[np.ndarray, np.ndarray]:
    """The non-zero tripling coefficients with i ≤ j ≤ k: indices (M, 3) and values (M,),
    from the two cases of the module docstring (C is symmetric in i, j, k)."""
    rows: list[tuple[int, int, int]] = []
    values: list[float] = []
    for root, area in enumerate(basis.root_areas):
        rows.append((root, root, root))
        values.append(1.0 / np.sqrt(area))
    # ancestors[n] of the triangles of the current level: (index, value on n) pairs.
    ancestors = [[(root, 1.0 / np.sqrt(area))] for root, area in enumerate(basis.root_areas)]
    for level in range(basis.leaf_level):
        tensors = basis.node_tensors(level)
        w = basis.wavelets[level]
        below: list[list[tuple[int, float]]] = []
        for n, coarser in enumerate(ancestors):
            own = [level_start(level) + 3 * n + t for t in range(3)]
            for a in range(3):
                for b in range(a, 3):
                    for c in range(b, 3):
                        rows.append((own[a], own[b], own[c]))
                        values.append(tensors[n, a, b, c])
                for index, value in coarser:
                    rows.append((index, own[a], own[a]))
                    values.append(value)
            for child in range(4):
                below.append(coarser + [(own[t], w[n, t, child]) for t in range(3)])
        ancestors = below
    return np.array(rows, np.int64), np.array(values)


def tripling_by_quadrature(basis: WaveletBasis, i: int, j: int, k: int) -> float:
    """C_ijk = Σ_leaf Ω_leaf ψ_i ψ_j ψ_k, summed leaf by leaf (for tests)."""
    psi = basis_functions(basis, np.array([i, j, k]))
    return float(np.sum(basis.leaf_areas() * psi[0] * psi[1] * psi[2]))

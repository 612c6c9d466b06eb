"""Correspondence of spherical Gaussian lobe slots across views and vertices (paper 003
§4.2): slot j of a vertex's lobes must mean the same lobe at every view and at the
neighbouring vertices, or interpolation blends unrelated lobes ("Gaussian flips").

**Distance of two lobe sets.** For lobe means A, B (N, 3) (unit) and a permutation π of
the N slots, c(π) = Σ_k arccos(A_k · B_π(k)) (radians). The best match is the π
minimising c over all N! permutations (N ≤ 3: at most 6).

**Flip.** A pair of neighbours (two views of one vertex that are neighbours on the
92-view icosahedron, or one view of two vertices sharing a mesh edge) both holding
N ≥ 2 lobes with weight (above the horizon, T ≠ 0) is flipped when the identity is not
a best match: c(id) > min_π c(π) + ``FLIP_MARGIN``. Counted by :func:`count_flips`.

**Slot alignment** (:func:`align_views`): a vertex's views are relabelled by a
breadth-first walk over the view graph from its strongest view, each view taking the
permutation that best matches its already-walked neighbours. **Relaxation** (the pass
the paper proposes for the flips left after the flood fill, 003 §7): sweeps over the
vertices in flood order in which each vertex first takes, for all its views at once,
the permutation that best matches its mesh neighbours (processed before or after it)
summed over the views they share — a whole vertex labelled the other way round is
outvoted by its own views otherwise — and then every (vertex, view) the permutation
that best matches all its neighbours — the vertex's neighbouring views and the same
view at every neighbouring vertex — until no label changes
(:func:`relax`). Relabelling keeps every fit's error; it changes only which slot holds
which lobe.

**Filling views without data** (:func:`fill_views`): views below the horizon or with
T ≡ 0 get w = 0 and, slot by slot, the normalised mean of their filled neighbours' means
and the geometric mean of their λ, walked outwards from the fitted views: the
minimiser of the paper's mean and σ alignment terms when the data term is zero.
"""

from __future__ import annotations

import itertools

import numpy as np

FLIP_MARGIN = 1e-6  # radians: a best match must beat the identity by this to count
# a flip that matters for interpolation: the relabelling moves the means by more than
# this in total (two near-coincident lobes — one feature split in two — swap for free)
SIGNIFICANT_DEG = 5.0


def view_neighbours(views: np.ndarray, max_angle_deg: float = 26.0) -> list[np.ndarray]:
    """Neighbours of each of the (V, 3) unit views: those within ``max_angle_deg``
    (the frequency-3 icosahedron's neighbours are 20.1–23.8° apart, the next ring
    beyond 35°): 5 or 6 each."""
    cos = views @ views.T
    np.fill_diagonal(cos, -2.0)
    return [np.flatnonzero(row > np.cos(np.radians(max_angle_deg))) for row in cos]


def permutations(n: int) -> np.ndarray:
    """All permutations (N!, N) of N slots, in itertools order (the identity first)."""
    return np.array(list(itertools.permutations(range(n))), np.int64)


def match_cost(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """c(π) (..., N!) of every permutation π (in itertools order) between lobe means
    a (..., N, 3) and b (..., N, 3): Σ_k arccos(a_k · b_π(k))."""
    perms = permutations(a.shape[-2])
    dots = np.clip(a @ np.swapaxes(b, -1, -2), -1.0, 1.0)         # (..., N, N)
    angles = np.arccos(dots)
    k = np.arange(a.shape[-2])
    return angles[..., k, perms].sum(axis=-1)                      # (..., N!)


def is_flip(a: np.ndarray, b: np.ndarray, margin: float = FLIP_MARGIN) -> np.ndarray:
    """Whether the identity is not a best match between a and b (..., N, 3), N ≥ 2:
    another permutation costs ``margin`` radians less."""
    cost = match_cost(a, b)
    return cost[..., 0] > cost.min(axis=-1) + margin


def count_flips(mean: np.ndarray, active: np.ndarray, count: np.ndarray,
                edges: np.ndarray, neighbours: list[np.ndarray]) -> dict[str, int]:
    """Flips among P vertices' lobes ``mean`` (P, V, L, 3) with ``active`` (P, V) (views
    holding data) and lobe counts ``count`` (P,): over the mesh ``edges`` (E, 2) (local
    vertex indices) at every view active at both ends, the first min(count) slots; and
    over the view graph ``neighbours`` within each vertex. Pairs with fewer than 2 lobes
    cannot flip and are not counted. Returns flips, flips by more than
    :data:`SIGNIFICANT_DEG` (``*_flips_5deg``) and pairs checked, of each kind."""
    out = {"vertex_flips": 0, "vertex_flips_5deg": 0, "vertex_pairs": 0,
           "view_flips": 0, "view_flips_5deg": 0, "view_pairs": 0}
    big = np.radians(SIGNIFICANT_DEG)
    for n in (2, 3):
        e = edges[np.minimum(count[edges[:, 0]], count[edges[:, 1]]) == n]
        both = active[e[:, 0]] & active[e[:, 1]]                     # (E, V)
        pair, view = np.nonzero(both)
        if len(pair):
            a, b = mean[e[pair, 0], view, :n], mean[e[pair, 1], view, :n]
            out["vertex_flips"] += int(is_flip(a, b).sum())
            out["vertex_flips_5deg"] += int(is_flip(a, b, big).sum())
            out["vertex_pairs"] += len(pair)
        vertices = np.flatnonzero(count == n)
        for v1, nbs in enumerate(neighbours):
            nbs = nbs[nbs > v1]
            ok = active[vertices, v1][:, None] & active[vertices][:, nbs]   # (P', K)
            p, j = np.nonzero(ok)
            if len(p):
                a, b = mean[vertices[p], v1, :n], mean[vertices[p], nbs[j], :n]
                out["view_flips"] += int(is_flip(a, b).sum())
                out["view_flips_5deg"] += int(is_flip(a, b, big).sum())
                out["view_pairs"] += len(p)
    return out


def _best_permutation(own: np.ndarray, others: list[np.ndarray]) -> np.ndarray | None:
    """The permutation of ``own`` (N, 3) minimising the summed cost to ``others`` (each
    (N, 3)), or None without others. Ties keep the identity (itertools order)."""
    if not others:
        return None
    cost = match_cost(np.stack(others), np.broadcast_to(own, (len(others),) + own.shape))
    return permutations(own.shape[0])[int(np.argmin(cost.sum(axis=0)))]


def vertex_permutation(own: np.ndarray, others: list[tuple[np.ndarray, np.ndarray]]
                       ) -> np.ndarray | None:
    """One slot permutation π (N,) for all views of a vertex with lobe means ``own``
    (V, N, 3), minimising Σ over ``others`` — (their means (V, N, 3), the views both
    see (V,) bool) — and over those views of Σ_k angle(other_k, own_π(k)); apply as
    own[:, π]. None when no view is shared; the identity unless another permutation is
    better by :data:`FLIP_MARGIN`."""
    pairs = [(m[shared], own[shared]) for m, shared in others if shared.any()]
    if not pairs:
        return None
    cost = match_cost(np.concatenate([a for a, _ in pairs]),
                      np.concatenate([b for _, b in pairs])).sum(axis=0)
    best = int(np.argmin(cost))
    return permutations(own.shape[1])[best if cost[0] > cost[best] + FLIP_MARGIN else 0]


def align_views(mean: np.ndarray, active: np.ndarray, strength: np.ndarray,
                neighbours: list[np.ndarray]) -> np.ndarray:
    """Per view, the slot permutation (V, N) that makes one vertex's lobes ``mean``
    (V, N, 3) consistent over its ``active`` views (V,), walking the view graph
    breadth-first from the view of largest ``strength`` (V,) (e.g. ∫‖T‖²); inactive
    views keep the identity. Apply as mean[v, perm[v]]."""
    v_count, n = mean.shape[:2]
    perm = np.tile(np.arange(n), (v_count, 1))
    if n < 2 or not active.any():
        return perm
    done = np.zeros(v_count, bool)
    start = int(np.argmax(np.where(active, strength, -np.inf)))
    done[start] = True
    queue = [start]
    while queue:
        v = queue.pop(0)
        for u in neighbours[v]:
            if done[u] or not active[u]:
                continue
            others = [mean[w, perm[w]] for w in neighbours[u] if done[w]]
            perm[u] = _best_permutation(mean[u], others)
            done[u] = True
            queue.append(u)
    # active views not reached through active neighbours: their own components
    for v in np.flatnonzero(active & ~done):
        done[v] = True
    return perm


def relax(mean: np.ndarray, active: np.ndarray, count: np.ndarray, vertex_neighbours:
          list[np.ndarray], neighbours: list[np.ndarray], order: np.ndarray,
          sweeps: int) -> tuple[np.ndarray, int]:
    """The relaxation pass (module docstring) on ``mean`` (P, V, L, 3) (and whatever
    per-slot arrays the caller permutes alike): returns per (vertex, view) the slot
    permutation (P, V, L) to apply and the number of sweeps that changed a label.
    ``vertex_neighbours``: local neighbour indices of each vertex; ``order``: the flood
    order; only the first ``count`` slots of a vertex are permuted."""
    p_count, v_count, lobes = mean.shape[:3]
    perm = np.tile(np.arange(lobes), (p_count, v_count, 1))
    current = mean.copy()
    changed_sweeps = 0
    for _ in range(sweeps):
        changed = False
        for p in order:
            n = int(count[p])
            if n < 2:
                continue
            # the vertex as a whole against its neighbours, summed over shared views
            best = vertex_permutation(current[p, :, :n], [
                (current[q, :, :n], active[p] & active[q]) for q in vertex_neighbours[p]
                if count[q] >= n])
            if best is not None and np.any(best != np.arange(n)):
                current[p, :, :n] = current[p][:, best]
                perm[p, :, :n] = perm[p][:, best]
                changed = True
            # then each view against its neighbouring views and vertices
            for v in np.flatnonzero(active[p]):
                others = [current[p, u, :n] for u in neighbours[v] if active[p, u]]
                others += [current[q, v, :n] for q in vertex_neighbours[p]
                           if active[q, v] and count[q] >= n]
                best = _best_permutation(current[p, v, :n], others)
                if best is None or np.all(best == np.arange(n)):
                    continue
                current[p, v, :n] = current[p, v, best]
                perm[p, v, :n] = perm[p, v, best]
                changed = True
        if not changed:
            break
        changed_sweeps += 1
    return perm, changed_sweeps


def fill_views(mean: np.ndarray, sharpness: np.ndarray, filled: np.ndarray,
               neighbours: list[np.ndarray], fallback_mean: np.ndarray,
               fallback_sharpness: float) -> tuple[np.ndarray, np.ndarray]:
    """Means (V, L, 3) and sharpnesses (V, L) of one vertex with the views not ``filled``
    (V,) set from their filled neighbours, walking outwards (module docstring); with no
    filled view at all, ``fallback_mean`` (V, 3) and ``fallback_sharpness`` in every
    slot."""
    mean, sharpness, filled = mean.copy(), sharpness.copy(), filled.copy()
    if not filled.any():
        mean[:] = fallback_mean[:, None]
        sharpness[:] = fallback_sharpness
        return mean, sharpness
    while not filled.all():
        ring = [v for v in np.flatnonzero(~filled) if filled[neighbours[v]].any()]
        for v in ring:
            nbs = neighbours[v][filled[neighbours[v]]]
            m = mean[nbs].sum(axis=0)
            norm = np.linalg.norm(m, axis=-1, keepdims=True)
            # opposite neighbour means (rare): keep the first neighbour's
            mean[v] = np.where(norm > 1e-9, m / np.maximum(norm, 1e-300), mean[nbs[0]])
            sharpness[v] = np.exp(np.log(sharpness[nbs]).mean(axis=0))
        filled[ring] = True
    return mean, sharpness

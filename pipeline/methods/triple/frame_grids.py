"""Grids of local shading frames and of view directions, with their interpolation
(method triple, paper 004 §3.2 and §5).

**Local frames.** A shading frame is the rotation R whose columns are the tangent t,
the bitangent b = n × t and the normal n (world coordinates); local coordinates are
ω_local = Rᵀ ω_world, as :func:`pipeline.math.brdf.to_local`. Lighting cannot be
rotated in the wavelet basis, so the environment map is resampled in a grid of frames
and each shading point interpolates the nearest ones (paper 004: 32 × 16 × 32). The
grid is over ZYZ Euler angles about the world's +y pole (the environment map's pole),
with A = +z and B = +x completing it (A × B = +y)::

    R(φ, θ, ψ) = M · R_P(φ) · R_B'(θ) · R_P'(ψ),   M = [A | B | P]

i.e. in (A, B, P) coordinates Rz(φ) Ry(θ) Rz(ψ): the normal is
n = sin θ cos φ A + sin θ sin φ B + cos θ P, and ψ turns the tangent about n from the
reference tangent Rz(φ) Ry(θ) e_x. θ takes ``n_theta`` values from 0 to π, both poles
included (a floor's normal +y is exactly a grid row); φ and ψ take ``n_phi``,
``n_psi`` values over [0, 2π) and wrap. At the poles only φ + ψ matters, and the
Euler angles computed for a normal there put φ = 0, which the grid holds exactly.

**View directions.** A BRDF table holds a function of ω_i for each local view ω_o on
a grid over (θ_o, φ_o): θ_o takes ``n_theta`` values from 0 (normal view) to π/2
(grazing), φ_o ``n_phi`` values over [0, 2π), wrapping (paper 004: 128 × 64).

Interpolation is multilinear in the grid coordinates (8 frames, 4 views), its weights
summing to 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

POLE_BASIS = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]).T  # [A | B | P]


def _rz(angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    zero, one = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, -s, zero], -1), np.stack([s, c, zero], -1),
                     np.stack([zero, zero, one], -1)], -2)


def _ry(angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    zero, one = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, zero, s], -1), np.stack([zero, one, zero], -1),
                     np.stack([-s, zero, c], -1)], -2)


def euler_frame(phi: np.ndarray, theta: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """Frames R (..., 3, 3), columns (t, b, n) in world coordinates, of Euler angles
    (radians)."""
    phi, theta, psi = np.broadcast_arrays(*(np.asarray(x, np.float64) for x in (phi, theta, psi)))
    return POLE_BASIS @ _rz(phi) @ _ry(theta) @ _rz(psi)


def euler_angles(normal: np.ndarray, tangent: np.ndarray) -> tuple[np.ndarray, ...]:
    """(φ, θ, ψ) (...,) of the frames with unit ``normal`` and unit ``tangent`` ⊥ normal
    (..., 3): φ, ψ ∈ [0, 2π), θ ∈ [0, π]; φ = 0 where the normal is a pole."""
    n = np.asarray(normal, np.float64) @ POLE_BASIS
    t = np.asarray(tangent, np.float64) @ POLE_BASIS
    theta = np.arccos(np.clip(n[..., 2], -1.0, 1.0))
    at_pole = np.hypot(n[..., 0], n[..., 1]) < 1e-9
    phi = np.where(at_pole, 0.0, np.mod(np.arctan2(n[..., 1], n[..., 0]), 2 * np.pi))
    reference = _rz(phi) @ _ry(theta)  # columns: reference tangent, bitangent, normal
    psi = np.arctan2(np.einsum("...i,...i->...", t, reference[..., :, 1]),
                     np.einsum("...i,...i->...", t, reference[..., :, 0]))
    return phi, theta, np.mod(psi, 2 * np.pi)


def _linear(x: np.ndarray, count: int, wrap: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lower and upper grid indices and the upper weight of grid coordinates ``x``
    (in units of the spacing)."""
    if wrap:
        lo = np.floor(x)
        frac = x - lo
        lo = np.mod(lo.astype(np.int64), count)
        return lo, np.mod(lo + 1, count), frac
    x = np.clip(x, 0.0, count - 1)
    lo = np.minimum(np.floor(x).astype(np.int64), count - 2)
    return lo, lo + 1, x - lo


@dataclass(frozen=True)
class FrameGrid:
    """The grid of local frames: ``n_phi`` × ``n_theta`` × ``n_psi`` entries, entry
    (j, i, k) at index (j · n_theta + i) · n_psi + k."""

    n_phi: int = 32
    n_theta: int = 16
    n_psi: int = 32

    @property
    def size(self) -> int:
        return self.n_phi * self.n_theta * self.n_psi

    def angles(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(φ, θ, ψ) of every entry, each (size,), in index order."""
        phi = 2 * np.pi * np.arange(self.n_phi) / self.n_phi
        theta = np.pi * np.arange(self.n_theta) / (self.n_theta - 1)
        psi = 2 * np.pi * np.arange(self.n_psi) / self.n_psi
        grids = np.meshgrid(phi, theta, psi, indexing="ij")
        return tuple(g.reshape(-1) for g in grids)

    def frames(self) -> np.ndarray:
        """Frames (size, 3, 3) of every entry."""
        return euler_frame(*self.angles())

    def weights(self, normal: np.ndarray, tangent: np.ndarray, turn: float = 0.0
                ) -> tuple[np.ndarray, np.ndarray]:
        """The 8 entries (..., 8) around each frame and their trilinear weights (..., 8).

        ``turn`` (radians) looks the frames up as if the world were turned by −turn
        about the +y pole: a function baked per frame, L_F(ω) = L(F ω), then gives
        L(R_y(−turn) F ω) — the environment map turned by +turn — because
        R_y(−turn) · F(φ, θ, ψ) = F(φ − turn, θ, ψ)."""
        phi, theta, psi = euler_angles(normal, tangent)
        phi = phi - turn
        j0, j1, wj = _linear(phi * self.n_phi / (2 * np.pi), self.n_phi, wrap=True)
        i0, i1, wi = _linear(theta * (self.n_theta - 1) / np.pi, self.n_theta, wrap=False)
        k0, k1, wk = _linear(psi * self.n_psi / (2 * np.pi), self.n_psi, wrap=True)
        entries, weights = [], []
        for j, a in ((j0, 1 - wj), (j1, wj)):
            for i, b in ((i0, 1 - wi), (i1, wi)):
                for k, c in ((k0, 1 - wk), (k1, wk)):
                    entries.append((j * self.n_theta + i) * self.n_psi + k)
                    weights.append(a * b * c)
        return np.stack(entries, -1), np.stack(weights, -1)


@dataclass(frozen=True)
class ViewGrid:
    """The grid of local view directions: ``n_phi`` × ``n_theta`` entries, entry (j, i)
    at index j · n_theta + i."""

    n_phi: int = 128
    n_theta: int = 64

    @property
    def size(self) -> int:
        return self.n_phi * self.n_theta

    def directions(self) -> np.ndarray:
        """Unit local ω_o (size, 3) of every entry."""
        phi = 2 * np.pi * np.arange(self.n_phi) / self.n_phi
        theta = 0.5 * np.pi * np.arange(self.n_theta) / (self.n_theta - 1)
        p, t = (g.reshape(-1) for g in np.meshgrid(phi, theta, indexing="ij"))
        return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)

    def weights(self, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The 4 entries (..., 4) around each local unit ω_o (..., 3) (below the horizon:
        clamped to grazing) and their bilinear weights (..., 4)."""
        wo = np.asarray(wo, np.float64)
        theta = np.arccos(np.clip(wo[..., 2], 0.0, 1.0))
        phi = np.mod(np.arctan2(wo[..., 1], wo[..., 0]), 2 * np.pi)
        j0, j1, wj = _linear(phi * self.n_phi / (2 * np.pi), self.n_phi, wrap=True)
        i0, i1, wi = _linear(theta * (self.n_theta - 1) / (0.5 * np.pi), self.n_theta,
                             wrap=False)
        entries = [j * self.n_theta + i for j in (j0, j1) for i in (i0, i1)]
        weights = [a * b for a in (1 - wj, wj) for b in (1 - wi, wi)]
        return np.stack(entries, -1), np.stack(weights, -1)

"""Grids of local frames and view directions (pipeline/methods/triple/frame_grids.py)."""

from __future__ import annotations

import numpy as np

from pipeline.math.brdf import to_local
from pipeline.methods.triple.frame_grids import FrameGrid, ViewGrid, euler_angles, euler_frame

ROUNDING = 1e-12


def random_angles(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0, 2 * np.pi, n), np.arccos(rng.uniform(-1, 1, n)), \
        rng.uniform(0, 2 * np.pi, n)


def test_euler_frames_are_right_handed_shading_frames():
    frames = euler_frame(*random_angles(500))
    assert np.abs(frames @ frames.transpose(0, 2, 1) - np.eye(3)).max() < ROUNDING
    t, b, n = frames[..., 0], frames[..., 1], frames[..., 2]
    assert np.abs(np.cross(n, t) - b).max() < ROUNDING  # the frame of brdf.to_local
    v = np.random.default_rng(1).normal(size=(500, 3))
    assert np.abs(to_local(v, n, t) - np.einsum("nij,ni->nj", frames, v)).max() < ROUNDING
    # θ = 0 is the world's +y pole
    assert np.allclose(euler_frame(1.0, 0.0, 0.5)[:, 2], [0.0, 1.0, 0.0])


def test_euler_angles_invert_euler_frame():
    phi, theta, psi = random_angles(500)
    frames = euler_frame(phi, theta, psi)
    found = euler_angles(frames[..., 2], frames[..., 0])
    assert np.abs(found[0] - phi).max() < 1e-9
    assert np.abs(found[1] - theta).max() < 1e-9
    assert np.abs(np.angle(np.exp(1j * (found[2] - psi)))).max() < 1e-9
    # at a pole φ is 0 and ψ takes the whole turn
    up = euler_frame(0.7, 0.0, 0.2)
    assert np.allclose(euler_frame(*euler_angles(up[:, 2], up[:, 0])), up)


def test_frame_grid_interpolation_hits_entries_and_converges():
    grid = FrameGrid(16, 9, 16)
    frames = grid.frames()
    entries, weights = grid.weights(frames[..., 2], frames[..., 0])
    assert np.allclose(weights.sum(-1), 1.0)
    best = entries[np.arange(grid.size), np.argmax(weights, -1)]
    assert np.abs(frames[best] - frames).max() < 1e-9  # every entry finds itself
    assert weights.max(-1).min() > 1 - 1e-9

    def smooth(f: np.ndarray) -> np.ndarray:  # a smooth function of the frame
        return np.sin(f[..., 0, 0] + 2 * f[..., 1, 2]) + f[..., 2, 1] * f[..., 0, 1]

    probe = euler_frame(*random_angles(2000, 3))
    errors = []
    for size in ((16, 9, 16), (32, 17, 32)):
        g = FrameGrid(*size)
        e, w = g.weights(probe[..., 2], probe[..., 0])
        errors.append(np.abs(np.sum(w * smooth(g.frames())[e], -1) - smooth(probe)).max())
    assert errors[1] < 0.35 * errors[0]  # second order: ≈ 1/4 for half the spacing


def test_view_grid_interpolation():
    grid = ViewGrid(32, 16)
    d = grid.directions()
    assert np.allclose(np.linalg.norm(d, axis=-1), 1.0) and d[:, 2].min() > -ROUNDING
    entries, weights = grid.weights(d)
    assert np.allclose(weights.sum(-1), 1.0)
    best = entries[np.arange(grid.size), np.argmax(weights, -1)]
    assert np.abs(d[best] - d).max() < 1e-9
    below = grid.weights(np.array([0.6, 0.0, -0.8]))  # clamped to grazing
    assert np.allclose(d[below[0][np.argmax(below[1])]], [1.0, 0.0, 0.0], atol=1e-9)


def test_a_turn_about_the_pole_shifts_phi():
    """R_y(−α) F(φ, θ, ψ) = F(φ − α, θ, ψ): turning the lookup by a whole grid step moves
    every frame's entries one φ column."""
    grid = FrameGrid(16, 9, 16)
    frames = euler_frame(*random_angles(200, 5))
    step = 2 * np.pi / grid.n_phi
    e0, w0 = grid.weights(frames[..., 2], frames[..., 0])
    e1, w1 = grid.weights(frames[..., 2], frames[..., 0], turn=3 * step)
    shifted = ((e0 // (grid.n_theta * grid.n_psi) - 3) % grid.n_phi) * grid.n_theta * grid.n_psi \
        + e0 % (grid.n_theta * grid.n_psi)
    order0, order1 = np.argsort(shifted, axis=1), np.argsort(e1, axis=1)
    assert np.array_equal(np.take_along_axis(shifted, order0, 1), np.take_along_axis(e1, order1, 1))
    assert np.allclose(np.take_along_axis(w0, order0, 1), np.take_along_axis(w1, order1, 1))
    # and the rotation identity itself
    a = 0.7
    ry = np.array([[np.cos(-a), 0, np.sin(-a)], [0, 1, 0], [-np.sin(-a), 0, np.cos(-a)]])
    phi, theta, psi = random_angles(50, 6)
    assert np.allclose(ry @ euler_frame(phi, theta, psi), euler_frame(phi - a, theta, psi))

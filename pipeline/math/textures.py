"""Scalar textures sampled bilinearly, and the bump-mapped normal (paper 004 §4.2).

**Texture coordinates.** A texture is an image of H rows × W columns of values (row 0
at the top). Texture coordinates (u, v) cover the image once over [0, 1]²: u runs
left to right, v bottom to top, and texel (i, j) (row i, column j) is centred at
u = (j + ½)/W, v = 1 − (i + ½)/H. In continuous texel units x = u·W − ½ (columns),
y = (1 − v)·H − ½ (rows), texel centres sit at integers.

**Bilinear sampling.** h(x, y) = Σ of the four texels around (x, y) weighted by
(1 − fx)(1 − fy), fx(1 − fy), (1 − fx)fy, fx·fy. ``wrap="repeat"`` tiles the image
(indices modulo W and H: a texture repeats every unit of u and v); ``"clamp"`` holds
the edge texels beyond the outermost centres. Its derivatives are those of the bilinear
patch (exact on a linear ramp, piecewise constant across texels):

    ∂h/∂u = W · [(1 − fy)(h₀₁ − h₀₀) + fy (h₁₁ − h₁₀)]
    ∂h/∂v = −H · [(1 − fx)(h₁₀ − h₀₀) + fx (h₁₁ − h₀₁)]   (rows run against v)

(on a clamped edge the patch is flat: the derivative across it is 0).

**Bump mapping.** A height map displaces the surface along its normal n by
d(p) = height · h(u(p), v(p)) (scene units). To first order (Blinn 1978, dropping the
curvature terms), the displaced surface's normal is

    n' = normalize(n − ∇_s d),   ∇_s d = height · (∂h/∂u ∇u + ∂h/∂v ∇v) projected on
                                  the tangent plane (⊥ n),

with ∇u, ∇v the surface gradients of the texture coordinates (world vectors, per scene
unit). A ramp of slope s (scene units of height per scene unit along the surface) tilts
the normal by arctan(s) away from the rising side; a flat map leaves n unchanged.

No project imports (a math module).
"""

from __future__ import annotations

import numpy as np

WRAPS = ("repeat", "clamp")


def _axis(coordinate: np.ndarray, size: int, wrap: str
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Lower and upper texel indices along one axis, the upper weight, and 1 where the
    patch varies along the axis (0 on a clamped edge)."""
    if wrap == "repeat":
        lo = np.floor(coordinate)
        frac = coordinate - lo
        lo = np.mod(lo.astype(np.int64), size)
        return lo, np.mod(lo + 1, size), frac, np.ones_like(frac)
    inside = (coordinate > 0.0) & (coordinate < size - 1.0)
    c = np.clip(coordinate, 0.0, size - 1.0)
    lo = np.minimum(np.floor(c).astype(np.int64), max(size - 2, 0))
    hi = np.minimum(lo + 1, size - 1)
    return lo, hi, c - lo, inside.astype(np.float64)


def sample(texture: np.ndarray, uv: np.ndarray, wrap: str = "repeat"
           ) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear values (N,) of ``texture`` (H, W) at texture coordinates ``uv`` (N, 2),
    and their derivatives (N, 2) = (∂h/∂u, ∂h/∂v) (see the module docstring)."""
    height, width = texture.shape
    uv = np.asarray(uv, np.float64)
    x = uv[:, 0] * width - 0.5
    y = (1.0 - uv[:, 1]) * height - 0.5
    x0, x1, fx, vary_x = _axis(x, width, wrap)
    y0, y1, fy, vary_y = _axis(y, height, wrap)
    h00, h01 = texture[y0, x0], texture[y0, x1]
    h10, h11 = texture[y1, x0], texture[y1, x1]
    value = (1 - fy) * ((1 - fx) * h00 + fx * h01) + fy * ((1 - fx) * h10 + fx * h11)
    du = width * vary_x * ((1 - fy) * (h01 - h00) + fy * (h11 - h10))
    dv = -height * vary_y * ((1 - fx) * (h10 - h00) + fx * (h11 - h01))
    return value, np.stack([du, dv], 1)


def uv_gradients(vertices: np.ndarray, uv: np.ndarray, faces: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Per face the surface gradients ∇u, ∇v (F, 3) of its linear uv mapping: the
    vectors g in the face's plane with g·e₁ = Δ₁, g·e₂ = Δ₂ for its edges e₁ = p₁ − p₀,
    e₂ = p₂ − p₀ and the coordinate's differences Δ along them (zero for a degenerate
    face)."""
    p = np.asarray(vertices, np.float64)[faces]
    t = np.asarray(uv, np.float64)[faces]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    a, b, c = (np.sum(x * y, 1) for x, y in ((e1, e1), (e1, e2), (e2, e2)))
    det = a * c - b * b
    ok = det > 1e-30 * np.maximum(a * c, 1e-300)
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    out = []
    for k in (0, 1):
        d1, d2 = t[:, 1, k] - t[:, 0, k], t[:, 2, k] - t[:, 0, k]
        alpha = (c * d1 - b * d2) * inv  # g = α e₁ + β e₂, Gram system solved
        beta = (a * d2 - b * d1) * inv
        out.append(alpha[:, None] * e1 + beta[:, None] * e2)
    return out[0], out[1]


def bumped_normal(normal: np.ndarray, gradient: np.ndarray) -> np.ndarray:
    """Unit normals (N, 3) of a surface with unit ``normal`` (N, 3) displaced along it
    by a height whose world gradient is ``gradient`` (N, 3), scene units per scene unit:
    normalize(n − (g − (g·n) n))."""
    tangential = gradient - np.sum(gradient * normal, 1, keepdims=True) * normal
    n = normal - tangential
    return n / np.linalg.norm(n, axis=1, keepdims=True)

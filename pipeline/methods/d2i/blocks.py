"""Transport rows across blocks of neighbours (d2i's D and Ms;
pipeline/methods/d2i/stages/truncate.py).

Neighbouring pixels have nearly the same transport rows: a pixel's D row is the smooth
geometry term to every gather sample, cut by visibility, and the pixel beside it sees
nearly the same; so do neighbouring gather samples' Ms rows (the gather stage orders
them along a space-filling curve). Paper 000 cuts each row alone. Here the rows of a
block of n neighbours are first replaced by their Haar combinations across the block —
the block's mean row and n − 1 difference rows (pipeline/math/haar.py, the same
orthonormal transform as along a row). In a smooth region the difference rows are small,
and a budget of coefficients shared by the block goes to the mean row, which then keeps
many more coefficients than one row could.

With the transform B (orthonormal, n × n) and the block's rows R (n, N):
(B R) l = B (R l), so the renderer multiplies the stored rows with the radiance vector
as before and applies Bᵀ to each block's n products — n multiply-adds per item
(:func:`unblock`, kernels/d2i/d2i.cl ``unblock``) — to get each item's R l. Dropped
coefficients still err by their energy alone (B is orthonormal), now counted over the
block.

Blocks: Ms's are runs of n consecutive gather samples (B = haar.matrix(n)); D's are
b × b pixel squares (n = b², B = W ⊗ W): pixel (x, y) is slot s = (y mod b)·b + (x mod
b) of block (⌊y/b⌋)·⌈width/b⌉ + ⌊x/b⌋; a block on the image's right or bottom edge has
slots for pixels outside the image, whose rows are zero.
"""

from __future__ import annotations

from functools import cache

import numpy as np

from pipeline.math.haar import matrix


@cache
def block_transform(block: int) -> np.ndarray:
    """B (b², b²) float64, the orthonormal 2D Haar transform of a b × b pixel block:
    B[i·b + j, y·b + x] = W[i, y] W[j, x] (the tensor product W ⊗ W, W = haar.matrix(b));
    row 0 is the block's mean (times b), the rest its differences at every scale."""
    w = matrix(block)
    return np.kron(w, w)


def pixel_blocks(pixel: np.ndarray, width: int, block: int) -> tuple[np.ndarray, np.ndarray]:
    """(block id, slot) of each pixel id y·width + x (int64 arrays)."""
    y, x = np.divmod(np.asarray(pixel, np.int64), width)
    return (y // block) * (-(-width // block)) + x // block, (y % block) * block + x % block


def unblock(products: np.ndarray, block_of: np.ndarray, slot: np.ndarray,
            transform: np.ndarray) -> np.ndarray:
    """Per item i (pixel or gather sample) the product of its own row, from the products
    of the block rows (blocks · n, ...) in block-row order (block · n + transformed row):
    Σ_q transform[q, slot[i]] · products[block_of[i] · n + q], transform (n × n)
    orthonormal (:func:`block_transform`, haar.matrix). The NumPy twin of
    kernels/d2i/d2i.cl ``unblock``."""
    n = len(transform)
    grouped = products.reshape(-1, n, *products.shape[1:])[block_of]  # (items, n, ...)
    return np.einsum("iq,iq...->i...", transform[:, slot].T, grouped)

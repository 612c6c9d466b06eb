"""Frames as the viewer sends them: tone-mapped 8-bit sRGB (the PNG previews' mapping,
pipeline/images.py ``srgb_encode``, bit for bit) compressed as JPEG, WebP or PNG, or the
linear frame as float16 for tone mapping in the page (decision 0043 measures each)."""

from __future__ import annotations

import io

import numpy as np

from pipeline.images import srgb_encode

FORMATS = {"jpeg": "image/jpeg", "webp": "image/webp", "png": "image/png",
           "f16": "application/octet-stream"}
DEFAULT_FORMAT = "jpeg"
QUALITY = {"jpeg": 90, "webp": 85}


def tone_map(rgb: np.ndarray, exposure: float = 0.0) -> np.ndarray:
    """Linear ``rgb`` (H, W, 3) × 2^``exposure`` as 8-bit sRGB (H, W, 3) uint8: the
    bytes of ``prt render``'s PNG preview with ``--exposure`` (the same function,
    pipeline/images.py ``write_png``)."""
    return np.round(srgb_encode(rgb, 2.0 ** exposure) * 255.0).astype(np.uint8)


def encode(rgb: np.ndarray, fmt: str, exposure: float = 0.0) -> bytes:
    """``rgb`` encoded as ``fmt`` (:data:`FORMATS`); float16 is linear, row-major RGB."""
    from PIL import Image

    if fmt == "f16":
        return np.ascontiguousarray(rgb, np.float16).tobytes()
    image = Image.fromarray(tone_map(rgb, exposure), "RGB")
    buffer = io.BytesIO()
    if fmt == "jpeg":
        image.save(buffer, format="JPEG", quality=QUALITY["jpeg"])
    elif fmt == "webp":
        image.save(buffer, format="WEBP", quality=QUALITY["webp"], method=0)
    elif fmt == "png":
        image.save(buffer, format="PNG", compress_level=1)
    else:
        raise ValueError(f"unknown frame format {fmt!r}")
    return buffer.getvalue()


def difference(rgb: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """The relative difference per pixel |frame − reference| / (reference + 0.01 ×
    its mean), as a linear grey image where 1 (white) is 100 % (for the page's
    difference view; tone-mapped like a frame at exposure 0)."""
    lum = reference.mean(axis=2, keepdims=True)
    rel = np.abs(rgb - reference).mean(axis=2, keepdims=True) / (lum + 0.01 * lum.mean()
                                                                 + 1e-12)
    return np.repeat(np.clip(rel, 0, 1), 3, axis=2).astype(np.float32)

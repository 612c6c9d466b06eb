"""Image error metrics against a reference.

Images are (height, width, 3) linear RGB radiance. ``mask`` arguments (height, width)
select the pixels that count (default: all).

* relative RMSE ‖I − R‖₂ / ‖R‖₂ over the selected pixels and all channels (the headline);
* PSNR in dB of the tonemapped images, tonemap(x) = sRGB(clip(x · exposure, 0, 1)) with
  ``exposure`` 1 (``pipeline.images.srgb_encode``, as the PNG previews), peak 1;
* HDR-FLIP (NVIDIA's ꟻLIP, PyPI ``flip-evaluator``) mean error when installed, else None;
* per-pixel relative error |I − R|₂ / |R|₂ (with a floor) for heat maps.
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.images import srgb_encode


def _select(image: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    a = np.asarray(image, np.float64)
    return a if mask is None else a[np.asarray(mask, bool)]


def relative_rmse(image: np.ndarray, reference: np.ndarray,
                  mask: np.ndarray | None = None) -> float:
    """‖I − R‖₂ / ‖R‖₂ over the pixels in ``mask`` and all channels."""
    i, r = _select(image, mask), _select(reference, mask)
    norm = math.sqrt(float(np.sum(r * r)))
    return math.sqrt(float(np.sum((i - r) ** 2))) / norm if norm > 0 else math.inf


def psnr(image: np.ndarray, reference: np.ndarray, exposure: float = 1.0,
         mask: np.ndarray | None = None) -> float:
    """PSNR (dB, peak 1) between the sRGB-tonemapped images; inf when identical."""
    mse = float(np.mean((_select(srgb_encode(image, exposure), mask)
                         - _select(srgb_encode(reference, exposure), mask)) ** 2))
    return math.inf if mse == 0 else -10.0 * math.log10(mse)


def hdr_flip(image: np.ndarray, reference: np.ndarray) -> float | None:
    """Mean HDR-FLIP error (0 = identical), or None when ``flip_evaluator`` is absent."""
    try:
        import flip_evaluator
    except ImportError:
        return None
    def prepared(a: np.ndarray) -> np.ndarray:  # HDR-FLIP takes non-negative values
        return np.ascontiguousarray(np.maximum(a, 0.0), np.float32)

    _, mean, _ = flip_evaluator.evaluate(prepared(reference), prepared(image), "HDR")
    return float(mean)


def error_map(image: np.ndarray, reference: np.ndarray, floor: float = 0.05) -> np.ndarray:
    """Per-pixel relative error |I − R|₂ / max(|R|₂, floor × mean |R|₂) (RGB norms),
    (height, width): the floor keeps near-black pixels from dominating the map."""
    diff = np.linalg.norm(np.asarray(image, np.float64) - reference, axis=-1)
    norm = np.linalg.norm(np.asarray(reference, np.float64), axis=-1)
    return diff / np.maximum(norm, max(floor * float(norm.mean()), 1e-30))


def image_metrics(image: np.ndarray, reference: np.ndarray,
                  mask: np.ndarray | None = None) -> dict[str, float | None]:
    """All metrics as a dict: rel_rmse, psnr_db, flip (None when not installed)."""
    return {"rel_rmse": relative_rmse(image, reference, mask),
            "psnr_db": psnr(image, reference, mask=mask),
            "flip": hdr_flip(image, reference)}
